"""Trajectories, batches of trajectories, state-transition matrices and tensors.

Integrator
----------
:func:`integrate_batch` is an explicit adaptive Runge-Kutta integrator for batches: the
Dormand-Prince 8(5,3) pair (Hairer, Norsett & Wanner, *Solving ODEs I*, Sec. II.10) with SciPy's
``DOP853`` tableau, error norm, step-size controller and initial-step rule, and one step size per
sample.  One step (12 stages, FSAL derivative, error norm) is a single CasADi Function built from
the right-hand side; it is generated as C together with a small C driver loop over samples and
steps (:mod:`ocreach._dop853_driver`), compiled once with the system C compiler (``cc -O2``; ``-O0`` for
sources over 400 kB such as spatial order-3 STTs, see :func:`_opt_flags`) and
cached on disk (``$OCREACH_CACHE_DIR`` or ``~/.cache/ocreach/jit``, keyed by a hash of the
source), then called through ctypes.  Without a compiler (or with ``OCREACH_JIT=0``) the same
algorithm runs as a NumPy loop over steps, vectorised over samples with ``Function.map``; results
agree to round-off, only slower.  Neither path has a Python loop over samples.

Why not CVODES: its default BDF/Newton is a poor fit for non-stiff orbits.  CVODES Adams with
functional iteration (reltol 1e-10, interpreted right-hand side) took ~49 ms for the order-2 STT
over one NRHO period against ~14 ms here at rtol 1e-12 (similar final-state error, ~1e-11; same
loaded machine), and it needs one integrator call per sample.  CVODES with a compiled
right-hand side was not compared.  The defaults ``rtol = 1e-10``, ``atol = 1e-12`` agree with
SciPy ``DOP853`` at ``rtol = 1e-12`` to ~1e-10 on the DRO test case.

State-transition tensors
------------------------
:func:`stt` integrates the STT equations of Foss et al. Eq. 11 for the augmented dynamics
``z = [x; u]``, ``dz/dt = [f; 0]`` (Eq. 12) on every segment ``[t_k, t_{k+1}]`` of a grid, restarted
from the identity at each ``t_k``, which gives the discrete map of Eq. 13::

    delta x(t_{k+1}) = sum_j 1/j! Phi_k^(j) [delta z(t_k)]^j.

Only the x-rows of the tensors are integrated (the u-rows are ``[0 I]`` and zero).  Phi2 and Phi3
are symmetric in their lower indices, so only the index tuples ``a <= b (<= c)`` are integrated
(for the spatial CR3BP with ``n_z = 9`` this is 45 instead of 81 and 165 instead of 729 columns).
The right-hand side is built symbolically from :meth:`Model.derivative_expressions`; the tensor
contractions of Eq. 11 are written as products of ``f``-derivative matrices with Kronecker
products of Phi columns, so CasADi's sparse SX algebra drops the structural zeros.
The reference trajectory is propagated first (sequential), then the K segments are integrated in
one :func:`integrate_batch` call as K independent samples.
"""
from __future__ import annotations

import hashlib
import itertools
import os
import shutil
import subprocess
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate._ivp import dop853_coefficients as _dop

from ocreach._dop853_driver import DRIVER_SRC
from ocreach.errors import ProblemError, SolverError, check_count
from ocreach.model import Model

__all__ = ["STTResult", "flow_rhs", "integrate_batch", "propagate", "stm", "stt", "stt_rhs"]

# --------------------------------------------------------------------------- DOP853 constants
_NS = _dop.N_STAGES  # 12
_A = _dop.A[:_NS, :_NS]
_B = _dop.B
_C = _dop.C[:_NS]
_E3 = _dop.E3
_E5 = _dop.E5
_ERR_EXP = -1.0 / 8.0  # -1 / (error estimator order + 1), as SciPy's DOP853
_SAFETY, _MIN_FACTOR, _MAX_FACTOR = 0.9, 0.2, 10.0


# --------------------------------------------------------------------------- C compilation
#: What a failed C build raises (no compiler or a failing one: RuntimeError; unwritable cache or a
#: library that will not load: OSError).  Callers fall back to CasADi's VM or NumPy on these and
#: only these, so a programming error in a kernel builder is not hidden behind a warning.
COMPILE_ERRORS: tuple[type[BaseException], ...] = (RuntimeError, OSError)

def c_identifier(name: str) -> str:
    """``name`` with every non-alphanumeric character replaced by ``_`` (``"anon"`` if empty), for
    the names of generated C functions."""
    return "".join(c if c.isalnum() else "_" for c in name) or "anon"


def _jit_enabled() -> bool:
    return os.environ.get("OCREACH_JIT", "1") not in ("0", "false", "no")


def _cache_dir() -> Path:
    root = os.environ.get("OCREACH_CACHE_DIR")
    return Path(root) if root else Path.home() / ".cache" / "ocreach" / "jit"


def _compile_source(name: str, sources: dict[str, bytes], main: str, flags: tuple[str, ...]) -> Path:
    """Compile ``sources`` (file name -> text; ``main`` is the translation unit) into a shared
    library cached on disk under a hash of the sources and flags; return its path."""
    digest = hashlib.sha256()
    for key in sorted(sources):
        digest.update(key.encode() + b"\0" + sources[key] + b"\0")
    digest.update(" ".join(flags).encode())
    cache = _cache_dir()
    cache.mkdir(parents=True, exist_ok=True)
    lib = cache / f"{name}_{digest.hexdigest()[:20]}.so"
    if lib.exists():
        return lib
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if cc is None:
        raise RuntimeError("no C compiler found (set CC)")
    with tempfile.TemporaryDirectory() as tmp:
        for key, text in sources.items():
            Path(tmp, key).write_bytes(text)
        out = Path(tmp, "lib.so")
        proc = subprocess.run([cc, *flags, "-shared", "-fPIC", "-o", str(out), str(Path(tmp, main)),
                               "-lm"], capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{cc} failed: {proc.stderr[-2000:]}")
        part = lib.with_name(f"{lib.name}.{os.getpid()}.part")
        shutil.copyfile(out, part)
        os.replace(part, lib)
    return lib


def _codegen(funs: list[ca.Function]) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        cg = ca.CodeGenerator("gen.c", {"with_header": False})
        for fun in funs:
            cg.add(fun)
        cg.generate(tmp + os.sep)
        return Path(tmp, "gen.c").read_bytes()


# Public names of the C-compilation helpers, for modules that generate their own kernels
# (ocreach.stochastic_mc, ocreach.reach.cut_kernel, the CUT rule cache of ocreach.quadrature).
def jit_enabled() -> bool:
    """True unless C compilation is switched off (environment ``OCREACH_JIT=0``)."""
    return _jit_enabled()


def cache_dir() -> Path:
    """Directory of the on-disk cache of compiled libraries (``OCREACH_CACHE_DIR`` or
    ``~/.cache/ocreach/jit``)."""
    return _cache_dir()


def compile_source(name: str, sources: dict[str, bytes], main: str, flags: tuple[str, ...]) -> Path:
    """Compile C ``sources`` (file name -> bytes; ``main`` is the translation unit) into a shared
    library cached on disk by a hash of sources and flags; returns its path."""
    return _compile_source(name, sources, main, flags)


def generate_c(funs: list[ca.Function]) -> bytes:
    """C source (no header) of the CasADi Functions ``funs``, from CasADi's code generator."""
    return _codegen(funs)


def compile_function(fun: ca.Function, flags: tuple[str, ...] = ("-O2",)) -> ca.Function:
    """Compile ``fun`` to C (cached on disk by source hash) and load it as a CasADi external.

    Returns ``fun`` unchanged (with a warning) if compilation is disabled or fails.
    """
    if not _jit_enabled():
        return fun
    try:
        lib = _compile_source(fun.name(), {"gen.c": _codegen([fun])}, "gen.c", flags)
        return ca.external(fun.name(), str(lib))
    except COMPILE_ERRORS as exc:  # compiler missing or failing: the VM gives the same numbers
        warnings.warn(f"ocreach.flow: compiling {fun.name()} failed ({exc}); "
                      "using CasADi's interpreted VM instead", RuntimeWarning, stacklevel=3)
        return fun


# --------------------------------------------------------------------------- step functions
def _dense_rhs(rhs: ca.Function) -> ca.Function:
    """``rhs`` with a dense output.  A structurally zero derivative (e.g. ``dlam_p/dt = 0`` of a
    double integrator) makes CasADi's generated C write only the non-zeros, which the native
    driver would read as a dense vector of length ``n_y``."""
    if rhs.sparsity_out(0).is_dense():
        return rhs
    y, t, a = (ca.MX.sym(rhs.name_in(i), rhs.sparsity_in(i)) for i in range(3))
    return ca.Function(rhs.name(), [y, t, a], [ca.densify(rhs(y, t, a))],
                       rhs.name_in(), rhs.name_out())


def _build_step(rhs: ca.Function) -> ca.Function:
    """One DOP853 step ``(y, f0, t, h, a, rtol, atol) -> (y_new, f_new, err)``.

    ``err`` is SciPy's DOP853 error norm (Hairer's combined 5th/3rd order estimate);
    a step is accepted when ``err < 1``.  ``h = 0`` returns ``y`` with ``err = 0``.
    """
    n_y = rhs.size1_in(0)
    n_a = rhs.size1_in(2)
    y = ca.MX.sym("y", n_y)
    f0 = ca.MX.sym("f0", n_y)
    t = ca.MX.sym("t")
    h = ca.MX.sym("h")
    a = ca.MX.sym("a", n_a)
    rtol = ca.MX.sym("rtol", n_y)
    atol = ca.MX.sym("atol", n_y)
    K = [f0]
    for s in range(1, _NS):
        dy = sum(float(_A[s, j]) * K[j] for j in range(s) if _A[s, j] != 0.0)
        K.append(rhs(y + h * dy, t + float(_C[s]) * h, a))
    y_new = y + h * sum(float(_B[j]) * K[j] for j in range(_NS))
    f_new = rhs(y_new, t + h, a)
    K.append(f_new)
    scale = atol + ca.fmax(ca.fabs(y), ca.fabs(y_new)) * rtol
    e5 = sum(float(_E5[j]) * K[j] for j in range(_NS + 1) if _E5[j] != 0.0) / scale
    e3 = sum(float(_E3[j]) * K[j] for j in range(_NS + 1) if _E3[j] != 0.0) / scale
    n5 = ca.sumsqr(e5)
    n3 = ca.sumsqr(e3)
    denom = ca.fmax(n5 + 0.01 * n3, 1e-300)
    err = ca.fabs(h) * n5 / ca.sqrt(denom * n_y)
    y_new, f_new = ca.densify(y_new), ca.densify(f_new)
    return ca.Function(f"dop853_{rhs.name()}", [y, f0, t, h, a, rtol, atol], [y_new, f_new, err],
                       ["y", "f0", "t", "h", "a", "rtol", "atol"], ["y_new", "f_new", "err"])


def _opt_flags(source_size: int) -> tuple[str, ...]:
    """Optimisation level: ``-O2`` for ordinary sources; huge generated sources (order-3 STTs of
    the spatial CR3BP, ~1.5 MB of straight-line C) take minutes at -O1/-O2, so they get ``-O0``
    (seconds).  ``OCREACH_JIT_FLAGS`` overrides (space separated)."""
    env = os.environ.get("OCREACH_JIT_FLAGS")
    if env:
        return tuple(env.split())
    return ("-O0",) if source_size > 400_000 else ("-O2",)


class _Stepper:
    """Everything integrate_batch needs for one rhs: the native C driver (or None) and the
    CasADi step Function with its mapped versions for the NumPy fallback loop."""

    def __init__(self, rhs: ca.Function):
        self.source = rhs  # keeps the caller's Function alive (ids in _STEPPERS stay unique)
        rhs = _dense_rhs(rhs)
        self.rhs = rhs
        self.step = _build_step(rhs)
        self.native = None
        self.maps: dict = {}
        if _jit_enabled():
            try:
                self.native = self._build_native()
            except COMPILE_ERRORS as exc:
                warnings.warn(f"ocreach.flow: compiling the DOP853 driver for {rhs.name()} failed "
                              f"({exc}); falling back to CasADi's VM (same results, slower)",
                              RuntimeWarning, stacklevel=4)
        if self.native is None:
            self.step = self.step.expand()

    def _build_native(self):
        import ctypes

        gen = _codegen([self.step, self.rhs])
        main = (f"#define STEP {self.step.name()}\n#define RHS {self.rhs.name()}\n"
                "#include \"gen.c\"\n#include \"driver.c\"\n").encode()
        flags = _opt_flags(len(gen))
        lib = _compile_source(f"ocr_{self.rhs.name()}",
                              {"gen.c": gen, "driver.c": DRIVER_SRC.encode(), "main.c": main},
                              "main.c", flags)
        dll = ctypes.CDLL(str(lib))
        fn = dll.ocreach_integrate
        dp = ctypes.POINTER(ctypes.c_double)
        fn.argtypes = [ctypes.c_long, ctypes.c_long, ctypes.c_long, dp, dp, dp, dp, dp, dp,
                       ctypes.c_long, ctypes.POINTER(ctypes.c_int), dp, ctypes.POINTER(ctypes.c_long)]
        fn.restype = ctypes.c_int
        self._dll = dll  # keep the library loaded
        return fn

    def mapped(self, fun: ca.Function, n: int) -> ca.Function:
        key = (fun.name(), n)
        if key not in self.maps:
            self.maps[key] = fun.map(n, "serial") if n > 1 else fun
        return self.maps[key]


_STEPPERS: dict[int, _Stepper] = {}


def _stepper(rhs: ca.Function) -> _Stepper:
    st = _STEPPERS.get(id(rhs))
    if st is None or st.source is not rhs:  # the stepper keeps rhs alive, so ids stay unique
        st = _STEPPERS[id(rhs)] = _Stepper(rhs)
    return st


# --------------------------------------------------------------------------- integrate_batch
def _as_batch_times(value, n: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ProblemError(f"{name} must be a scalar or an array of shape ({n},); got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ProblemError(f"{name} must be finite; got {arr!r}")
    return arr


def _tol_vector(value, n_y: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n_y, float(arr))
    if arr.shape != (n_y,) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ProblemError(f"{name} must be a finite number >= 0 or an array of {n_y} of them; got {value!r}")
    return arr


def integrate_batch(rhs: ca.Function, y0: np.ndarray, t0, t1, args: np.ndarray | None = None, *,
                    rtol: float = 1e-10, atol: float = 1e-12, max_steps: int = 100000) -> np.ndarray:
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
    if not np.all(np.isfinite(y0)):
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
    if not np.all(np.isfinite(args)):
        raise ProblemError("args must be finite")
    max_steps = check_count("max_steps", max_steps, 1)
    rtol_v = _tol_vector(rtol, n_y, "rtol")
    atol_v = _tol_vector(atol, n_y, "atol")

    st = _stepper(rhs)
    if st.native is not None:
        return _integrate_native(st, y0, t0, t1, args, rtol_v, atol_v, int(max_steps))
    return _integrate_numpy(st, y0, t0, t1, args, rtol_v, atol_v, int(max_steps))


def _fail_message(kind: str, bad: np.ndarray, n: int, t: np.ndarray, t1: np.ndarray) -> str:
    more = " ..." if bad.size > 10 else ""
    return (f"integrate_batch: {kind} for samples {bad[:10].tolist()}{more} (of {n}); "
            f"they stopped at t = {t[bad[:5]].tolist()} of t1 = {t1[bad[:5]].tolist()}")


_STATUS = {1: "max_steps exceeded", 2: "step size underflow (stiff or singular dynamics?)",
           3: "non-finite value of the state or rhs"}


def _integrate_native(st: _Stepper, y0, t0, t1, args, rtol_v, atol_v, max_steps) -> np.ndarray:
    import ctypes

    n, n_y = y0.shape
    Y = np.array(y0, dtype=float, order="C", copy=True)
    A = np.ascontiguousarray(args, dtype=float)
    t0c, t1c = np.ascontiguousarray(t0), np.ascontiguousarray(t1)
    status = np.zeros(n, dtype=np.intc)
    t_reached = np.zeros(n)
    n_steps = np.zeros(n, dtype=np.int_)
    dp = ctypes.POINTER(ctypes.c_double)

    def ptr(a):
        return a.ctypes.data_as(dp)

    rc = st.native(n, n_y, A.shape[1], ptr(Y), ptr(t0c), ptr(t1c), ptr(A), ptr(rtol_v), ptr(atol_v),
                   max_steps, status.ctypes.data_as(ctypes.POINTER(ctypes.c_int)), ptr(t_reached),
                   n_steps.ctypes.data_as(ctypes.POINTER(ctypes.c_long)))
    if rc < 0:
        raise SolverError("integrate_batch: the native DOP853 driver could not allocate memory")
    if rc > 0:
        msgs = []
        for code, kind in _STATUS.items():
            bad = np.flatnonzero(status == code)
            if bad.size:
                if code == 1:
                    kind = f"max_steps = {max_steps} exceeded"
                msgs.append(_fail_message(kind, bad, n, t_reached, t1))
        raise SolverError("; ".join(msgs))
    return Y


def _integrate_numpy(st: _Stepper, y0, t0, t1, args, rtol_v, atol_v, max_steps) -> np.ndarray:
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
        t_new = np.where(last, t1, t_new)
        h = np.where(active, t_new - t, 0.0)
        Yn, Fn, err = step(Y, F, t[None, :], h[None, :], A, rtol_v, atol_v)
        Yn, Fn, err = Yn.full(), Fn.full(), err.full().ravel()
        finite = np.isfinite(err)
        ok = active & finite & (err < 1.0)
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            fac = _SAFETY * err ** _ERR_EXP
        fac_ok = np.where(err == 0.0, _MAX_FACTOR, np.minimum(_MAX_FACTOR, fac))
        fac_ok = np.where(rejected, np.minimum(1.0, fac_ok), fac_ok)
        fac_bad = np.where(finite, np.maximum(_MIN_FACTOR, fac), _MIN_FACTOR)
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


# --------------------------------------------------------------------------- model helpers
def flow_rhs(model: Model) -> ca.Function:
    """``(x, t, a = [u; p]) -> f(x, u, t; p)`` for :func:`integrate_batch`, cached on the model."""
    def build():
        a = ca.vertcat(model.u, model.p)
        return ca.Function(f"flow_{c_identifier(model.name)}", [model.x, model.t, a], [model.f],
                           ["y", "t", "a"], ["ydot"])

    return model.cached("flow_rhs", build)


def check_grid(grid, name: str = "grid") -> np.ndarray:
    """``grid`` as a finite, strictly monotone 1-D float array of >= 2 times, or a clear
    :class:`ProblemError` (decreasing grids mean backward time)."""
    g = np.asarray(grid, dtype=float)
    if g.ndim != 1 or g.size < 2:
        raise ProblemError(f"{name} must be a 1-D array of at least 2 times; got shape {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ProblemError(f"{name} must be finite; got {g!r}")
    d = np.diff(g)
    if not (np.all(d > 0) or np.all(d < 0)):
        raise ProblemError(f"{name} must be strictly increasing (or strictly decreasing for "
                           f"backward time); got {g!r}")
    return g


def _params(model: Model, p, n: int | None) -> np.ndarray:
    """Parameters as ``(n_p,)`` or ``(N, n_p)``."""
    if p is None:
        return model.p_default.astype(float)
    arr = np.asarray(p, dtype=float)
    if arr.shape == (model.n_p,) or (n is not None and arr.shape == (n, model.n_p)):
        if not np.all(np.isfinite(arr)):
            raise ProblemError(f"p must be finite; got {arr!r}")
        return arr
    allowed = f"({model.n_p},)" + (f" or ({n}, {model.n_p})" if n is not None else "")
    raise ProblemError(f"p must have shape {allowed} for model {model.name} "
                       f"(parameters {list(model.param_names)}); got {arr.shape}")


def _controls(model: Model, controls, k: int, n: int | None) -> np.ndarray:
    arr = np.asarray(controls, dtype=float)
    if model.n_u == 0 and arr.size == 0:
        return np.zeros((k, 0)) if n is None else np.zeros((n, k, 0))
    ok = arr.shape == (k, model.n_u) or (arr.ndim == 3 and arr.shape[1:] == (k, model.n_u)
                                         and (n is None or arr.shape[0] == n))
    if not ok:
        raise ProblemError(f"controls must have shape (K, n_u) = ({k}, {model.n_u}) or "
                           f"(N, {k}, {model.n_u}) for a grid of {k + 1} times; got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ProblemError("controls must be finite")
    return arr


def propagate(model: Model, x0: ArrayLike, controls: ArrayLike, grid: ArrayLike, *,
              p: ArrayLike | None = None, rtol: float = 1e-10, atol: float = 1e-12,
              substeps: int = 0, max_steps: int = 100000
              ) -> np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Propagate one state or a batch under piecewise-constant controls on ``grid``.

    Parameters
    ----------
    model : the dynamics.
    x0 : ``(n_x,)`` or ``(N, n_x)`` initial states at ``grid[0]``.
    controls : ``(K, n_u)`` (shared) or ``(N, K, n_u)``: control ``u_k`` held on ``[t_k, t_{k+1}]``.
    grid : ``(K+1,)`` strictly monotone times (decreasing = backward time).
    p : parameter vector ``(n_p,)`` (default ``model.p_default``) or ``(N, n_p)`` per sample.
    substeps : if > 0 also return ``substeps`` equally spaced points per segment (for plotting).

    Returns ``states`` of shape ``(N, K+1, n_x)``, or ``(K+1, n_x)`` for a single ``x0`` with 2-D
    controls; with ``substeps > 0`` returns ``(states, dense_times (K*substeps+1,),
    dense_states (N, K*substeps+1, n_x))`` (leading ``N`` dropped likewise).
    """
    g = check_grid(grid)
    k = g.size - 1
    x0a = model.validate_state(x0, "x0")
    single = x0a.ndim == 1
    if x0a.ndim not in (1, 2):
        raise ProblemError(f"x0 must have shape ({model.n_x},) or (N, {model.n_x}); got {x0a.shape}")
    X0 = x0a[None, :] if single else x0a
    n = X0.shape[0]
    U = _controls(model, controls, k, None)
    if U.ndim == 3:
        if single and U.shape[0] >= 1:
            X0 = np.repeat(X0, U.shape[0], axis=0)
            n = X0.shape[0]
        elif U.shape[0] != n:
            raise ProblemError(f"controls of shape {U.shape} need N = {U.shape[0]} initial states; "
                               f"got x0 of shape {x0a.shape}")
        single = False
    else:
        U = np.broadcast_to(U, (n, k, model.n_u))
    P = _params(model, p, n)
    P = np.broadcast_to(P, (n, model.n_p))
    substeps = int(substeps)
    if substeps < 0:
        raise ProblemError(f"substeps must be >= 0; got {substeps}")
    m = max(substeps, 1)
    times = np.concatenate([np.linspace(g[i], g[i + 1], m + 1)[:-1] for i in range(k)] + [g[-1:]])
    rhs = flow_rhs(model)
    out = np.empty((n, times.size, model.n_x))
    out[:, 0] = X0
    x = X0
    for j in range(times.size - 1):
        seg = j // m
        args = np.concatenate([U[:, seg], P], axis=1)
        x = integrate_batch(rhs, x, times[j], times[j + 1], args, rtol=rtol, atol=atol,
                            max_steps=max_steps)
        out[:, j + 1] = x
    states = out[:, ::m]
    if single:
        states, out = states[0], out[0]
    if substeps > 0:
        return states, times, out
    return states


# --------------------------------------------------------------------------- STT
@dataclass(frozen=True)
class STTResult:
    """Reference and per-segment state-transition tensors (Foss et al. Eq. 13).

    ``states[k]`` is the reference at ``times[k]``; ``phi[j-1][k]`` is ``Phi_k^(j)`` with shape
    ``(n_x,) + (n_z,) * j`` (x-rows of the augmented STT from ``t_k`` to ``t_{k+1}``), so that
    ``delta x(t_{k+1}) = sum_j 1/j! Phi_k^(j) [delta z(t_k)]^j`` with ``z = [x; u]``.
    """

    times: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    phi: tuple[np.ndarray, ...]

    @property
    def order(self) -> int:
        return len(self.phi)

    @property
    def Phi1(self) -> np.ndarray:
        return self.phi[0]

    @property
    def Phi2(self) -> np.ndarray:
        if self.order < 2:
            raise ProblemError(f"Phi2 needs an STT of order >= 2; this one has order {self.order}")
        return self.phi[1]

    @property
    def Phi3(self) -> np.ndarray:
        if self.order < 3:
            raise ProblemError(f"Phi3 needs an STT of order 3; this one has order {self.order}")
        return self.phi[2]

    def predict(self, k: int, dz: np.ndarray) -> np.ndarray:
        """``delta x(t_{k+1})`` from ``delta z(t_k)`` (shape ``(..., n_z)``) by Eq. 13."""
        dz = np.asarray(dz, dtype=float)
        out = np.einsum("ia,...a->...i", self.phi[0][k], dz)
        if self.order >= 2:
            out = out + 0.5 * np.einsum("iab,...a,...b->...i", self.phi[1][k], dz, dz)
        if self.order >= 3:
            out = out + np.einsum("iabc,...a,...b,...c->...i", self.phi[2][k], dz, dz, dz) / 6.0
        return out


def _sym_index(n_z: int, order: int) -> tuple[list[tuple[int, ...]], np.ndarray]:
    """Sorted index tuples ``a <= b (<= c)`` and the map from full to packed positions."""
    tuples = list(itertools.combinations_with_replacement(range(n_z), order))
    pos = {tup: i for i, tup in enumerate(tuples)}
    full = np.empty((n_z,) * order, dtype=np.int64)
    for idx in itertools.product(range(n_z), repeat=order):
        full[idx] = pos[tuple(sorted(idx))]
    return tuples, full


def stt_rhs(model: Model, order: int) -> ca.Function:
    """Right-hand side of the reference + STT equations (Foss et al. Eq. 11, augmented Eq. 12).

    ``y = [x; vec(Phi1_x); packed Phi2_x; packed Phi3_x]`` with ``Phi1_x`` (n_x, n_z) row-major and
    the packed tensors holding, per row ``i``, the entries with sorted lower indices
    (``itertools.combinations_with_replacement`` order).  ``a = [u; p]``.  Cached on the model.
    """
    if order not in (1, 2, 3):
        raise ProblemError(f"order must be 1, 2 or 3; got {order!r}")

    def build():
        nx, nz = model.n_x, model.n_z
        D = model.derivative_expressions(order)
        # f-derivative matrices with rows i and row-major multi-index columns
        F1 = D[0]                                            # (nx, nz)
        F2 = _rowmajor_reshape(D[1], nx, nz * nz) if order >= 2 else None
        F3 = _rowmajor_reshape(D[2], nx, nz ** 3) if order >= 3 else None
        p1 = ca.SX.sym("phi1", nx * nz)
        P1x = _rowmajor_reshape(p1, nx, nz)
        P = ca.vertcat(P1x, ca.horzcat(ca.SX.zeros(model.n_u, nx), ca.SX.eye(model.n_u)))  # (nz, nz)
        syms = [model.x, p1]
        dots = [model.f, _rowmajor_flat(ca.mtimes(F1, P))]
        if order >= 2:
            t2, full2 = _sym_index(nz, 2)
            p2 = ca.SX.sym("phi2", nx * len(t2))
            Q2x = _rowmajor_reshape(p2, nx, len(t2))             # packed (nx, n2)
            Qfull = ca.vertcat(Q2x, ca.SX.zeros(model.n_u, len(t2)))  # rows alpha over z

            def Q(a, b):
                return Qfull[:, int(full2[a, b])]

            cols = [ca.kron(P[:, a], P[:, b]) for a, b in t2]
            d2 = ca.mtimes(F1, Qfull) + ca.mtimes(F2, ca.horzcat(*cols))
            syms.append(p2)
            dots.append(_rowmajor_flat(d2))
        if order >= 3:
            t3, _ = _sym_index(nz, 3)
            p3 = ca.SX.sym("phi3", nx * len(t3))
            R3x = _rowmajor_reshape(p3, nx, len(t3))
            cols2 = [ca.kron(P[:, a], Q(b, c)) + ca.kron(P[:, c], Q(a, b)) + ca.kron(P[:, b], Q(a, c))
                     for a, b, c in t3]
            cols3 = [ca.kron(P[:, a], ca.kron(P[:, b], P[:, c])) for a, b, c in t3]
            d3 = (ca.mtimes(F1[:, :nx], R3x) + ca.mtimes(F2, ca.horzcat(*cols2))
                  + ca.mtimes(F3, ca.horzcat(*cols3)))
            syms.append(p3)
            dots.append(_rowmajor_flat(d3))
        y = ca.vertcat(*syms)
        a = ca.vertcat(model.u, model.p)
        return ca.Function(f"stt{order}_{c_identifier(model.name)}", [y, model.t, a], [ca.vertcat(*dots)],
                           ["y", "t", "a"], ["ydot"], {"cse": True})

    return model.cached(("stt_rhs", order), build)


def _rowmajor_reshape(v: ca.SX, rows: int, cols: int) -> ca.SX:
    """Row-major reshape (NumPy C order) of an SX to ``(rows, cols)``."""
    return ca.reshape(ca.reshape(v.T, -1, 1) if v.size2() > 1 else v, cols, rows).T


def _rowmajor_flat(m: ca.SX) -> ca.SX:
    return ca.reshape(m.T, -1, 1)


def _stt_initial(model: Model, order: int, X: np.ndarray) -> np.ndarray:
    nx, nz = model.n_x, model.n_z
    parts = [X, np.tile(np.eye(nx, nz).ravel(), (X.shape[0], 1))]
    for j in range(2, order + 1):
        nt = len(list(itertools.combinations_with_replacement(range(nz), j)))
        parts.append(np.zeros((X.shape[0], nx * nt)))
    return np.concatenate(parts, axis=1)


def _stt_unpack(model: Model, order: int, Y: np.ndarray) -> list[np.ndarray]:
    nx, nz = model.n_x, model.n_z
    k = Y.shape[0]
    off = nx
    out = [Y[:, off:off + nx * nz].reshape(k, nx, nz)]
    off += nx * nz
    for j in range(2, order + 1):
        tuples, full = _sym_index(nz, j)
        nt = len(tuples)
        packed = Y[:, off:off + nx * nt].reshape(k, nx, nt)
        out.append(packed[:, :, full])  # (k, nx, nz, ..., nz)
        off += nx * nt
    return out


def stt(model: Model, x0: ArrayLike, controls: ArrayLike, grid: ArrayLike, order: int, *,
        p: ArrayLike | None = None, rtol: float = 1e-10,
        atol: float = 1e-12, max_steps: int = 100000) -> STTResult:
    """Reference trajectory and per-segment STTs of orders 1..``order`` (Foss et al. Eq. 11-13).

    ``x0`` (n_x,), ``controls`` (K, n_u), ``grid`` (K+1,).  The reference is propagated first;
    then the K segments (each restarted from the identity at ``t_k``) are integrated as one batch.
    """
    if order not in (1, 2, 3):
        raise ProblemError(f"order must be 1, 2 or 3; got {order!r}")
    g = check_grid(grid)
    x0a = model.validate_state(x0, "x0")
    if x0a.ndim != 1:
        raise ProblemError(f"stt takes one reference state x0 of shape ({model.n_x},); got {x0a.shape}")
    U = _controls(model, controls, g.size - 1, None)
    if U.ndim != 2:
        raise ProblemError(f"stt takes controls of shape (K, n_u); got {U.shape}")
    P = _params(model, p, None)
    states = propagate(model, x0a, U, g, p=P, rtol=rtol, atol=atol, max_steps=max_steps)
    k = g.size - 1
    Y0 = _stt_initial(model, order, states[:-1])
    args = np.concatenate([U, np.broadcast_to(P, (k, model.n_p))], axis=1)
    Y1 = integrate_batch(stt_rhs(model, order), Y0, g[:-1], g[1:], args, rtol=rtol, atol=atol,
                         max_steps=max_steps)
    phi = _stt_unpack(model, order, Y1)
    return STTResult(times=g, states=states, controls=U, phi=tuple(phi))


def stm(model: Model, x0: ArrayLike, t0: float, t1: float, u: ArrayLike | None = None, *,
        p: ArrayLike | None = None, rtol: float = 1e-10,
        atol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """State and state-transition matrix ``(x(t1), dx(t1)/dx(t0))`` under a constant control."""
    u = np.zeros(model.n_u) if u is None else np.asarray(u, dtype=float).reshape(model.n_u)
    res = stt(model, x0, u[None, :], [t0, t1], 1, p=p, rtol=rtol, atol=atol)
    return res.states[-1], res.phi[0][0][:, :model.n_x]
