"""Adversarial checks of the verified three-way membership of ``ocreach.sets.pz_witness``.

Points are placed on the boundary of the set enlarged by the tolerance box, to the last few
units in the last place, and every verdict is compared with an oracle in exact rational
arithmetic (``fractions``) on the floating-point inputs: a zonotope enlarged by a box is a
zonotope, and a full-dimensional zonotope in 2-D or 3-D is the intersection of the slabs normal
to every (n - 1)-subset of its generators.  A verdict "inside" where the oracle says outside (an
escape hidden) or "outside" where it says inside fails.
"""
from __future__ import annotations

import itertools
from fractions import Fraction as Fr

import numpy as np
import pytest
from _sets_truth import exact_pz_value
from hypothesis import given, settings
from hypothesis import strategies as st

from ocreach.errors import SetError
from ocreach.sets import PolyZonotope, new_ids
from ocreach.sets.interval import Interval
from ocreach.sets.union import ZonotopeUnion
from ocreach.sets.zonotope import Zonotope

SET = settings(max_examples=12, deadline=None)


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def exact_inside(c, G, x, eps) -> bool:
    """``x in (c, G) + [-eps, eps]^n`` exactly (n = 2 or 3), every float read as the rational it
    is."""
    return exact_in_zonotope(G, [Fr(float(xi)) - Fr(float(ci)) for xi, ci in zip(x, c)], eps)


def exact_in_zonotope(G, r, eps) -> bool:
    """The rational vector ``r`` in ``G [-1, 1]^h + [-eps, eps]^n`` (n = 2 or 3): inside every
    slab normal to an (n - 1)-subset of the generators and the box's edges."""
    n = len(r)
    cols = [[Fr(float(v)) for v in g] for g in np.asarray(G, float).reshape(n, -1).T]
    cols += [[Fr(float(eps)) if i == k else Fr(0) for i in range(n)] for k in range(n)]
    for sub in itertools.combinations(cols, n - 1):
        nv = [-sub[0][1], sub[0][0]] if n == 2 else _cross(sub[0], sub[1])
        if not any(nv):
            continue
        lhs = abs(sum(a * b for a, b in zip(nv, r)))
        rhs = sum(abs(sum(a * b for a, b in zip(nv, g))) for g in cols)
        if lhs > rhs:
            return False
    return True


def boundary_points(rng, c, G, eps, k):
    """Points ``c + G xi + eps s + delta w``: most factors ``xi`` on the faces, ``s`` in
    {-1, 0, 1}^n, ``delta`` from 0 to a few units of the last place of the coordinates' scale
    (or of eps) up to 1e-12 of it, either sign."""
    n, h = G.shape
    xi = rng.uniform(-1, 1, (k, h))
    face = rng.uniform(size=xi.shape) < 0.7
    xi[face] = np.sign(xi[face])
    s = rng.integers(-1, 2, (k, n)).astype(float)
    scale = 1.0 + np.abs(c).max() + np.abs(G).sum()
    delta = rng.choice([0.0, 1e-16, 4e-16, 3e-15, 1e-13, 1e-12], size=(k, 1)) \
        * rng.choice([scale, eps], size=(k, 1)) * rng.choice([-1.0, 1.0], size=(k, 1))
    return c + xi @ G.T + eps * s + delta * rng.normal(size=(k, n))


def rand_zonotope(rng, n):
    h = int(rng.integers(0, 5))
    c = rng.normal(size=n) * 10.0 ** rng.integers(-1, 4)
    G = rng.normal(size=(n, h)) * 10.0 ** rng.uniform(-2, 1, h)
    if h >= 2 and rng.uniform() < 0.3:          # parallel generators (degenerate facets)
        G[:, 1] = G[:, 0] * rng.uniform(0.1, 2)
    return c, G


@SET
@given(st.integers(0, 100_000), st.sampled_from([2, 3]), st.sampled_from([1e-15, 1e-12, 1e-9, 1e-3]))
def test_classify_zonotope_verdicts_agree_with_exact_arithmetic(seed, n, rel_eps):
    """Zonotopes (also with parallel or no generators) and intervals: every verdict at points on
    the boundary of the enlarged set, to a few ulps either side, agrees with the exact oracle."""
    from ocreach.sets.pz_witness import classify_zonotope

    rng = np.random.default_rng(seed)
    c, G = rand_zonotope(rng, n)
    eps = rel_eps * (1.0 + np.abs(c).max())
    XZ = boundary_points(rng, c, G, eps, 25)
    lo = c - np.abs(G).sum(axis=1) * rng.uniform(0, 2)
    hi = c + np.abs(G).sum(axis=1) * rng.uniform(0, 2)
    # the interval's own faces and corners, to a few ulps either side of the enlarged box
    t = np.where(rng.uniform(size=(25, n)) < 0.7, rng.integers(0, 2, (25, n)), rng.uniform(size=(25, n)))
    XI = lo + (hi - lo) * t + eps * rng.integers(-1, 2, (25, n)) \
        + rng.choice([0.0, 1e-16, 4e-16, 3e-15], size=(25, 1)) * np.abs(lo - hi + c).max() \
        * rng.normal(size=(25, n))
    for S, X in ((Zonotope(c, G), XZ), (Interval(lo, hi), XI)):
        v = classify_zonotope(S, X, eps)
        assert not (v.inside & v.outside).any()
        for i in np.flatnonzero(v.inside | v.outside):
            if isinstance(S, Interval):     # exactly: lo - eps <= x <= hi + eps
                truth = all(Fr(float(lo[j])) - Fr(eps) <= Fr(float(X[i, j])) <= Fr(float(hi[j])) + Fr(eps)
                            for j in range(n))
            else:
                truth = exact_inside(c, G, X[i], eps)
            assert truth == bool(v.inside[i]), (type(S).__name__, i, X[i].tolist(), eps, bool(v.inside[i]))


@SET
@given(st.integers(0, 100_000), st.sampled_from([2, 3]))
def test_classify_zonotope_union_verdicts_agree_with_exact_arithmetic(seed, n):
    """Unions: inside iff inside some part, outside only if outside every part (exact oracle per
    part), at points on the boundaries of all parts."""
    from ocreach.sets.pz_witness import classify_zonotope

    rng = np.random.default_rng(seed)
    parts = [rand_zonotope(rng, n) for _ in range(int(rng.integers(2, 4)))]
    # overlapping parts: the others' centres moved near the first
    parts = [parts[0]] + [(parts[0][0] + 0.5 * rng.normal(size=n) * (1 + np.abs(G).sum()), G)
                          for _, G in parts[1:]]
    eps = 1e-9 * (1.0 + np.abs(parts[0][0]).max())
    X = np.vstack([boundary_points(rng, c, G, eps, 12) for c, G in parts])
    v = classify_zonotope(ZonotopeUnion([Zonotope(c, G) for c, G in parts]), X, eps)
    assert not (v.inside & v.outside).any()
    for i in np.flatnonzero(v.inside | v.outside):
        truth = any(exact_inside(c, G, X[i], eps) for c, G in parts)
        assert truth == bool(v.inside[i]), (i, X[i].tolist(), bool(v.inside[i]))


def known_preimage_points(seed, rel_eps, k=20):
    """A random polynomial zonotope (dependent factors of degree up to 3, constant monomials, no
    or one independent generator) and points ``c + G m(a0) + GI b0 + eps s + delta w`` with most
    of ``a0`` on the faces, ``b0`` at the corners: ``(pz, X, eps, a0, b0)``."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 4))
    p, h, q = int(rng.integers(1, 4)), int(rng.integers(1, 6)), int(rng.integers(0, 2))
    E = rng.integers(0, 4, size=(p, h))
    E[:, rng.uniform(size=h) < 0.15] = 0                  # constant monomials
    pz = PolyZonotope(rng.normal(size=n) * 10.0 ** rng.integers(-1, 3), rng.normal(size=(n, h)),
                      rng.normal(size=(n, q)) * 0.1 if q else None, E, new_ids(p))
    eps = rel_eps * (1.0 + np.abs(pz.c).max())
    A = rng.uniform(-1, 1, (k, p))
    face = rng.uniform(size=A.shape) < 0.6
    A[face] = np.sign(A[face])
    B = np.sign(rng.uniform(-1, 1, (k, q)))
    base = np.atleast_2d(pz.evaluate(A, B if q else None))
    s = rng.integers(-1, 2, (k, n)).astype(float)
    delta = rng.choice([0.0, 1e-16, 1e-14, 1e-12], size=(k, 1)) * (1 + np.abs(base).max()) \
        * rng.choice([-1.0, 1.0], size=(k, 1))
    X = base + eps * s + delta * rng.normal(size=(k, n))
    return pz, X, eps, A, B


@settings(max_examples=8, deadline=None)
@given(st.integers(0, 100_000), st.sampled_from([1e-12, 1e-9, 1e-4]))
def test_classify_pz_verdicts_at_points_of_known_preimage(seed, rel_eps):
    """Polynomial zonotopes (dependent factors of degree up to 3, constant monomials, no or some
    independent generators): points ``c + G m(a0) + eps s + delta w`` with most of ``a0`` on the
    faces.  Every witness of a point classified inside is in the factor box and maps within eps
    in every coordinate in exact arithmetic (the independent part checked by the exact zonotope
    oracle); a point whose offset from its preimage's image is within eps exactly is never
    classified outside."""
    from ocreach.sets.pz_witness import classify

    pz, X, eps, A, B = known_preimage_points(seed, rel_eps)
    q = pz.n_independent
    v = classify(pz, X, eps, lsq=False)
    assert not (v.inside & v.outside).any()
    cols = np.searchsorted(v.ids, pz.id)
    for i in np.flatnonzero(v.inside):
        a = v.witness[i, cols]
        assert np.all(np.abs(a) <= 1.0)
        r = exact_pz_value(pz, a, np.zeros(q), X[i])
        if q == 0:
            assert max(abs(t) for t in r) <= Fr(eps), (i, X[i].tolist())
        else:       # some b in the box with GI b within eps of -r
            assert exact_in_zonotope(pz.GI, [-t for t in r], eps), (i, X[i].tolist())
    for i in np.flatnonzero(v.outside):
        # the constructing preimage's offset: within eps exactly means the point is inside
        r = exact_pz_value(pz, A[i], B[i] if q else [], X[i])
        assert max(abs(t) for t in r) > Fr(eps), (i, X[i].tolist(), eps)


def test_witness_search_returns_the_verified_witness():
    """The factors returned for a point found inside are its verified witness: here a later
    start's witness (within eps in every coordinate) was found, but the factors of an earlier
    start, closer in the 2-norm and not within eps, were returned (and became ``Classified.witness``
    and the next grid time's warm start)."""
    from ocreach.sets.pz_witness import _Residual, witness_search

    pz, X, eps, _, _ = known_preimage_points(0, 1e-4)
    found, best = witness_search(pz, X, eps)
    assert found[6]
    assert _Residual(pz).verified(best[found], X[found], eps).all()
    for i in np.flatnonzero(found):
        r = exact_pz_value(pz, best[i, : pz.n_factors], best[i, pz.n_factors:], X[i])
        assert max(abs(t) for t in r) <= Fr(eps)


def test_pz_without_dependent_factors_is_classified():
    """A polynomial zonotope with constant dependent monomials and no dependent factors (a
    zonotope with a shifted centre) is classified like that zonotope."""
    from ocreach.sets.pz_witness import classify

    pz = PolyZonotope(np.zeros(2), np.array([[1.0], [0.0]]), np.eye(2), np.zeros((0, 1), dtype=int), [])
    X = np.array([[1.5, 0.5], [0.0, -1.0], [3.0, 0.0], [-0.5, 0.0]])     # the set: [0, 2] x [-1, 1]
    v = classify(pz, X, 1e-9)
    assert v.inside.tolist() == [True, True, False, False]
    assert v.outside.tolist() == [False, False, True, True]


@pytest.mark.parametrize("eps", [-0.5, float("nan"), float("inf")])
def test_classify_rejects_a_bad_tolerance(eps):
    """A negative tolerance shrinks the set (a point inside it was certified outside); NaN or
    inf decides nothing: each is a clear error naming ``eps``."""
    from ocreach.sets.pz_witness import classify, classify_zonotope

    Z = Zonotope(np.zeros(2), np.eye(2))
    with pytest.raises(SetError, match="eps"):
        classify_zonotope(Z, np.array([[0.9, 0.0]]), eps)
    with pytest.raises(SetError, match="eps"):
        classify(PolyZonotope.from_zonotope(Z), np.array([[0.9, 0.0]]), eps)


@pytest.mark.parametrize("P", [np.array([[0.5], [3.0]]), np.array([[0.5, 0.1, 0.0]]),
                               np.array([[np.nan, 0.0]]), np.array([[np.inf, 0.0]])])
def test_classify_rejects_points_of_the_wrong_shape_or_not_finite(P):
    from ocreach.sets.pz_witness import classify, classify_zonotope

    Z = Zonotope(np.zeros(2), np.eye(2))
    with pytest.raises(SetError, match="P"):
        classify_zonotope(Z, P, 1e-9)
    with pytest.raises(SetError, match="P"):
        classify(PolyZonotope.from_zonotope(Z), P, 1e-9)


def test_support_certificate_counts_the_bound_s_own_rounding():
    """A zonotope written as a polynomial zonotope (centre ~100, vertex near the origin): the two
    points, exactly in the set, were certified outside at eps = 0 and 1e-14 by the
    branch-and-bound support bound, which lies below the exact support by its rounding (~1e-14
    here, against a comparison padded only by that of ``d^T x``, ~1e-27)."""
    from ocreach.sets.pz_witness import classify

    c = [99.7972774737739, -107.5858924189239]
    G = [[-15.817321864274168, 13.050291128014512, 35.08947899840664, 7.153075971541025,
          5.750461444927422, 34.437570956464995],
         [-0.41958803071520034, -5.720635275418194, -26.155469981314052, -9.494560976645403,
          40.32216864501901, -26.31264557124219]]
    X = np.array([[-6.389824472838945e-15, -2.6532533779768564e-13],
                  [-1.4210854715202004e-14, -2.5579538487363607e-13]])
    assert all(exact_inside(c, G, x, 0.0) for x in X)
    pz = PolyZonotope(c, G, None, np.eye(6, dtype=int), new_ids(6))
    for eps in (0.0, 1e-14):
        assert not classify(pz, X, eps, lsq=False).outside.any()


@settings(max_examples=6, deadline=None)
@given(st.integers(0, 100_000))
def test_classify_pz_support_certificates_at_vertices_agree_with_exact_arithmetic(seed):
    """Zonotopes as polynomial zonotopes with large centres and a vertex near the origin, points
    a few ulps of the set's scale either side of it along the direction it supports, eps = 0:
    no witness can be verified, so every verdict is a certificate, and each must agree with the
    exact oracle."""
    from ocreach.sets.pz_witness import classify

    rng = np.random.default_rng(seed)
    h = int(rng.integers(2, 7))
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    d = np.array([np.cos(t), np.sin(t)])[:, rng.integers(0, 64)]
    scale = 10.0 ** rng.uniform(0, 8)
    G = rng.normal(size=(2, h)) * scale
    s = np.sign(G.T @ d)
    c = -(G @ s) + rng.normal(size=2) * 1e-14 * scale
    X = c + G @ s + rng.integers(-40, 5, size=(8, 1)) * 2.0**-52 * scale * d
    v = classify(PolyZonotope(c, G, None, np.eye(h, dtype=int), new_ids(h)), X, 0.0, lsq=False)
    assert not v.inside.any()
    for i in np.flatnonzero(v.outside):
        assert not exact_inside(c, G, X[i], 0.0), (X[i].tolist(), c.tolist(), G.tolist())


def test_witness_lsq_returns_its_witnesses():
    """The last-resort search returns the witnesses it verified (``classify`` stores them in
    ``Classified.witness``; those points had zeros there): each maps within eps exactly."""
    from ocreach.sets.pz_witness import witness_lsq

    pz, X, eps, _, _ = known_preimage_points(3, 1e-9)
    guess = np.zeros((X.shape[0], pz.n_factors + pz.n_independent))
    found, wit = witness_lsq(pz, X, eps, guess)
    assert found.any()
    for i in np.flatnonzero(found):
        r = exact_pz_value(pz, wit[i, : pz.n_factors], wit[i, pz.n_factors:], X[i])
        assert np.all(np.abs(wit[i]) <= 1.0) and max(abs(t) for t in r) <= Fr(eps)


@SET
@given(st.integers(0, 100_000))
def test_support_upper_bound_with_its_rounding_bounds_the_exact_support(seed):
    """Zonotopes written as polynomial zonotopes (their exact support is a rational sum): the
    branch-and-bound ``upper`` alone falls below it by a few ulps for some of 64 directions;
    ``upper + upper_rounding`` never does."""
    from ocreach.sets.pz_exact import support_bounds, upper_rounding

    rng = np.random.default_rng(seed)
    h = int(rng.integers(20, 60))
    G = rng.normal(size=(2, h)) * 10.0 ** rng.uniform(-3, 0, h)
    c = rng.normal(size=2) * 10.0 ** rng.uniform(-3, 3)
    pz = PolyZonotope(c, G, None, np.eye(h, dtype=int), new_ids(h))
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    D = np.c_[np.cos(t), np.sin(t)]
    sb = support_bounds(pz, D, tol=1e-3)
    pad = upper_rounding(pz, D)
    for j in range(64):
        d = [Fr(float(v)) for v in D[j]]
        exact = sum(a * Fr(float(b)) for a, b in zip(d, c)) \
            + sum(abs(sum(a * Fr(float(b)) for a, b in zip(d, G[:, i]))) for i in range(h))
        assert exact <= Fr(float(sb.upper[j])) + Fr(float(pad[j]))
