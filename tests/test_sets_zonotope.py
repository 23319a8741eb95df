"""Zonotopes, intervals, ellipsoids, matrix zonotopes against independent LPs / closed forms."""
import numpy as np
import pytest
from _sets_truth import lp_in_zonotope, lp_support
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from ocreach.errors import SetError
from ocreach.sets import (
    Ellipsoid,
    Interval,
    MatrixZonotope,
    Zonotope,
    polygon_area,
    reduce,
    unit_ball_zonotope,
)

SET = settings(max_examples=30, deadline=None)


def rand_z(rng, n=None, h=None):
    n = n or int(rng.integers(1, 5))
    h = int(rng.integers(0, 8)) if h is None else h
    return Zonotope(rng.normal(size=n), rng.normal(size=(n, h)))


@SET
@given(st.integers(0, 10**6))
def test_exact_ops_pointwise(seed):
    rng = np.random.default_rng(seed)
    Z1, Z2 = rand_z(rng, n=3), rand_z(rng, n=3)
    M = rng.normal(size=(2, 3))
    x1 = rng.uniform(-1, 1, size=(10, Z1.n_generators))
    x2 = rng.uniform(-1, 1, size=(10, Z2.n_generators))
    p1, p2 = Z1.evaluate(x1), Z2.evaluate(x2)
    assert np.allclose((M @ Z1).evaluate(x1), p1 @ M.T)
    assert np.allclose((Z1 + Z2).evaluate(np.hstack([x1, x2])), p1 + p2)
    assert np.allclose(Z1.cartesian(Z2).evaluate(np.hstack([x1, x2])), np.hstack([p1, p2]))
    v = rng.normal(size=3)
    assert np.allclose((Z1 + v).evaluate(x1), p1 + v)
    assert np.allclose(Z1.project([2, 0]).evaluate(x1), p1[:, [2, 0]])


@SET
@given(st.integers(0, 10**6))
def test_support_matches_lp(seed):
    rng = np.random.default_rng(seed)
    Z = rand_z(rng)
    d = rng.normal(size=Z.dim)
    assert np.isclose(Z.support(d), lp_support(Z.c, Z.G, d), atol=1e-7)
    I = Z.interval_hull()
    assert np.isclose(I.support(d), lp_support(I.center, np.diag(I.radius), d), atol=1e-7)


@SET
@given(st.integers(0, 10**6), st.sampled_from(["girard", "pca"]))
def test_reduction_and_hull_contain_samples(seed, method):
    rng = np.random.default_rng(seed)
    Z = rand_z(rng, h=int(rng.integers(3, 15)))
    order = float(rng.integers(1, 3))
    R = reduce(Z, order, method)
    assert R.n_generators <= int(order * Z.dim)
    pts = np.vstack([Z.sample(15, rng), Z.sample(15, rng, mode="extreme")])
    assert all(lp_in_zonotope(R.c, R.G, x, tol=1e-6) for x in pts)
    assert np.all(Z.interval_hull().contains(pts))


@SET
@given(st.integers(0, 10**6))
def test_matrix_zonotope_product_contains_samples(seed):
    rng = np.random.default_rng(seed)
    n, q = int(rng.integers(1, 4)), int(rng.integers(0, 3))
    MZ = MatrixZonotope(rng.normal(size=(n, n)), rng.normal(size=(q, n, n)) * 0.3)
    Z = rand_z(rng, n=n, h=int(rng.integers(1, 4)))
    P = MZ @ Z
    A = MZ.sample(20, rng, mode=["uniform", "extreme"][seed % 2])
    X = Z.sample(20, rng, mode="extreme")
    Y = np.einsum("kij,kj->ki", A, X)
    assert all(lp_in_zonotope(P.c, P.G, y, tol=1e-6) for y in Y)


@SET
@given(st.integers(0, 10**6))
def test_split_halves_cover_and_outline_is_convex_hull(seed):
    rng = np.random.default_rng(seed)
    Z = rand_z(rng, n=2, h=int(rng.integers(2, 7)))
    a, b = Z.split()
    pts = Z.sample(30, rng)
    assert all(lp_in_zonotope(a.c, a.G, x) or lp_in_zonotope(b.c, b.G, x) for x in pts)
    P = Z.outline()
    hull = ConvexHull(Z.vertices())
    assert np.isclose(polygon_area(P), hull.volume, rtol=1e-9)
    assert np.isclose(Z.volume(), hull.volume, rtol=1e-9)


def test_volume_3d_against_convex_hull():
    rng = np.random.default_rng(4)
    Z = Zonotope(rng.normal(size=3), rng.normal(size=(3, 6)))
    assert np.isclose(Z.volume(), ConvexHull(Z.vertices()).volume, rtol=1e-9)
    assert Zonotope([0, 0, 0], np.eye(3)[:, :2]).volume() == 0.0


def test_interval_and_ellipsoid():
    rng = np.random.default_rng(5)
    I = Interval([-1, 0], [2, 1])
    pts = I.sample(50, rng)
    assert I.contains(pts).all() and not I.contains([2.1, 0.5])
    V = I.sample(10, rng, mode="extreme")  # vertices: every coordinate at lo or hi
    assert np.all((V == [-1, 0]) | (V == [2, 1]))
    A = rng.normal(size=(3, 3))
    E = Ellipsoid(rng.normal(size=3), A @ A.T + 0.1 * np.eye(3))
    d = rng.normal(size=3)
    # support: closed form against the max over many boundary samples
    bnd = E.sample(20000, rng, mode="extreme")
    assert E.support(d) >= (bnd @ d).max() - 1e-12
    assert E.support(d) - (bnd @ d).max() < 5e-2
    Qi = np.linalg.inv(E.Q)
    P = E.sample(200, rng) * 1.0
    P = np.vstack([P, E.q + 1.01 * (bnd[:50] - E.q), E.q + 0.99 * (bnd[:50] - E.q)])
    truth = np.einsum("ka,ab,kb->k", P - E.q, Qi, P - E.q) <= 1
    assert np.array_equal(E.contains(P), truth)
    Zo = E.to_zonotope(12)
    assert all(lp_in_zonotope(Zo.c, Zo.G, x) for x in bnd[:100])
    B = unit_ball_zonotope(2, 6)
    t = np.linspace(0, 2 * np.pi, 400)
    circle = np.column_stack([np.cos(t), np.sin(t)])
    assert B.contains(circle).all()
    # regular 12-gon with inradius 1: circumradius 1/cos(pi/12) towards a vertex (angle pi/12 + k pi/6)
    assert np.isclose(B.support([np.cos(7 * np.pi / 12), np.sin(7 * np.pi / 12)]), 1 / np.cos(np.pi / 12))
    assert np.isclose(np.min(B.support(circle)), 1.0, atol=1e-9)


def test_degenerate_and_errors():
    Z0 = Zonotope([1.0, 2.0])
    assert Z0.n_generators == 0 and Z0.contains([1.0, 2.0]) and not Z0.contains([1.0, 2.1])
    assert np.allclose(Z0.sample(3, 0), [1, 2])
    Z1 = Zonotope([0.0], [[2.0, 0.0]])
    assert Z1.contains([[1.9], [2.1]]).tolist() == [True, False]
    with pytest.raises(SetError):
        Zonotope([0, 0], np.ones((3, 2)))
    with pytest.raises(SetError):
        Interval([1, 0], [0, 1])
    with pytest.raises(SetError):
        Ellipsoid([0, 0], [[1, 0], [0, -1]])
    with pytest.raises(SetError):
        Zonotope([0, 0], np.eye(2)).sample(3, 0, mode="corners")
    with pytest.raises(SetError):
        reduce(Zonotope([0, 0], np.eye(2)), 0.5)
    with pytest.raises(AttributeError):
        Z0.c = np.zeros(2)
    with pytest.raises(ValueError):
        Z0.c[0] = 3.0
    with pytest.raises(SetError):
        np.ones((2, 3)) @ Zonotope([0, 0], np.eye(2))
    MZ = MatrixZonotope(np.eye(2), [np.ones((2, 2))])
    with pytest.raises(AttributeError):
        MZ.C = np.zeros((2, 2))
    with pytest.raises(SetError):
        MatrixZonotope(np.eye(2), np.ones((1, 3, 2)))
