"""Minimum enclosing ball (ocreach.geometry.meb) against brute force, an SOCP, and its own certificate.

Brute force: every subset of at most d + 1 points, the sphere through it with centre in its
affine hull (solved independently here by least squares), kept if it encloses all points; the
smallest such sphere is the MEB.  Degenerate sets: collinear, co-spherical (regular polygon and
cube vertices), duplicates, a single point.
"""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from ocreach.errors import SetError
from ocreach.geometry import minimum_enclosing_ball, support_outer_ball


def brute_force(P: np.ndarray) -> float:
    m, d = P.shape
    best = np.inf
    scale = np.ptp(P, axis=0).max() + 1.0
    for k in range(1, min(d + 1, m) + 1):
        for sub in itertools.combinations(range(m), k):
            B = P[list(sub)]
            A = B[1:] - B[0]
            if k > 1:
                if np.linalg.matrix_rank(A, tol=1e-9 * scale) < k - 1:
                    continue
                # centre c = B0 + A^T lam with |c - B_j| = |c - B0|: (2 A A^T) lam = |A|^2
                lam = np.linalg.lstsq(2 * A @ A.T, (A * A).sum(1), rcond=None)[0]
                c = B[0] + lam @ A
            else:
                c = B[0]
            r = np.linalg.norm(B - c, axis=1).max()
            if np.all(np.linalg.norm(P - c, axis=1) <= r * (1 + 1e-12) + 1e-14):
                best = min(best, r)
    return best


def _cases():
    rng = np.random.default_rng(1)
    ang = np.linspace(0, 2 * np.pi, 9)[:-1]
    cube = np.array(list(itertools.product([-1.0, 1.0], repeat=3)))
    yield "random-2d", rng.standard_normal((9, 2))
    yield "random-3d", rng.standard_normal((9, 3))
    yield "random-4d", rng.standard_normal((8, 4))
    yield "random-5d", rng.standard_normal((9, 5))
    yield "random-6d", rng.standard_normal((10, 6))
    yield "flat-3d-in-6d", np.column_stack([rng.standard_normal((9, 3)), np.zeros((9, 3))]) @ \
        np.linalg.qr(rng.standard_normal((6, 6)))[0]
    yield "simplex-vertices-6d", np.vstack([np.eye(6), np.full(6, (1 - np.sqrt(7)) / 6)])
    yield "collinear-2d", np.outer(rng.uniform(-2, 3, 7), [1.0, 2.0]) + [0.5, -1.0]
    yield "collinear-3d", np.outer(rng.uniform(-1, 1, 7), [1.0, -1.0, 0.5])
    yield "cospherical-octagon", np.column_stack([np.cos(ang), np.sin(ang)]) * 2.0 + 5.0
    yield "cube-vertices", cube + 1e3
    yield "duplicates", np.repeat(rng.standard_normal((3, 3)), 3, axis=0)
    yield "single", np.array([[1.0, 2.0, 3.0]])
    yield "coplanar-in-3d", np.column_stack([rng.standard_normal((8, 2)), np.zeros(8)])
    yield "far-from-origin", 1.0 + 1e-4 * rng.standard_normal((8, 3))


@pytest.mark.parametrize("name,P", list(_cases()), ids=[c[0] for c in _cases()])
def test_meb_matches_brute_force(name, P):
    ball = minimum_enclosing_ball(P, verify=True)
    r_bf = brute_force(P)
    assert abs(ball.radius - r_bf) <= 1e-12 * max(1.0, r_bf), (ball.radius, r_bf)
    assert ball.certificate(1e-12)
    # certificate contents: support on the sphere, centre their convex combination
    np.testing.assert_allclose(np.linalg.norm(ball.support - ball.center, axis=1), ball.radius,
                               rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(ball.barycentric @ ball.support, ball.center, rtol=0, atol=1e-11 *
                               max(1.0, np.abs(P).max()))
    assert np.all(ball.contains(P, tol=1e-12))


@pytest.mark.parametrize("d", [3, 6])
def test_meb_matches_socp(d):
    cp = pytest.importorskip("cvxpy")
    rng = np.random.default_rng(d)
    P = rng.standard_normal((3000, d)) * rng.uniform(0.5, 2.0, d) + 3.0
    ball = minimum_enclosing_ball(P)
    c, r = cp.Variable(d), cp.Variable()
    prob = cp.Problem(cp.Minimize(r), [cp.norm(P - c[None, :], axis=1) <= r])
    prob.solve(solver=cp.CLARABEL)
    assert ball.certificate(1e-12)
    # the SOCP solves to ~1e-8; the exact ball is never larger than a feasible SOCP ball
    assert ball.radius <= r.value * (1 + 1e-7)
    assert abs(ball.radius - r.value) <= 1e-6 * r.value
    assert np.linalg.norm(ball.center - c.value) <= 1e-4 * r.value


def test_meb_large_set_certificate():
    rng = np.random.default_rng(0)
    P = rng.standard_normal((200_000, 6))
    ball = minimum_enclosing_ball(P, verify=True)
    assert ball.certificate(1e-12)
    assert np.all(ball.barycentric >= 0)
    d = np.linalg.norm(P - ball.center, axis=1)
    assert d.max() <= ball.radius * (1 + 1e-12)
    # support points realise the radius
    assert np.abs(d[ball.support_index] - ball.radius).max() <= 1e-12 * ball.radius


def test_meb_bad_input():
    with pytest.raises(SetError, match="non-empty"):
        minimum_enclosing_ball(np.zeros((0, 3)))
    P = np.ones((5, 3))
    P[2, 1] = np.nan
    with pytest.raises(SetError, match="rows \\[2\\]"):
        minimum_enclosing_ball(P)
    with pytest.raises(SetError, match="non-empty"):
        minimum_enclosing_ball(np.ones(4))


def test_support_outer_ball_encloses_set():
    rng = np.random.default_rng(3)
    pts = rng.standard_normal((5000, 3)) * [1.0, 0.3, 0.1] + [2.0, -1.0, 0.5]
    dirs = rng.standard_normal((60, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    h = (pts @ dirs.T).max(axis=0)
    outer = support_outer_ball(dirs, h)
    inner = minimum_enclosing_ball(pts)
    assert np.all(outer.contains(pts, tol=1e-9))
    assert outer.radius >= inner.radius
    assert outer.radius <= 2.0 * inner.radius  # 60 directions: a reasonably tight polytope
    with pytest.raises(SetError, match="unbounded"):
        support_outer_ball(np.abs(dirs), (pts @ np.abs(dirs).T).max(axis=0))


@pytest.mark.parametrize("d", [2, 3, 6])
def test_meb_many_cospherical_points(d):
    """20,000 points on the unit sphere (all of them near-support points): radius 1 to 1e-12."""
    rng = np.random.default_rng(d)
    P = rng.standard_normal((20_000, d))
    P /= np.linalg.norm(P, axis=1, keepdims=True)
    ball = minimum_enclosing_ball(P + 7.0, verify=True)
    assert abs(ball.radius - 1.0) <= 1e-12
    assert np.linalg.norm(ball.center - 7.0) <= 1e-9
    assert ball.certificate(1e-12)
