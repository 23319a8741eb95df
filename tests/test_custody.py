"""Custody (Tucker et al.): reachability balls against Monte Carlo and direct transcription, the
short-horizon limit, FOV geometry against dense sampling, covered fraction against Monte Carlo,
the horizon search against known horizons, observers, and bad input."""
from __future__ import annotations

import numpy as np
import pytest

from ocreach import custody as cu
from ocreach.custody.reach_balls import ReachableBalls, validate_with_mc
from ocreach.errors import ProblemError, SetError, SolverError
from ocreach.geometry import minimum_enclosing_ball
from ocreach.reach.base import reach
from ocreach.registry import get_problem

KM = 384400.0


@pytest.fixture(scope="module")
def l1_balls():
    rb = ReachableBalls("custody-l1", bvp_options={"samples": 30})
    rb.at(1.0)
    return rb


# ------------------------------------------------------------------ reachability against truth
def test_mc_inside_outer_ball_and_below_support(l1_balls):
    out = validate_with_mc(l1_balls, 1.0, samples=1500, seed=3)
    assert out["outside_outer"] == 0
    assert out["above_support"] == 0 and out["max_support_excess_rel"] <= 1e-6
    hb = l1_balls.at(1.0)
    assert hb.outer.radius >= hb.inner.radius * (1 - 1e-12)


def test_initial_ellipsoid_manifold(l1_balls):
    """Eq. 6 initial manifold (50 km / 1 m/s semi-axes): the ball grows by roughly the drift of
    the uncertainty, and MC endpoints from the ellipsoid stay inside the outer ball."""
    rb = ReachableBalls("custody-l1", overrides={"uncertain": True, "sigma_pos_km": 50.0, "sigma_vel_mps": 1.0},
                        bvp_options={"samples": 20})
    r0 = l1_balls.at(1.0).inner.radius * KM
    r = rb.at(1.0).inner.radius * KM
    assert r0 + 60.0 < r < r0 + 50.0 + 86.4 + 20.0  # 50 km + 1 m/s x 1 d, gravity gradient aside
    out = validate_with_mc(rb, 1.0, samples=1000, seed=5)
    assert out["outside_outer"] == 0 and out["above_support"] == 0


def test_warm_start_across_horizons(l1_balls):
    hb = l1_balls.at(1.5)
    assert hb.warm_started
    cold = ReachableBalls("custody-l1", bvp_options={"samples": 30}).at(1.5)
    assert abs(hb.inner.radius - cold.inner.radius) <= 1e-9 * cold.inner.radius


def test_warm_start_across_thrust_levels():
    prob = get_problem("custody-l5", t_days=1.0, dt_hours=6.0)
    a = prob.param("a_max")
    base = reach(prob, "bvp", samples=8)
    warm = reach(prob, "bvp", samples=8, thrust=1.3 * a, costate_guess=base.meta["costate0"])
    cold = reach(prob, "bvp", samples=8, thrust=1.3 * a)
    assert warm.meta["warm_started"][1:].all()  # every direction after the first: Newton from the guess
    assert warm.meta["shots"] < cold.meta["shots"]
    np.testing.assert_allclose(warm.points[-1], cold.points[-1], atol=1e-9)  # DU (0.4 m)


@pytest.mark.parametrize("control_set,factor", [("ball", 1.0), ("box", np.sqrt(3.0))])
def test_short_horizon_limit(control_set, factor):
    """r -> a t^2 / 2 (ball; sqrt(3) a t^2 / 2 for the box corner) as t -> 0."""
    t_days = 0.02
    prob = get_problem("custody-l2", t_days=t_days, dt_hours=0.12, control_set=control_set)
    res = reach(prob, "bvp", samples=20, dims="position")
    r = minimum_enclosing_ball(np.asarray(res.points[-1])[:, :3]).radius
    T = prob.grid[-1]
    limit = factor * 0.5 * prob.param("a_max") * T**2
    assert abs(r / limit - 1) < 1e-3, r / limit


def test_box_bvp_matches_direct_transcription():
    from ocreach.reach.direct import transcription_support

    prob = get_problem("custody-l1", t_days=1.0, dt_hours=6.0)
    res = reach(prob, "bvp", samples=6, dims="position", seed=1)
    ref = np.asarray(res.meta["reference_final"])
    for j in (0, 2, 4):
        z = np.asarray(res.meta["directions"][j])
        J_bvp = float(z @ (res.points[-1][j] - ref))
        J_dt = float(transcription_support(prob, z, refine=6, n_sub=4)) - float(z @ ref)
        # piecewise-constant box controls (24 segments) vs the continuous smoothed bang-bang law
        assert abs(J_bvp - J_dt) <= 2e-4 * J_bvp, (j, J_bvp * KM, J_dt * KM)


def test_quadratic_cost_same_extremals_as_linear():
    prob = get_problem("custody-l1", t_days=1.0, dt_hours=6.0)
    lin = reach(prob, "bvp", samples=8, cost="linear")
    quad = reach(prob, "bvp", samples=8, cost="quadratic")
    Z, ref = lin.meta["directions"], lin.meta["reference_final"]
    J_l = np.einsum("ij,ij->i", Z, lin.points[-1] - ref)
    J_q = np.einsum("ij,ij->i", Z, quad.points[-1] - ref)
    # Eq. 4 maximises |z . e|: each extremal is the linear one on the +z or the -z side
    plus = J_q > 0
    assert plus.sum() >= 2
    np.testing.assert_allclose(J_q[plus], J_l[plus], rtol=2e-6)
    assert np.all(np.abs(J_q) > 0.5 * J_l.min())  # no trivial root (x_f = x_ref)


def test_smoothing_is_a_runtime_parameter():
    from ocreach.reach.bvp import costate_stm_rhs

    prob = get_problem("custody-l3", t_days=0.5, dt_hours=6.0)
    a = reach(prob, "bvp", samples=4, smooth=1e-7)
    b = reach(prob, "bvp", samples=4, smooth=1e-9)
    assert costate_stm_rhs(prob.model) is costate_stm_rhs(prob.model)
    assert costate_stm_rhs(prob.model).size1_in(2) == prob.model.n_p + 1
    assert a.meta["smoothing_levels"][0] >= 2 and b.meta["smoothing_levels"][0] > a.meta["smoothing_levels"][0]
    ra = minimum_enclosing_ball(a.points[-1][:, :3]).radius
    rb = minimum_enclosing_ball(b.points[-1][:, :3]).radius
    assert rb >= ra and (rb - ra) <= 1e-4 * rb  # less smoothing: slightly more reach


# ------------------------------------------------------------------ FOV geometry
def _sphere(n, rng):
    g = rng.standard_normal((n, 3))
    return g / np.linalg.norm(g, axis=1, keepdims=True)


@pytest.mark.parametrize("fov", [cu.FOV.circle(2.0), cu.FOV.rect(2.0, 1.0, roll_deg=30.0)],
                         ids=["circle", "rect-roll"])
def test_ball_in_fov_against_dense_sampling(fov):
    rng = np.random.default_rng(0)
    o = np.array([-0.0121, 0.0, 0.0])
    S = _sphere(40_000, rng)
    boresight = np.array([1.0, 0.05, 0.02])
    agree = 0
    for _ in range(60):
        c = o + rng.uniform(0.5, 1.2) * (boresight / np.linalg.norm(boresight)
                                        + rng.uniform(-0.02, 0.02, 3))
        r = rng.uniform(0.001, 0.02)
        inside = cu.ball_in_fov(c, r, o, fov, axis=boresight)
        samples = cu.points_in_fov(c + r * S, o, fov, boresight)
        if inside:
            assert samples.all()
        else:
            # a ball that is not inside has sampled surface points outside, unless the excess is
            # thinner than the sampling resolution: then an enlarged-by-2 % ball must show it
            assert (not samples.all()) or (not cu.points_in_fov(c + 1.02 * r * S, o, fov, boresight).all())
        agree += 1
    assert agree == 60


def test_ball_in_fov_edge_cases():
    o = np.zeros(3)
    fov = cu.FOV.circle(2.0)
    D = 1.0
    r_edge = D * np.sin(np.deg2rad(1.0))
    assert cu.ball_in_fov([D, 0, 0], r_edge * (1 - 1e-9), o, fov)
    assert not cu.ball_in_fov([D, 0, 0], r_edge * (1 + 1e-9), o, fov)
    sq = cu.FOV.rect(2.0)
    # the inscribed circle of the square pyramid: distance to a side plane is D sin(h)
    assert cu.ball_in_fov([D, 0, 0], D * np.sin(np.deg2rad(1.0)) * (1 - 1e-9), o, sq)
    assert not cu.ball_in_fov([D, 0, 0], D * np.sin(np.deg2rad(1.0)) * (1 + 1e-9), o, sq)


@pytest.mark.parametrize("fov,offset", [(cu.FOV.circle(1.0), 0.0), (cu.FOV.circle(1.0), 0.006),
                                        (cu.FOV.rect(1.0, 0.6, roll_deg=20.0), 0.004)])
def test_covered_fraction_against_monte_carlo(fov, offset):
    """MC: uniform focal-plane points, kept where the sight line meets the ball (angle to the
    centre <= asin(r/D)); the share of them inside the FOV."""
    rng = np.random.default_rng(1)
    o = np.array([-0.0121, 0.0, 0.0])
    c = np.array([0.84, 0.0, 0.0])
    r = 0.012
    axis = (c - o) + np.array([0.0, offset, 0.0])
    frac = cu.covered_fraction(c, r, o, fov, axis=axis)
    F = cu.boresight_frame(axis, fov.roll)
    w = (c - o) / np.linalg.norm(c - o)
    alpha = np.arcsin(r / np.linalg.norm(c - o))
    lim = 3 * np.tan(alpha) + np.tan(0.02)
    XY = rng.uniform(-lim, lim, (800_000, 2))
    d = XY[:, :1] * F[0] + XY[:, 1:] * F[1] + F[2]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hit = d @ w >= np.cos(alpha)
    n = hit.sum()
    mc = fov.contains_plane(XY[hit]).mean()
    assert 0 < frac < 1
    assert abs(frac - mc) <= 4 * np.sqrt(mc * (1 - mc) / n) + 1e-4, (frac, mc, n)


def test_probability_models_and_tucker_inversion():
    o = np.zeros(3)
    fov = cu.FOV.rect(1.0)
    c = np.array([1.0, 0, 0])
    p_small = cu.custody_probability(c, 0.002, o, fov)
    p_big = cu.custody_probability(c, 0.02, o, fov)
    assert p_small == 1.0
    # square of side 2 tan(h) against the disc of radius tan(asin(r/D))
    expect = (2 * np.tan(np.deg2rad(0.5))) ** 2 / (np.pi * np.tan(np.arcsin(0.02)) ** 2)
    assert abs(p_big - expect) <= 1e-5
    t_small = cu.custody_probability(c, 0.02, o, fov, model="tucker-eq14")
    t_big = cu.custody_probability(c, 0.2, o, fov, model="tucker-eq14")
    assert t_big > t_small  # Eq. 14 as printed grows as the ball outgrows the FOV (inverted)
    with pytest.raises(ProblemError, match="model"):
        cu.custody_probability(c, 0.02, o, fov, model="area")


def test_sampled_positions_in_fov():
    o = np.zeros(3)
    pts = np.array([[1.0, 0.0, 0.0], [1.0, 0.0087, 0.0], [1.0, 0.0089, 0.0], [-1.0, 0.0, 0.0]])
    m = cu.points_in_fov(pts, o, cu.FOV.circle(1.0), axis=[1.0, 0, 0])
    assert m.tolist() == [True, True, False, False]  # tan(0.5 deg) = 0.008727; the last is behind


# ------------------------------------------------------------------ horizon search
def test_horizon_search_recovers_synthetic_step():
    t_star = 2.3456789
    h = cu.custody_horizon(lambda t: 1.0 if t < t_star else 0.5, 0.95, 5.0, t_step=1.0, tol=1e-6)
    assert h.t_safe <= t_star <= h.t_loss and h.t_loss - h.t_safe <= 1e-6
    assert h.converged and h.message == "" and not h.lost_at_start
    assert h.evaluations[0] == (0.0, 1.0)  # t_min is evaluated first
    never = cu.custody_horizon(lambda t: 1.0, 0.95, 5.0, t_step=1.0, tol=1e-3)
    assert never.t_loss is None and never.t_safe == 5.0 and never.converged


def test_horizon_search_reports_when_it_did_not_converge():
    t_star = 2.3456789
    step = lambda t: 1.0 if t < t_star else 0.5  # noqa: E731
    # bisection budget: 3 halvings of the [2, 3] bracket leave 1/8, far above tol
    h = cu.custody_horizon(step, 0.95, 5.0, t_step=1.0, tol=1e-6, max_bisections=3)
    assert not h.converged and "max_bisections = 3" in h.message
    assert h.t_safe <= t_star <= h.t_loss and h.t_loss - h.t_safe == pytest.approx(1 / 8)
    assert cu.custody_horizon(step, 0.95, 5.0, t_step=1.0, tol=0.2, max_bisections=3).converged
    # a tolerance below the float spacing of t: the search stops (it looped forever before)
    h = cu.custody_horizon(step, 0.95, 5.0, t_step=1.0, tol=1e-300)
    assert not h.converged and "floating-point resolution" in h.message
    assert h.t_safe <= t_star <= h.t_loss and h.t_loss == np.nextafter(h.t_safe, np.inf)
    # an evaluation that fails inside the bracket (e.g. a bvp continuation): the bracket so far
    def flaky(t):
        if t == 2.25:  # the second bisection point of [2, 3]
            raise SolverError("bvp: continuation failed (test)")
        return step(t)

    h = cu.custody_horizon(flaky, 0.95, 5.0, t_step=1.0, tol=1e-6)
    assert not h.converged and "failed at t = 2.25" in h.message and "continuation failed" in h.message
    assert (h.t_safe, h.t_loss) == (2.0, 2.5)

    def broken(t):
        if t > 0:
            raise SolverError("bvp: no solution (test)")
        return 1.0

    with pytest.raises(SolverError, match="no solution"):  # no bracket yet: the failure is raised
        cu.custody_horizon(broken, 0.95, 5.0, t_step=1.0, tol=1e-6)


def test_horizon_search_evaluates_t_min():
    # custody already lost at the start (and regained later): no horizon, lost at t_min; the
    # scan alone (t_min + k t_step) would have reported custody held to t_max
    late = lambda t: 0.5 if t < 0.1 else 1.0  # noqa: E731
    h = cu.custody_horizon(late, 0.95, 5.0, t_step=1.0, tol=1e-6)
    assert h.lost_at_start and h.t_safe is None and h.t_loss == 0.0 and h.converged
    assert h.evaluations == ((0.0, 0.5),) and "already lost at t_min = 0" in h.message
    h = cu.custody_horizon(lambda t: 1.0 if t < 1.2 else 0.5, 0.95, 5.0, t_step=1.0, tol=1e-6, t_min=1.5)
    assert h.lost_at_start and h.t_loss == 1.5 and h.evaluations == ((1.5, 0.5),)
    h = cu.custody_horizon(lambda t: 1.0 if t < 2.2 else 0.5, 0.95, 5.0, t_step=1.0, tol=1e-6, t_min=1.5)
    assert not h.lost_at_start and h.t_safe <= 2.2 <= h.t_loss and h.evaluations[0] == (1.5, 1.0)


def test_custody_report_start_ball_and_search_at_start():
    from ocreach.custody.reach_balls import ReachableBalls
    from ocreach.custody.report import _search

    point = ReachableBalls("custody-l1")
    c, r = point.start_ball()
    assert r == 0.0 and np.allclose(c, point.base.x0[:3])
    fuzzy = ReachableBalls("custody-l1", overrides={"uncertain": True, "sigma_pos_km": 3.0})
    c, r = fuzzy.start_ball()
    assert r * fuzzy.base.units.length / 1e3 == pytest.approx(3.0, rel=1e-12)
    below = _search(lambda t: 1.0, 0.95, 5.0, 1.0, 1e-3, t_set=0.0)  # set below the mask at t = 0
    assert below.lost_at_start and below.t_loss == 0.0


def test_horizon_search_recovers_analytic_ball_horizon():
    """Ball r(t) = a t^2 / 2 on the boresight at range D, circular FOV of half-angle h: the
    covered fraction is tan^2 h / tan^2 asin(r / D), so p drops below p* at
    r* = D sin(atan(tan h / sqrt(p*)))."""
    a, D, h, p_req = 0.02, 0.85, np.deg2rad(0.5), 0.95
    o = np.zeros(3)
    fov = cu.FOV.circle(1.0)
    prob = lambda t: cu.custody_probability([D, 0, 0], 0.5 * a * t**2, o, fov)
    r_star = D * np.sin(np.arctan(np.tan(h) / np.sqrt(p_req)))
    t_star = np.sqrt(2 * r_star / a)
    hz = cu.custody_horizon(prob, p_req, 3.0, t_step=0.5, tol=1e-7)
    assert hz.t_safe <= t_star <= hz.t_loss, (hz, t_star)
    # Algorithm 1 as printed: compares an area with (1 - p)/length and returns one step late
    t_alg = cu.tucker_algorithm1(lambda t: np.pi * (0.5 * a * t**2) ** 2, p_req, 2 * h, D)
    assert t_alg >= 1.0


# ------------------------------------------------------------------ observers
def test_earth_rotation_angle_and_ground_site():
    assert np.isclose(np.rad2deg(cu.earth_rotation_angle(2451545.0)), 280.46061837504, atol=1e-9)
    sidereal_day = 1.0 / 1.00273781191135448
    a = cu.earth_rotation_angle(2460000.5)
    b = cu.earth_rotation_angle(2460000.5 + sidereal_day)
    assert abs(np.angle(np.exp(1j * (b - a)))) < 1e-8  # JD in one double: ~5e-10 d
    from ocreach.units import EARTH_MOON_PATEL as U

    F = cu.earth_moon_frame("2026-12-01")
    np.testing.assert_allclose(F @ F.T, np.eye(3), atol=1e-12)
    g = cu.ground_site(0.0, 0.0, 0.0, "2026-12-01", mu=0.01215, units=U)
    P = g.position(np.linspace(0, 1, 7))
    np.testing.assert_allclose(np.linalg.norm(P - [-0.01215, 0, 0], axis=1) * U.length / 1e3,
                               cu.WGS84_A_KM, rtol=1e-12)
    up = g.up_fn(np.array([0.0]))[0]
    assert np.isclose(np.linalg.norm(up), 1.0)
    # a target straight above the site is visible, one through the Earth is not
    above = P[0] + 0.5 * up
    below = P[0] - 0.5 * up
    assert g.visible([0.0], [above])[0] and not g.visible([0.0], [below])[0]


def test_ground_site_applies_tt_minus_ut1():
    """UT1 = TDB - 69.2 s: an equatorial site sits 2 pi x 1.00273781 x 69.2 / 86400 rad = 0.2891
    deg behind (about the Earth's pole) the site with UT1 taken equal to TDB."""
    from ocreach.units import EARTH_MOON_PATEL as U

    mu = 0.01215
    g = cu.ground_site(0.0, 30.0, 0.0, "2026-12-01", mu=mu, units=U)
    g0 = cu.ground_site(0.0, 30.0, 0.0, "2026-12-01", mu=mu, units=U, tt_minus_ut1_s=0.0)
    assert g.info["tt_minus_ut1_s"] == cu.TT_MINUS_UT1_S == 69.2
    t = np.array([0.0, 0.3])
    a, b = g.position(t) - [-mu, 0, 0], g0.position(t) - [-mu, 0, 0]
    expected = 2 * np.pi * 1.00273781191135448 * 69.2 / 86400.0
    ang = np.arccos(np.clip(np.einsum("ij,ij->i", a, b) / np.einsum("ij,ij->i", a, a), -1, 1))
    np.testing.assert_allclose(ang, expected, rtol=1e-6)
    assert np.rad2deg(expected) == pytest.approx(0.2891, abs=1e-4)
    F = cu.earth_moon_frame("2026-12-01")
    pole = F[:, 2]  # the ICRF z-axis (the Earth's pole here) in the rotating frame at t = 0
    assert np.cross(a[0], b[0]) @ pole > 0  # the site with UT1 = TDB is ahead: Earth turned further
    with pytest.raises(ProblemError, match="tt_minus_ut1_s"):
        cu.ground_site(0.0, 30.0, 0.0, "2026-12-01", mu=mu, units=U, tt_minus_ut1_s=1e4)


def test_orbit_observer_follows_the_problem_orbit():
    prob = get_problem("custody-gateway", t_days=1.0)
    obs = cu.orbit_observer(prob.model, prob.x0, prob.params)
    P = obs.position([0.0, 0.1, 0.2])
    assert np.allclose(P[0], prob.x0[:3])
    from ocreach.dynamics.flow import propagate

    p0 = prob.params.copy()
    p0[1] = 0.0
    ref = propagate(prob.model, prob.x0, np.zeros((2, 3)), [0.0, 0.1, 0.2], p=p0)
    np.testing.assert_allclose(P, ref[:, :3], atol=1e-9)


# ------------------------------------------------------------------ bad input
def test_bad_input():
    o = np.zeros(3)
    for bad in (0.0, -1.0, 180.0, 200.0, float("nan")):
        with pytest.raises(ProblemError, match="fov"):
            cu.FOV.circle(bad)
        with pytest.raises(ProblemError, match="fov"):
            cu.FOV.rect(bad)
    for bad in (0.0, -0.1, 1.01, float("nan")):
        with pytest.raises(ProblemError, match="probability"):
            cu.custody_horizon(lambda t: 1.0, bad, 5.0, t_step=1.0, tol=0.1)
    with pytest.raises(ProblemError, match="inside the reachable-set ball"):
        cu.custody_probability([1.0, 0, 0], 2.0, o, cu.FOV.circle(1.0))
    with pytest.raises(ProblemError, match="inside the reachable-set ball"):
        cu.ball_in_fov([0.0, 0, 0], 0.1, o, cu.FOV.circle(1.0))
    with pytest.raises(ProblemError, match="non-empty"):
        cu.points_in_fov(np.zeros((0, 3)), o, cu.FOV.circle(1.0), [1, 0, 0])
    with pytest.raises(ProblemError, match="finite"):
        cu.points_in_fov([[1.0, np.nan, 0.0]], o, cu.FOV.circle(1.0), [1, 0, 0])
    with pytest.raises(SetError, match="non-empty"):
        minimum_enclosing_ball(np.zeros((0, 3)))
    with pytest.raises(SetError, match="finite"):
        minimum_enclosing_ball([[0.0, 1.0, np.nan]])
    with pytest.raises(ProblemError, match="latitude"):
        cu.ground_site(95.0, 0.0, 0.0, "2026-01-01", mu=0.012, units=get_problem("custody-l1").units)
    with pytest.raises(ProblemError, match="control_set"):
        get_problem("custody-l1", control_set="free")
