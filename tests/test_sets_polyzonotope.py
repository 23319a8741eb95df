"""Polynomial zonotopes: exact operations agree pointwise, over-approximations contain samples."""
import numpy as np
import pytest
from _sets_truth import lp_in_zonotope
from hypothesis import given, settings
from hypothesis import strategies as st

from ocreach.errors import SetError
from ocreach.sets import (
    Interval,
    PolyZonotope,
    Zonotope,
    cartesian_product,
    new_ids,
    reduce,
    tensor_map,
    unit_ball_pz,
)

SET = settings(max_examples=30, deadline=None)


def rand_pz(rng, n=None, h=None, p=None, q=0, emax=3):
    n = n or int(rng.integers(1, 5))
    h = int(rng.integers(0, 7)) if h is None else h
    p = p or int(rng.integers(1, 4))
    return PolyZonotope(rng.normal(size=n), rng.normal(size=(n, h)), rng.normal(size=(n, q)),
                        rng.integers(0, emax + 1, size=(p, h)), new_ids(p))


def alpha_for(pz, ids, values):
    """Factor values of ``pz`` (in its id order) taken from a dict id -> value column."""
    return np.column_stack([values[int(i)] for i in pz.id]) if pz.n_factors else np.zeros((len(next(iter(values.values()))), 0))


def factor_dict(rng, ids, N):
    return {int(i): rng.uniform(-1, 1, N) for i in ids}


def pointwise(pz, vals):
    """Evaluate the polynomial directly from c, G, E (independent of evaluate())."""
    N = len(next(iter(vals.values())))
    out = np.tile(pz.c, (N, 1))
    for i in range(pz.n_dependent):
        m = np.ones(N)
        for k, ident in enumerate(pz.id):
            m = m * vals[int(ident)] ** pz.E[k, i]
        out += m[:, None] * pz.G[:, i]
    return out


@SET
@given(st.integers(0, 10**6))
def test_linear_map_translation_exact(seed):
    rng = np.random.default_rng(seed)
    pz = rand_pz(rng)
    M = rng.normal(size=(int(rng.integers(1, 4)), pz.dim))
    v = rng.normal(size=M.shape[0])
    out = M @ pz + v
    vals = factor_dict(rng, pz.id, 20)
    assert np.allclose(pointwise(out, vals), pointwise(pz, vals) @ M.T + v)


@SET
@given(st.integers(0, 10**6))
def test_exact_sum_keeps_shared_ids(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 4))
    shared = new_ids(2)
    a = PolyZonotope(rng.normal(size=n), rng.normal(size=(n, 4)), None, rng.integers(0, 3, size=(3, 4)),
                     np.r_[shared, new_ids(1)])
    b = PolyZonotope(rng.normal(size=n), rng.normal(size=(n, 5)), None, rng.integers(0, 3, size=(3, 5)),
                     np.r_[new_ids(1), shared[::-1]])
    s = a + b
    vals = factor_dict(rng, np.union1d(a.id, b.id), 25)
    assert np.allclose(s.evaluate(alpha_for(s, None, vals)), pointwise(a, vals) + pointwise(b, vals))
    # equal monomials are merged: no two equal exponent columns remain
    assert np.unique(s.E, axis=1).shape[1] == s.n_dependent


@SET
@given(st.integers(0, 10**6))
def test_cartesian_product_exact(seed):
    rng = np.random.default_rng(seed)
    a = rand_pz(rng)
    b = PolyZonotope(rng.normal(size=2), rng.normal(size=(2, 3)), None, rng.integers(0, 3, size=(2, 3)),
                     np.r_[a.id[:1], new_ids(1)])  # shares one factor with a
    cp_ = cartesian_product(a, b)
    vals = factor_dict(rng, np.union1d(a.id, b.id), 15)
    assert np.allclose(cp_.evaluate(alpha_for(cp_, None, vals)),
                       np.hstack([pointwise(a, vals), pointwise(b, vals)]))


@SET
@given(st.integers(0, 10**6), st.sampled_from([2, 3]))
def test_tensor_map_exact_including_centre(seed, order):
    rng = np.random.default_rng(seed)
    pz = rand_pz(rng, emax=2, h=int(rng.integers(0, 6)))
    m, n = int(rng.integers(1, 4)), pz.dim
    T = rng.normal(size=(m,) + (n,) * order)
    out = tensor_map(T, pz)
    vals = factor_dict(rng, pz.id, 20)
    s = pointwise(pz, vals)
    want = (np.einsum("iab,na,nb->ni", T, s, s) if order == 2 else np.einsum("iabc,na,nb,nc->ni", T, s, s, s))
    got = out.evaluate(alpha_for(out, None, vals)) if out.n_factors else np.tile(out.c, (20, 1))
    assert np.allclose(np.atleast_2d(got), want, atol=1e-9 * (1 + np.abs(want).max()))


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10**6))
def test_tensor_map_with_independent_generators_is_sound(seed):
    rng = np.random.default_rng(seed)
    pz = rand_pz(rng, n=2, h=3, p=2, q=2, emax=2)
    T = rng.normal(size=(2, 2, 2))
    out = tensor_map(T, pz)
    al = rng.uniform(-1, 1, size=(15, pz.n_factors))
    be = rng.choice([-1.0, 1.0, 0.3], size=(15, 2))
    s = pz.evaluate(al, be)
    want = np.einsum("iab,na,nb->ni", T, s, s)
    vals = {int(i): al[:, k] for k, i in enumerate(pz.id)}
    dep = out.evaluate(alpha_for(out, None, vals), np.zeros((15, out.n_independent))) if out.n_factors else \
        np.tile(out.c, (15, 1))
    for k in range(15):  # the rest must be reachable by the independent generators
        assert lp_in_zonotope(np.zeros(2), out.GI, want[k] - dep[k], tol=1e-6)


@SET
@given(st.integers(0, 10**6))
def test_split_is_exact_union(seed):
    rng = np.random.default_rng(seed)
    pz = rand_pz(rng, h=int(rng.integers(1, 6)))
    fid = int(pz.id[0])
    lo, hi = pz.split(fid)
    vals = factor_dict(rng, pz.id, 30)
    want = pointwise(pz, vals)
    a = vals[fid]
    for piece, sign in ((lo, -1.0), (hi, 1.0)):
        sel = (a <= 0) if sign < 0 else (a >= 0)
        v2 = {k: v[sel] for k, v in vals.items()}
        v2[fid] = 2 * a[sel] - sign  # a = (a' + sign) / 2
        if piece.n_factors:
            got = piece.evaluate(alpha_for(piece, None, v2))
        else:
            got = np.tile(piece.c, (sel.sum(), 1))
        assert np.allclose(np.atleast_2d(got).reshape(-1, pz.dim), want[sel])


@SET
@given(st.integers(0, 10**6))
def test_enclosure_hull_reduce_contain_samples(seed):
    rng = np.random.default_rng(seed)
    pz = rand_pz(rng, n=int(rng.integers(1, 4)), h=int(rng.integers(3, 12)), q=int(rng.integers(0, 3)))
    pts = np.vstack([pz.sample(20, rng), pz.sample(20, rng, mode="extreme")])
    Z = pz.to_zonotope()
    I = pz.interval_hull()
    h_max = max(pz.dim, int(rng.integers(pz.dim, pz.n_generators + 1)))
    method = ["pca", "girard"][seed % 2]
    R = reduce(pz, h_max, method)
    assert R.n_generators <= h_max
    RZ = R.to_zonotope()
    assert np.all(I.contains(pts, tol=1e-9))
    for x in pts:
        assert lp_in_zonotope(Z.c, Z.G, x)
        assert lp_in_zonotope(RZ.c, RZ.G, x, tol=1e-6)
    # support upper bound (with and without splitting) dominates every sample
    d = rng.normal(size=pz.dim)
    smax = (pts @ d).max()
    assert pz.support(d) >= smax - 1e-9
    assert pz.support(d, splits=4) >= smax - 1e-9
    assert pz.support(d, splits=4) <= pz.support(d) + 1e-9
    assert np.all(pz.contains(pts, splits=3))


@SET
@given(st.integers(0, 10**6), st.sampled_from(["pca", "girard"]))
def test_reduce_keeps_dependence_soundly(seed, method):
    """Stronger than enclosure: with the SAME values of the kept factors, every point of the
    original set is reached by the reduced set's independent generators (LP written in the test).
    Adversarial generators: widely different scales, a zero column, a near-duplicate column."""
    rng = np.random.default_rng(seed)
    n, h, q = int(rng.integers(1, 4)), int(rng.integers(3, 14)), int(rng.integers(0, 3))
    p = int(rng.integers(1, 4))
    G = rng.normal(size=(n, h)) * 10.0 ** rng.integers(-8, 2, size=h)
    G[:, 1] = 0.0
    G[:, 2] = G[:, 0] * (1 + 1e-12)
    pz = PolyZonotope(rng.normal(size=n), G, rng.normal(size=(n, q)), rng.integers(0, 6, size=(p, h)), new_ids(p))
    R = reduce(pz, int(rng.integers(n, h + q + 1)), method)
    al = rng.choice([-1.0, 1.0, 0.3, -0.7], size=(20, p))
    be = rng.choice([-1.0, 1.0, 0.2], size=(20, q))
    X = pointwise(pz, {int(i): al[:, k] for k, i in enumerate(pz.id)}) + be @ pz.GI.T
    dep = pointwise(R, {int(i): al[:, k] for k, i in enumerate(pz.id)})
    for x, y in zip(X, dep):
        assert lp_in_zonotope(np.zeros(n), R.GI, x - y, tol=1e-9)


def test_reduced_pz_still_dependent_on_kept_factors():
    rng = np.random.default_rng(3)
    pz = rand_pz(rng, n=3, h=30, p=4)
    R = reduce(pz, 10, "pca")
    assert R.n_generators <= 10 and R.n_dependent >= 1


def test_foss_eq15():
    pz = PolyZonotope([2, 0], [[3, 0, 1], [2, 4, 2]], None, [[1, 0, 2], [0, 2, 1]], [1, 2])
    a = np.array([[0.3, -0.7]])
    want = np.array([2, 0]) + np.array([3, 2]) * 0.3 + np.array([0, 4]) * 0.49 + np.array([1, 2]) * 0.09 * -0.7
    assert np.allclose(pz.evaluate(a), want)
    # exact x-range: 2 + 3a1 + a1^2 a2 spans [-2, 6]
    assert np.isclose(pz.support([1, 0], splits=8), 6.0, atol=1e-9)
    assert np.isclose(-pz.support([-1, 0], splits=8), -2.0, atol=1e-9)


def test_unit_ball_pz_encloses_disk_boundary_and_is_tight():
    for n in (2, 3):
        B = unit_ball_pz(n)
        d = np.random.default_rng(0).normal(size=(50, n))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        sup = B.support(d, splits=0)
        assert np.all(sup >= 1 - 1e-12)
        pts = B.sample(4000, 0)
        r = np.linalg.norm(pts, axis=1)
        assert r.max() < (1.01 if n == 2 else 1.03) and r.max() > 0.95
        # image of the cube's boundary lies outside the open unit ball (enclosure argument)
        F = np.random.default_rng(1).uniform(-1, 1, size=(2000, n))
        F[np.arange(2000), np.arange(2000) % n] = np.sign(F[np.arange(2000), np.arange(2000) % n])
        assert np.all(np.linalg.norm(B.evaluate(F), axis=1) >= 1 - 1e-12)


def test_degenerate_inputs():
    with pytest.raises(SetError, match="unique"):
        PolyZonotope([0, 0], np.eye(2), None, np.eye(2), [5, 5])
    with pytest.raises(SetError):
        PolyZonotope([0, 0], np.eye(2), None, [[1, -1], [0, 1]], None)
    with pytest.raises(SetError):
        PolyZonotope([0, 0], np.ones((3, 2)))
    empty = PolyZonotope([1.0, 2.0])
    assert empty.n_generators == 0 and np.allclose(empty.sample(3, 0), [1, 2])
    assert np.allclose(tensor_map(np.ones((1, 2, 2)), empty).c, [9.0])
    one = PolyZonotope([0.5], [[2.0]], None, [[2]], None)
    assert np.isclose(one.support([1.0]), 2.5) and np.isclose(one.support([-1.0]), -0.5)
    z = PolyZonotope([0.0, 0.0], np.zeros((2, 3)))
    assert z.compact().n_generators == 0
    with pytest.raises(SetError):
        reduce(rand_pz(np.random.default_rng(0), n=3, h=5), 2)
    assert PolyZonotope.from_interval(Interval([0, 0], [1, 0])).n_dependent == 1
    assert PolyZonotope.from_zonotope(Zonotope([0, 0])).n_generators == 0


def test_outline_pieces_cover_samples():
    pz = PolyZonotope([2, 0], [[3, 0, 1], [2, 4, 2]], None, [[1, 0, 2], [0, 2, 1]], [1, 2])
    polys = pz.outline((0, 1), pieces=16)
    assert len(polys) == 16
    pts = pz.sample(300, 0)
    from matplotlib.path import Path
    inside = np.zeros(300, bool)
    for P in polys:
        inside |= Path(P).contains_points(pts, radius=1e-9) | Path(P[::-1]).contains_points(pts, radius=1e-9)
    assert inside.all()


def test_merge_is_exact_under_hash_collisions(monkeypatch):
    """With a deliberately colliding hash (key = total degree) the exact re-check must still keep
    different monomials apart: sum, compact and tensor map agree with direct evaluation."""
    import ocreach.sets.polyzonotope as pzmod

    monkeypatch.setattr(pzmod, "_hash_weights", lambda p: np.ones((2, p), dtype=np.int64))
    monkeypatch.setattr(pzmod, "exact_keys", lambda E, bound: None)  # the hash path, not the int64 keys
    rng = np.random.default_rng(11)
    ids = new_ids(3)
    a = PolyZonotope(rng.normal(size=2), rng.normal(size=(2, 6)), None, rng.integers(0, 3, size=(3, 6)), ids)
    b = PolyZonotope(rng.normal(size=2), rng.normal(size=(2, 5)), None, rng.integers(0, 3, size=(3, 5)), ids[::-1])
    vals = factor_dict(rng, ids, 25)
    s = a + b
    assert np.unique(s.E, axis=1).shape[1] == s.n_dependent
    assert np.allclose(pointwise(s, vals), pointwise(a, vals) + pointwise(b, vals))
    for order in (2, 3):
        T = rng.normal(size=(2,) + (2,) * order)
        out = tensor_map(T, a)
        sa = pointwise(a, vals)
        want = np.einsum("iab,na,nb->ni", T, sa, sa) if order == 2 else np.einsum("iabc,na,nb,nc->ni", T, sa, sa, sa)
        assert np.allclose(pointwise(out, vals), want)


def test_outline_union_is_one_nonconvex_ring_covering_samples():
    """Foss Eq. 15: the merged outline is one ring (no overlaps), non-convex (its area is below its
    convex hull's), contains every sample, and its area equals the union area of the pieces."""
    from matplotlib.path import Path
    from scipy.spatial import ConvexHull

    pz = PolyZonotope([2, 0], [[3, 0, 1], [2, 4, 2]], None, [[1, 0, 2], [0, 2, 1]], [1, 2])
    rings = pz.outline_union((0, 1), pieces=64)
    assert len(rings) == 1
    R = rings[0]
    x, y = R[:, 0], R[:, 1]
    signed = 0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    assert signed > 0  # counter-clockwise exterior
    assert signed < 0.97 * ConvexHull(R).volume
    assert np.isclose(signed, pz.area((0, 1), pieces=64), rtol=1e-9)
    pts = pz.sample(500, 1)
    assert Path(R).contains_points(pts, radius=1e-9).all() or Path(R).contains_points(pts, radius=-1e-9).all()
    # degenerate projection (a segment): no area, no rings; plotting falls back to the pieces
    seg = PolyZonotope([0.0, 0.0], [[1.0], [1.0]], None, [[2]], None)
    assert seg.outline_union() == []
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    seg.plot(ax)
    pz.plot(ax, pieces=16)
    plt.close(fig)


@SET
@given(st.integers(0, 10**6), st.booleans())
def test_merge_by_exact_int64_keys_equals_unique_grouping(seed, exact):
    """merge_monomials with one exact int64 key per column (argsort + reduceat, no re-check) or
    with the 128-bit hash (re-checked) sums exactly the columns ``np.unique`` groups together."""
    from ocreach.sets.polyzonotope import exact_keys, merge_monomials, monomial_keys

    rng = np.random.default_rng(seed)
    p, h = int(rng.integers(1, 5)), int(rng.integers(0, 40))
    pool = rng.integers(0, 4, size=(p, max(1, h // 3)))
    E = pool[:, rng.integers(0, pool.shape[1], size=h)]          # many repeated monomials
    G = rng.normal(size=(3, h))
    keys = exact_keys(E, E.max(axis=1, initial=0)) if exact else monomial_keys(E)
    Gm, rep = merge_monomials(G, keys, None if exact else E)
    U, inv = np.unique(E, axis=1, return_inverse=True)
    want = np.zeros((3, U.shape[1]))
    np.add.at(want.T, inv.ravel(), G.T)
    col = {tuple(u): k for k, u in enumerate(U.T)}
    got_cols = [col[tuple(e)] for e in E[:, rep].T]
    assert sorted(got_cols) == list(range(U.shape[1]))          # every monomial once
    np.testing.assert_allclose(Gm, want[:, got_cols], rtol=1e-12, atol=1e-12)


def test_exact_keys_add_and_refuse_what_does_not_fit(monkeypatch):
    """Keys of sums are sums of keys within the bound; exponents that do not fit one int64 word
    give None, and the tensor map then takes the hash path with the same points."""
    import ocreach.sets.polyzonotope as pzmod
    from ocreach.sets.polyzonotope import exact_keys

    rng = np.random.default_rng(4)
    E1, E2 = rng.integers(0, 3, size=(5, 30)), rng.integers(0, 3, size=(5, 30))
    np.testing.assert_array_equal(exact_keys(E1 + E2, np.full(5, 4)),
                                  exact_keys(E1, np.full(5, 4)) + exact_keys(E2, np.full(5, 4)))
    assert exact_keys(rng.integers(0, 10, size=(30, 4)), np.full(30, 10)) is None
    pz = rand_pz(rng, n=3, h=12, p=4, q=2, emax=2)
    vals = factor_dict(rng, pz.id, 20)
    for order in (2, 3):
        T = rng.normal(size=(2,) + (3,) * order)
        fast = tensor_map(T, pz)
        with monkeypatch.context() as m:
            m.setattr(pzmod, "exact_keys", lambda E, bound: None)
            hashed = tensor_map(T, pz)
        assert fast.n_dependent == hashed.n_dependent and fast.n_independent == hashed.n_independent
        np.testing.assert_allclose(pointwise(fast, vals), pointwise(hashed, vals), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(fast.c, hashed.c, rtol=1e-12, atol=1e-12)


def test_monomial_values_large_batches_equal_the_direct_powers():
    """The log-space evaluation used for large batches equals prod a^e, with negative factors,
    zeros (0^0 = 1, 0^e = 0) and factors outside [-1, 1]."""
    from ocreach.sets.polyzonotope import monomial_values

    rng = np.random.default_rng(5)
    E = (rng.random((60, 400)) < 0.1) * rng.integers(1, 4, (60, 400))
    A = rng.uniform(-2, 2, (30, 60))
    A[rng.random(A.shape) < 0.1] = 0.0
    ref = np.prod(A[:, :, None] ** E[None], axis=1)
    got = monomial_values(A, E)
    assert A.size * E.shape[1] > 50_000  # the log-space branch
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-300)
    assert np.all(got[ref == 0] == 0)


def test_monomial_values_large_batches_keep_nan_and_inf():
    """A NaN factor value gives NaN monomials in the log-space branch too (it was read as a zero
    factor: 0 instead of NaN, a silent NaN path), and inf follows the direct powers."""
    from ocreach.sets.polyzonotope import monomial_values

    rng = np.random.default_rng(6)
    E = (rng.random((60, 400)) < 0.1) * rng.integers(1, 4, (60, 400))
    A = rng.uniform(-1, 1, (30, 60))
    A[0, :] = np.nan
    A[1, 3] = np.inf
    ref = np.prod(A[:, :, None] ** E[None], axis=1)
    got = monomial_values(A, E)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    assert np.isnan(got[0, E.sum(axis=0) > 0]).all()
    np.testing.assert_allclose(got[2:], ref[2:], rtol=1e-12, atol=1e-300)
    np.testing.assert_array_equal(got[1], ref[1])
