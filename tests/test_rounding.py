"""Rigorous rounding bounds of the set arithmetic (``ocreach.sets.rounding``) against exact rational
arithmetic (``fractions.Fraction``: every float is a rational number, so the exact results of the
float inputs are computed without any rounding) and mpmath at 60 digits."""
from __future__ import annotations

from fractions import Fraction

import mpmath
import numpy as np
import pytest

from ocreach.reach.linsys import linear_step
from ocreach.sets.reduce import box_generators
from ocreach.sets.rounding import gamma, rounding_radius, two_sum_error, up
from ocreach.sets.zonotope import Zonotope


def _exact_matmul(M: np.ndarray, X: np.ndarray) -> list[list[Fraction]]:
    return [[sum((Fraction(float(M[i, k])) * Fraction(float(X[k, j])) for k in range(M.shape[1])),
                 Fraction(0)) for j in range(X.shape[1])] for i in range(M.shape[0])]


def _bad_inputs(rng, n):
    """Inputs with wide dynamic range and cancellation (where rounding is largest)."""
    M = rng.standard_normal((n, n)) * 10.0 ** rng.integers(-8, 9, (n, n))
    X = rng.standard_normal((n, 3)) * 10.0 ** rng.integers(-8, 9, (n, 3))
    return M, X


@pytest.mark.parametrize("seed", range(6))
def test_matmul_rounding_bound_holds_exactly(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 30))
    M, X = _bad_inputs(rng, n)
    Y = M @ X  # BLAS, any summation order / FMA
    r = rounding_radius(np.abs(M) @ np.abs(X), n)
    exact = _exact_matmul(M, X)
    worst = 0.0
    for i in range(n):
        for j in range(3):
            err = abs(Fraction(float(Y[i, j])) - exact[i][j])
            assert err <= Fraction(float(r[i, j])), (i, j, float(err), r[i, j])
            worst = max(worst, float(err / Fraction(float(r[i, j]))))
    assert worst > 0  # the bound is exercised: some products did round


def test_gamma_and_up():
    assert gamma(0) == 0.0
    assert gamma(10) > 10 * 2.0**-53
    with pytest.raises(ValueError):
        gamma(2**52)
    rng = np.random.default_rng(1)
    x = np.abs(rng.standard_normal((50, 40)))
    s = x.sum(axis=1)
    s_up = up(s, 40)
    for i in range(50):
        exact = sum((Fraction(float(v)) for v in x[i]), Fraction(0))
        assert Fraction(float(s_up[i])) >= exact


def test_two_sum_error_is_exact():
    rng = np.random.default_rng(2)
    a = rng.standard_normal(200) * 1e8
    b = rng.standard_normal(200) * 1e-9
    s, e = two_sum_error(a, b)
    for i in range(200):
        assert Fraction(float(s[i])) + Fraction(float(e[i])) == Fraction(float(a[i])) + Fraction(float(b[i]))
    assert np.any(e != 0)


def test_split_halves_contain_the_exact_extremes():
    """Large centre, small generators: ``c -+ g/2`` rounds; the halves still reach ``c -+ g``
    exactly (checked with Fractions along the split generator's extremes in every coordinate)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        c = rng.standard_normal(3) * 1e9
        G = rng.standard_normal((3, 1)) * 1e-3
        Z = Zonotope(c, G)
        a, b = Z.split(0)
        for part, sgn in ((a, -1), (b, 1)):
            # the exact point c + sgn * g_0 and c (the shared face) lie in the part's box
            rad = np.abs(part.G).sum(axis=1)
            for i in range(3):
                for target in (Fraction(float(c[i])) + sgn * Fraction(float(G[i, 0])),
                               Fraction(float(c[i]))):
                    lo = Fraction(float(part.c[i])) - Fraction(float(rad[i]))
                    hi = Fraction(float(part.c[i])) + Fraction(float(rad[i]))
                    assert lo <= target <= hi


@pytest.mark.parametrize("method", ["girard", "pca"])
def test_box_generators_contain_the_exact_extremes(method):
    """Every vertex ``G s`` (s in {-1, 1}^h, exact) lies in the parallelotope ``B`` found by
    ``box_generators``: ``|B^{-1} x|_inf <= 1`` checked in mpmath at 60 digits."""
    rng = np.random.default_rng(4)
    mpmath.mp.dps = 60
    for _ in range(5):
        n, h = 3, 6
        G = rng.standard_normal((n, h)) * 10.0 ** rng.integers(-3, 4, (n, 1))
        B = box_generators(G, method)
        assert B.shape == (n, n)
        Bi = mpmath.matrix([[mpmath.mpf(float(v)) for v in row] for row in B]) ** -1
        for s in np.array(np.meshgrid(*[[-1.0, 1.0]] * h)).reshape(h, -1).T:
            x = mpmath.matrix([sum(mpmath.mpf(float(G[i, j])) * int(s[j]) for j in range(h))
                               for i in range(n)])
            y = Bi * x
            assert max(abs(v) for v in y) <= 1


def test_linear_step_point_set_contains_the_exact_image_with_large_centre():
    """``d' = A d`` from a box with a centre 1e8 times its radius (rounding of the centre's map is
    then of the order of the radius' ulps): the exact images ``e^{A h} x0`` of the vertices (mpmath
    ``expm`` at 60 digits) lie in the interval hull of the time-point set, compared exactly."""
    mpmath.mp.dps = 60
    A = np.array([[0.1, 1.0], [-1.0, 0.1]])
    h = 0.3
    c = np.array([1.0e8 / 3.0, -2.0e8 / 7.0])
    R0 = Zonotope(c, np.diag([1e-3, 2e-3]))
    step = linear_step(R0, A, h, np.zeros(2))
    hull = step.point.interval_hull()
    E = mpmath.expm(mpmath.matrix(A.tolist()) * mpmath.mpf(h))
    for s1 in (-1, 1):
        for s2 in (-1, 1):
            x0 = mpmath.matrix([mpmath.mpf(float(c[0])) + s1 * mpmath.mpf(1e-3),
                                mpmath.mpf(float(c[1])) + s2 * mpmath.mpf(2e-3)])
            y = E * x0
            for i in range(2):
                assert mpmath.mpf(float(hull.lo[i])) <= y[i] <= mpmath.mpf(float(hull.hi[i]))


def test_interval_outward_rounding_nextafter_mode(monkeypatch):
    """The ``np.nextafter`` mode of ``ocreach.intervals`` (small evaluations) rounds outward past
    the neighbouring float, also for subnormals, infinities and NaN, like the formula mode."""
    from ocreach.intervals import ops

    monkeypatch.setattr(ops._ROUNDING, "nextafter", True)
    x = np.array([0.0, -0.0, 5e-324, -5e-324, 2.0**-1022, 1.0, -1.0, 1.5, 1e308, -1e308, 3.0**40])
    assert np.all(ops._up(x) >= np.nextafter(x, np.inf)) and np.all(ops._up(x) > x)
    assert np.all(ops._dn(x) <= np.nextafter(x, -np.inf)) and np.all(ops._dn(x) < x)
    assert ops._up(np.inf) == np.inf and ops._dn(-np.inf) == -np.inf
    assert 1e308 < ops._dn(np.inf) < np.inf and -np.inf < ops._up(-np.inf) < -1e308
    assert np.isnan(ops._dn(np.nan)) and np.isnan(ops._up(np.nan))
