"""Soundness of the zonotope methods ``taylor`` and ``sdc`` against independent truth.

Truth: trajectories integrated by SciPy's DOP853 (rtol 1e-12) on numpy right-hand sides written in
``tests/_reach_truth.py`` (not the project's CasADi models), initial states at vertices and inside
the initial set, constant / bang-bang / random admissible controls, disturbances at +-W.  A point
is inside when its scaled gauge (smallest t with x in c + t G) is <= 1 + 1e-9.  Short horizons and
~1,000 samples keep the suite fast; the 10,000-sample full-horizon checks are in
``examples/patel_subbarao_sets.py``.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from _reach_truth import assert_contained as _assert_contained
from _reach_truth import ball_controls, initial_samples, simulate
from scipy.linalg import expm

import ocreach
from ocreach.errors import ProblemError, SolverError
from ocreach.model import Model
from ocreach.problem import Problem
from ocreach.reach.linsys import expm_terms, linear_step
from ocreach.registry import get_problem
from ocreach.sets.union import union_gauge
from ocreach.sets.zonotope import Zonotope

HOUR = 3600.0 / 375200.0
TOL = 1 + 1e-9


def _nrho(hours: float, dt_h: float = 1.0) -> Problem:
    p = get_problem("nrho-9-2", t_final=hours * HOUR, dt=dt_h * HOUR)
    assert p.initial_set is not None  # the paper's G_pos = 1e-4 I, G_vel = 5e-4 I
    return p


def _mc(problem, n_per_law: int, seed: int = 0, W: float | None = None):
    rng = np.random.default_rng(seed)
    K = problem.n_segments
    X0 = initial_samples(rng, problem.initial_set or Zonotope(problem.x0), 3 * n_per_law)
    U = np.concatenate([ball_controls(rng, n_per_law, K, law) for law in ("constant", "bang", "random")])
    Wacc = None
    if W is not None:
        Wacc = np.zeros((3 * n_per_law, K, 3))
        Wacc[:] = W * rng.choice([-1.0, 1.0], size=(3 * n_per_law, 1, 3))
    return simulate(problem, X0, U, Wacc, inner=2)


# ------------------------------------------------------------------------------------------ linsys
def test_linear_step_contains_exact_linear_solutions():
    rng = np.random.default_rng(3)
    n = 4
    A = rng.standard_normal((n, n)) * 2.0
    h = 0.3
    R0 = Zonotope(rng.standard_normal(n), 0.2 * rng.standard_normal((n, 5)))
    u_c = rng.standard_normal(n)
    W = Zonotope(np.zeros(n), 0.5 * np.diag(rng.uniform(0.5, 1.0, n)))
    step = linear_step(R0, A, h, u_c, W)
    # exact solutions for inputs constant on two halves of the step (augmented matrix exponential)
    N = 400
    x0 = np.vstack([R0.sample(N // 2, rng, "extreme"), R0.sample(N // 2, rng)])
    w1, w2 = (W.sample(N, rng, "extreme") for _ in range(2))

    def flow(x, w, t):
        M = np.zeros((2 * n, 2 * n))
        M[:n, :n], M[:n, n:] = A, np.eye(n)
        E = expm(M * t)
        return x @ E[:n, :n].T + (u_c + w) @ E[:n, n:].T

    xm = flow(x0, w1, h / 2)
    xe = flow(xm, w2, h / 2)
    assert union_gauge(step.point, xe).max() <= TOL
    for s in (0.1, 0.37, 0.5, 0.8):
        xs = flow(x0, w1, s * h) if s <= 0.5 else flow(xm, w2, (s - 0.5) * h)
        assert union_gauge(step.tube, xs).max() <= TOL
    # tight for a pure linear map: the point set's box is close to the sampled spread
    spread = np.ptp(xe, axis=0)
    width = 2 * np.abs(step.point.G).sum(axis=1)
    assert np.all(width < 3.0 * spread)


def test_expm_remainder_bounds_the_tail():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((5, 5)) * 3
    et = expm_terms(A, 0.4)
    err = np.abs(expm(A * 0.4) - et.Phi)
    assert np.all(err <= et.E)
    with pytest.raises(SolverError, match="too large"):
        expm_terms(A * 1e3, 1.0)


# ------------------------------------------------------------------------------------------ taylor
@pytest.fixture(scope="module")
def nrho6():
    p = _nrho(6.0)
    traj, mid = _mc(p, 300)
    return p, traj, mid


def test_taylor_contains_mc_nrho(nrho6):
    p, traj, mid = nrho6
    res = ocreach.reach(p, "taylor")
    assert res.meta["guaranteed"] is True and not res.meta["truncated"]
    assert len(res.tubes) == p.n_segments
    _assert_contained(res, traj, mid)


def test_taylor_pca_and_splitting_contain_mc(nrho6):
    p, traj, mid = nrho6
    res = ocreach.reach(p, "taylor", reduction="pca", order=6, max_error=2e-6, max_parts=3)
    assert max(res.meta["steps"]["parts"]) > 1  # the threshold forced splits
    _assert_contained(res, traj, mid)


def test_taylor_disturbance_contains_mc():
    p = _nrho(4.0)
    w = 1e-2  # 27 % of a_max: large enough to matter over 4 h
    traj, mid = _mc(p, 200, seed=2, W=w)
    res = ocreach.reach(p, "taylor", disturbance=w)
    _assert_contained(res, traj, mid)
    plain = ocreach.reach(p, "taylor")
    assert union_gauge(plain.sets[-1], traj[:, -1]).max() > 1  # W matters: without it, escapes


def test_taylor_earth_mars_contains_mc():
    p = get_problem("earth-mars", t_days=20.0, dt_days=5.0)
    traj, mid = _mc(p, 200, seed=4)
    res = ocreach.reach(p, "taylor")
    _assert_contained(res, traj, mid)


def test_taylor_dt_contains_the_rk4_model():
    p = _nrho(4.0)
    res = ocreach.reach(p, "taylor", alg="dt", rk4_substeps=2)
    assert "discrete" in res.meta["guaranteed_for"] and res.tubes is None
    rng = np.random.default_rng(5)
    from ocreach.dynamics.discretize import Discretization

    d = Discretization(p.model, float(p.grid[1] - p.grid[0]), 2)
    N = 300
    X = initial_samples(rng, p.initial_set, N)
    U = np.concatenate([ball_controls(rng, N // 3, p.n_segments, law) for law in ("constant", "bang", "random")])
    F = d.F.map(N)
    for k in range(p.n_segments):
        X = np.asarray(F(X.T, U[:, k].T, p.grid[k], np.tile(p.params[:, None], (1, N)))).T
        assert union_gauge(res.sets[k + 1], X).max() <= TOL


# ------------------------------------------------------------------------------------------ sdc
def test_sdc_contains_mc_and_is_not_looser_than_taylor(nrho6):
    p, traj, mid = nrho6
    res = ocreach.reach(p, "sdc")
    assert res.meta["guaranteed"] is True
    _assert_contained(res, traj, mid)
    tay = ocreach.reach(p, "taylor")
    D = np.random.default_rng(0).standard_normal((50, 6))
    ratio = res.sets[-1].support(D) - tay.sets[-1].support(D)
    # both expand about the same point with the same linear part: they agree to the remainder
    width = tay.sets[-1].support(D) + tay.sets[-1].support(-D)
    assert np.max(np.abs(ratio) / width) < 0.05


def test_sdc_and_taylor_agree_on_a_linear_model():
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    f = ca.vertcat(x[1], -x[0] - 0.1 * x[1] + u[0])
    m = Model.build("osc", x, u, f, control_set="box")
    Z0 = Zonotope([1.0, 0.0], 0.1 * np.eye(2))
    p = Problem(id="osc", model=m, x0=np.array([1.0, 0.0]), grid=np.linspace(0, 2, 5), initial_set=Z0)
    a = ocreach.reach(p, "taylor")
    b = ocreach.reach(p, "sdc")
    D = np.random.default_rng(1).standard_normal((50, 2))
    assert np.allclose(a.sets[-1].support(D), b.sets[-1].support(D), rtol=1e-9, atol=1e-12)


def test_sdc_origin_variant_is_flagged_unsound():
    p = _nrho(2.0)
    res = ocreach.reach(p, "sdc", base="origin")
    assert res.meta["guaranteed"] is False and "f(0)" in res.meta["unsound_reason"]


# ------------------------------------------------------------------------------------------ errors
def test_bad_inputs_give_clear_errors():
    p = _nrho(2.0)
    p.initial_set = Zonotope(np.zeros(4), np.eye(4))
    with pytest.raises(ProblemError, match="dimension 4"):
        ocreach.reach(p, "taylor")
    for bad in ({"order": 0.5}, {"reduction": "foo"}, {"max_parts": 0}, {"alg": "xx"},
                {"max_error": -1}, {"input_set": "ball"}, {"split": "maybe"}):
        with pytest.raises(ProblemError, match=next(iter(bad))):
            ocreach.reach(_nrho(1.0), "taylor", **bad)
    with pytest.raises(ProblemError, match="disturbance"):
        ocreach.reach(_nrho(1.0), "taylor", disturbance=[1.0, 2.0])


def test_nonsmooth_model_is_refused():
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    m = Model.build("kink", x, u, ca.vertcat(x[1], -ca.fabs(x[0]) + u[0]), control_set="box")
    p = Problem(id="kink", model=m, x0=np.array([0.0, 1.0]), grid=np.linspace(0, 1, 3))
    for meth in ("taylor", "sdc"):
        with pytest.raises(ProblemError, match="not smooth"):
            ocreach.reach(p, meth)


def test_box_around_the_singularity_fails_with_partial_result():
    p = get_problem("earth-mars", t_days=4.0, dt_days=1.0)
    p.initial_set = Zonotope(p.x0, np.diag([1.2, 1.2, 0.1, 0.0, 0.0, 0.0]))  # contains the Sun
    with pytest.raises(SolverError, match="step 0") as info:
        ocreach.reach(p, "taylor", max_parts=1, max_halvings=1)
    assert "primary" in str(info.value) or "contain" in str(info.value)
    assert info.value.partial.meta["truncated"] is True
    assert len(info.value.partial.sets) == 1


def test_taylor_time_dependent_model_contains_scipy_solutions():
    """``f`` depends on ``t`` (a forced, softening oscillator): ``taylor`` takes ``t`` as an input
    with the box ``[t, t + h]`` and must contain solutions of a numpy right-hand side integrated by
    SciPy (DOP853, rtol 1e-11), controls in [-1, 1] constant or bang-bang per step, started at
    the vertices and inside the initial box; checked at every grid time by the scaled gauge."""
    from scipy.integrate import solve_ivp

    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    t = ca.SX.sym("t")
    f = ca.vertcat(x[1], -x[0] + 0.3 * x[0] ** 3 * ca.cos(t) + 0.5 * ca.sin(2 * t) + 0.2 * u[0])
    m = Model.build("forced", x, u, f, t=t, control_set="box")
    Z0 = Zonotope([0.5, 0.0], np.diag([0.05, 0.05]))
    grid = np.linspace(0.0, 3.0, 16)
    p = Problem(id="forced", model=m, x0=np.array([0.5, 0.0]), grid=grid, initial_set=Z0)
    res = ocreach.reach(p, "taylor")
    assert res.meta["guaranteed"] and len(res.sets) == grid.size

    def rhs(tt, y, uk):
        X = y.reshape(-1, 2)
        dx = np.column_stack([X[:, 1], -X[:, 0] + 0.3 * X[:, 0] ** 3 * np.cos(tt)
                              + 0.5 * np.sin(2 * tt) + 0.2 * uk])
        return dx.ravel()

    rng = np.random.default_rng(7)
    corners = np.array([[s1, s2] for s1 in (-1, 1) for s2 in (-1, 1)], dtype=float)
    X0 = np.vstack([Z0.evaluate(np.repeat(corners, 10, axis=0)), Z0.sample(60, rng)])
    N, K = X0.shape[0], grid.size - 1
    U = np.where(rng.random((N, K)) < 0.5, -1.0, 1.0)
    U[: N // 3] = U[: N // 3, :1]          # constant controls for a third
    U[N // 3: N // 2] = rng.uniform(-1, 1, (N // 2 - N // 3, K))
    X = X0.copy()
    for k in range(K):
        sol = solve_ivp(rhs, (grid[k], grid[k + 1]), X.ravel(), args=(U[:, k],), method="DOP853",
                        rtol=1e-11, atol=1e-13)
        assert sol.success
        X = sol.y[:, -1].reshape(N, 2)
        g = union_gauge(res.sets[k + 1], X)
        assert g.max() <= TOL, f"step {k + 1}: gauge {g.max()!r} > 1"


def test_mass_varies_encloses_the_propellant_burn():
    """A double integrator ``p'' = a u`` (``a = T/m0``, box control): at full thrust the true
    acceleration grows to ``T / m(t)``, ``m(t) = m0 - T t / (Isp g0)`` (SciPy on the rocket
    equation).  Those trajectories leave the constant-mass set and lie in the ``mass_varies``
    set, whose input scale is ``m0 / m_min`` computed here by hand."""
    from scipy.integrate import solve_ivp

    from ocreach.units import Units

    T_N, m0, isp, g0 = 0.003, 10.0, 30.0, 9.80665
    units = Units(length=1e3, time=1e3)
    a = T_N / m0 / (units.length / units.time**2)          # model units
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    m = Model.build("dbl", x, u, ca.vertcat(x[1], a * u[0]), control_set="box", units=units)
    grid = np.linspace(0.0, 10.0, 6)
    p = Problem(id="dbl", model=m, x0=np.zeros(2), grid=grid,
                extra={"thrust_N": T_N, "mass_kg": m0, "isp_s": isp})
    plain = ocreach.reach(p, "taylor")
    burn = ocreach.reach(p, "taylor", mass_varies=True)
    m_min = m0 - T_N / (isp * g0) * 10.0 * units.time
    assert "mass_varies" in burn.meta["input_enclosure"]
    assert f"{m0 / m_min:.6g}" in burn.meta["input_enclosure"]
    mdot = T_N / (isp * g0)

    def rhs(t, y, s):   # SI: position, velocity; s = +-1 full thrust, 0 coast (no burn)
        return [y[1], s * T_N / (m0 - abs(s) * mdot * t)]

    escaped = False
    for s in (-1.0, 1.0, 0.0):
        sol = solve_ivp(rhs, (0.0, grid[-1] * units.time), [0.0, 0.0], args=(s,), method="DOP853",
                        rtol=1e-12, atol=1e-12, t_eval=grid * units.time)
        X = np.column_stack([sol.y[0] / units.length, sol.y[1] / (units.length / units.time)])
        for k in range(1, grid.size):
            assert union_gauge(burn.sets[k], X[k:k + 1]).max() <= TOL, (s, k)
            escaped |= bool(union_gauge(plain.sets[k], X[k:k + 1]).max() > TOL)
    assert escaped  # the burn matters: without mass_varies the full-thrust trajectories escape
    with pytest.raises(ProblemError, match="mass_varies"):
        ocreach.reach(Problem(id="dbl", model=m, x0=np.zeros(2), grid=grid), "taylor",
                      mass_varies=True)
    with pytest.raises(ProblemError, match="mass_varies"):
        ocreach.reach(p, "taylor", mass_varies="maybe")


def _switched_model():
    """``x' = [x1, -x0 + 0.2 u]`` before ``t = 0.55``, ``[x1, -2 x0 - 0.3 x1 + 0.2 u]`` after: an
    ``if_else`` on time alone (and a comparison of time feeding a product)."""
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    t = ca.SX.sym("t")
    a = ca.vertcat(x[1], -x[0] + 0.2 * u[0])
    b = ca.vertcat(x[1], -2 * x[0] - 0.3 * x[1] + 0.2 * u[0])
    f = ca.if_else(t < 0.55, a, b) + ca.vertcat(0, (t >= 0.55) * 0.1 * x[0] ** 2)
    return Model.build("switched", x, u, f, t=t, control_set="box")


def test_switch_on_time_alone_is_accepted_where_no_step_contains_it():
    """taylor accepts ``if_else`` on time alone: on grids that stay on one side of the switch
    its sets contain SciPy solutions of that side's branch (started at the initial box's corners
    and inside, controls +-1 per step); a step whose closed time box contains the switch fails
    with a SolverError (never a bound across it).  An if_else or comparison on the state, or
    logic on it, is still refused."""
    from scipy.integrate import solve_ivp

    m = _switched_model()
    Z0 = Zonotope([0.5, 0.0], np.diag([0.05, 0.05]))
    rng = np.random.default_rng(2)
    X0 = np.vstack([Z0.evaluate(np.array([[s1, s2] for s1 in (-1, 1) for s2 in (-1, 1)], float)),
                    Z0.sample(12, rng)])

    def rhs(tt, y, uk):
        X = y.reshape(-1, 2)
        if tt < 0.55:
            d = np.column_stack([X[:, 1], -X[:, 0] + 0.2 * uk])
        else:
            d = np.column_stack([X[:, 1], -2 * X[:, 0] - 0.3 * X[:, 1] + 0.2 * uk
                                 + 0.1 * X[:, 0] ** 2])
        return d.ravel()

    for grid in (np.linspace(0.0, 0.5, 6), np.linspace(0.6, 1.6, 6)):
        p = Problem(id="switched", model=m, x0=np.array([0.5, 0.0]), grid=grid, initial_set=Z0)
        res = ocreach.reach(p, "taylor")
        assert res.meta["guaranteed"] and len(res.sets) == grid.size
        U = np.where(rng.random((X0.shape[0], grid.size - 1)) < 0.5, -1.0, 1.0)
        X = X0.copy()
        for k in range(grid.size - 1):
            sol = solve_ivp(rhs, (grid[k], grid[k + 1]), X.ravel(), args=(U[:, k],),
                            method="DOP853", rtol=1e-11, atol=1e-13)
            X = sol.y[:, -1].reshape(-1, 2)
            assert union_gauge(res.sets[k + 1], X).max() <= 1.0 + 1e-9, (grid[0], k)
    p = Problem(id="switched", model=m, x0=np.array([0.5, 0.0]),
                grid=np.linspace(0.0, 1.0, 5), initial_set=Z0)  # step 2 is [0.5, 0.75]
    with pytest.raises(SolverError, match="step 2") as info:
        ocreach.reach(p, "taylor", max_halvings=2)
    assert "undecided" in str(info.value)

    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    t = ca.SX.sym("t")
    for f in (ca.vertcat(x[1], ca.if_else(x[0] < 0, -x[0], x[0]) + u[0]),
              ca.vertcat(x[1], (x[0] < t) * x[0] + u[0]),
              ca.vertcat(x[1], ca.logic_not(x[0]) + u[0])):
        m = Model.build("state-switch", x, u, f, t=t, control_set="box")
        p = Problem(id="s", model=m, x0=np.array([0.5, 0.0]), grid=np.linspace(0, 1, 3))
        with pytest.raises(ProblemError, match="not smooth"):
            ocreach.reach(p, "taylor")


def test_time_switch_hidden_from_the_trace_is_still_refused():
    """What the instruction trace of ``check_smooth`` cannot see is refused elsewhere: an
    ``if_else`` on the state inside a call node (a ``never_inline`` Function) passes the trace
    but the interval evaluator refuses the call (ProblemError, no result); ``sdc`` refuses the
    switch on time alone (it needs autonomous dynamics)."""
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    t = ca.SX.sym("t")
    g = ca.Function("g", [t, x], [ca.if_else(x[0] < t, 1.0, 2.0)], {"never_inline": True})
    m = Model.build("hidden", x, u, ca.vertcat(x[1], g(t, x) * x[0] + u[0]), t=t,
                    control_set="box")
    p = Problem(id="hidden", model=m, x0=np.array([0.5, 0.0]), grid=np.linspace(0.0, 1.0, 3),
                initial_set=Zonotope([0.5, 0.0], np.diag([0.05, 0.05])))
    with pytest.raises(ProblemError, match="call"):
        ocreach.reach(p, "taylor")
    m = _switched_model()
    p = Problem(id="switched", model=m, x0=np.array([0.5, 0.0]), grid=np.linspace(0.0, 0.5, 3),
                initial_set=Zonotope([0.5, 0.0], np.diag([0.05, 0.05])))
    with pytest.raises(ProblemError, match="autonomous"):
        ocreach.reach(p, "sdc")


def test_a_blown_up_bound_is_not_dropped_from_a_box():
    """A NaN radius (an overflowed bound) keeps its generator, so the set is visibly not finite
    (before, ``r > 0`` dropped it and the box lost that direction's width silently)."""
    from ocreach.reach.linsys import all_finite, diag_columns
    from ocreach.reach.taylor_step import interval_box

    assert diag_columns(np.array([1.0, 0.0, np.nan])).shape == (3, 2)
    assert not all_finite(interval_box(np.array([np.nan, 0.0]), np.array([1.0, np.inf])))


def test_taylor_stops_with_an_error_where_the_solution_blows_up():
    """x' = x^2 (and x^3) from around 1 escapes to infinity near t = 0.45: both algorithms stop
    with a SolverError and the sets so far, finite and containing the exact solutions."""
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    m = Model.build("blowup", x, u, ca.vertcat(x[0] ** 2, x[1] ** 3 + 0 * u[0]),
                    control_set="box")
    p = Problem(id="blowup", model=m, x0=np.ones(2), grid=np.linspace(0, 2, 41),
                initial_set=Zonotope([1.0, 1.0], 0.05 * np.eye(2)))
    corners = np.array([[a, b] for a in (0.95, 1.05) for b in (0.95, 1.05)])
    for alg in ("dt", "ct"):
        with pytest.raises(SolverError) as err:
            ocreach.reach(p, "taylor", alg=alg, split=False)
        part = err.value.partial
        assert 0 < len(part.sets) < p.grid.size
        for k, S in enumerate(part.sets):
            assert np.all(np.isfinite(S.c)) and np.all(np.isfinite(S.G))
            t = float(part.times[k])
            exact = np.column_stack([corners[:, 0] / (1 - t * corners[:, 0]),
                                     corners[:, 1] / np.sqrt(1 - 2 * t * corners[:, 1] ** 2)])
            assert union_gauge(S, exact).max() <= 1 + 1e-9, (alg, k)
