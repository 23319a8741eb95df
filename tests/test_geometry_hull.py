"""geometry.in_convex_hull, including degenerate hulls, against an LP feasibility test."""
import numpy as np
import pytest
from scipy.optimize import linprog

from ocreach.errors import SetError
from ocreach.geometry import in_convex_hull


def _lp_inside(p, H):
    """p in conv(H) iff {lam >= 0, sum lam = 1, H^T lam = p} is feasible (independent truth)."""
    n = H.shape[0]
    res = linprog(np.zeros(n), A_eq=np.vstack([H.T, np.ones(n)]), b_eq=np.r_[p, 1.0],
                  bounds=[(0, None)] * n, method="highs")
    return res.status == 0


def _cases():
    rng = np.random.default_rng(3)
    yield "full 3-D", rng.normal(size=(12, 3))
    plane = rng.normal(size=(10, 2)) @ np.array([[1.0, 0.5, -0.2], [0.3, -1.0, 0.4]]) + [1, 2, 3]
    yield "flat 2-D set in 3-D", plane
    seg = np.outer(rng.uniform(-1, 1, 6), [1.0, 2.0, -1.0]) + [0.5, 0, 0]
    yield "segment in 3-D", seg
    yield "one point repeated", np.tile([1.0, -2.0, 0.5], (4, 1))
    yield "collinear in 2-D", np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])


@pytest.mark.parametrize("name,H", list(_cases()))
def test_in_convex_hull_matches_lp(name, H):
    rng = np.random.default_rng(7)
    d = H.shape[1]
    # convex combinations (inside), perturbed copies (mostly outside), far points
    W = rng.dirichlet(np.ones(H.shape[0]), size=40)
    inside = W @ H
    off = inside + 0.05 * rng.normal(size=inside.shape)
    far = H.mean(axis=0) + 10 * rng.normal(size=(10, d))
    P = np.vstack([inside, off, far, H])
    got = in_convex_hull(P, H)
    want = np.array([_lp_inside(p, H) for p in P])
    assert got[:40].all() and got[-H.shape[0]:].all(), name
    assert np.array_equal(got, want), (name, np.flatnonzero(got != want))
    if name != "full 3-D":
        assert not got[40:80].all()  # the off-plane perturbations are outside the flat hull


def test_in_convex_hull_bad_input():
    with pytest.raises(SetError, match="non-empty"):
        in_convex_hull(np.zeros((1, 2)), np.zeros((0, 2)))
    with pytest.raises(SetError, match=r"\(m, 2\)"):
        in_convex_hull(np.zeros((1, 3)), np.zeros((3, 2)))
    with pytest.raises(SetError, match="finite"):
        in_convex_hull(np.array([[np.nan, 0.0]]), np.eye(2))
