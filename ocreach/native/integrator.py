"""The adaptive batch integrator :func:`integrate_batch` (Dormand-Prince 8(5,3), one step size per sample).

The step Function of :mod:`ocreach.native.dop853` is generated as C together with the driver loop
over samples and steps, compiled once (:func:`ocreach.native.compile.compile_source`, ``-O2``;
``-O0`` for sources over 400 kB such as spatial order-3 STTs) and cached on disk, then called
through ctypes.  Without a compiler (or with ``OCREACH_JIT=0``) the same algorithm runs as a
NumPy loop over steps, vectorised over samples with ``Function.map``; results agree to round-off,
only slower.  Neither path has a Python loop over samples.

:func:`propagate_segments` (behind :func:`ocreach.dynamics.flow.propagate`) integrates every sample over
a grid of segments with piecewise-constant arguments; with the SIMD-lane driver all segments of
a batch are one C call per thread.  Threads of one batch take samples from a shared counter; a
sample's arithmetic does not depend on its thread or lane, so results are bit-identical for any
thread count.
"""
from __future__ import annotations

import ctypes
import functools
import threading
import warnings
from concurrent.futures import ThreadPoolExecutor

import casadi as ca
import numpy as np

from ocreach import parallel
from ocreach.errors import ProblemError, SolverError, check_count
from ocreach.native.codegen import generate_c
from ocreach.native.compile import (
    COMPILE_ERRORS,
    compile_source,
    jit_enabled,
    load_library,
    opt_flags,
)
from ocreach.native.dop853 import (
    DRIVER_LANES_SRC,
    DRIVER_SRC,
    MAX_FACTOR,
    MIN_FACTOR,
    SAFETY,
    build_step,
    dense_rhs,
)
from ocreach.native.lanes import LANE_FLAGS, LaneCodegenError, lane_sources

#: samples per SIMD step of the native driver (``OCREACH_LANES`` overrides; 1 = scalar driver)
LANES = 8
#: larger expanded steps (order-2/3 STT right-hand sides) use the scalar driver: their lane code
#: takes too long to compile.  First-order STTs of 7-state models (~23,000 instructions, ~8 s
#: at -O1) still get lanes: 8x less CPU than the scalar driver for OLE's partials.
MAX_LANE_INSTRUCTIONS = 30000
#: lane sources above this size are compiled at -O1 (a third less compile time, same speed)
LANE_O1_BYTES = 200_000

__all__ = ["Batch", "integrate_batch", "propagate_segments", "stepper", "tol_vector"]


class _Stepper:
    """Everything integrate_batch needs for one rhs: the native C driver (or None) and the
    CasADi step Function with its mapped versions for the NumPy fallback loop."""

    def __init__(self, rhs: ca.Function):
        self.source = rhs  # keeps the caller's Function alive (ids in _STEPPERS stay unique)
        rhs = dense_rhs(rhs)
        self.rhs = rhs
        self.step = build_step(rhs)
        self.native = None
        self.native_segments = None  # the lane driver's ocreach_propagate (None: scalar driver)
        self.maps: dict = {}
        self._sx: ca.Function | None = None
        self.lane_width = 1  # samples per SIMD step of the native driver (1: scalar driver)
        if jit_enabled():
            try:
                self.native = self._build_native()
            except COMPILE_ERRORS as exc:
                warnings.warn(f"ocreach.native: compiling the DOP853 driver for {rhs.name()} failed "
                              f"({exc}); falling back to CasADi's VM (same results, slower)",
                              RuntimeWarning, stacklevel=4)
        if self.native is None:
            self.step = self.step.expand()

    def _build_native(self):
        lanes = self._lane_width()
        if lanes > 1:
            try:
                fn = self._load(*self._lane_sources(lanes))
                self.lane_width = lanes
                seg = self._dll.ocreach_propagate
                vp, lg = ctypes.c_void_p, ctypes.c_long
                seg.argtypes = [lg, lg, lg, vp, vp, lg, lg, vp, lg, vp, vp, vp, vp, lg, vp, vp, vp, vp,
                                vp]
                seg.restype = ctypes.c_int
                self.native_segments = seg
                return fn
            except LaneCodegenError:
                pass  # an operation without a lane form: the scalar driver below
        gen = generate_c([self.step, self.rhs])
        main = (f"#define STEP {self.step.name()}\n#define RHS {self.rhs.name()}\n"
                "#include \"gen.c\"\n#include \"driver.c\"\n").encode()
        return self._load({"gen.c": gen, "driver.c": DRIVER_SRC.encode(), "main.c": main},
                          opt_flags(len(gen)))

    def _lane_width(self) -> int:
        """SIMD lanes for this step (1 = the scalar driver): ``OCREACH_LANES`` or 8, and 1 for
        steps too large to unroll into lane code (STT right-hand sides)."""
        width = parallel.env_count("OCREACH_LANES")
        width = LANES if width is None else width
        return width if width > 1 and self._sx_size() <= MAX_LANE_INSTRUCTIONS else 1

    def _sx_size(self) -> int:
        """Instructions of the step as one SX Function (expanded only when the rhs is small)."""
        if self._sx is None:
            rhs = self.source
            n_rhs = rhs.n_instructions() if rhs.is_a("SXFunction") else 0
            if 13 * n_rhs > MAX_LANE_INSTRUCTIONS:  # 12 stages + the final derivative
                return MAX_LANE_INSTRUCTIONS + 1
            try:
                self._sx = self.step.expand()
            except RuntimeError:  # not expandable to SX (an MX-only operation): scalar driver
                return MAX_LANE_INSTRUCTIONS + 1
        return self._sx.n_instructions()

    def _lane_sources(self, width: int) -> tuple[dict[str, bytes], tuple[str, ...]]:
        lane = lane_sources([(self._sx, "ocr_lstep"), (self.rhs, "ocr_lrhs")], width)
        main = (f"#define RHS {self.rhs.name()}\n#define OCR_W {width}\n#define LSTEP ocr_lstep\n"
                "#define LRHS ocr_lrhs\n"
                "#include \"gen.c\"\n#include \"lanes.c\"\n#include \"driver.c\"\n").encode()
        flags = LANE_FLAGS if len(lane) <= LANE_O1_BYTES else ("-O1",) + LANE_FLAGS[1:]
        return ({"gen.c": generate_c([self.rhs]), "lanes.c": lane.encode(),
                 "driver.c": DRIVER_LANES_SRC.encode(), "main.c": main}, flags)

    def _load(self, sources: dict[str, bytes], flags: tuple[str, ...]):
        lib = compile_source(f"ocr_{self.rhs.name()}", sources, "main.c", flags)
        dll = load_library(lib)
        fn = dll.ocreach_integrate
        vp = ctypes.c_void_p  # addresses passed as ints: cheaper than ctypes pointer casts
        fn.argtypes = [ctypes.c_long, ctypes.c_long, ctypes.c_long, vp, vp, vp, vp, vp, vp,
                       ctypes.c_long, vp, vp, vp, vp, vp]
        fn.restype = ctypes.c_int
        self._dll = dll  # keep the library loaded
        return fn

    def mapped(self, fun: ca.Function, n: int) -> ca.Function:
        key = (fun.name(), n)
        if key not in self.maps:
            self.maps[key] = fun.map(n, "serial") if n > 1 else fun
        return self.maps[key]


_STEPPERS: dict[int, _Stepper] = {}


def stepper(rhs: ca.Function) -> _Stepper:
    """The compiled (or NumPy-fallback) DOP853 stepper of ``rhs``, built once per Function."""
    st = _STEPPERS.get(id(rhs))
    if st is None or st.source is not rhs:  # the stepper keeps rhs alive, so ids stay unique
        st = _STEPPERS[id(rhs)] = _Stepper(rhs)
    return st


def _as_batch_times(value, n: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ProblemError(f"{name} must be a scalar or an array of shape ({n},); got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ProblemError(f"{name} must be finite; got {arr!r}")
    return arr


def tol_vector(value, n_y: int, name: str) -> np.ndarray:
    """``rtol`` or ``atol`` as a vector of ``n_y`` (scalars: one cached read-only vector)."""
    if isinstance(value, float | int) and not isinstance(value, bool):
        return _tol_scalar(float(value), n_y, name)
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return _tol_scalar(float(arr), n_y, name)
    if arr.shape != (n_y,) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ProblemError(f"{name} must be a finite number >= 0 or an array of {n_y} of them; got {value!r}")
    return np.ascontiguousarray(arr)


@functools.lru_cache(maxsize=64)
def _tol_scalar(value: float, n_y: int, name: str) -> np.ndarray:
    """Tolerance vector of a scalar tolerance, built once per (value, size) (read-only)."""
    if not (np.isfinite(value) and value >= 0):
        raise ProblemError(f"{name} must be a finite number >= 0 or an array of {n_y} of them; got {value!r}")
    arr = np.full(n_y, value)
    arr.flags.writeable = False
    return arr


def integrate_batch(rhs: ca.Function, y0: np.ndarray, t0, t1, args: np.ndarray | None = None, *,
                    rtol: float = 1e-10, atol: float = 1e-12, max_steps: int = 100000,
                    h_init: np.ndarray | None = None, threads: int | None = None) -> np.ndarray:
    """Integrate ``dy/dt = rhs(y, t, a)`` for a batch of samples from ``t0`` to ``t1``.

    Parameters
    ----------
    rhs : CasADi Function ``(y (n_y,), t, a (n_a,)) -> ydot (n_y,)``.
    y0 : initial states, shape ``(N, n_y)``.
    t0, t1 : scalars or ``(N,)`` arrays; ``t1 < t0`` integrates backward in time.
    args : ``(N, n_a)`` (or ``(n_a,)`` shared by all samples), constant over ``[t0, t1]``.
    rtol, atol : tolerances of the error norm (SciPy's DOP853 definition, per component scale
        ``atol + rtol * max(|y|, |y_new|)``).
    max_steps : maximum number of attempted steps per sample.
    h_init : optional ``(N,)`` float array, read and written: entries > 0 are the first step size
        to try (instead of Hairer's starting-step rule); on return every integrated sample's entry
        is the step size the controller proposed for its last step.  Passing the same array to
        consecutive segments (as :func:`ocreach.dynamics.flow.propagate` does) continues each sample's
        step-size sequence across segment boundaries.
    threads : split the batch over this many threads (default :func:`ocreach.parallel.threads`);
        results are identical for every thread count.

    Returns ``y(t1)`` of shape ``(N, n_y)``.  Dormand-Prince 8(5,3) with per-sample adaptive steps
    (see module docstring).  Raises :class:`SolverError` naming the failed samples if ``max_steps``
    is exceeded, the step size underflows or a non-finite value appears.
    """
    if not isinstance(rhs, ca.Function) or rhs.n_in() != 3:
        raise ProblemError(f"rhs must be a casadi.Function (y, t, a) -> ydot; got {rhs!r}")
    n_y, n_a = rhs.size1_in(0), rhs.size1_in(2)
    y0 = np.asarray(y0, dtype=float)
    if y0.ndim != 2 or y0.shape[1] != n_y:
        raise ProblemError(f"y0 must have shape (N, {n_y}); got {y0.shape}")
    if not np.isfinite(y0).all():
        bad = np.flatnonzero(~np.all(np.isfinite(y0), axis=1))
        raise ProblemError(f"y0 must be finite; samples {bad[:10].tolist()} are not")
    n = y0.shape[0]
    if n == 0:
        return y0.copy()
    t0 = _as_batch_times(t0, n, "t0")
    t1 = _as_batch_times(t1, n, "t1")
    if args is None:
        args = np.zeros((n, n_a))
    args = np.asarray(args, dtype=float)
    if args.ndim == 1 and args.shape == (n_a,):
        args = np.broadcast_to(args, (n, n_a))
    if args.shape != (n, n_a):
        raise ProblemError(f"args must have shape ({n}, {n_a}) or ({n_a},); got {args.shape}")
    if not np.isfinite(args).all():
        raise ProblemError("args must be finite")
    max_steps = check_count("max_steps", max_steps, 1)
    rtol_v = tol_vector(rtol, n_y, "rtol")
    atol_v = tol_vector(atol, n_y, "atol")
    if h_init is not None and (not isinstance(h_init, np.ndarray) or h_init.shape != (n,)
                               or h_init.dtype != np.float64 or not h_init.flags.c_contiguous):
        raise ProblemError(f"h_init must be a C-contiguous float64 array of shape ({n},); got "
                           f"{getattr(h_init, 'shape', type(h_init).__name__)}")
    n_threads = parallel.threads() if threads is None else check_count("threads", threads, 1)
    batch = Batch(stepper(rhs), np.array(y0, dtype=float, order="C", copy=True), n_a, rtol_v,
                  atol_v, int(max_steps), n_threads, h_init)
    batch.t0[:], batch.t1[:], batch.A[:] = t0, t1, args
    batch.run()
    return batch.Y


def _fail_message(kind: str, bad: np.ndarray, n: int, t: np.ndarray, t1: np.ndarray) -> str:
    more = " ..." if bad.size > 10 else ""
    return (f"integrate_batch: {kind} for samples {bad[:10].tolist()}{more} (of {n}); "
            f"they stopped at t = {t[bad[:5]].tolist()} of t1 = {t1[bad[:5]].tolist()}")


_STATUS = {1: "max_steps exceeded", 2: "step size underflow (stiff or singular dynamics?)",
           3: "non-finite value of the state or rhs"}

#: a batch is split over threads only in parts of at least ``max(2, THREAD_WORK // n_y)``
#: samples (a thread costs ~50 us; a 4-state sample segment ~1 us, an order-2 STT one ~50 us)
THREAD_WORK = 1024
_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _pool(n: int) -> ThreadPoolExecutor:
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL._max_workers < n:
            _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="ocreach-native")
        return _POOL


class Batch:
    """The arrays of one batch integration, allocated once and re-used over many segments.

    ``Y`` (N, n_y) C-contiguous is advanced in place by :meth:`run` from ``t0`` to ``t1`` (N,)
    with constant arguments ``A`` (N, n_a); the caller fills ``t0``, ``t1``, ``A`` (validated
    values: :func:`integrate_batch` checks them, :func:`ocreach.dynamics.flow.propagate` checks its inputs
    once).  ``H`` carries each sample's step size from one run to the next.  The native call
    gets plain addresses computed here once, so a segment costs one ctypes call per thread.
    """

    def __init__(self, st: _Stepper, Y: np.ndarray, n_a: int, rtol_v: np.ndarray,
                 atol_v: np.ndarray, max_steps: int, threads: int = 1,
                 H: np.ndarray | None = None):
        n, n_y = Y.shape
        self.st, self.Y, self.rtol_v, self.atol_v, self.max_steps = st, Y, rtol_v, atol_v, max_steps
        self.t0, self.t1 = np.zeros(n), np.zeros(n)
        self.A = np.zeros((n, n_a))
        self.H = np.zeros(n) if H is None else H
        self.status = np.zeros(n, dtype=np.intc)
        self.t_reached = np.zeros(n)
        self.n_steps = np.zeros(n, dtype=np.int_)
        arrays = (Y, self.t0, self.t1, self.A)
        self._queue = np.zeros(1, dtype=np.int64)
        self._calls = _parts(_parts_count(n, n_y, threads), self._queue,
                             (n, n_y, n_a, *(arr.ctypes.data for arr in arrays), rtol_v.ctypes.data,
                              atol_v.ctypes.data, max_steps, self.status.ctypes.data,
                              self.t_reached.ctypes.data, self.n_steps.ctypes.data, self.H.ctypes.data))

    def run(self) -> None:
        """Integrate every sample from ``t0`` to ``t1`` (raises :class:`SolverError` naming the
        samples that failed)."""
        st = self.st
        if st.native is None:
            self.Y[:] = _integrate_numpy(st, self.Y, self.t0, self.t1, self.A, self.rtol_v,
                                         self.atol_v, self.max_steps, self.H)
            return
        self._queue[0] = 0
        _check(_run_parts(st.native, self._calls), self.status, self.max_steps, self.t_reached,
               self.t1)


def _parts_count(n: int, n_y: int, threads: int, segments: int = 1) -> int:
    """Threads for a batch: at most ``threads``, each with at least ``max(2, THREAD_WORK //
    n_y)`` sample segments on average."""
    return max(1, min(int(threads), n, n * segments // max(2, THREAD_WORK // n_y)))


def _parts(parts: int, queue: np.ndarray, args: tuple) -> list[tuple]:
    """The driver calls of a batch run by ``parts`` threads: all on the whole batch, taking
    samples from the shared counter ``queue`` (reset to 0 before each run), so a thread that gets
    less CPU (another process on its core) takes fewer samples; one part gets its own counter.
    Each sample's arithmetic does not depend on the thread or lane it ran in."""
    if parts == 1:
        return [(*args, None)]
    return [(*args, queue.ctypes.data)] * parts


def _run_parts(fn, calls: list[tuple]) -> list[int]:
    """``fn(*c)`` for every part ``c``: the first in this thread, the others in the thread pool
    (the C loop runs without the GIL: ctypes releases it; no wake-up of a pool thread for the
    first part, which on a loaded machine can cost a scheduler time slice)."""
    if len(calls) == 1:
        return [fn(*calls[0])]
    futures = [_pool(len(calls) - 1).submit(fn, *c) for c in calls[1:]]
    first = fn(*calls[0])
    return [first] + [f.result() for f in futures]


def _check(rcs: list[int], status: np.ndarray, max_steps: int, t_reached: np.ndarray,
           t1: np.ndarray) -> None:
    """Raise :class:`SolverError` naming the failed samples if a driver part reported any."""
    if min(rcs) < 0:
        raise SolverError("integrate_batch: the native DOP853 driver could not allocate memory")
    if max(rcs) > 0:
        msgs = []
        for code, kind in _STATUS.items():
            bad = np.flatnonzero(status == code)
            if bad.size:
                if code == 1:
                    kind = f"max_steps = {max_steps} exceeded"
                msgs.append(_fail_message(kind, bad, status.size, t_reached, t1))
        raise SolverError("; ".join(msgs))


def propagate_segments(st: _Stepper, X0: np.ndarray, U: np.ndarray, P: np.ndarray,
                       times: np.ndarray, m: int, rtol_v: np.ndarray, atol_v: np.ndarray,
                       max_steps: int, threads: int = 1) -> np.ndarray:
    """States ``(N, len(times), n_y)`` of ``dy/dt = rhs(y, t, [U[:, j // m]; P])`` on each
    segment ``[times[j], times[j+1]]`` from ``X0`` (N, n_y); ``U`` (N, (len(times)-1) / m, n_u),
    ``P`` (N, n_p).  Inputs are the caller's validated values.

    Each sample's last step size carries over to the next segment instead of restarting from
    Hairer's starting-step rule.  The lane driver runs all segments of a sample in one C call
    (no per-segment return to Python; a lane that ends a segment starts the next at once); the
    scalar driver and the NumPy fallback take one :class:`Batch` run per segment, with the same
    arithmetic per sample.  Raises :class:`SolverError` naming failed samples.
    """
    n, n_y = X0.shape
    k = times.size - 1
    nu, n_p = U.shape[2], P.shape[1]
    if st.native_segments is None:
        batch = Batch(st, np.array(X0, dtype=float, order="C"), nu + n_p, rtol_v, atol_v,
                      max_steps, threads)
        batch.A[:, nu:] = P
        Ut = np.ascontiguousarray(np.moveaxis(U, 1, 0))  # (K/m, N, n_u): one block per control
        out = np.empty((times.size,) + batch.Y.shape)  # time-major while filling
        out[0] = batch.Y
        for j in range(k):
            batch.A[:, :nu] = Ut[j // m]
            batch.t0.fill(times[j])
            batch.t1.fill(times[j + 1])
            batch.run()
            out[j + 1] = batch.Y
        return np.ascontiguousarray(np.moveaxis(out, 0, 1))
    X0 = np.ascontiguousarray(X0, dtype=float)
    U = np.ascontiguousarray(U, dtype=float)
    P = np.ascontiguousarray(P, dtype=float)
    G = np.ascontiguousarray(times, dtype=float)
    out = np.empty((n, k + 1, n_y))
    out[:, 0] = X0
    status, t_reached = np.zeros(n, dtype=np.intc), np.zeros(n)
    n_steps, H = np.zeros(n, dtype=np.int_), np.zeros(n)
    queue = np.zeros(1, dtype=np.int64)
    calls = _parts(_parts_count(n, n_y, threads, k), queue,
                   (n, n_y, k, G.ctypes.data, U.ctypes.data, nu, m, P.ctypes.data, n_p,
                    X0.ctypes.data, out.ctypes.data, rtol_v.ctypes.data, atol_v.ctypes.data,
                    max_steps, status.ctypes.data, t_reached.ctypes.data, n_steps.ctypes.data,
                    H.ctypes.data))
    _check(_run_parts(st.native_segments, calls), status, max_steps, t_reached,
           np.full(n, times[-1]))
    return out


def _integrate_numpy(st: _Stepper, y0, t0, t1, args, rtol_v, atol_v, max_steps,
                     h_init=None) -> np.ndarray:
    """The same algorithm as the C driver, vectorised over samples in NumPy (fallback)."""
    n = y0.shape[0]
    rhs = st.rhs
    step = st.mapped(st.step, n)
    rhs_n = st.mapped(rhs, n)

    Y = np.array(y0.T, order="C", copy=True)  # (n_y, N): one column per sample (never alias y0)
    A = np.ascontiguousarray(args.T)
    t = t0.copy()
    direction = np.where(t1 >= t0, 1.0, -1.0)
    span = np.abs(t1 - t0)
    done = span == 0.0

    F = rhs_n(Y, t[None, :], A).full()
    if not np.all(np.isfinite(F)):
        bad = np.flatnonzero(~np.all(np.isfinite(F), axis=0))
        raise SolverError(f"integrate_batch: rhs is not finite at the initial state of samples "
                          f"{bad[:10].tolist()}")
    # initial step (Hairer's algorithm, as SciPy's select_initial_step), vectorised
    scale = atol_v[:, None] + np.abs(Y) * rtol_v[:, None]
    d0 = np.sqrt(np.mean((Y / scale) ** 2, axis=0))
    d1 = np.sqrt(np.mean((F / scale) ** 2, axis=0))
    h0 = np.where((d0 < 1e-5) | (d1 < 1e-5), 1e-6, 0.01 * d0 / np.maximum(d1, 1e-300))
    h0 = np.minimum(h0, np.where(span > 0, span, 1.0))
    Y1 = Y + (h0 * direction)[None, :] * F
    F1 = rhs_n(Y1, (t + h0 * direction)[None, :], A).full()
    d2 = np.sqrt(np.mean(((F1 - F) / scale) ** 2, axis=0)) / h0
    dmax = np.maximum(d1, d2)
    with np.errstate(divide="ignore", invalid="ignore"):
        h1 = np.where(dmax <= 1e-15, np.maximum(1e-6, h0 * 1e-3), (0.01 / dmax) ** (1.0 / 8.0))
    h_abs = np.minimum(100 * h0, h1)
    h_abs = np.where(np.isfinite(h_abs), h_abs, 1e-6)
    if h_init is not None:  # the caller's first step sizes, as the C driver
        h_abs = np.where(h_init > 0, np.minimum(h_init, span), h_abs)
    rejected = np.zeros(n, dtype=bool)

    steps = 0
    while not done.all():
        steps += 1
        active = ~done
        if steps > max_steps:
            bad = np.flatnonzero(active)
            raise SolverError(f"integrate_batch: max_steps = {max_steps} exceeded for samples "
                              f"{bad[:10].tolist()}{' ...' if bad.size > 10 else ''} (of {n}); "
                              f"they reached t = {t[bad[:5]].tolist()} of t1 = {t1[bad[:5]].tolist()}")
        min_step = 10 * np.abs(np.nextafter(t, t + direction) - t)
        tiny = active & (h_abs < min_step)
        if tiny.any():
            bad = np.flatnonzero(tiny)
            raise SolverError(f"integrate_batch: step size underflow for samples {bad[:10].tolist()} "
                              f"at t = {t[bad[:5]].tolist()} (stiff or singular dynamics?)")
        t_new = t + direction * h_abs
        last = active & (direction * (t_new - t1) >= 0)
        if h_init is not None:
            h_init[last] = h_abs[last]
        t_new = np.where(last, t1, t_new)
        h = np.where(active, t_new - t, 0.0)
        Yn, Fn, err = step(Y, F, t[None, :], h[None, :], A, rtol_v, atol_v)
        Yn, Fn, err = Yn.full(), Fn.full(), err.full().ravel()
        finite = np.isfinite(err)
        ok = active & finite & (err < 1.0)
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            fac = SAFETY / np.sqrt(np.sqrt(np.sqrt(err)))  # err ** ERR_EXP as the C driver
        fac_ok = np.where(err == 0.0, MAX_FACTOR, np.minimum(MAX_FACTOR, fac))
        fac_ok = np.where(rejected, np.minimum(1.0, fac_ok), fac_ok)
        fac_bad = np.where(finite, np.maximum(MIN_FACTOR, fac), MIN_FACTOR)
        h_abs = np.where(ok, np.abs(h) * fac_ok, np.where(active, h_abs * fac_bad, h_abs))
        rejected = np.where(active, ~ok, rejected)
        Y[:, ok] = Yn[:, ok]
        F[:, ok] = Fn[:, ok]
        t = np.where(ok, t_new, t)
        done = done | (ok & last)
        if ok.any() and not np.all(np.isfinite(Yn[:, ok])):
            bad = np.flatnonzero(ok & ~np.all(np.isfinite(Yn), axis=0))
            raise SolverError(f"integrate_batch: non-finite state for samples {bad[:10].tolist()} "
                              f"at t = {t[bad[:5]].tolist()}")
    return Y.T.copy()


