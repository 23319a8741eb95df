"""The sound ``poly`` method (conservative polynomialization) and its rigorous polynomial-zonotope
arithmetic (``ocreach.sets.pz_sound``).

Truth: trajectories integrated by SciPy's DOP853 (rtol 1e-12) on numpy right-hand sides of
``tests/_reach_truth.py`` (not the project's CasADi models), from vertices and inside the initial
set, constant / bang-bang / random admissible controls.  A point is inside a polynomial zonotope
when a witness (factors in the box mapping within 1e-9 of it) is found, outside when it is outside
the zonotope enclosure or excluded by a support certificate (``ocreach.sets.pz_witness``); tubes
are zonotopes (scaled gauge).  Short horizons and a few hundred samples keep this under a minute;
the 10,000-sample rows are in ``examples/poly_validation.py``.
"""
from __future__ import annotations

from fractions import Fraction

import casadi as ca
import numpy as np
import pytest
from _reach_truth import ball_controls, initial_samples, simulate

import ocreach
from ocreach.errors import ProblemError, SolverError
from ocreach.model import Model
from ocreach.problem import Problem
from ocreach.registry import get_problem
from ocreach.sets import pz_sound as spz
from ocreach.sets.polyzonotope import PolyZonotope
from ocreach.sets.pz_witness import classify
from ocreach.sets.union import union_gauge
from ocreach.sets.zonotope import Zonotope

HOUR = 3600.0 / 375200.0
TOL = 1 + 1e-9


def _assert_contained(res, ends, mids=None):
    for k in range(res.times.size):
        S, P = res.sets[k], ends[:, k]
        eps = 1e-9 * (1 + np.abs(P).max())
        if isinstance(S, PolyZonotope):
            v = classify(S, P, eps)
            assert not v.outside.any(), f"time index {k}: {int(v.outside.sum())} points outside"
            assert not v.undecided.any(), f"time index {k}: {int(v.undecided.sum())} undecided"
        else:
            g = union_gauge(S, P)
            assert g.max() <= TOL, f"time index {k}: gauge {g.max()!r} > 1"
    if mids is not None:
        for k in range(res.times.size - 1):
            for j in range(mids.shape[2]):
                g = union_gauge(res.tubes[k], mids[:, k, j])
                assert g.max() <= TOL, f"tube {k}, interior time {j}: gauge {g.max()!r} > 1"


# ------------------------------------------------------------------------------ rigorous arithmetic
def _exact_poly(S: spz.SoundPZ, alpha: np.ndarray) -> list[list[Fraction]]:
    """The polynomial part of ``S`` at factor values ``alpha`` (dict local index -> Fraction)."""
    out = []
    for i in range(S.dim):
        v = Fraction(S.c[i])
        for j in range(S.n_dependent):
            m = Fraction(1)
            for f in S.I[j]:
                if f:
                    m *= alpha[int(f)]
            v += Fraction(S.G[i, j]) * m
        out.append(v)
    return out


def _within(S: spz.SoundPZ, alpha: dict, exact: list[Fraction]) -> bool:
    """Is the exact point within ``S``'s independent part around its polynomial at ``alpha``?
    (Checked on the box of the independent part: enough here, where it holds rounding boxes.)"""
    poly = _exact_poly(S, alpha)
    rad = np.abs(S.GI).sum(axis=1) + S.r
    return all(abs(e - p) <= Fraction(float(r)) for e, p, r in zip(exact, poly, rad))


def test_rounded_operations_contain_the_exact_results():
    """Linear map, sum with shared factors, quadratic and bilinear maps of ``pz_sound`` computed in
    floating point contain the results in exact rational arithmetic (at random factor values),
    on inputs with entries of mixed magnitudes where rounding is not negligible."""
    rng = np.random.default_rng(3)
    fid = spz.FactorIds(3)
    for trial in range(6):
        n = 3
        Z = Zonotope(rng.normal(size=n) * 1e3, rng.normal(size=(n, 4)) * 10.0 ** rng.integers(-3, 3, (1, 4)))
        S = spz.from_zonotope(Z, fid, 3)
        H = rng.normal(size=(n, n, n))
        H = 0.5 * (H + H.transpose(0, 2, 1))
        M = rng.normal(size=(n, n)) / 3.0
        Q = spz.quadratic(H, S, fid.bits)
        L = spz.linear_map(M, S)
        A = spz.add(L, Q, fid.bits)
        B = spz.bilinear(H, S, L, fid.bits)
        for _ in range(5):
            a = {int(k): Fraction(float(v)) for k, v in zip(S.factors(), rng.uniform(-1, 1, S.factors().size))}
            x = _exact_poly(S, a)
            Mx = [sum(Fraction(M[i, j]) * x[j] for j in range(n)) for i in range(n)]
            qx = [sum(Fraction(H[i, j, k]) * x[j] * x[k] for j in range(n) for k in range(n)) for i in range(n)]
            bx = [sum(Fraction(H[i, j, k]) * x[j] * Mx[k] for j in range(n) for k in range(n)) for i in range(n)]
            assert _within(L, a, Mx)
            assert _within(Q, a, qx)
            assert _within(A, a, [p + q for p, q in zip(Mx, qx)])
            assert _within(B, a, bx)


def test_reduction_split_and_conversion_enclose_the_set():
    """Reduction (three parts, with refactoring), the factor split and the conversion to a
    :class:`PolyZonotope` keep every point of the set: points of the original (random factors)
    are witnessed in the reduced set, in one of the two halves, and in the converted set."""
    rng = np.random.default_rng(5)
    fid = spz.FactorIds(3)
    S = spz.from_zonotope(Zonotope(np.zeros(2), rng.normal(size=(2, 6))), fid, 3)
    H = rng.normal(size=(2, 2, 2))
    S = spz.add(S, spz.quadratic(0.5 * (H + H.transpose(0, 2, 1)), S, fid.bits), fid.bits)
    P0 = spz.to_polyzonotope(S, fid)
    pts = P0.sample(200, rng)
    for R in (spz.reduce(S, 3, 4, "girard", fid), spz.reduce(S, 2, 0, "pca", None)):
        v = classify(spz.to_polyzonotope(R, fid), pts, 1e-9)
        assert v.inside.all()
    f = int(S.factors()[0])
    a, b = spz.split(S, f, fid.bits)
    va = classify(spz.to_polyzonotope(a, fid), pts, 1e-9)
    rest = pts[~va.inside]          # every point not witnessed in one half is in the other
    assert classify(spz.to_polyzonotope(b, fid), rest, 1e-9).inside.all()


# ------------------------------------------------------------------------------------ soundness
def test_poly_vdp_contains_scipy_truth_and_is_tighter_than_taylor():
    """Van der Pol (Foss Sec. 3.1) over 3 TU: every sampled trajectory in every set and tube, and
    the final set narrower than taylor's in most random directions."""
    from scipy.integrate import solve_ivp

    p = get_problem("vdp")
    res = ocreach.reach(p, "poly")
    assert res.meta["guaranteed"] and res.times.size == p.grid.size
    rng = np.random.default_rng(1)
    N, K = 90, p.grid.size - 1
    U = np.where(rng.random((N, K)) < 0.5, -1.0, 1.0)
    U[: N // 3] = U[: N // 3, :1]
    U[N // 3: 2 * N // 3] = rng.uniform(-1, 1, (N // 3, K))
    mu, g = p.param("mu"), p.param("gain")
    X = np.tile(p.x0, (N, 1))
    ends, mids = [X], []
    for k in range(K):
        def rhs(t, y, uk=U[:, k]):
            x1, x2 = y.reshape(-1, 2).T
            return np.column_stack([x2, mu * (1 - x1**2) * x2 - x1 + g * uk]).ravel()
        t0, t1 = p.grid[k], p.grid[k + 1]
        sol = solve_ivp(rhs, (t0, t1), X.ravel(), method="DOP853", rtol=1e-12, atol=1e-14,
                        t_eval=[0.5 * (t0 + t1), t1])
        mids.append(sol.y[:, 0].reshape(N, 2))
        X = sol.y[:, 1].reshape(N, 2)
        ends.append(X)
    ends = np.stack(ends, axis=1)
    mids = np.stack(mids, axis=1)[:, :, None, :]
    _assert_contained(res, ends, mids)
    tay = ocreach.reach(p, "taylor")
    D = rng.normal(size=(20, 2))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    w_poly = res.sets[-1].support(D) + res.sets[-1].support(-D)
    w_tay = tay.sets[-1].support(D) + tay.sets[-1].support(-D)
    assert np.mean(w_poly < w_tay) > 0.7


@pytest.fixture(scope="module")
def nrho6():
    p = get_problem("nrho-9-2", t_final=6 * HOUR)
    rng = np.random.default_rng(0)
    K = p.grid.size - 1
    X0 = initial_samples(rng, p.initial_set, 240)
    U = np.concatenate([ball_controls(rng, 80, K, law) for law in ("constant", "bang", "random")])
    ends, mids = simulate(p, X0, U, inner=2)
    return p, ends, mids


def test_poly_nrho_contains_scipy_truth(nrho6):
    p, ends, mids = nrho6
    res = ocreach.reach(p, "poly")
    _assert_contained(res, ends, mids)


def test_poly_splitting_and_zonotope_output_contain_truth(nrho6):
    """A small ``max_error`` forces splits (factor splits of the rounded arithmetic); the zonotope
    output (``output="zonotope"``) is checked by the exact gauge."""
    p, ends, mids = nrho6
    res = ocreach.reach(p, "poly", max_error=1e-7, max_parts=4, output="zonotope")
    assert res.meta["max_parts_used"] > 1
    _assert_contained(res, ends, mids)


def test_poly_time_dependent_model_with_disturbance_contains_scipy_solutions():
    """``f`` depends on ``t`` (a forced, softening oscillator) and a disturbance box acts on the
    velocity: ``poly`` takes ``t`` as an input over ``[t, t + h]``; checked by witnesses."""
    from scipy.integrate import solve_ivp

    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    t = ca.SX.sym("t")
    f = ca.vertcat(x[1], -x[0] + 0.3 * x[0] ** 3 * ca.cos(t) + 0.5 * ca.sin(2 * t) + 0.2 * u[0])
    m = Model.build("forced", x, u, f, t=t, control_set="box")
    Z0 = Zonotope([0.5, 0.0], np.diag([0.05, 0.05]))
    grid = np.linspace(0.0, 3.0, 16)
    p = Problem(id="forced", model=m, x0=np.array([0.5, 0.0]), grid=grid, initial_set=Z0)
    w = 0.02
    res = ocreach.reach(p, "poly", disturbance=[0.0, w])
    rng = np.random.default_rng(7)
    X0 = np.vstack([Z0.sample(40, rng, mode="extreme"), Z0.sample(40, rng)])
    N, K = X0.shape[0], grid.size - 1
    U = np.where(rng.random((N, K)) < 0.5, -1.0, 1.0)
    U[: N // 3] = U[: N // 3, :1]
    Wd = w * np.where(rng.random((N, K)) < 0.5, -1.0, 1.0)
    X = X0.copy()
    ends = [X]
    for k in range(K):
        def rhs(tt, y, uk=U[:, k], wk=Wd[:, k]):
            Y = y.reshape(-1, 2)
            return np.column_stack([Y[:, 1], -Y[:, 0] + 0.3 * Y[:, 0] ** 3 * np.cos(tt)
                                    + 0.5 * np.sin(2 * tt) + 0.2 * uk + wk]).ravel()
        sol = solve_ivp(rhs, (grid[k], grid[k + 1]), X.ravel(), method="DOP853", rtol=1e-12,
                        atol=1e-14)
        X = sol.y[:, -1].reshape(N, 2)
        ends.append(X)
    _assert_contained(res, np.stack(ends, axis=1))


# ------------------------------------------------------------------------------------ interface
@pytest.mark.parametrize("opts, word", [
    ({"order": 0}, "order"), ({"poly_order": -1}, "poly_order"), ({"error_order": 0.5}, "error_order"),
    ({"max_degree": 1}, "max_degree"), ({"max_degree": 9}, "max_degree"),
    ({"remainder_splits": 0}, "remainder_splits"), ({"growth_tol": -0.1}, "growth_tol"),
    ({"output": "ellipsoid"}, "output"), ({"refactor": "maybe"}, "refactor"),
    ({"max_error": -1.0}, "max_error"), ({"tube_order": 0}, "tube_order"),
    ({"input_order": 0}, "input_order"), ({"no_such_option": 1}, "no_such_option"),
])
def test_bad_options_are_refused_before_any_work(opts, word):
    with pytest.raises(ProblemError, match=word):
        ocreach.reach(get_problem("vdp"), "poly", **opts)


def test_method_is_registered_as_guaranteed_and_stops_with_a_partial_result():
    from ocreach.reach.base import method_class

    assert method_class("poly").guaranteed
    p = get_problem("nrho-9-2", t_final=12 * HOUR, thrust=1e3)   # 10,000 x the thrust
    with pytest.raises(SolverError) as err:
        ocreach.reach(p, "poly", max_parts=1, max_halvings=1)
    part = err.value.partial
    assert part.meta["truncated"] and part.meta["guaranteed"] and part.times.size >= 1


def test_poly_contains_the_escape_found_by_the_harness():
    """x' = 0, y' = x y from the box [-1/8, 1/8]^2, 3 steps to t = 0.5: the exact flow
    y(t) = y0 exp(x0 t) at the vertex (1/8, 1/8) must lie in every set (independent truth).  Its
    set missed it by 4.4e-8 while the dynamic error left out the chord term lambda (P_end - P)."""
    from ocreach.testing import generated_case, run_method
    from ocreach.testing.strategies import GeneratedSystem, Term

    system = GeneratedSystem(
        label="known-escape", A=np.zeros((2, 2)), B=np.zeros((2, 1)), control="box",
        terms=(Term(row=0, coef=0.0, powers=(2, 0), t_power=0, weights=None),
               Term(row=1, coef=1.0, powers=(1, 1), t_power=0, weights=None)),
        x0=np.zeros(2), generators=np.eye(2) * 0.125, initial="box", t_final=0.5, steps=3,
        notes={})
    out = run_method("poly", generated_case(system), n_samples=60)
    assert out.status == "complete" and out.escapes == 0, out.line()


@pytest.mark.parametrize("opts", [{}, {"growth_tol": None, "max_halvings": 0}])
def test_poly_contains_the_flow_of_a_disturbance_with_a_nonzero_centre(opts):
    """x1' = x2 + w1, x2' = -x1, x3' = x1^2 with w = (1, 0, 0) exactly, one step of pi: the
    centre's input solution Gamma(tau) w_c is larger for tau < h than at h (the rotation turns
    it), so boxing it by |Gamma(h) w_c| missed the flow (tube and time-point set).  Truth:
    SciPy DOP853 from x(0) = 0 (the centre of the initial box), checked at 4 times."""
    from scipy.integrate import solve_ivp

    from ocreach.testing.containment import check_points
    from ocreach.testing.strategies import GeneratedSystem, Term

    A = np.zeros((3, 3))
    A[0, 1], A[1, 0] = 1.0, -1.0
    system = GeneratedSystem(
        label="disturbance-centre", A=A, B=np.zeros((3, 1)), control="box",
        terms=(Term(row=2, coef=1.0, powers=(2, 0, 0)),), x0=np.zeros(3),
        generators=np.eye(3) * 1e-3, initial="box", t_final=np.pi, steps=1, notes={})
    wc = np.array([1.0, 0.0, 0.0])
    res = ocreach.reach(system.problem(), "poly", disturbance=Zonotope(wc, np.zeros((3, 0))), **opts)

    def rhs(t, x):
        return system.rhs(t, x[None], np.zeros((1, 1)))[0] + wc

    sol = solve_ivp(rhs, (0.0, np.pi), np.zeros(3), method="DOP853", rtol=1e-12, atol=1e-15,
                    dense_output=True)
    for k, (t0, t1) in enumerate(zip(res.times[:-1], res.times[1:])):
        for tau in (t0, 0.5 * (t0 + t1), t1):
            assert not check_points(res.tubes[k], sol.sol(tau)[None]).escaped[0], (k, tau)
    for k, t in enumerate(res.times):
        verdict = check_points(res.sets[k], sol.sol(t)[None])
        assert not verdict.escaped[0] and not verdict.undecided[0], (k, t)
