"""Tests of ocreach.dynamics.flow against independent references: SciPy's solve_ivp, central finite
differences of the propagated flow, and heyoka's variational equations (Foss et al. Eq. 11-13)."""
from __future__ import annotations

import itertools

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ocreach.dynamics import flow
from ocreach.dynamics.flow import integrate_batch, propagate, stm, stt
from ocreach.errors import ProblemError, SolverError
from ocreach.models import cr3bp, vanderpol
from ocreach.native.integrator import stepper

MU = 0.0122
A_MAX = 1.1e-3 / 14 / (3.825e8 / 3.724e5**2)
X_DRO = np.array([0.2765, 0.0, 0.0, 2.1379])
TIGHT = dict(rtol=1e-13, atol=1e-15)


@pytest.fixture(scope="module")
def dro_model():
    return cr3bp(MU, planar=True, a_max=A_MAX)


@pytest.fixture(scope="module")
def vdp_model():
    return vanderpol(gain=0.5)


def disk_controls(rng, shape):
    ang = rng.uniform(0, 2 * np.pi, shape)
    rad = np.sqrt(rng.uniform(0, 1, shape))
    return np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=-1)


def scipy_reference(model, x0, controls, grid):
    """Independent truth: SciPy DOP853 segment by segment (rtol 1e-12)."""
    p = model.p_default
    fun = model.f_fun
    x = np.array(x0, dtype=float)
    out = [x]
    for k in range(len(grid) - 1):
        sol = solve_ivp(lambda t, y, u=controls[k]: np.asarray(fun(y, u, t, p)).ravel(),
                        (grid[k], grid[k + 1]), x, method="DOP853", rtol=1e-12, atol=1e-14)
        assert sol.success
        x = sol.y[:, -1]
        out.append(x)
    return np.array(out)


# ----------------------------------------------------------------------------- propagation
def test_propagate_batch_matches_scipy_on_dro(dro_model):
    rng = np.random.default_rng(1)
    grid = np.linspace(0.0, 3.0, 31)
    U = disk_controls(rng, (5, 30))
    X0 = X_DRO + 1e-3 * rng.normal(size=(5, 4))
    states = propagate(dro_model, X0, U, grid)
    assert states.shape == (5, 31, 4)
    for i in (0, 3):
        ref = scipy_reference(dro_model, X0[i], U[i], grid)
        np.testing.assert_allclose(states[i], ref, rtol=0, atol=1e-8)


def test_single_trajectory_shapes_and_dense_output(dro_model):
    rng = np.random.default_rng(2)
    grid = np.linspace(0.0, 1.0, 5)
    U = disk_controls(rng, (4,))
    states = propagate(dro_model, X_DRO, U, grid)
    assert states.shape == (5, 4)
    s2, times, dense = propagate(dro_model, X_DRO, U, grid, substeps=3)
    assert times.shape == (13,) and dense.shape == (13, 4)
    np.testing.assert_allclose(times[::3], grid)
    np.testing.assert_allclose(dense[::3], states, atol=1e-10)
    ref = scipy_reference(dro_model, X_DRO, np.repeat(U, 3, axis=0), times)
    np.testing.assert_allclose(dense, ref, atol=1e-8)


def test_per_sample_parameters(dro_model):
    grid = [0.0, 0.5]
    U = np.array([[1.0, 0.0]])
    P = np.array([[MU, 0.0], [MU, 10 * A_MAX]])
    states = propagate(dro_model, np.tile(X_DRO, (2, 1)), np.tile(U, (2, 1, 1)), grid, p=P)
    for i in range(2):
        m = cr3bp(MU, planar=True, a_max=P[i, 1])
        ref = scipy_reference(m, X_DRO, U, grid)
        np.testing.assert_allclose(states[i], ref, atol=1e-9)


def test_backward_time_round_trip(dro_model):
    rng = np.random.default_rng(3)
    grid = np.linspace(0.0, 2.0, 11)
    U = disk_controls(rng, (3, 10))
    X0 = np.tile(X_DRO, (3, 1))
    fwd = propagate(dro_model, X0, U, grid)
    back = propagate(dro_model, fwd[:, -1], U[:, ::-1], grid[::-1])
    np.testing.assert_allclose(back[:, ::-1], fwd, atol=1e-9)


def test_integrate_batch_per_sample_times_and_directions():
    x = ca.SX.sym("x", 2)
    t = ca.SX.sym("t")
    a = ca.SX.sym("a", 1)
    rhs = ca.Function("osc_test", [x, t, a], [ca.vertcat(x[1], -a[0] ** 2 * x[0])])
    w = np.array([1.0, 2.0, 0.5, 3.0])
    t0 = np.array([0.0, 1.0, 2.0, 0.5])
    t1 = np.array([5.0, -2.0, 2.0, 0.7])  # forward, backward, zero-length, short
    y0 = np.tile([1.0, 0.0], (4, 1))
    y = integrate_batch(rhs, y0, t0, t1, w[:, None])
    dt = t1 - t0
    exact = np.stack([np.cos(w * dt), -w * np.sin(w * dt)], axis=1)
    np.testing.assert_allclose(y, exact, atol=1e-9)


def test_numpy_fallback_matches_native(monkeypatch):
    x = ca.SX.sym("x", 2)
    t = ca.SX.sym("t")
    a = ca.SX.sym("a", 1)
    f = ca.vertcat(x[1], a[0] * (1 - x[0] ** 2) * x[1] - x[0])
    rhs_native = ca.Function("vdp_native_test", [x, t, a], [f])
    rhs_vm = ca.Function("vdp_vm_test", [x, t, a], [f])
    y0 = np.array([[2.0, 0.0], [0.5, -1.0], [1.0, 1.0]])
    mus = np.array([[0.5], [1.0], [2.0]])
    y_nat = integrate_batch(rhs_native, y0, 0.0, 4.0, mus)
    monkeypatch.setenv("OCREACH_JIT", "0")
    y_vm = integrate_batch(rhs_vm, y0, 0.0, 4.0, mus)
    assert stepper(rhs_vm).native is None
    np.testing.assert_allclose(y_vm, y_nat, rtol=0, atol=1e-12)
    ref = [solve_ivp(lambda tt, yy, m=m[0]: [yy[1], m * (1 - yy[0] ** 2) * yy[1] - yy[0]],
                     (0, 4), y, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
           for y, m in zip(y0, mus)]
    np.testing.assert_allclose(y_nat, ref, atol=1e-8)


# ----------------------------------------------------------------------------- STM / STT vs FD
def _flow_map(model, z, grid_seg, p=None):
    """x(t_{k+1}) for a batch of augmented states z = [x; u] (N, n_z) at t_k (vectorised)."""
    nx = model.n_x
    return propagate(model, z[:, :nx], z[:, None, nx:], grid_seg, p=p, **TIGHT)[:, -1]


def fd_tensors(model, z0, grid_seg, h1, h2, h3):
    """Central finite differences of the flow map with one Richardson extrapolation step
    (error O(h^4)): Jacobian, Hessian and third derivatives."""
    coarse = _fd_tensors(model, z0, grid_seg, h1, h2, h3)
    fine = _fd_tensors(model, z0, grid_seg, h1 / 2, h2 / 2, h3 / 2)
    return [(4 * f - c) / 3 for f, c in zip(fine, coarse)]


def _fd_tensors(model, z0, grid_seg, h1, h2, h3):
    nz = z0.size
    E = np.eye(nz)
    pts1 = np.concatenate([z0 + h1 * E, z0 - h1 * E])
    F = _flow_map(model, pts1, grid_seg)
    J = ((F[:nz] - F[nz:]) / (2 * h1)).T
    pairs = list(itertools.product(range(nz), repeat=2))
    signs2 = list(itertools.product((1, -1), repeat=2))
    pts2 = np.array([z0 + h2 * (sa * E[a] + sb * E[b]) for a, b in pairs for sa, sb in signs2])
    F2 = _flow_map(model, pts2, grid_seg).reshape(len(pairs), 4, -1)
    w2 = np.array([sa * sb for sa, sb in signs2])
    H = (np.einsum("s,psi->pi", w2, F2) / (4 * h2**2)).reshape(nz, nz, -1).transpose(2, 0, 1)
    triples = list(itertools.combinations_with_replacement(range(nz), 3))
    signs3 = list(itertools.product((1, -1), repeat=3))
    pts3 = np.array([z0 + h3 * (sa * E[a] + sb * E[b] + sc * E[c])
                     for a, b, c in triples for sa, sb, sc in signs3])
    F3 = _flow_map(model, pts3, grid_seg).reshape(len(triples), 8, -1)
    w3 = np.array([sa * sb * sc for sa, sb, sc in signs3])
    T = np.zeros((F3.shape[-1], nz, nz, nz))
    vals = np.einsum("s,psi->pi", w3, F3) / (8 * h3**3)
    for (a, b, c), v in zip(triples, vals):
        for perm in set(itertools.permutations((a, b, c))):
            T[(slice(None),) + perm] = v
    return J, H, T


@pytest.mark.parametrize("case", ["cr3bp", "vdp"])
def test_stt_orders_1_to_3_match_finite_differences(case, dro_model, vdp_model):
    rng = np.random.default_rng(4)
    if case == "cr3bp":
        model, x0, grid = dro_model, X_DRO, np.linspace(0.0, 1.2, 4)
        U = disk_controls(rng, (3,))
        hs = (1e-5, 1e-3, 1e-2)
    else:
        model, x0, grid = vdp_model, np.array([1.0, -0.5]), np.linspace(0.0, 1.5, 4)
        U = rng.uniform(-1, 1, (3, 1))
        hs = (1e-5, 1e-3, 2e-2)
    res = stt(model, x0, U, grid, 3, **TIGHT)
    assert res.states.shape == (4, model.n_x)
    assert res.Phi1.shape == (3, model.n_x, model.n_z)
    assert res.Phi3.shape == (3, model.n_x) + (model.n_z,) * 3
    np.testing.assert_allclose(res.states, propagate(model, x0, U, grid), atol=1e-10)
    k = 1
    z0 = np.concatenate([res.states[k], U[k]])
    J, H, T = fd_tensors(model, z0, grid[k:k + 2], *hs)
    scale = [np.abs(J).max(), np.abs(H).max(), np.abs(T).max()]
    assert np.abs(res.Phi1[k] - J).max() < 1e-7 * scale[0]
    assert np.abs(res.Phi2[k] - H).max() < 1e-5 * scale[1]
    assert np.abs(res.Phi3[k] - T).max() < 2e-3 * scale[2]
    # lower orders from a lower-order call agree with the order-3 call
    res2 = stt(model, x0, U, grid, 2, **TIGHT)
    np.testing.assert_allclose(res2.Phi2, res.Phi2, atol=1e-9 * scale[1])


def test_stt_prediction_error_converges_with_order(dro_model):
    """Foss Eq. 13: the order-j truncation error of a deviation dz scales like |dz|^(j+1)."""
    rng = np.random.default_rng(5)
    grid = np.linspace(0.0, 1.0, 3)
    U = disk_controls(rng, (2,))
    res = stt(dro_model, X_DRO, U, grid, 3, **TIGHT)
    k = 0
    z0 = np.concatenate([res.states[k], U[k]])
    d = rng.normal(size=6)
    d /= np.linalg.norm(d)
    errs = {}
    for eps in (1e-2, 5e-3):
        truth = _flow_map(dro_model, (z0 + eps * d)[None], grid[:2])[0] - res.states[k + 1]
        dz = eps * d
        pred = np.einsum("ia,a->i", res.Phi1[k], dz)
        errs[(1, eps)] = np.abs(pred - truth).max()
        pred = pred + 0.5 * np.einsum("iab,a,b->i", res.Phi2[k], dz, dz)
        errs[(2, eps)] = np.abs(pred - truth).max()
        pred = pred + np.einsum("iabc,a,b,c->i", res.Phi3[k], dz, dz, dz) / 6
        errs[(3, eps)] = np.abs(pred - truth).max()
        np.testing.assert_allclose(res.predict(k, dz), pred + (res.states[k + 1] * 0), atol=1e-15)
    for j in (1, 2, 3):
        ratio = errs[(j, 1e-2)] / errs[(j, 5e-3)]
        assert 0.6 * 2 ** (j + 1) < ratio < 1.6 * 2 ** (j + 1), (j, ratio, errs)


def test_stm_helper(dro_model):
    x1, Phi = stm(dro_model, X_DRO, 0.0, 0.7, u=[0.3, -0.2], **TIGHT)
    h = 1e-6
    E = np.eye(4)
    pts = np.concatenate([X_DRO + h * E, X_DRO - h * E])
    U = np.tile([0.3, -0.2], (8, 1, 1))
    F = propagate(dro_model, pts, U, [0.0, 0.7], **TIGHT)[:, -1]
    np.testing.assert_allclose(Phi, ((F[:4] - F[4:]) / (2 * h)).T, atol=1e-7)
    np.testing.assert_allclose(x1, propagate(dro_model, X_DRO, U[0], [0, 0.7])[-1], atol=1e-10)


def test_stm_batch_arcs_match_the_single_arc_helper(dro_model):
    """Independent arcs with their own start and end times, in one batch, against :func:`stm`."""
    X0 = X_DRO + np.array([[0.0, 0.0, 0.0, 0.0], [0.01, -0.02, 0.0, 0.01], [-0.01, 0.0, 0.02, 0.0]])
    t0, t1 = np.array([0.0, 0.3, 1.1]), np.array([0.7, 0.2, 1.9])  # one arc backward
    X1, Phi = flow.stm_batch(dro_model, X0, t0, t1, u=[0.3, -0.2], **TIGHT)
    assert X1.shape == (3, 4) and Phi.shape == (3, 4, 4)
    for i in range(3):
        x1, P = stm(dro_model, X0[i], t0[i], t1[i], u=[0.3, -0.2], **TIGHT)
        np.testing.assert_allclose(X1[i], x1, atol=1e-12)
        np.testing.assert_allclose(Phi[i], P, atol=1e-10)
    with pytest.raises(ProblemError, match="X0 must have shape"):
        flow.stm_batch(dro_model, X_DRO, 0.0, 1.0)
    # times and control of the wrong shape or type name the parameter (were numpy errors)
    for kw, word in [(dict(t0=[0.0, 1.0], t1=1.0), "t0"), (dict(t0=0.0, t1="a"), "t1"),
                     (dict(t0=0.0, t1=np.ones((3, 1))), "t1"),
                     (dict(t0=0.0, t1=1.0, u=[1.0, 2.0, 3.0]), "u")]:
        with pytest.raises(ProblemError, match=word):
            flow.stm_batch(dro_model, X0, **kw)


# ----------------------------------------------------------------------------- heyoka
def test_stt2_matches_heyoka_var_ode_sys(dro_model):
    hy = pytest.importorskip("heyoka")
    x, y, vx, vy = hy.make_vars("x", "y", "vx", "vy")
    r1 = hy.sqrt((x + MU) ** 2 + y**2)
    r2 = hy.sqrt((x - 1 + MU) ** 2 + y**2)
    ux, uy = hy.par[0], hy.par[1]
    sys = [(x, vx), (y, vy),
           (vx, x + 2 * vy - (1 - MU) * (x + MU) / r1**3 - MU * (x - 1 + MU) / r2**3 + A_MAX * ux),
           (vy, y - 2 * vx - (1 - MU) * y / r1**3 - MU * y / r2**3 + A_MAX * uy)]
    vsys = hy.var_ode_sys(sys, hy.var_args.vars | hy.var_args.params, order=2)
    u = np.array([0.6, -0.3])
    ta = hy.taylor_adaptive(vsys, list(X_DRO), compact_mode=True, tol=1e-14, pars=list(u))
    T = 1.5
    ta.propagate_until(T)
    res = stt(dro_model, X_DRO, u[None, :], [0.0, T], 2, **TIGHT)
    np.testing.assert_allclose(res.states[-1], ta.state[:4], atol=1e-11)
    P1 = ta.state[ta.get_vslice(order=1)].reshape(4, 6)
    np.testing.assert_allclose(res.Phi1[0], P1, atol=1e-9 * np.abs(P1).max())
    sl = ta.get_vslice(order=2)
    H = np.zeros((4, 6, 6))
    for idx in range(sl.start, sl.stop):
        mi = ta.get_mindex(idx)
        a, b = [j for j in range(6) for _ in range(mi[1 + j])]
        H[mi[0], a, b] = H[mi[0], b, a] = ta.state[idx]
    assert np.abs(H).max() > 1.0
    np.testing.assert_allclose(res.Phi2[0], H, atol=1e-8 * np.abs(H).max())


# ----------------------------------------------------------------------------- bad inputs
def test_bad_inputs_raise_problem_error(dro_model):
    grid = np.linspace(0, 1, 4)
    U = np.zeros((3, 2))
    with pytest.raises(ProblemError, match="x0"):
        propagate(dro_model, np.zeros(3), U, grid)
    with pytest.raises(ProblemError, match="finite"):
        propagate(dro_model, [np.nan, 0, 0, 0], U, grid)
    with pytest.raises(ProblemError, match="controls"):
        propagate(dro_model, X_DRO, np.zeros((2, 2)), grid)
    with pytest.raises(ProblemError, match="grid"):
        propagate(dro_model, X_DRO, U, [0.0, 0.5, 0.5, 1.0])
    with pytest.raises(ProblemError, match="grid"):
        propagate(dro_model, X_DRO, U, [0.0, 0.5, 0.2, 1.0])
    with pytest.raises(ProblemError, match="grid"):
        propagate(dro_model, X_DRO, np.zeros((0, 2)), [0.0])
    with pytest.raises(ProblemError, match="p must"):
        propagate(dro_model, X_DRO, U, grid, p=[MU])
    with pytest.raises(ProblemError, match="controls"):
        propagate(dro_model, np.tile(X_DRO, (2, 1)), np.zeros((3, 3, 2)), grid)
    with pytest.raises(ProblemError, match="order"):
        stt(dro_model, X_DRO, U, grid, 4)
    rhs = flow.flow_rhs(dro_model)
    with pytest.raises(ProblemError, match="y0"):
        integrate_batch(rhs, np.zeros((2, 3)), 0.0, 1.0, np.zeros((2, 4)))
    with pytest.raises(ProblemError, match="args"):
        integrate_batch(rhs, np.tile(X_DRO, (2, 1)), 0.0, 1.0, np.zeros((3, 4)))
    with pytest.raises(ProblemError, match="t1"):
        integrate_batch(rhs, np.tile(X_DRO, (2, 1)), 0.0, [1.0, np.inf], np.zeros((2, 4)))


def test_solver_failures_raise_solver_error(dro_model):
    rhs = flow.flow_rhs(dro_model)
    args = np.tile([0.0, 0.0, MU, A_MAX], (3, 1))
    y0 = np.tile(X_DRO, (3, 1))
    with pytest.raises(SolverError, match=r"max_steps = 5 exceeded for samples \[0, 1, 2\]"):
        integrate_batch(rhs, y0, 0.0, 3.0, args, max_steps=5)
    y0[1] = [-MU, 0.0, 0.0, 0.0]  # exactly at the primary: singular rhs
    with pytest.raises(SolverError, match=r"samples \[1\]"):
        integrate_batch(rhs, y0, 0.0, 1.0, args)


def test_rhs_with_structurally_zero_derivative():
    """dlam_p/dt = 0 is a structural zero of the rhs output; the compiled driver must still see a
    dense derivative (regression: it read the sparse output as dense and never converged)."""
    y, t, a = ca.SX.sym("y", 3), ca.SX.sym("t"), ca.SX.sym("a", 0)
    rhs = ca.Function("sparse_out", [y, t, a], [ca.vertcat(y[1], ca.SX(1, 1), -y[0])])
    assert not rhs.sparsity_out(0).is_dense()
    out = integrate_batch(rhs, np.array([[1.0, 0.5, 0.0]]), 0.0, 1.0)
    assert np.allclose(out, [[1.5, 0.5, -1.25]], atol=1e-12)
