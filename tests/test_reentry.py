"""Re-entry model (Jain et al. Eq. 19-23, corrected), problems and the stochastic Monte Carlo.

Truths: the spherical-Earth equations written out here in physical units (Vinh; Betts' shuttle
example) with NumPy, SciPy's solve_ivp, and the exact mean/covariance recursion of a linear system.
"""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ocreach.dynamics.stochastic_mc import psd_factor, step_map_for, stochastic_monte_carlo
from ocreach.errors import ProblemError
from ocreach.models.reentry import GLIDER, SHUTTLE, reentry
from ocreach.problem import Problem, StochasticSpec
from ocreach.registry import get_problem

D = np.pi / 180


def phys_rhs(x, u, veh):
    """Vinh's 3-DOF equations, azimuth from north, physical units, lift/drag of Tables 2/4."""
    h, v, gam, th, psi, phi = x
    alpha, bank = u
    a = alpha / D if veh.alpha_in_degrees else alpha
    cl = veh.a0 + veh.a1 * a
    cd = veh.b0 + veh.b1 * a + veh.b2 * a**2
    r = veh.Re + h
    g = veh.mu / r**2
    q = 0.5 * veh.rho0 * np.exp(-h / veh.h_r) * v**2 * veh.S
    L, Dr = q * cl, q * cd
    return np.array([
        v * np.sin(gam),
        -Dr / veh.m - g * np.sin(gam),
        L * np.cos(bank) / (veh.m * v) + np.cos(gam) * (v / r - g / v),
        v * np.cos(gam) * np.cos(psi) / r,
        L * np.sin(bank) / (veh.m * v * np.cos(gam)) + v * np.cos(gam) * np.sin(psi) * np.tan(th) / r,
        v * np.cos(gam) * np.sin(psi) / (r * np.cos(th)),
    ])


@pytest.mark.parametrize("veh", [SHUTTLE, GLIDER], ids=["shuttle", "glider"])
def test_model_matches_spherical_earth_equations(veh):
    rng = np.random.default_rng(1)
    model = reentry(veh)
    sm = step_map_for(get_problem("shuttle-reentry" if veh is SHUTTLE else "glider-reentry",
                                  t_final=10.0))
    base = np.array([60000.0, 5000.0, -5 * D, 10 * D, 40 * D, 5 * D]) if veh is GLIDER else \
        np.array([200000.0, 20000.0, -2 * D, 20 * D, 70 * D, 30 * D])
    for _ in range(5):
        xp = base * (1 + 0.1 * rng.uniform(-1, 1, 6))
        u = np.array([rng.uniform(5, 25), rng.uniform(-80, 80)]) * D
        truth = phys_rhs(xp, u, veh)
        got = model(veh.to_model(xp), u) * veh.scale
        np.testing.assert_allclose(got, truth, rtol=1e-11, atol=1e-14)
        # the split Euler step is x + dt f (Jain Eq. 21-23, corrected)
        dt = 0.7
        step = sm.step(veh.to_model(xp)[None], u[None], dt)[0] * veh.scale
        np.testing.assert_allclose(step, xp + dt * truth, rtol=1e-11, atol=1e-12)


def _euler_vs_scipy(pid, dt, times):
    p = get_problem(pid, dt=dt)
    veh = p.extra["vehicle"]
    sm = step_map_for(p)
    u = p.stochastic.u_nominal
    x = p.x0.copy()
    xs = [x]
    for k in range(p.n_segments):
        x = sm.step(x[None], u[k][None], p.grid[k + 1] - p.grid[k])[0]
        xs.append(x)
    xs = veh.to_physical(np.array(xs))
    grid = p.grid
    idx = [int(np.argmin(np.abs(grid - t))) for t in times]
    y = veh.to_physical(p.x0)
    # integrate segment by segment (controls piecewise constant)
    out = [y]
    for k in range(p.n_segments):
        y = solve_ivp(lambda t, yy: phys_rhs(yy, u[k], veh), (grid[k], grid[k + 1]), y,
                      rtol=1e-10, atol=1e-10 * np.abs(y).max(), method="DOP853").y[:, -1]
        out.append(y)
    out = np.array(out)
    ref = out[idx]
    return np.abs(xs[idx] - ref)


def test_euler_step_against_accurate_integration_shuttle():
    """Stated tolerance (docs/reentry.md): at dt = 1 s the Euler map stays within 1000 ft in h,
    50 ft/s in v and 0.01 rad in the angles of the DOP853 solution over 1000 s, and the error is
    first order (halves with dt)."""
    e1 = _euler_vs_scipy("shuttle-reentry", 1.0, [500.0, 1000.0])
    e2 = _euler_vs_scipy("shuttle-reentry", 0.5, [500.0, 1000.0])
    assert np.all(e1[:, 0] < 1000.0) and np.all(e1[:, 1] < 50.0) and np.all(e1[:, 2:] < 0.01)
    ratio = e1[-1, :2] / e2[-1, :2]
    assert np.all((ratio > 1.6) & (ratio < 2.4)), ratio


def test_euler_step_against_accurate_integration_glider():
    """At dt = 0.1 s: within 500 m, 30 m/s and 0.02 rad of the DOP853 solution over 120 s."""
    e = _euler_vs_scipy("glider-reentry", 0.1, [30.0, 60.0, 120.0])
    assert np.all(e[:, 0] < 500.0) and np.all(e[:, 1] < 30.0) and np.all(e[:, 2:] < 0.02), e


def test_problems_follow_the_paper():
    p = get_problem("shuttle-reentry")
    veh = p.extra["vehicle"]
    assert p.grid[-1] == 2000.0 and p.n_segments == 2000
    mean = veh.to_physical(p.stochastic.x0_mean)
    np.testing.assert_allclose(mean[:3], [260000.0, 25600.0, -D])
    std = np.sqrt(np.diag(p.stochastic.x0_cov)) * veh.scale
    np.testing.assert_allclose(std, [3000.0, 0, 0, 0.5 * D, 0.5 * D, 0], atol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.diag(p.stochastic.u_cov)), [3 * D, 3 * D])
    np.testing.assert_allclose(p.stochastic.u_nominal[[0, -1], 1], [-75 * D, (-75 + 70 * 1999 / 2000) * D])
    g = get_problem("glider-reentry")
    gm = GLIDER.to_physical(g.stochastic.x0_mean)
    np.testing.assert_allclose(gm, [80000.0, 5000.0, -35.0822 * D, 0, 0, 0])
    assert g.grid[-1] == 120.0
    with pytest.raises(ProblemError, match="dt"):
        get_problem("glider-reentry", dt=0.0)


def _nominal_path(**kw):
    """Mean state under the nominal controls (Euler map) at t = 0, 500, 1000, 2000 s, physical."""
    p = get_problem("shuttle-reentry", **kw)
    sm = step_map_for(p)
    x, out = p.x0.copy(), {0: p.x0.copy()}
    for k in range(p.n_segments):
        x = sm.step(x[None], p.stochastic.u_nominal[k][None], 1.0, p.grid[k])[0]
        out[k + 1] = x
    return p.extra["vehicle"].to_physical(np.array([out[t] for t in (0, 500, 1000, 2000)]))


def test_shuttle_azimuth_default_reproduces_the_papers_trends():
    """Jain et al. describe Fig. 4: 'altitude h, velocity v and azimuth psi decreasing, latitude
    theta and longitude phi increasing'.  The default psi0 = 90 deg (Betts Ex. 6.1, the source
    problem) gives all five; the literal Eq. 24 value psi0 = -1 deg (an option) cannot: with the
    left bank the longitude decreases, with the mirrored right bank psi increases."""
    x = _nominal_path()
    assert x[0, 4] == pytest.approx(90 * D)
    d = np.diff(x, axis=0)
    assert np.all(d[:, [0, 1, 4]] < 0) and np.all(d[:, [3, 5]] > 0), d
    lit = _nominal_path(psi0_deg=-1.0)
    assert lit[0, 4] == pytest.approx(-D)
    assert np.all(np.diff(lit[:, 5]) < 0)  # longitude decreases: contradicts the text
    mirror = _nominal_path(psi0_deg=-1.0, bank0_deg=75.0, bank1_deg=5.0)
    assert np.all(np.diff(mirror[:, 4]) > 0)  # azimuth increases: contradicts the text


def _linear_problem(cov0, u_cov, K=30, dt=0.1, A=None):
    """x' = A x + B u: the exact mean/covariance recursion of its Euler map is the truth.
    A zero column of ``A`` makes that state absent from f (exercises ``cut``'s ``reduce``)."""
    import casadi as ca

    from ocreach.model import Model

    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    A = np.array([[0.0, 1.0], [-1.0, -0.2]]) if A is None else np.asarray(A, dtype=float)
    B = np.array([[0.0], [0.5]])
    f = ca.vertcat(*[sum((float(A[i, j]) * x[j] for j in range(2) if A[i, j] != 0), ca.SX(0))
                     for i in range(2)]) + ca.mtimes(ca.DM(B), u)
    model = Model.build("lin" if A[0, 0] or A[1, 0] else "lin_red", x, u, f, control_set="free")
    grid = np.arange(K + 1) * dt
    spec = StochasticSpec(x0_mean=np.array([1.0, 0.0]), x0_cov=np.asarray(cov0),
                          u_nominal=np.sin(grid[:-1])[:, None], u_cov=np.asarray(u_cov))
    p = Problem(id="lin", model=model, x0=spec.x0_mean, grid=grid, stochastic=spec)
    Ad = np.eye(2) + dt * A
    Bd = dt * B
    m, P = spec.x0_mean.copy(), np.asarray(cov0, float).copy()
    means, covs = [m], [P]
    for k in range(K):
        m = Ad @ m + Bd @ spec.u_nominal[k]
        P = Ad @ P @ Ad.T + Bd @ spec.u_cov @ Bd.T
        means.append(m)
        covs.append(P)
    return p, np.array(means), np.array(covs)


def test_stochastic_mc_linear_system_within_standard_error():
    p, means, covs = _linear_problem(np.diag([0.04, 0.01]), np.array([[0.25]]))
    N = 20000
    out = stochastic_monte_carlo(p, samples=N, seed=3, times=[p.grid[10], p.grid[-1]])
    idx = out["index"]
    sd = np.sqrt(np.einsum("kii->ki", covs[idx]))
    # 4 standard errors: 8 comparisons, family-wise false-alarm probability < 1e-3
    assert np.all(np.abs(out["mean"] - means[idx]) < 4 * sd / np.sqrt(N))
    assert np.all(np.abs(out["std"] - sd) < 4 * sd / np.sqrt(2 * N))
    assert out["trajectories"].shape == (N, 2, 2)
    # the per-step statistics on the whole grid follow the exact recursion too (fresh controls
    # every step; one draw per trajectory would give another spread); 5 SE over 62 comparisons
    sd_all = np.sqrt(np.einsum("kii->ki", covs))
    assert np.all(np.abs(out["grid_std"] - sd_all) < 5 * sd_all / np.sqrt(2 * N))
    assert np.all(np.abs(out["grid_mean"] - means) < 5 * sd_all / np.sqrt(N) + 1e-15)


def test_psd_factor_and_errors():
    P = np.array([[4.0, 2.0], [2.0, 1.0]])  # singular PSD
    L = psd_factor("P", P, 2)
    np.testing.assert_allclose(L @ L.T, P, atol=1e-12)
    with pytest.raises(ProblemError, match="positive semidefinite"):
        psd_factor("stochastic.x0_cov", np.diag([1.0, -0.5]), 2)
    with pytest.raises(ProblemError, match="symmetric"):
        psd_factor("P", np.array([[1.0, 0.5], [0.0, 1.0]]), 2)
    with pytest.raises(ProblemError, match=r"\(2, 2\)"):
        psd_factor("P", np.eye(3), 2)
    p, _, _ = _linear_problem(np.diag([0.04, -0.01]), np.array([[0.25]]))
    with pytest.raises(ProblemError, match="x0_cov must be positive semidefinite"):
        stochastic_monte_carlo(p, samples=10)
    with pytest.raises(ProblemError, match="times must be times of the problem grid"):
        stochastic_monte_carlo(get_problem("glider-reentry", t_final=1.0), samples=10, times=[0.55])


def test_compiled_monte_carlo_matches_per_step_path():
    """The fused C Monte Carlo (steps + per-step statistics in one call per block of steps) gives
    the numbers of the per-step batched path: same random stream, same compiled step."""
    p = get_problem("glider-reentry", t_final=8.0)
    T = [0.1, 3.0, 8.0]
    a = stochastic_monte_carlo(p, samples=500, seed=4, times=T, keep_controls=True)
    sm = step_map_for(p)
    kern = sm._maps.pop("mc_kernel")
    sm._maps["mc_kernel"] = None  # per-step path
    try:
        b = stochastic_monte_carlo(p, samples=500, seed=4, times=T, keep_controls=True)
    finally:
        sm._maps["mc_kernel"] = kern
    assert kern is not None
    for key in ("trajectories", "controls", "grid_mean"):
        np.testing.assert_allclose(a[key], b[key], rtol=1e-13, atol=0)
    np.testing.assert_allclose(a["grid_std"], b["grid_std"], rtol=1e-10, atol=0)
    # the per-step statistics are the sample mean/std of the kept states (independent numpy)
    k = int(a["index"][1])
    np.testing.assert_allclose(a["grid_std"][k], a["trajectories"][:, 1].std(axis=0, ddof=1), rtol=1e-10)
