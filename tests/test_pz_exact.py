"""Exact set queries on polynomial zonotopes (ocreach.sets.pz_exact) against brute force."""
import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ocreach.geometry import hull_area
from ocreach.sets import PolyZonotope, new_ids, unit_ball_pz
from ocreach.sets.pz_exact import hull_area_bounds, membership, points_at, support_bounds


def rand_pz(rng, n=2, p=None, h=None, q=None, emax=3):
    p = p or int(rng.integers(1, 4))
    h = h or int(rng.integers(1, 7))
    q = int(rng.integers(0, 2)) if q is None else q
    return PolyZonotope(rng.normal(size=n), rng.normal(size=(n, h)), rng.normal(size=(n, q)),
                        rng.integers(0, emax + 1, size=(p, h)), new_ids(p))


def grid_points(pz, per_dim=None):
    """Dense factor grid (corners included) mapped through the set; independent part in the support."""
    p = pz.n_factors
    g = np.linspace(-1, 1, per_dim or {1: 801, 2: 101, 3: 31}[p])
    A = np.array(list(itertools.product(g, repeat=p)))
    return pz.c + pz.monomials(A) @ pz.G.T


def dirs(rng, n, m):
    D = rng.normal(size=(m, n))
    return D / np.linalg.norm(D, axis=1, keepdims=True)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_support_bounds_bracket_brute_force(seed):
    rng = np.random.default_rng(seed)
    pz = rand_pz(rng)
    D = dirs(rng, 2, 12)
    tol = 1e-4
    sb = support_bounds(pz, D, tol=tol)
    X = grid_points(pz)
    grid_max = (X @ D.T).max(axis=0) + np.abs(D @ pz.GI).sum(axis=1)
    radius = np.abs(D @ pz.G).sum(axis=1) + np.abs(D @ pz.GI).sum(axis=1)
    assert np.all(grid_max <= sb.upper + 1e-9)              # upper bound is an upper bound
    # lower bound is attained by the witness, a point of the set
    assert np.allclose(np.einsum("ij,ij->i", sb.points, D), sb.lower, atol=1e-9)
    assert np.allclose(pz.evaluate(sb.alpha, sb.beta if pz.n_independent else None), sb.points)
    assert np.all(np.abs(sb.alpha) <= 1) and np.all(np.abs(sb.beta) <= 1)
    assert sb.converged.all()
    assert np.all(sb.gap <= tol * radius + 1e-12)
    # and the grid (which misses the exact maximiser by its spacing) is close to it
    assert np.all(sb.lower - grid_max <= 0.05 * radius)


def test_support_bounds_decomposed_many_factors():
    """16 factors in 8 blocks (separable plus small cross terms): the truth is the sum of the
    blocks' maxima (dense grids) with the cross terms bracketed by their range."""
    rng = np.random.default_rng(3)
    parts = [rand_pz(rng, p=2, h=5, q=0) for _ in range(8)]
    G = np.hstack([pc.G for pc in parts])
    E = np.zeros((16, G.shape[1]), dtype=np.int64)
    col = 0
    for b, pc in enumerate(parts):
        E[2 * b: 2 * b + 2, col: col + pc.n_dependent] = pc.E
        col += pc.n_dependent
    pz = PolyZonotope(sum(pc.c for pc in parts), G, None, E, new_ids(16))
    D = dirs(rng, 2, 8)
    sb = support_bounds(pz, D, tol=1e-4)
    truth = sum((grid_points(pc, 201) @ D.T).max(axis=0) for pc in parts)
    assert np.all(truth <= sb.upper + 1e-9)
    assert np.all(sb.lower <= truth + 1e-9 + 1e-3 * np.abs(D @ G).sum(axis=1))
    assert np.all(sb.gap <= 1e-3 * np.abs(D @ G).sum(axis=1))
    # with weak cross terms the bounds stay valid (sampled maximum below the upper bound)
    Gc = 1e-3 * rng.normal(size=(2, 10))
    Ec = np.zeros((16, 10), dtype=np.int64)
    for i in range(10):
        Ec[rng.choice(16, 2, replace=False), i] = 1
    pz2 = PolyZonotope(pz.c, np.hstack([G, Gc]), None, np.hstack([E, Ec]), new_ids(16))
    sb2 = support_bounds(pz2, D, tol=1e-4)
    S = pz2.sample(20000, 0, mode="extreme")
    assert np.all((S @ D.T).max(axis=0) <= sb2.upper + 1e-9)
    assert np.allclose(np.einsum("ij,ij->i", sb2.points, D), sb2.lower)
    assert np.all(sb2.lower >= (S @ D.T).max(axis=0) - 1e-9)  # better than sampling the vertices


def test_membership_witness_and_certificate():
    rng = np.random.default_rng(5)
    for _ in range(5):
        pz = rand_pz(rng, q=1)
        A = rng.uniform(-1, 1, (50, pz.n_factors))
        B = rng.uniform(-1, 1, (50, pz.n_independent))
        inside_pts = pz.evaluate(A, B)
        far = pz.c + 3 * (np.abs(pz.G).sum(axis=1) + np.abs(pz.GI).sum(axis=1) + 1) * dirs(rng, 2, 20)
        m = membership(pz, np.vstack([inside_pts, far]), tol=1e-6)
        ins = m.status[:50]
        assert np.mean(ins == 1) > 0.9 and not np.any(ins == -1)   # no false exclusion
        ok = np.flatnonzero(m.status == 1)
        x = pz.evaluate(m.alpha[ok], m.beta[ok])
        assert np.all(np.linalg.norm(x - np.vstack([inside_pts, far])[ok], axis=1) <= 1e-6)
        assert np.all(m.status[50:] == -1)
        # certificate: the direction separates the point from the whole set (dense grid)
        X = grid_points(pz)
        for i in np.flatnonzero(m.status == -1):
            d = m.direction[i]
            assert (X @ d).max() + np.abs(d @ pz.GI).sum() <= m.bound[i] + 1e-9
            assert np.vstack([inside_pts, far])[i] @ d > m.bound[i]


def test_hull_area_bounds_and_boundary_points():
    rng = np.random.default_rng(8)
    for _ in range(4):
        pz = rand_pz(rng, q=0)
        lo, hi = hull_area_bounds(pz, n_dirs=128)
        true = hull_area(grid_points(pz))
        assert lo <= true * (1 + 1e-9) + 1e-12 and true <= hi * (1 + 1e-9) + 1e-12
        if true > 1e-3:  # not a degenerate (flat) projection
            assert hi <= lo * 1.05
        D = dirs(rng, 2, 10)
        P = points_at(pz, D)
        assert np.all(np.einsum("ij,ij->i", P, D) >= (grid_points(pz) @ D.T).max(axis=0) - 1e-3)


def test_unit_ball_pz_tight_and_contains_ball():
    rng = np.random.default_rng(0)
    for n in (2, 3, 4):  # n = 5 (405 generators) is slower; docs/stt.md has its sampled radius
        B = unit_ball_pz(n)
        D = np.vstack([dirs(rng, n, 60), np.eye(n), np.ones((1, n)) / np.sqrt(n)])
        sb = support_bounds(B, D, tol=5e-4)
        assert np.all(sb.upper >= 1) and np.all(sb.lower >= 1 - 0.01)
        assert np.all(sb.upper <= 1.03)                       # within 3 % of the ball
        F = rng.uniform(-1, 1, size=(4000, n))                # boundary of the factor cube ...
        F[np.arange(4000), np.arange(4000) % n] = np.sign(F[np.arange(4000), np.arange(4000) % n])
        assert np.all(np.linalg.norm(B.evaluate(F), axis=1) >= 1 - 1e-9)   # ... maps outside the ball


def test_support_bounds_block_with_more_than_255_monomials():
    """A factor block with 260 monomials (the block cache key once packed the shape with
    ``bytes(shape)``, which refuses sizes > 255): bounds bracket the dense-grid maximum."""
    rng = np.random.default_rng(7)
    blocks, cols = [], []
    for b in range(2):                                         # 2 blocks of 4 factors (8 > 6)
        all_e = np.array(list(itertools.product(range(5), repeat=4))).T[:, 1:]
        E = all_e[:, rng.choice(all_e.shape[1], 260, replace=False)]
        G = rng.normal(size=(2, 260)) / (1 + E.sum(axis=0)) ** 2
        blocks.append((G, E))
    G = np.hstack([g for g, _ in blocks])
    E = np.zeros((8, G.shape[1]), dtype=np.int64)
    E[:4, :260], E[4:, 260:] = blocks[0][1], blocks[1][1]
    pz = PolyZonotope(np.zeros(2), G, None, E, new_ids(8))
    D = dirs(rng, 2, 2)
    sb = support_bounds(pz, D, tol=1e-2)
    a = np.linspace(-1, 1, 15)
    A = np.array(list(itertools.product(a, repeat=4)))         # dense grid of each block's factors
    grid_max = sum((np.prod(A[:, :, None] ** Eb[None, :, :], axis=1) @ Gb.T @ D.T).max(axis=0)
                   for Gb, Eb in blocks)
    assert np.all(grid_max <= sb.upper + 1e-9)
    assert np.all(sb.lower <= sb.upper + 1e-12)
    assert np.all(sb.gap <= 1e-2 * np.abs(D @ G).sum(axis=1) + 1e-12)
