"""Tests of ocreach.orbits against independent truth: a NumPy CR3BP written here, SciPy DOP853,
finite differences, literature values and synthetic symplectic matrices."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ocreach.errors import ProblemError
from ocreach.models import cr3bp, twobody
from ocreach.orbits import (
    continue_family,
    correct_symmetric,
    lagrange_points,
    nrho_9_2,
    stability_indices,
)
from ocreach.units import EARTH_MOON_PATEL

MU_NRHO = 0.012150585609624
HALO_SEED = [1.1720, 0.0, -0.0862, 0.0, -0.1880, 0.0]
DRO_SEED = [0.2765, 0.0, 0.0, 2.1379]


# ---------------------------------------------------------------- independent CR3BP (NumPy)
def grad_omega(r, mu):
    """Gradient of Omega = (x^2 + y^2)/2 + (1-mu)/r1 + mu/r2 (written independently here)."""
    x, y, z = r
    r1 = np.sqrt((x + mu) ** 2 + y**2 + z**2)
    r2 = np.sqrt((x - 1 + mu) ** 2 + y**2 + z**2)
    gx = x - (1 - mu) * (x + mu) / r1**3 - mu * (x - 1 + mu) / r2**3
    gy = y - (1 - mu) * y / r1**3 - mu * y / r2**3
    gz = -(1 - mu) * z / r1**3 - mu * z / r2**3
    return np.array([gx, gy, gz])


def rhs(mu, planar):
    def f(_t, s):
        if planar:
            x, y, vx, vy = s
            g = grad_omega((x, y, 0.0), mu)
            return [vx, vy, g[0] + 2 * vy, g[1] - 2 * vx]
        x, y, z, vx, vy, vz = s
        g = grad_omega((x, y, z), mu)
        return [vx, vy, vz, g[0] + 2 * vy, g[1] - 2 * vx, g[2]]
    return f


def flow(x0, T, mu, planar=False):
    sol = solve_ivp(rhs(mu, planar), (0, T), np.asarray(x0, float), method="DOP853",
                    rtol=1e-13, atol=1e-13)
    assert sol.success
    return sol.y[:, -1]


# ---------------------------------------------------------------- fixtures (module scope: one correction each)
@pytest.fixture(scope="module")
def dro():
    return correct_symmetric(cr3bp(0.0122, planar=True), DRO_SEED, fix="x", family="DRO")


@pytest.fixture(scope="module")
def halo():
    return correct_symmetric(cr3bp(0.01215), HALO_SEED, fix="z", family="L2 halo")


@pytest.fixture(scope="module")
def nrho():
    return nrho_9_2(MU_NRHO, EARTH_MOON_PATEL)


# ---------------------------------------------------------------- Lagrange points
@pytest.mark.parametrize("mu", [0.0122, 0.01215, MU_NRHO, 3.0e-6, 0.1, 0.45])
def test_lagrange_points_are_equilibria(mu):
    L = lagrange_points(mu)
    assert L.shape == (5, 3)
    for r in L:
        assert np.max(np.abs(grad_omega(r, mu))) < 1e-12
    # the model's vector field also vanishes there (at rest, no thrust)
    m = cr3bp(mu)
    for r in L:
        assert np.max(np.abs(m(np.concatenate([r, np.zeros(3)])))) < 1e-12
    # ordering: L3 < Earth < L1 < Moon < L2
    assert L[2, 0] < -mu < L[0, 0] < 1 - mu < L[1, 0]


def test_lagrange_points_literature_earth_moon():
    # Earth-Moon values (Szebehely / common CR3BP tables for mu = 0.01215058...)
    L = lagrange_points(MU_NRHO)
    np.testing.assert_allclose(L[:3, 0], [0.8369151, 1.1556822, -1.0050626], atol=2e-7)
    np.testing.assert_allclose(L[3, :2], [0.5 - MU_NRHO, np.sqrt(3) / 2], atol=1e-15)


def test_lagrange_points_rejects_bad_mu():
    with pytest.raises(ProblemError, match="mu"):
        lagrange_points(0.7)


# ---------------------------------------------------------------- closure by independent integration
def test_dro_closes(dro):
    xT = flow(dro.x0, dro.period, 0.0122, planar=True)
    assert np.linalg.norm(xT - dro.x0) < 1e-9
    # the Foss state is already nearly periodic: only vy0 moves, by < 1e-3
    assert dro.x0[0] == 0.2765
    assert abs(dro.x0[3] - 2.1379) < 1e-3
    assert 6.0 < dro.period < 6.5          # observed 6.2374 TU (~26.9 d); Foss's 3 TU is ~half
    assert dro.stability_indices[0] == pytest.approx(0.3448, abs=1e-3)  # stable DRO: |nu| < 1


def test_halo_closes_and_period_vs_paper(halo):
    xT = flow(halo.x0, halo.period, 0.01215)
    assert np.linalg.norm(xT - halo.x0) < 1e-9
    # corrected state rounds to the paper's 4-digit state
    np.testing.assert_allclose(halo.x0, HALO_SEED, atol=5e-5)
    hours = halo.period * EARTH_MOON_PATEL.time / 3600
    # paper: 346.322857 h; observed 349.32 h (+0.87 %)
    assert abs(hours - 346.322857) / 346.322857 < 0.01
    assert halo.stability_indices[0] > 100     # unstable L2 halo (observed nu ~ 345)


def test_halo_fix_x_agrees_with_fix_z(halo):
    other = correct_symmetric(cr3bp(0.01215), HALO_SEED, fix="x")
    assert other.x0[0] == 1.1720
    assert np.linalg.norm(flow(other.x0, other.period, 0.01215) - other.x0) < 1e-9
    assert abs(other.period - halo.period) < 2e-3   # neighbouring family members


def test_nrho_closes_and_period(nrho):
    xT = flow(nrho.x0, nrho.period, MU_NRHO)
    assert np.linalg.norm(xT - nrho.x0) < 1e-9
    assert nrho.x0[2] < 0                                   # southern family, x0 at apolune
    np.testing.assert_allclose(nrho.x0[[0, 2, 4]], [1.0220, -0.1821, -0.1033], atol=5e-4)
    # 9 revolutions in 2 synodic months: 6.562 d = 1.5112 TU (brief's 1.509 TU is ~6.55 d)
    assert nrho.period == pytest.approx(1.509, abs=3e-3)
    days = nrho.period * EARTH_MOON_PATEL.time / 86400
    assert days == pytest.approx(29.530589 / 4.5, rel=1e-6)
    # apolune is the farthest point from the Moon along the orbit
    sol = solve_ivp(rhs(MU_NRHO, False), (0, nrho.period), nrho.x0, method="DOP853",
                    rtol=1e-12, atol=1e-12, t_eval=np.linspace(0, nrho.period, 400))
    r2 = np.linalg.norm(sol.y[:3] - np.array([[1 - MU_NRHO], [0], [0]]), axis=0)
    assert r2[0] >= r2.max() - 1e-9
    # nearly stable: both nontrivial indices of order one (observed -1.32 and 0.68)
    assert all(abs(v) < 2 for v in nrho.stability_indices)


# ---------------------------------------------------------------- monodromy
@pytest.mark.parametrize("name", ["dro", "halo", "nrho"])
def test_monodromy_trivial_pair_and_symplectic(name, request):
    orb = request.getfixturevalue(name)
    M = orb.monodromy
    lam = np.linalg.eigvals(M)
    pair = lam[np.argsort(np.abs(lam - 1.0))[:2]]
    # The trivial pair is a Jordan block, so each eigenvalue moves by ~sqrt(integration error):
    # observed |lambda - 1| = 3.5e-6 (DRO), 1.5e-7 (halo), 3.7e-5 (NRHO) at rtol = 1e-12.  The pair's
    # mean is well conditioned and must be 1 to integration accuracy.
    assert np.all(np.abs(pair - 1.0) < 1e-4)
    assert abs(pair.mean() - 1.0) < 1e-8
    # the flow direction is an exact eigenvector for eigenvalue 1
    planar = M.shape[0] == 4
    f0 = np.asarray(rhs(orb.mu, planar)(0, orb.x0))
    assert np.linalg.norm(M @ f0 - f0) < 1e-7 * np.linalg.norm(M) * np.linalg.norm(f0)
    assert np.linalg.det(M) == pytest.approx(1.0, rel=1e-6)
    # reciprocal pairs: every eigenvalue's reciprocal is also an eigenvalue
    for v in lam:
        assert np.min(np.abs(lam - 1 / v)) < 1e-5 * max(1, abs(v))


def test_monodromy_matches_finite_differences(halo):
    n, h = 6, 1e-7
    fd = np.zeros((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        fd[:, j] = (flow(halo.x0 + e, halo.period, 0.01215) - flow(halo.x0 - e, halo.period, 0.01215)) / (2 * h)
    np.testing.assert_allclose(halo.monodromy, fd, rtol=0, atol=1e-5 * np.abs(fd).max())


# ---------------------------------------------------------------- stability indices (synthetic)
def test_stability_indices_synthetic():
    th = 0.7
    B = np.zeros((6, 6))
    B[:2, :2] = [[1, 1], [0, 1]]                       # trivial Jordan pair
    B[2:4, 2:4] = np.diag([5.0, 0.2])                   # hyperbolic pair
    B[4:, 4:] = [[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]  # centre pair
    S = np.random.default_rng(1).standard_normal((6, 6)) + 3 * np.eye(6)
    nus, trivial = stability_indices(S @ B @ np.linalg.inv(S))
    assert nus == pytest.approx((2.6, np.cos(th)), abs=1e-9)
    assert np.allclose(trivial, 1.0, atol=1e-6)


# ---------------------------------------------------------------- correction from a linear seed, continuation
def test_l1_lyapunov_from_linear_seed():
    mu = 0.01215
    xL = lagrange_points(mu)[0, 0]
    # linearised in-plane oscillation about L1
    c2 = (1 - mu) / abs(xL + mu) ** 3 + mu / abs(xL - 1 + mu) ** 3
    w = np.sqrt((2 - c2 + np.sqrt(9 * c2**2 - 8 * c2)) / 2)
    k = (w**2 + 1 + 2 * c2) / (2 * w)
    ax = 1e-3
    orb = correct_symmetric(cr3bp(mu, planar=True), [xL - ax, 0, 0, k * w * ax], fix="x")
    assert abs(orb.period - 2 * np.pi / w) < 1e-3           # small orbit: linear period
    assert np.linalg.norm(flow(orb.x0, orb.period, mu, planar=True) - orb.x0) < 1e-9


def test_continuation_along_halo_family(halo):
    zs = [-0.0870, -0.0880]
    fam = continue_family(cr3bp(0.01215), halo, "z", zs)
    assert [o.x0[2] for o in fam] == zs
    for o in fam:
        assert np.linalg.norm(flow(o.x0, o.period, 0.01215) - o.x0) < 1e-9


def test_period_constraint_recovers_member(halo):
    guess = np.array(halo.x0) + [2e-4, 0, 1e-4, 0, -1e-4, 0]
    orb = correct_symmetric(cr3bp(0.01215), guess, period=halo.period)
    np.testing.assert_allclose(orb.x0, halo.x0, atol=1e-8)


def test_bad_inputs():
    m = cr3bp(0.01215)
    with pytest.raises(ProblemError, match="fix"):
        correct_symmetric(m, HALO_SEED, fix="vx")
    with pytest.raises(ProblemError, match="symmetry plane"):
        correct_symmetric(m, [1.172, 0.1, -0.08, 0, -0.188, 0])
    with pytest.raises(ProblemError, match="length 6"):
        correct_symmetric(m, DRO_SEED)
    with pytest.raises(ProblemError, match="CR3BP"):
        correct_symmetric(twobody(), [1, 0, 0, 0, 1, 0])
    with pytest.raises(ProblemError, match="period"):
        correct_symmetric(m, HALO_SEED, period=-1.0)


def test_to_reference(halo):
    ref = halo.to_reference()
    np.testing.assert_array_equal(ref.x0, halo.x0)
    assert ref.period == halo.period and ref.stability == halo.stability_indices


def test_nrho_continuation_from_a_poor_seed():
    # seed ~1.5 % off in period: exercises the z0 secant continuation before the final correction
    orb = nrho_9_2(0.01215, EARTH_MOON_PATEL, seed=(1.03, 0, -0.17, 0, -0.12, 0))
    assert orb.period * EARTH_MOON_PATEL.time / 86400 == pytest.approx(29.530589 / 4.5, rel=1e-9)
    assert np.linalg.norm(flow(orb.x0, orb.period, 0.01215) - orb.x0) < 1e-9
    assert orb.x0[2] == pytest.approx(-0.1821, abs=1e-3)
