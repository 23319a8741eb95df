"""STT on models whose mass flow depends on ||u|| (elliptic-earth / lunar-flyby, which exploded
to ~1e10 DU after one step before the throttle relaxation).

``||u||`` has no Taylor expansion at the STT's reference control ``u = 0``: with the builders'
regularised ``sqrt(|u|^2 + 1e-30)`` its second derivative there is ``1e15``, so the order-2 STT of
the mass flow was ~2e9 after one 2-hour step.  ``Model.throttle_relaxed`` replaces ``||u||`` by an
extra input; these tests check the relaxation against the true dynamics and the STT sets against
Monte Carlo endpoints of the true system."""
from __future__ import annotations

import numpy as np
import pytest

import ocreach
from ocreach.models.cr3bp import cr3bp
from ocreach.reach.mc import MonteCarlo
from ocreach.sets.pz_exact import support_bounds
from ocreach.units import Units


def _ball_controls(rng, n, m):
    u = rng.normal(size=(n, m))
    return u / np.linalg.norm(u, axis=1, keepdims=True) * rng.uniform(0.01, 1.0, size=(n, 1))


@pytest.fixture(scope="module")
def mass_models():
    units = Units(length=3.844e8, time=3.75e5, mass=1.0, name="em")
    return [cr3bp(0.01215, variable_mass=True, thrust=0.02, isp=3000.0, units=units),
            ocreach.get_problem("elliptic-earth", segments=2).model]


def test_relaxed_model_reproduces_the_dynamics_at_sigma_equal_norm(mass_models):
    rng = np.random.default_rng(0)
    for m in mass_models:
        r = m.throttle_relaxed()
        assert r.n_u == m.n_u + 1 and r.throttle is None
        assert m.throttle_relaxed() is r                          # cached
        x = np.array([0.55, 0.1, 0.02, 0.3, 0.7, 0.01, 1.0][: m.n_x])
        for u in _ball_controls(rng, 20, m.n_u):
            s = 2 * np.linalg.norm(u) - 1
            np.testing.assert_allclose(r(x, np.r_[u, s], 0.1), m(x, u, 0.1), rtol=1e-13, atol=1e-15)


def test_relaxed_model_is_smooth_at_zero_control(mass_models):
    """The Hessian in the controls at u = 0 is the limit of the Hessians at small u (relaxed),
    while the regularised norm's is ~1e15 x T/c (true model): the cause of the explosion."""
    for m in mass_models:
        r = m.throttle_relaxed()
        x = np.array([0.55, 0.1, 0.02, 0.3, 0.7, 0.01, 1.0][: m.n_x])
        H0 = r.tensors(x, np.zeros(r.n_u), 0.1, order=2)[2]
        H1 = r.tensors(x, np.r_[1e-4, np.zeros(r.n_u - 1)], 0.1, order=2)[2]
        np.testing.assert_allclose(H0, H1, atol=1e-6 * (1 + np.abs(H0).max()))
        Ht = m.tensors(x, np.zeros(m.n_u), 0.1, order=2)[2]
        nx = m.n_x
        assert np.abs(Ht[nx - 1, nx:, nx:]).max() > 1e6 * (1 + np.abs(H0).max())


@pytest.mark.parametrize("pid", ["elliptic-earth", "lunar-flyby"])
def test_stt_on_mass_flow_models_covers_mc_and_stays_near_it(pid):
    """8 segments of 2 h: every MC endpoint (true dynamics, ball controls) is inside every
    half-space of the set's support upper bound, and the set reaches no further beyond the MC
    cloud than half the cloud's width (it reached 1e10 DU before the relaxation)."""
    p = ocreach.get_problem(pid, segments=8)
    res = ocreach.reach(p, "stt")
    assert res.meta["throttle_relaxed"]
    mc = MonteCarlo(samples=400, seed=5).solve(p)
    rng = np.random.default_rng(2)
    D = rng.normal(size=(26, 3))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    D = np.vstack([D, -D])
    for k in (4, 8):
        X = mc.points[k][:, :3]
        h = (X @ D.T).max(axis=0)
        width = h + (X @ -D.T).max(axis=0)
        sb = support_bounds(res.sets[k].project([0, 1, 2]), D, tol=1e-3)
        assert np.all(h <= sb.upper + 1e-9 * width), f"MC endpoint outside at t = {res.times[k]}"
        assert np.all(sb.upper - h <= 0.5 * width), (k, np.max((sb.upper - h) / width))


def test_bad_throttle_declaration_is_refused():
    import casadi as ca

    from ocreach.errors import ProblemError
    from ocreach.model import Model

    x, u, s = ca.SX.sym("x"), ca.SX.sym("u"), ca.SX.sym("s")
    with pytest.raises(ProblemError, match=r"throttle\[0\] must be one scalar SX symbol"):
        Model.build("m", x, u, x + u, throttle=(2 * s, x + s))
    with pytest.raises(ProblemError, match=r"throttle\[1\] must have the shape of f"):
        Model.build("m", x, u, x + u, throttle=(s, ca.vertcat(x, s)))
    m = Model.build("m", x, u, x + ca.fabs(u), throttle=(s, x + s))
    assert m.throttle_relaxed().n_u == 2 and Model.build("m", x, u, x + u).throttle_relaxed().n_u == 1


def test_stt_throttle_on_a_box_reaches_the_corners_mass_flow():
    """On the box input set ``||u||`` reaches ``sqrt(n_u)`` at a corner: the relaxed throttle must
    reach it too, so the set's mass range covers the propellant of full corner thrust (with the
    ball's throttle bound of 1 it stopped at the ball's)."""
    import dataclasses

    from ocreach.dynamics.flow import propagate

    p = ocreach.get_problem("elliptic-earth", segments=4)
    p = dataclasses.replace(p, model=p.model.with_control_set("box"), control_set=None)
    assert p.control_set.kind == "box"
    res = ocreach.reach(p, "stt")
    corner = np.ones((p.n_segments, p.model.n_u))
    X = propagate(p.model, p.x0, corner, p.grid, p=p.params)
    nx = p.model.n_x
    e = np.zeros(nx)
    e[nx - 1] = 1.0
    for k in range(1, p.n_segments + 1):
        sb = support_bounds(res.sets[k], np.array([e, -e]), tol=1e-6)
        lo, hi = -sb.upper[1], sb.upper[0]
        tol = 1e-12 * abs(X[k, nx - 1])   # the corner is the extreme: equal up to rounding
        assert lo - tol <= X[k, nx - 1] <= hi + tol, (k, lo, X[k, nx - 1], hi)
