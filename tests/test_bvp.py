"""bvp (PMP shooting + continuation) on the Foss DRO against a direct-transcription optimum.

The bvp control is continuous, so the truth is the transcription on a 10x finer grid (300
piecewise-constant segments) and, for the upper bound, its Richardson extrapolation to continuous
controls from the 30- and 300-segment optima (the gap shrinks like h^2).  Re-simulation uses the
state-costate equations written out here and scipy DOP853.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from test_indirect import cr3bp_np, dt_optimum

from ocreach.errors import ProblemError
from ocreach.models import cr3bp
from ocreach.problem import Problem
from ocreach.reach.base import reach
from ocreach.registry import get_problem
from ocreach.units import EARTH_MOON_FOSS

N_DIRS = 6


def state_costate(t, y, mu, a):
    """Foss Eq. 4 for the planar CR3BP, hand-written: u* = -lam_v / |lam_v|."""
    x, lam = y[:4], y[4:]
    u = -lam[2:] / np.linalg.norm(lam[2:])
    # gravity-gradient (Hessian of the potential) by central differences of the acceleration
    h = 1e-6
    G = np.empty((2, 2))
    for i in range(2):
        e = np.zeros(4)
        e[i] = h
        G[:, i] = (cr3bp_np(x + e, u, mu, a)[2:] - cr3bp_np(x - e, u, mu, a)[2:]) / (2 * h)
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2:, :2] = G
    A[2, 3], A[3, 2] = 2.0, -2.0
    return np.concatenate([cr3bp_np(x, u, mu, a), -A.T @ lam])


@pytest.fixture(scope="module")
def dro():
    return get_problem("dro")


@pytest.fixture(scope="module")
def bvp_run(dro):
    return reach(dro, "bvp", samples=N_DIRS)


def test_bvp_matches_transcription(dro, bvp_run):
    mu, a = dro.param("mu"), dro.param("a_max")
    dirs = bvp_run.meta["directions"]
    fine = np.array([dt_optimum(dro.x0, dro.grid, z, mu, a, refine=10, n_sub=4) for z in dirs])
    coarse = np.array([dt_optimum(dro.x0, dro.grid, z, mu, a) for z in dirs])
    cont = fine + (fine - coarse) / 99.0  # Richardson, O(h^2)
    width = fine + np.roll(fine, N_DIRS // 2)
    J = bvp_run.meta["cost"]
    assert np.all(np.abs(J - fine) <= 0.01 * width), (J - fine) / width
    assert np.all(J <= cont + 1e-6), J - cont       # not above the continuous optimum
    assert np.all(J >= fine - 1e-7), J - fine        # continuous control beats piecewise constant
    # ole (piecewise constant on the problem grid) lies below bvp
    ole = reach(dro, "ole", samples=N_DIRS)
    assert np.all(ole.meta["cost"] <= J + 1e-9)


def test_bvp_resimulates_from_costates(dro, bvp_run):
    mu, a = dro.param("mu"), dro.param("a_max")
    g = dro.grid
    for j in range(0, N_DIRS, 2):
        y0 = np.concatenate([bvp_run.trajectories[j, 0], bvp_run.meta["costate0"][j]])
        sol = solve_ivp(state_costate, (g[0], g[-1]), y0, args=(mu, a), method="DOP853",
                        rtol=1e-12, atol=1e-13, t_eval=g)
        assert np.max(np.abs(sol.y[:4].T - bvp_run.trajectories[j])) < 1e-7
        # terminal condition of the linear cost: lam(t_f) = -z-hat
        assert np.allclose(sol.y[4:, -1], -bvp_run.meta["directions"][j], atol=1e-6)


def test_quadratic_cost_gives_same_extremals(dro, bvp_run):
    """Tucker Eq. 4: with G = z z^T the terminal costate is -z (z . e); where z . e > 0 the
    extremal is the linear-cost one."""
    quad = reach(dro, "bvp", samples=N_DIRS, cost="quadratic")
    e = np.einsum("ni,ni->n", bvp_run.meta["directions"],
                  bvp_run.trajectories[:, -1] - bvp_run.meta["reference_final"])
    same = e > 0
    assert same.any()
    assert np.allclose(quad.trajectories[same, -1], bvp_run.trajectories[same, -1], atol=1e-7)


def test_bvp_ellipsoid_manifold(dro):
    """Tucker Eq. 6 / Patel & Scheeres Eq. 23: x0 on a 0.01 DU position sphere."""
    mu, a = dro.param("mu"), dro.param("a_max")
    res = reach(dro, "bvp", samples=4, uncertainty_radius=0.01)
    r0 = res.trajectories[:, 0, :2] - dro.x0[:2]
    assert np.allclose(np.linalg.norm(r0, axis=1), 0.01, atol=1e-14)
    lam_r = res.meta["costate0"][:, :2]
    assert np.allclose(np.einsum("ni,ni->n", r0, -lam_r) / (0.01 * np.linalg.norm(lam_r, axis=1)), 1.0)
    truth = np.array([dt_optimum(dro.x0, dro.grid, z, mu, a, x0_radius=0.01)
                      for z in res.meta["directions"]])
    width = truth + np.roll(truth, 2)
    assert np.all(np.abs(res.meta["cost"] - truth) <= 0.01 * width)
    assert np.all(res.meta["cost"] >= truth - 1e-7)


def test_bvp_bad_input(dro):
    with pytest.raises(ProblemError):
        reach(dro, "bvp", cost="cubic")
    with pytest.raises(ProblemError):
        reach(dro, "bvp", dims=[5])
    mass = cr3bp(0.0122, planar=True, variable_mass=True, thrust=1.1e-3, isp=3000.0,
                 units=EARTH_MOON_FOSS, control_set="box")
    prob = Problem(id="m", model=mass, x0=np.array([0.2765, 0, 0, 2.1379, 1 / 14.0]),
                   grid=np.linspace(0, 1, 11))
    with pytest.raises(ProblemError, match="control-affine"):
        reach(prob, "bvp", samples=4)


def test_bvp_variable_mass(dro):
    """Inverse-mass CR3BP (Patel & Scheeres Eq. 11 form, n-equation with ||u||): bvp uses the
    full-thrust law of Eq. 18.  Truth: the state-costate equations written here (u* = -lam_v/|lam_v|,
    dn/dt = T n^2 |u| / c, costate Jacobian by central differences of the hand-written f)."""
    mass = cr3bp(dro.param("mu"), planar=True, variable_mass=True, thrust=1.1e-3, isp=3000.0,
                 units=EARTH_MOON_FOSS)
    prob = Problem(id="m", model=mass, x0=np.concatenate([dro.x0, [1 / 14.0]]), grid=dro.grid)
    res = reach(prob, "bvp", samples=4)
    mu, T, c = (prob.param(k) for k in ("mu", "T_max", "c_ex"))

    def f(x, u):
        n = x[4]
        return np.concatenate([cr3bp_np(x[:4], u, mu, T * n), [T * n * n * np.linalg.norm(u) / c]])

    def rhs(t, y):
        x, lam = y[:5], y[5:]
        u = -lam[2:4] / np.linalg.norm(lam[2:4])
        A = np.empty((5, 5))
        for i in range(5):
            e = np.zeros(5)
            e[i] = 1e-6
            A[:, i] = (f(x + e, u) - f(x - e, u)) / 2e-6
        return np.concatenate([f(x, u), -A.T @ lam])

    for j in (0, 3):
        y0 = np.concatenate([res.trajectories[j, 0], res.meta["costate0"][j]])
        sol = solve_ivp(rhs, (prob.grid[0], prob.grid[-1]), y0, method="DOP853", rtol=1e-12,
                        atol=1e-13, t_eval=prob.grid)
        assert np.max(np.abs(sol.y[:5].T - res.trajectories[j])) < 1e-7
        assert np.allclose(sol.y[5:, -1], -res.meta["directions"][j], atol=1e-6)
    assert np.all(np.diff(res.trajectories[:, :, 4], axis=1) > 0)   # full thrust burns fuel
    ole = reach(prob, "ole", samples=4)
    assert np.all(ole.meta["cost"] <= res.meta["cost"] + 1e-9)      # continuous >= piecewise const.
