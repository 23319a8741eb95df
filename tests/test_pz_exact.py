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


# ------------------------------------------------------------------ verified three-way membership
def _exact_residual_ok(pz, a, x, eps):
    """|c + G m(a) - x|_inf <= eps in exact rational arithmetic (independent of the float check)."""
    from fractions import Fraction as Fr

    from _sets_truth import exact_pz_value

    return all(abs(v) <= Fr(eps) for v in exact_pz_value(pz, a, [0.0] * pz.n_independent, x))


def _assert_witnesses_exact(pz, v, X, eps):
    """The witnesses of (up to 10 of) the points ``v`` classified inside map within ``eps``."""
    cols = np.searchsorted(v.ids, pz.id)
    for i in np.flatnonzero(v.inside)[:10]:
        assert _exact_residual_ok(pz, v.witness[i, cols], X[i], eps)


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.0, 1.0))
def test_classify_witnesses_points_built_from_known_factors(seed, face):
    """A point that is the image of known factors (a share of them on the box's faces, where
    the boundary points of reachable sets have theirs) is never excluded, is witnessed when at
    most half of its factors are on faces (in sets shaped like those of ``poly``: more factors
    than dimensions, each with a linear generator, smaller terms of degree 2 and 3; a point whose
    only preimages are corners of the box may be left undecided), and every witness returned maps
    within the tolerance in exact arithmetic."""
    from ocreach.sets.pz_witness import classify

    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 5))
    p = n + int(rng.integers(1, 5))
    h2 = int(rng.integers(1, 2 * p))
    E2 = rng.integers(0, 2, size=(p, h2)) + (rng.uniform(size=(p, h2)) < 0.2)
    E2[rng.integers(0, p, h2), np.arange(h2)] += 1            # every column of degree >= 1
    pz = PolyZonotope(rng.normal(size=n), np.hstack([rng.normal(size=(n, p)), 0.3 * rng.normal(size=(n, h2))]),
                      None, np.hstack([np.eye(p, dtype=int), E2]), new_ids(p))
    A = rng.uniform(-1, 1, (30, pz.n_factors))
    on_face = rng.uniform(size=A.shape) < face
    A[on_face] = np.sign(A[on_face])
    X = pz.evaluate(A)
    eps = 1e-9 * (1 + np.abs(X).max())
    v = classify(pz, X, eps)
    assert not v.outside.any()
    if face <= 0.5:   # with most factors on faces the witness may be a corner only: undecided
        assert v.inside.mean() >= 0.95, f"{int((~v.inside).sum())} of 30 not witnessed"
    _assert_witnesses_exact(pz, v, X, eps)


@settings(max_examples=8, deadline=None)
@given(st.integers(0, 10_000))
def test_classify_outside_verdicts_are_outside(seed):
    """Points around the set (images pushed outwards by up to a tenth of its size) and far from
    it: a point classified outside has no factor on a dense grid of the box mapping within the
    tolerance (no witness contradicts the certificate), every point classified inside has a
    witness that maps within it in exact arithmetic, and the far points are certified outside.
    (Points in a non-convex notch of the set may stay undecided: a support certificate cannot
    exclude them.)"""
    from ocreach.sets.pz_witness import classify

    rng = np.random.default_rng(seed)
    pz = rand_pz(rng, n=2, p=int(rng.integers(1, 3)), q=0, emax=2)
    size = np.abs(pz.G).sum()
    near = pz.evaluate(rng.uniform(-1, 1, (30, pz.n_factors))) \
        + 0.1 * size * rng.uniform(0, 1, (30, 1)) * dirs(rng, 2, 30)
    far = pz.c + 3 * (size + 1) * dirs(rng, 2, 5)
    X = np.vstack([near, far])
    eps = 1e-9 * (1 + np.abs(X).max())
    v = classify(pz, X, eps, lsq=False)
    assert not (v.inside & v.outside).any()
    assert v.outside[30:].all()
    grid = grid_points(pz)
    for i in np.flatnonzero(v.outside):
        assert np.abs(grid - X[i]).max(axis=1).min() > eps
    _assert_witnesses_exact(pz, v, X, eps)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000))
def test_box_min_norm_is_the_minimum_norm_solution_in_the_box(seed):
    """For systems with a solution ``z0`` in the box the batched solve returns a solution in the
    box whose norm is at most ``|z0|``; every iterate it returns is in the box."""
    from ocreach.sets.box_lsq import box_min_norm

    rng = np.random.default_rng(seed)
    n, m, N = int(rng.integers(1, 5)), int(rng.integers(5, 30)), 50
    J = rng.normal(size=(N, n, m)) * rng.uniform(0.01, 1, (1, 1, m))
    lo = -rng.uniform(0, 1, (N, m))
    hi = rng.uniform(0, 1, (N, m))
    z0 = lo + (hi - lo) * rng.uniform(size=(N, m))
    z0 = np.where(rng.uniform(size=(N, m)) < 0.5, np.where(rng.uniform(size=(N, m)) < 0.5, lo, hi), z0)
    r = np.einsum("Nim,Nm->Ni", J, z0)
    sol = box_min_norm(J, r, lo, hi, iters=60)
    assert np.all((sol.dz >= lo) & (sol.dz <= hi))
    res = np.abs(np.einsum("Nim,Nm->Ni", J, sol.dz) - r).max(axis=1)
    scale = np.abs(J).sum(axis=2).max(axis=1)
    ok = res <= 1e-9 * scale
    assert ok.mean() >= 0.95
    assert np.all(np.linalg.norm(sol.dz[ok], axis=1) <= np.linalg.norm(z0[ok], axis=1) * (1 + 1e-6) + 1e-9)
