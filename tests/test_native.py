"""Tests of ocreach.native's compile cache: concurrent builds of one kernel, cache layout."""
from __future__ import annotations

import ctypes
import hashlib
import multiprocessing as mp
import os

import casadi as ca
import numpy as np
import pytest

from ocreach.native import compile as nc
from ocreach.native.codegen import generate_c


def _kernel_sources() -> dict[str, bytes]:
    x = ca.SX.sym("x", 3)
    f = ca.Function("ocr_race_test", [x], [ca.vertcat(ca.sin(x[0]) * x[1], x[2] ** 2, ca.exp(x[0]))])
    return {"gen.c": generate_c([f])}


def _build(cache: str, barrier, queue) -> None:
    os.environ["OCREACH_CACHE_DIR"] = cache
    try:
        sources = _kernel_sources()
        barrier.wait(timeout=60)  # everybody finds an empty cache and compiles at the same time
        lib = nc.compile_source("ocr_race_test", sources, "gen.c", ("-O2",))
        data = lib.read_bytes()
        dll = ctypes.CDLL(str(lib))
        queue.put((str(lib), hashlib.sha256(data).hexdigest(), bool(dll.ocr_race_test)))
    except BaseException as exc:  # reported to the parent, which fails the test
        queue.put(("error", repr(exc), False))


def test_concurrent_builds_into_an_empty_cache_agree(tmp_path):
    ctx = mp.get_context("spawn")
    n = 4
    barrier, queue = ctx.Barrier(n), ctx.Queue()
    procs = [ctx.Process(target=_build, args=(str(tmp_path), barrier, queue)) for _ in range(n)]
    for p in procs:
        p.start()
    out = [queue.get(timeout=240) for _ in range(n)]
    for p in procs:
        p.join(timeout=60)
    assert all(p.exitcode == 0 for p in procs)
    assert all(o[0] != "error" for o in out), out
    assert len({o[0] for o in out}) == 1 and len({o[1] for o in out}) == 1 and all(o[2] for o in out)
    jit = tmp_path / "jit"
    assert [f.name for f in jit.iterdir()] == [os.path.basename(out[0][0])]  # no temporaries left
    # a later build in this process finds the published library and does not rebuild it
    with pytest.MonkeyPatch.context() as mpatch:
        mpatch.setenv("OCREACH_CACHE_DIR", str(tmp_path))
        mpatch.setattr(nc.subprocess, "run", lambda *a, **k: pytest.fail("rebuilt a cached library"))
        assert str(nc.compile_source("ocr_race_test", _kernel_sources(), "gen.c", ("-O2",))) == out[0][0]


def test_one_cache_root_and_unique_temporary_names(tmp_path, monkeypatch):
    monkeypatch.setenv("OCREACH_CACHE_DIR", str(tmp_path))
    assert nc.cache_dir() == tmp_path / "jit"
    from ocreach.dynamics import quadrature

    assert quadrature._disk_cache_path(5, 8, "cut").parent == tmp_path / "cut_rules"
    target = tmp_path / "x" / "data.bin"
    names = {nc._temp_name(target).name for _ in range(50)}
    assert len(names) == 50 and all(str(os.getpid()) in n for n in names)
    nc.write_atomic(target, b"abc")
    assert target.read_bytes() == b"abc" and os.listdir(target.parent) == ["data.bin"]


def test_compiler_failure_is_a_compile_error(tmp_path, monkeypatch):
    monkeypatch.setenv("OCREACH_CACHE_DIR", str(tmp_path))
    with pytest.raises(nc.COMPILE_ERRORS, match="failed"):
        nc.compile_source("ocr_broken", {"main.c": b"this is not C"}, "main.c", ("-O0",))
    assert not any((tmp_path / "jit").iterdir())


# ----------------------------------------------------------------------------- batch integrator
def _fresh_rhs(name: str, kind: str) -> ca.Function:
    """A new Function object per call (the integrator caches one driver per Function)."""
    y, t, a = ca.SX.sym("y", 4), ca.SX.sym("t"), ca.SX.sym("a", 4)
    if kind == "cr3bp":  # planar CR3BP with thrust a[0:2], mu = a[2], a_max = a[3]
        mu = a[2]
        r1 = ca.sqrt((y[0] + mu) ** 2 + y[1] ** 2)
        r2 = ca.sqrt((y[0] - 1 + mu) ** 2 + y[1] ** 2)
        f = ca.vertcat(y[2], y[3],
                       y[0] + 2 * y[3] - (1 - mu) * (y[0] + mu) / r1 ** 3
                       - mu * (y[0] - 1 + mu) / r2 ** 3 + a[3] * a[0],
                       y[1] - 2 * y[2] - (1 - mu) * y[1] / r1 ** 3 - mu * y[1] / r2 ** 3 + a[3] * a[1])
    else:  # every operation family the lane code generator writes
        f = ca.vertcat(
            -ca.sin(y[1]) + 0.1 * ca.fmax(y[0], 0.2) + 0.01 * ca.atan2(y[1], 2.0 + a[0]),
            ca.fmin(y[0], 1.0) * ca.cos(y[1]) - 0.05 * (1 + y[0] ** 2) ** 1.5
            + 0.01 * ca.if_else(y[0] > a[1], 1.0, -1.0) * ca.tanh(y[0]),
            -0.3 * y[2] + 0.1 * ca.exp(-y[0] ** 2) + 0.01 * ca.sign(y[1]) * ca.fabs(y[3]) ** 2.3,
            0.2 * ca.log(1.5 + y[0] ** 2) - 0.1 * y[3] / ca.sqrt(1 + y[2] ** 2)
            + 0.01 / (2 + y[1] ** 2) ** 2 + a[2] * ca.sinh(0.1 * y[2]))
    return ca.Function(name, [y, t, a], [f])


def _dro_batch(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    y0 = np.array([0.2765, 0.0, 0.0, 2.1379]) + 1e-3 * rng.standard_normal((n, 4))
    ang = rng.uniform(0, 2 * np.pi, n)
    a = np.stack([np.cos(ang), np.sin(ang), np.full(n, 0.0122), np.full(n, 0.02)], axis=1)
    return y0, a


def _dro_segments(n: int, k: int, t_end: float, seed: int):
    """A planar CR3BP DRO batch: model, grid of k segments on [0, t_end], controls (n, k, 2) in
    [-0.7, 0.7]^2 and initial states near the DRO."""
    from ocreach.models import cr3bp

    rng = np.random.default_rng(seed)
    U = rng.uniform(-0.7, 0.7, (n, k, 2))
    X0 = np.array([0.2765, 0.0, 0.0, 2.1379]) + 1e-3 * rng.standard_normal((n, 4))
    return cr3bp(0.0122, planar=True, a_max=0.02), np.linspace(0.0, t_end, k + 1), U, X0


@pytest.mark.parametrize("kind", ["cr3bp", "ops"])
def test_lane_driver_matches_scalar_driver_and_scipy(kind, monkeypatch):
    """The SIMD-lane driver against the one-sample-at-a-time driver and against SciPy's DOP853 at
    rtol 1e-12 (independent truth, 1e-8).  One forced single step (h_init = span, loose rtol)
    compares the lane code of every operation with CasADi's scalar code to round-off; whole
    integrations agree to round-off on smooth dynamics and to the tolerance on the non-smooth
    "ops" right-hand side (a last-bit difference can flip a step-size decision there)."""
    from scipy.integrate import solve_ivp

    from ocreach.native.integrator import integrate_batch, stepper

    y0, a = _dro_batch(13)  # not a multiple of the lane width
    if kind == "ops":
        y0 = np.random.default_rng(3).uniform(-1, 1, (13, 4))
    t1 = np.linspace(0.5, 2.0, 13)
    t1[4] = 0.0  # a zero-length sample among the lanes
    out = {}
    for width in (8, 1):
        monkeypatch.setenv("OCREACH_LANES", str(width))
        rhs = _fresh_rhs(f"lanes{width}_{kind}", kind)
        out[width] = integrate_batch(rhs, y0, 0.0, t1, a, rtol=1e-11, atol=1e-13)
        one = np.full(13, 1e-3)
        out[width, "step"] = integrate_batch(rhs, y0, 0.0, 1e-3, a, rtol=1e-4, atol=1e-4, h_init=one)
        assert stepper(rhs).lane_width == width
    np.testing.assert_allclose(out[8, "step"], out[1, "step"], rtol=0, atol=1e-15)
    np.testing.assert_allclose(out[8], out[1], rtol=0, atol=1e-12 if kind == "cr3bp" else 1e-8)
    np.testing.assert_array_equal(out[8][4], y0[4])
    fun = _fresh_rhs("scipy_" + kind, kind)
    for i in (0, 5, 12):
        ref = solve_ivp(lambda t, y: np.asarray(fun(y, t, a[i])).ravel(), (0.0, t1[i]), y0[i],
                        method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
        np.testing.assert_allclose(out[8][i], ref, rtol=0, atol=1e-8)


def test_threaded_and_serial_runs_are_identical(monkeypatch):
    from ocreach.native import integrator
    from ocreach.native.integrator import integrate_batch

    monkeypatch.setattr(integrator, "THREAD_WORK", 16)  # split small batches too

    rhs = _fresh_rhs("threads_cr3bp", "cr3bp")
    y0, a = _dro_batch(301, seed=5)
    t1 = np.random.default_rng(6).uniform(0.5, 3.0, 301)
    serial = integrate_batch(rhs, y0, 0.0, t1, a, threads=1)
    h2 = np.zeros(301)
    threaded = integrate_batch(rhs, y0, 0.0, t1, a, threads=3, h_init=h2)
    h1 = np.zeros(301)
    integrate_batch(rhs, y0, 0.0, t1, a, threads=1, h_init=h1)
    np.testing.assert_array_equal(serial, threaded)
    np.testing.assert_array_equal(h1, h2)
    assert np.all(h1 > 0)


def test_propagate_is_thread_count_independent_and_matches_scipy(monkeypatch):
    """propagate (step sizes carried across segments) with 1 and 2 threads, against SciPy
    segment by segment with fresh step-size control (1e-8)."""
    from scipy.integrate import solve_ivp

    from ocreach import parallel
    from ocreach.native import integrator

    monkeypatch.setattr(integrator, "THREAD_WORK", 16)
    from ocreach.dynamics.flow import propagate

    model, grid, U, X0 = _dro_segments(100, 30, 3.0, seed=7)
    with parallel.settings(threads=1):
        one = propagate(model, X0, U, grid)
    with parallel.settings(threads=2):
        two = propagate(model, X0, U, grid)
    np.testing.assert_array_equal(one, two)
    f = model.f_fun
    for i in (0, 99):
        x = X0[i]
        for k in range(30):
            x = solve_ivp(lambda t, y, u=U[i, k]: np.asarray(f(y, u, t, model.p_default)).ravel(),
                          (grid[k], grid[k + 1]), x, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
        np.testing.assert_allclose(one[i, -1], x, rtol=0, atol=1e-8)


def test_bad_thread_settings_are_problem_errors(monkeypatch):
    from ocreach import parallel
    from ocreach.errors import ProblemError
    from ocreach.native.integrator import integrate_batch

    rhs = _fresh_rhs("bad_threads", "cr3bp")
    y0, a = _dro_batch(2)
    with pytest.raises(ProblemError, match="threads must be an integer >= 1; got 0"):
        integrate_batch(rhs, y0, 0.0, 1.0, a, threads=0)
    with pytest.raises(ProblemError, match=r"h_init must be a C-contiguous float64 array of shape \(2,\)"):
        integrate_batch(rhs, y0, 0.0, 1.0, a, h_init=np.zeros(3))
    monkeypatch.setenv("OCREACH_THREADS", "two")
    with pytest.raises(ProblemError, match="OCREACH_THREADS must be an integer >= 1; got 'two'"):
        parallel.default_threads()


# ----------------------------------------------------------------------------- segment driver
def _old_paths(model):
    """propagate through the per-segment Batch loop with the same lane code (the path before
    the segment driver) and through the scalar one-sample driver (fresh stepper, no lanes)."""
    from ocreach.dynamics.flow import flow_rhs
    from ocreach.native import integrator

    st = integrator.stepper(flow_rhs(model))
    assert st.native_segments is not None and st.lane_width == integrator.LANES
    return st


@pytest.mark.parametrize("name", ["dro", "vdp", "nrho-9-2", "earth-mars", "shuttle-reentry"])
def test_segment_driver_matches_per_segment_loops_and_scipy(name, monkeypatch):
    """propagate with all segments of a sample in one lane-driver call against (a) the
    per-segment loop over the same lane code: bit-identical, (b) the scalar one-sample driver:
    round-off (1e-10 relative), (c) SciPy's DOP853 segment by segment at rtol 1e-12 (independent
    truth, 1e-8 relative), on problems of the registry with their own grids, sub-steps and
    per-sample parameters."""
    from scipy.integrate import solve_ivp

    from ocreach.dynamics.flow import flow_rhs, propagate
    from ocreach.native import integrator
    from ocreach.registry import get_problem

    prob = get_problem(name)
    model = prob.model
    grid = np.asarray(prob.grid, dtype=float)[:11]
    rng = np.random.default_rng(11)
    n = 19  # not a multiple of the lane width
    U = rng.uniform(-0.8, 0.8, (n, grid.size - 1, model.n_u)) / np.sqrt(max(model.n_u, 1))
    x0 = np.asarray(prob.x0, dtype=float)
    X0 = x0 + 1e-6 * np.abs(x0).max() * rng.standard_normal((n, model.n_x))
    P = np.tile(np.asarray(prob.params if prob.params is not None else model.p_default, float), (n, 1))
    P *= 1 + 1e-3 * rng.standard_normal(P.shape)  # per-sample parameters
    st = _old_paths(model)
    kw = dict(p=P, rtol=1e-11, atol=1e-13, substeps=2)
    new, times, dense = propagate(model, X0, U, grid, **kw)
    seg = st.native_segments
    monkeypatch.setattr(st, "native_segments", None)
    old, _, dense_old = propagate(model, X0, U, grid, **kw)
    monkeypatch.setattr(st, "native_segments", seg)
    np.testing.assert_array_equal(new, old)
    np.testing.assert_array_equal(dense, dense_old)
    monkeypatch.setenv("OCREACH_LANES", "1")
    monkeypatch.setattr(integrator, "_STEPPERS", {})
    monkeypatch.delitem(model.cache, "flow_rhs")  # a new rhs Function: a new stepper (restored after)
    scalar = propagate(model, X0, U, grid, **{**kw, "substeps": 0})
    assert integrator.stepper(flow_rhs(model)).native_segments is None
    scale = np.abs(new).max(axis=(0, 1))
    np.testing.assert_allclose(new / scale, scalar / scale, rtol=0, atol=1e-10)
    f = model.f_fun
    for i in (0, n - 1):
        x = X0[i]
        for k in range(grid.size - 1):
            x = solve_ivp(lambda t, y, u=U[i, k]: np.asarray(f(y, u, t, P[i])).ravel(),
                          (grid[k], grid[k + 1]), x, method="DOP853", rtol=1e-12,
                          atol=1e-14 * scale).y[:, -1]
            np.testing.assert_allclose(new[i, k + 1] / scale, x / scale, rtol=0, atol=1e-8)


def test_segment_driver_reports_failed_samples(monkeypatch):
    """A sample that hits a primary (non-finite rhs) or exceeds max_steps inside a later segment
    is named in the SolverError; the others still integrate."""
    from ocreach.dynamics.flow import propagate
    from ocreach.errors import SolverError
    from ocreach.models import cr3bp

    model = cr3bp(0.0122, planar=True, a_max=0.02)
    grid = np.linspace(0.0, 1.0, 6)
    X0 = np.tile([0.2765, 0.0, 0.0, 2.1379], (11, 1))
    X0[7] = [-0.0122, 0.0, 0.0, 0.0]  # at the Earth: rhs not finite at the start
    with pytest.raises(SolverError, match=r"non-finite value of the state or rhs for samples \[7\]"):
        propagate(model, X0, np.zeros((5, 2)), grid)
    with pytest.raises(SolverError, match=r"max_steps = 2 exceeded for samples \[0, 1, 2"):
        propagate(model, X0[:3], np.zeros((5, 2)), grid, max_steps=2)


def test_threads_take_samples_from_a_shared_queue_with_identical_results(monkeypatch):
    """1, 2 and 3 threads on one batch (samples handed out by the shared counter, so the split
    differs from run to run) give bit-identical states, for propagate and integrate_batch."""
    from ocreach import parallel
    from ocreach.dynamics.flow import propagate
    from ocreach.native import integrator

    monkeypatch.setattr(integrator, "THREAD_WORK", 16)
    model, grid, U, X0 = _dro_segments(203, 20, 2.0, seed=12)
    runs = []
    for th in (1, 2, 3, 2):
        with parallel.settings(threads=th):
            runs.append(propagate(model, X0, U, grid))
    for r in runs[1:]:
        np.testing.assert_array_equal(r, runs[0])
    rhs = _fresh_rhs("queue_cr3bp", "cr3bp")
    y0, a = _dro_batch(203, seed=13)
    one = integrate_batch_threads(rhs, y0, a, 1)
    for th in (2, 3):
        np.testing.assert_array_equal(integrate_batch_threads(rhs, y0, a, th), one)


def integrate_batch_threads(rhs, y0, a, threads):
    from ocreach.native.integrator import integrate_batch

    return integrate_batch(rhs, y0, 0.0, np.linspace(0.5, 3.0, y0.shape[0]), a, threads=threads)


def test_segment_driver_on_an_empty_batch():
    from ocreach import parallel
    from ocreach.dynamics.flow import propagate

    model, grid, _, _ = _dro_segments(1, 3, 0.3, seed=0)
    for th in (1, 2):
        with parallel.settings(threads=th):
            assert propagate(model, np.zeros((0, 4)), np.zeros((0, 3, 2)), grid).shape == (0, 4, 4)


def test_lane_code_with_shared_divisors_matches_casadi(tmp_path, monkeypatch):
    """Divisors used by several divisions become one reciprocal; work variables are re-used by
    CasADi, so a divisor is identified by variable and assignment.  Many divisors, shared and not,
    whose work variables are recycled between uses: the lane code on 8 random samples against
    CasADi's own evaluation (1e-15 relative)."""
    from ocreach.native.lanes import LANE_FLAGS, lane_source

    monkeypatch.setenv("OCREACH_CACHE_DIR", str(tmp_path))
    x = ca.SX.sym("x", 4)
    outs = []
    for k in range(6):
        d = x[k % 4] + x[(k + 1) % 4] * (k + 1)          # shared by two divisions
        e = x[(k + 2) % 4] * x[(k + 3) % 4] + k          # used once (its slot may be d's)
        outs += [x[(k + 2) % 4] / d, (x[(k + 3) % 4] - k) / d, x[k % 4] / e, 1 / (d + e)]
    fun = ca.Function("ocr_shared_div", [x], [ca.vertcat(*outs)])
    src = lane_source(fun, "ocr_lane_f", 8)
    assert src.count("1.0 / w") >= 6
    wrap = ("\nvoid ocr_run(const double* a, double* b) {\n"
            "  const double* i[1] = {a}; double* o[1] = {b}; ocr_lane_f(i, o);\n}\n")
    lib = nc.compile_source("ocr_shared_div", {"main.c": (src + wrap).encode()}, "main.c", LANE_FLAGS)
    dll = ctypes.CDLL(str(lib))
    X = np.random.default_rng(14).uniform(0.5, 2.0, (8, 4))
    inp = np.ascontiguousarray(X.T)  # component-major: entry i of lane l at i * 8 + l
    out = np.zeros((len(outs), 8))
    dll.ocr_run(ctypes.c_void_p(inp.ctypes.data), ctypes.c_void_p(out.ctypes.data))
    ref = np.array([np.asarray(fun(X[lane])).ravel() for lane in range(8)]).T
    np.testing.assert_allclose(out, ref, rtol=1e-15, atol=0)
