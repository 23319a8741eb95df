"""Monte Carlo and extremal-ODE methods against independent truth (scipy, CasADi + IPOPT)."""
import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import ocreach
from ocreach.reach.extremal import extremal_rhs


@pytest.fixture(scope="module")
def dro():
    return ocreach.get_problem("dro")


@pytest.fixture(scope="module")
def mc_result(dro):
    return ocreach.reach(dro, "mc", samples=300, seed=3)


def _scipy_resimulate(problem, x0, controls):
    """Independent integration of one sample under its piecewise-constant controls."""
    model, p = problem.model, problem.params
    x = np.asarray(x0, float)
    out = [x]
    for k in range(problem.n_segments):
        u = controls[k]
        sol = solve_ivp(lambda t, y: model(y, u, t, p), (problem.grid[k], problem.grid[k + 1]), x,
                        method="DOP853", rtol=1e-12, atol=1e-13)
        x = sol.y[:, -1]
        out.append(x)
    return np.array(out)


def test_mc_samples_resimulate_from_stored_controls(dro, mc_result):
    r = mc_result
    assert r.controls.shape == (300, dro.n_segments, 2)
    assert np.all(dro.control_set.contains(r.controls))
    law = np.asarray(r.meta["control_law"])
    assert set(law.tolist()) == {0, 1, 2}
    rng = np.random.default_rng(0)
    for i in rng.choice(300, 12, replace=False):
        traj = _scipy_resimulate(dro, r.trajectories[i, 0], r.controls[i])
        assert np.abs(traj - r.trajectories[i]).max() < 1e-8


def test_mc_constant_and_bang_laws_use_full_thrust(mc_result):
    law = np.asarray(mc_result.meta["control_law"])
    norms = np.linalg.norm(mc_result.controls, axis=-1)
    assert np.allclose(norms[law > 0], 1.0)
    assert np.all(norms[law == 0] <= 1.0 + 1e-12)


def test_result_points_support_and_roundtrip(tmp_path, mc_result):
    d = np.array([0.3, -0.7, 0.1, 0.2])
    expected = np.max(mc_result.trajectories[:, -1] @ d)
    assert mc_result.support(d) == pytest.approx(expected)
    assert mc_result.support(d[:2], dims=[0, 1]) == pytest.approx(
        np.max(mc_result.trajectories[:, -1, :2] @ d[:2]))
    path = mc_result.save(tmp_path / "r.npz")
    back = ocreach.load(path)
    assert np.array_equal(back.controls, mc_result.controls)
    assert back.support(d) == pytest.approx(expected)
    assert back.meta["method"] == "mc"


def _direct_support(problem, direction, n_seg=60, substeps=8, box=False):
    """max d^T x(t_f) over piecewise-constant controls, ||u|| <= 1 (or |u_i| <= 1 with ``box``):
    multiple shooting, RK4, IPOPT."""
    m = problem.model
    t0, tf = problem.grid[0], problem.grid[-1]
    h = (tf - t0) / n_seg / substeps
    x, u = ca.MX.sym("x", m.n_x), ca.MX.sym("u", m.n_u)
    f = lambda xx: m.f_fun(xx, u, 0.0, problem.params)
    xk = x
    for _ in range(substeps):
        k1 = f(xk); k2 = f(xk + h / 2 * k1); k3 = f(xk + h / 2 * k2); k4 = f(xk + h * k3)
        xk = xk + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    step = ca.Function("step", [x, u], [xk])
    opti = ca.Opti()
    X = opti.variable(m.n_x, n_seg + 1)
    U = opti.variable(m.n_u, n_seg)
    opti.subject_to(X[:, 0] == problem.x0)
    for k in range(n_seg):
        opti.subject_to(X[:, k + 1] == step(X[:, k], U[:, k]))
        if box:
            opti.subject_to(opti.bounded(-1, U[:, k], 1))
        else:
            opti.subject_to(ca.sumsqr(U[:, k]) <= 1)
    opti.minimize(-ca.dot(direction, X[:, -1]))
    # warm start on the unforced trajectory pushed along the direction's velocity part
    opti.set_initial(U, 0.0)
    xs = problem.x0.copy()
    for k in range(n_seg + 1):
        opti.set_initial(X[:, k], xs)
        if k < n_seg:
            xs = np.asarray(step(xs, np.zeros(m.n_u))).ravel()
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes", "tol": 1e-10})
    sol = opti.solve()
    return float(np.dot(direction, sol.value(X[:, -1])))


def test_ode_endpoints_are_extremal_and_never_exceed_direct_optimum(dro):
    r = ocreach.reach(dro, "ode", samples=6, seed=11)
    lam_f = np.asarray(r.meta["costate_final"])
    ends = r.points[-1]
    width_scale = 0.25  # DU-scale of the final set (position ~0.2, velocity ~0.3)
    for i in range(len(ends)):
        d = -lam_f[i] / np.linalg.norm(lam_f[i])
        best = _direct_support(dro, d)
        val = float(d @ ends[i])
        # never beyond the optimum (piecewise-constant optimum on 60 segments lies below the true
        # support by O(discretisation); the slack is 1e-4 of the set scale)
        assert val <= best + 1e-4 * width_scale, (i, val, best)
        # and on the boundary: PMP extremal attains the optimum in its own direction
        assert val >= best - 1e-2 * width_scale, (i, val, best)


def test_ode_costate_dynamics_reproduce_trajectory(dro):
    r = ocreach.reach(dro, "ode", samples=3, seed=5)
    rhs = extremal_rhs(dro.model)
    lam0 = np.asarray(r.meta["costate0"])
    for i in range(3):
        y0 = np.concatenate([dro.x0, lam0[i]])
        sol = solve_ivp(lambda t, y: np.asarray(rhs(y, t, dro.params)).ravel(),
                        (dro.grid[0], dro.grid[-1]), y0, method="DOP853", rtol=1e-12, atol=1e-13)
        assert np.abs(sol.y[:4, -1] - r.points[-1][i]).max() < 1e-7


def test_method_errors(dro):
    with pytest.raises(ocreach.UnknownNameError, match="unknown method"):
        ocreach.reach(dro, "magic")
    with pytest.raises(ocreach.ProblemError, match="samples"):
        ocreach.reach(dro, "mc", samples=0)
    with pytest.raises(ocreach.ProblemError, match="no option"):
        ocreach.reach(dro, "mc", samplez=10)


@pytest.mark.parametrize("method", ["mc", "ode"])
@pytest.mark.parametrize("bad,match", [
    ({"samples": 2.5}, "samples must be an integer >= 1; got 2.5"),
    ({"samples": True}, "samples must be an integer"),
    ({"seed": -1}, "seed must be an integer >= 0"),
    ({"rtol": 0.1}, r"rtol must be in \(0, 1e-3\)"),
    ({"atol": float("nan")}, "atol must be a finite number >= 0"),
])
def test_sampling_options_are_validated(method, bad, match):
    from ocreach.reach.base import method_class
    with pytest.raises(ocreach.ProblemError, match=match):
        method_class(method)(**bad)


def test_ode_box_control_set_on_ball_model(dro):
    """Problem with a box control set on the (ball) CR3BP model: bang-bang extremals that reach
    the box-constrained direct optimum and exceed the ball's reach (corners have norm sqrt 2)."""
    box = ocreach.Problem(id="dro-box", model=dro.model, x0=dro.x0, grid=dro.grid,
                          control_set=ocreach.ControlSet("box", 2))
    r = ocreach.reach(box, "ode", samples=2, seed=4)
    assert r.meta["control_set"] == "box"
    assert np.allclose(np.abs(r.controls), 1.0)
    lam_f = np.asarray(r.meta["costate_final"])
    for i in range(2):
        d = -lam_f[i] / np.linalg.norm(lam_f[i])
        best = _direct_support(box, d, box=True)
        val = float(d @ r.points[-1][i])
        assert best - 2.5e-3 <= val <= best + 2.5e-5, (i, val, best)
        assert val > _direct_support(dro, d) + 1e-3  # more than the ball allows


def test_ode_rejects_free_controls(dro):
    free = ocreach.Problem(id="dro-free", model=dro.model, x0=dro.x0, grid=dro.grid,
                           control_set=ocreach.ControlSet("free", 2))
    with pytest.raises(ocreach.ProblemError, match="bounded control set"):
        ocreach.reach(free, "ode", samples=2)


@pytest.mark.parametrize("mix,samples,expected", [
    ((0.0, 0.5, 0.5), 3, None), ((0.0, 1.0, 0.0), 7, (0, 7, 0)), ((1, 1, 1), 10, None),
])
def test_mc_mix_counts_respect_zero_fractions(dro, mix, samples, expected):
    from ocreach.reach.mc import sample_controls
    _, law = sample_controls(dro, samples, np.random.default_rng(0), mix)
    counts = np.bincount(law, minlength=3)
    assert counts.sum() == samples
    assert np.all(counts[np.asarray(mix) == 0] == 0)
    assert np.all(np.abs(counts - np.asarray(mix) / np.sum(mix) * samples) < 1)
    if expected is not None:
        assert tuple(counts) == expected


@pytest.mark.parametrize("backward", [False, True])
def test_ode_outward_normal_beats_monte_carlo(backward):
    """Each extremal endpoint is at least as far along its outward normal as every MC sample
    (forward and backward grids; in backward time the normal is +lam(t_f))."""
    vdp = ocreach.get_problem("vdp")
    grid = vdp.grid[::-1].copy() if backward else vdp.grid
    p = ocreach.Problem(id="v", model=vdp.model, x0=vdp.x0, grid=grid, control_set=vdp.control_set)
    r = ocreach.reach(p, "ode", samples=12, seed=2)
    mc = ocreach.reach(p, "mc", samples=400, seed=1).points[-1]
    n = np.asarray(r.meta["outward_normal"])
    own = np.einsum("ij,ij->i", n, r.points[-1])
    assert np.all(own >= np.max(mc @ n.T, axis=0) - 1e-9)


def test_ode_with_ellipsoid_initial_set_reaches_exact_linear_support():
    """Double integrator, |u| <= 1, ellipsoidal X0: endpoints attain the closed-form support
    h(nu) = nu^T Phi q + sqrt(nu^T Phi Q Phi^T nu) + int_0^T |nu^T Phi(T, t) B| dt."""
    import casadi as ca

    from ocreach.sets import Ellipsoid

    x, u = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    model = ocreach.Model.build("dint", x, u, ca.vertcat(x[1], u), control_set="box")
    T = 2.0
    q, Q = np.array([0.3, -0.2]), np.array([[0.05, 0.01], [0.01, 0.02]])
    prob = ocreach.Problem(id="dint", model=model, x0=q, grid=np.linspace(0, T, 5),
                           initial_set=Ellipsoid(q, Q))
    r = ocreach.reach(prob, "ode", samples=8, seed=2)
    Phi = np.array([[1.0, T], [0.0, 1.0]])
    s = np.linspace(0, T, 200001)
    for end, nu in zip(r.points[-1], r.meta["outward_normal"]):
        integrand = np.abs(nu[0] * (T - s) + nu[1])
        h = nu @ Phi @ q + np.sqrt(nu @ Phi @ Q @ Phi.T @ nu) + np.trapezoid(integrand, s)
        assert nu @ end == pytest.approx(h, abs=1e-6)
        # the start lies on the ellipsoid boundary
    starts = r.trajectories[:, 0]
    m = np.einsum("ij,jk,ik->i", starts - q, np.linalg.inv(Q), starts - q)
    assert np.allclose(m, 1.0)


def test_mc_rejects_options_a_stochastic_problem_cannot_use():
    glider = ocreach.get_problem("glider-reentry")
    with pytest.raises(ocreach.ProblemError, match="do not apply"):
        ocreach.reach(glider, "mc", samples=10, mix=(1, 0, 0))
