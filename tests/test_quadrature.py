"""Quadrature rules: exactness against closed-form moments, published CUT point counts, mappings."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ocreach.dynamics.quadrature import (
    CUT_SUPPORTED,
    cut_rule,
    cut_structure,
    gauss_hermite_rule,
    gauss_legendre_rule,
    moments,
    to_box,
    to_gaussian,
    unscented_rule,
)
from ocreach.errors import ProblemError


def exact_1d(k: int, density: str) -> float:
    """Independent truth: E[x^k] for N(0,1) is (k-1)!! (0 for odd k); uniform on [-1,1] 1/(k+1)."""
    if k % 2:
        return 0.0
    if density == "gaussian":
        return float(math.prod(range(k - 1, 0, -2)))
    return 1.0 / (k + 1)


def exponents(n: int, max_deg: int) -> np.ndarray:
    """All exponent vectors of n variables with total degree <= max_deg."""
    return np.array(list(_compositions(n, max_deg)), dtype=int)


def _compositions(n, max_deg):
    for d in range(max_deg + 1):
        for c in itertools.combinations_with_replacement(range(n), d):
            e = [0] * n
            for i in c:
                e[i] += 1
            yield tuple(e)


def check_exact(points, weights, n, degree, density, rtol=1e-10, atol=1e-10):
    E = exponents(n, degree)
    # monomial values, vectorised over points and exponents (chunks keep memory small)
    errs = []
    for chunk in np.array_split(E, max(1, len(E) // 2000)):
        vals = np.prod(points[:, None, :] ** chunk[None, :, :], axis=2)
        approx = weights @ vals
        exact = np.array([math.prod(exact_1d(k, density) for k in e) for e in chunk])
        even = np.all(chunk % 2 == 0, axis=1)
        assert np.all(np.abs(approx[~even]) < atol), np.max(np.abs(approx[~even]))
        rel = np.abs(approx[even] - exact[even]) / exact[even]
        errs.append(rel.max(initial=0.0))
        assert np.all(rel < rtol), (chunk[even][np.argmax(rel)], rel.max())
    return max(errs)


CASES = [(order, dens, n) for order, dd in CUT_SUPPORTED.items() for dens, (lo, hi) in dd.items()
         for n in range(lo, hi + 1)]


@pytest.mark.parametrize("order,density,n", CASES)
def test_cut_exact_positive(order, density, n):
    x, w = cut_rule(n, order, density)
    assert x.shape == (w.size, n)
    assert np.all(w > 0)
    check_exact(x, w, n, order + 1, density)
    if density == "uniform" and not (order == 4 and n >= 6):
        assert np.max(np.abs(x)) <= 1.0 + 1e-12  # inside the cube


@pytest.mark.parametrize("n,order,count", [
    (6, 8, 745), (2, 8, 21), (3, 8, 59), (6, 6, 137), (3, 6, 27), (6, 4, 76), (3, 4, 14),
])
def test_published_counts(n, order, count):
    x, w = cut_rule(n, order, "gaussian")
    assert w.size == count


def test_cut4_matches_closed_form():
    # CUT4 without centre: 2/r1^2 + 1/r2^2 = 1 and 2n/r1^4 + 1/r2^4 = 1 give r1 = 2, r2 = sqrt 2 for n = 6
    rows = cut_structure(6, 4)
    assert [r["orbit"] for r in rows] == ["sigma", "c^(n)"]
    assert rows[0]["radius"][0] == pytest.approx(2.0, rel=1e-12)
    assert rows[1]["radius"][0] == pytest.approx(math.sqrt(2.0), rel=1e-12)


def test_cut_returns_copies_and_is_deterministic():
    x1, w1 = cut_rule(3, 6)
    x1[:] = 0.0
    x2, w2 = cut_rule(3, 6)
    assert np.any(x2 != 0.0)
    np.testing.assert_array_equal(w1, w2)


def test_cut8_beats_ut_on_quartic_mean():
    # E[(z1^2 + z2 z3)^2] under N(0, I): 3 + 1 = 4 ; UT with kappa=0 misses it, CUT8 does not
    f = lambda z: (z[:, 0] ** 2 + z[:, 1] * z[:, 2]) ** 2
    x, w = cut_rule(3, 8)
    assert w @ f(x) == pytest.approx(4.0, rel=1e-12)
    xu, wu = unscented_rule(3, kappa=0.0)
    assert abs(wu @ f(xu) - 4.0) > 0.1


ALLOWED = r"Supported: order 4: gaussian n=1\.\.9, uniform n=1\.\.8, order 6: .*order 8: gaussian n=1\.\.6"


@pytest.mark.parametrize("bad,match", [
    (dict(n=3, order=5), r"order must be one of 4, 6, 8; got 5\. " + ALLOWED),
    (dict(n=7, order=8), r"CUT8 with density='gaussian' is supported for n = 1\.\.6; got n=7\. " + ALLOWED),
    (dict(n=0, order=4), r"supported for n = 1\.\.9; got n=0"),
    (dict(n=3, order=4, density="beta"), r"density must be 'gaussian' or 'uniform'; got 'beta'"),
    (dict(n=3, order=6, density="uniform"), r"CUT6 with density='uniform' is supported for n = 1\.\.2; got n=3"),
    (dict(n=10, order=4), r"supported for n = 1\.\.9; got n=10"),
    (dict(n=2.5, order=4), r"n must be an int; got 2\.5"),
])
def test_cut_unsupported(bad, match):
    """The message names the parameter, the value and what is supported."""
    with pytest.raises(ProblemError, match=match):
        cut_rule(**bad)


@pytest.mark.parametrize("n", [1, 2, 4, 6])
def test_unscented_exact_degree3(n):
    x, w = unscented_rule(n, kappa=1.0)
    assert w.size == 2 * n + 1
    check_exact(x, w, n, 3, "gaussian")
    x, w = unscented_rule(n)  # kappa = 3 - n matches the fourth marginal moment
    assert w @ x[:, 0] ** 4 == pytest.approx(3.0)


def test_unscented_bad_kappa():
    with pytest.raises(ProblemError, match="kappa"):
        unscented_rule(3, kappa=-3.0)


@pytest.mark.parametrize("n,m", [(1, 5), (2, 3), (3, 4)])
def test_tensor_rules_exact(n, m):
    x, w = gauss_hermite_rule(n, m)
    assert w.size == m**n
    check_exact(x, w, n, 2 * m - 1, "gaussian")
    x, w = gauss_legendre_rule(n, m)
    check_exact(x, w, n, 2 * m - 1, "uniform")
    # per-variable degree 2m is not integrated exactly
    assert abs(w @ x[:, 0] ** (2 * m) - exact_1d(2 * m, "uniform")) > 1e-6


def test_to_gaussian_mean_cov():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(4, 4))
    cov = A @ A.T + 0.1 * np.eye(4)
    mean = np.array([1.0, -2.0, 3.0, 0.5])
    x, w = cut_rule(4, 6)
    y = to_gaussian(x, mean, cov)
    m, P = moments(y, w)
    np.testing.assert_allclose(m, mean, atol=1e-12)
    np.testing.assert_allclose(P, cov, atol=1e-11)


def test_to_gaussian_singular_psd_and_nonlinear_moment():
    # Jain et al. Eq. 25-like covariance with zero variances; exact E and Var of a quadratic
    cov = np.diag([9.0, 0.0, 0.0, 0.25])
    mean = np.array([1.0, 2.0, 3.0, -1.0])
    x, w = cut_rule(4, 8)
    y = to_gaussian(x, mean, cov)
    assert np.allclose(y[:, 1], 2.0) and np.allclose(y[:, 2], 3.0)
    m, P = moments(y, w, lambda v: v[:, 0] ** 2)
    # x0 ~ N(1, 9): E[x^2] = 10, Var[x^2] = 2 s^4 + 4 mu^2 s^2 = 162 + 36 = 198
    assert m[0] == pytest.approx(10.0, rel=1e-12)
    assert P[0, 0] == pytest.approx(198.0, rel=1e-12)


@pytest.mark.parametrize("cov,match", [
    (np.array([[1.0, 0.5], [0.0, 1.0]]), "symmetric"),
    (np.array([[1.0, 2.0], [2.0, 1.0]]), "semidefinite"),
    (np.eye(3), "cov"),
])
def test_to_gaussian_bad_cov(cov, match):
    x, _ = cut_rule(2, 4)
    with pytest.raises(ProblemError, match=match):
        to_gaussian(x, np.zeros(2), cov)


def test_to_box_and_uniform_moments():
    lo, hi = np.array([-2.0, 1.0]), np.array([4.0, 1.5])
    x, w = cut_rule(2, 8, "uniform")
    y = to_box(x, lo, hi)
    assert np.all(y >= lo - 1e-12) and np.all(y <= hi + 1e-12)
    m, P = moments(y, w)
    np.testing.assert_allclose(m, (lo + hi) / 2, atol=1e-13)
    np.testing.assert_allclose(P, np.diag((hi - lo) ** 2 / 12), atol=1e-13)
    with pytest.raises(ProblemError, match="hi must be >= lo"):
        to_box(x, hi, lo)


def test_moments_errors():
    x, w = cut_rule(2, 4)
    with pytest.raises(ProblemError, match="non-finite"), np.errstate(all="ignore"):
        moments(x, w, lambda v: np.log(v[:, 0]))
    with pytest.raises(ProblemError, match="weights"):
        moments(x, w[:-1])


def test_cut_rule_disk_cache_is_verified(tmp_path, monkeypatch):
    """The solved rule is stored next to the JIT cache; a corrupt cached file is re-solved (the
    result is then checked by the closed-form moments, as in test_cut_exact_positive)."""
    from ocreach.dynamics import quadrature as q

    monkeypatch.setenv("OCREACH_CACHE_DIR", str(tmp_path / "jit"))
    solve = q._solve_cut.__wrapped__  # bypass the in-process cache
    _, params = solve(3, 6, "gaussian")
    path = q._disk_cache_path(3, 6, "gaussian")
    assert path.exists()
    _, again = solve(3, 6, "gaussian")  # from disk
    for a, b in zip(params, again):
        np.testing.assert_array_equal(a, b)
    np.save(path, np.concatenate(params) * 1.01)  # wrong radii and weights: must be rejected
    structure, fixed = solve(3, 6, "gaussian")
    pts = np.vstack([q._orbit_points(3, o, p) for o, p in zip(structure, fixed)])
    w = np.concatenate([np.full(q._orbit_size(3, o), p[-1]) for o, p in zip(structure, fixed)])
    check_exact(pts, w, 3, 7, "gaussian")
