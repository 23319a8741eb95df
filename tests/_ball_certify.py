"""Finite proofs for polynomial-zonotope balls (used by tests/test_ball_pz.py).

A ball candidate ``F(a) = sum_h G[:, h] prod_k a_k^E[k, h]`` (centre 0, factors in [-1, 1]) whose
components each have one parity pattern of exponents has ``|F|^2`` a polynomial in ``x = a^2``
(:func:`squared_norm_in_squares`), and ``|F|`` is unchanged by flipping the sign of any factor.
Bounds of a polynomial on ``[0, 1]^m`` are proved by Bernstein coefficients with subdivision
(:func:`max_over_unit_box`): on a box the polynomial lies between its smallest and largest
Bernstein coefficients, the vertex coefficients are values, and subdivision converges
quadratically.  So a returned True is a proof (up to floating-point round-off), not a sample.
The ``*_exact`` functions at the end redo it in exact rational arithmetic (no round-off caveat).
"""
from __future__ import annotations

import itertools
from math import comb

import numpy as np


def _values(G, E, A):
    """``F`` at the factor values ``A`` (N, m)."""
    M = np.prod(A[:, :, None] ** np.asarray(E)[None, :, :], axis=1)   # (N, h)
    return M @ np.asarray(G, float).T


def squared_norm_in_squares(G, E, exact=False):
    """``|F|^2`` as a polynomial in ``x = a^2`` (dense coefficient tensor), or None when some
    component mixes parity patterns (then it is not one).  ``exact``: in exact rationals (an
    object array of ``Fraction``; floats are dyadic rationals, so the stored generators are read
    exactly), else in floats."""
    from fractions import Fraction

    G, E = np.asarray(G, float), np.asarray(E, int)
    num = (lambda v: Fraction(float(v))) if exact else float
    terms: dict = {}
    for i in range(G.shape[0]):
        hs = np.flatnonzero(G[i])
        if len({tuple(E[:, h] % 2) for h in hs}) > 1:
            return None
        for h1, h2 in itertools.product(hs, hs):
            e = tuple(int(v) for v in (E[:, h1] + E[:, h2]) // 2)
            terms[e] = terms.get(e, num(0)) + num(G[i, h1]) * num(G[i, h2])
    shape = tuple(int(v) for v in np.max(np.array(list(terms)), axis=0) + 1)
    C = np.full(shape, num(0), dtype=object) if exact else np.zeros(shape)
    for e, v in terms.items():
        C[e] += v
    return C


def _axis_matrices(d, lo, s):
    """(N, d+1, d+1): monomial coefficients in x on [lo, lo + s] -> Bernstein coefficients in
    t = (x - lo) / s (substitution x = lo + s t, then the monomial-to-Bernstein change of basis)."""
    T = np.zeros((lo.shape[0], d + 1, d + 1))            # new_j = sum_i c_i C(i, j) lo^(i-j) s^j
    for i in range(d + 1):
        for j in range(i + 1):
            T[:, j, i] = comb(i, j) * lo ** (i - j) * s ** j
    B = np.array([[comb(k, j) / comb(d, j) if j <= k else 0.0 for j in range(d + 1)] for k in range(d + 1)])
    return np.einsum("kj,nji->nki", B, T)


def max_over_unit_box(C, bound, max_level=30, max_boxes=2_000_000):
    """Prove ``p(x) <= bound`` on ``[0, 1]^m`` (``C``: dense coefficients of ``p``).  A box is
    settled when its largest Bernstein coefficient is <= ``bound``, else split in 2^m; a vertex
    value above ``bound`` is a counterexample.  Returns (proved, largest vertex value seen)."""
    C = np.asarray(C, float)
    m = C.ndim
    lo, s, seen = np.zeros((1, m)), 1.0, -np.inf
    kids = np.array(list(itertools.product((0.0, 1.0), repeat=m)))
    for _ in range(max_level):
        Bc = np.broadcast_to(C, (lo.shape[0],) + C.shape).copy()
        for ax in range(m):
            M = _axis_matrices(C.shape[ax] - 1, lo[:, ax], np.full(lo.shape[0], s))
            Bc = np.moveaxis(np.einsum("nki,n...i->n...k", M, np.moveaxis(Bc, ax + 1, -1)), -1, ax + 1)
        corners = Bc[(slice(None),) + tuple(slice(None, None, max(C.shape[ax] - 1, 1)) for ax in range(m))]
        seen = max(seen, float(corners.max()))
        if seen > bound:
            return False, seen
        open_ = Bc.reshape(lo.shape[0], -1).max(axis=1) > bound
        if not open_.any():
            return True, seen
        s /= 2
        lo = (lo[open_][:, None, :] + s * kids[None]).reshape(-1, m)
        if lo.shape[0] > max_boxes:
            return False, seen
    return False, seen


def face_at_least(C, k, bound, **kw):
    """Prove ``p >= bound`` on the face ``x_k = 1`` of ``[0, 1]^m``."""
    return max_over_unit_box(-np.asarray(C).sum(axis=k), -bound, **kw)[0]


def boundary_at_least_one(G, E):
    """Prove ``|F| >= 1`` on the boundary of the factor cube (every face ``a_k = +-1`` is the
    face ``x_k = 1``)."""
    C = squared_norm_in_squares(G, E)
    return C is not None and all(face_at_least(C, k, 1.0) for k in range(C.ndim))


# ------------------------------------------------------------------ exact rational certificates
# The float certifier above rounds in |F|^2's coefficients (products of the float generators) and
# in the Bernstein change of basis; its True is a proof only up to that round-off.  The functions
# below redo both in exact rational arithmetic (floats are dyadic rationals, so the stored
# coefficients are represented exactly), with de Casteljau halving (exact), so their True is a
# proof for the coefficients exactly as stored.  Pure Python: meant for the small leaves.

def _to_bernstein_exact(C):
    """Bernstein coefficients on ``[0, 1]^m`` of the dense monomial coefficients ``C`` (exact)."""
    from fractions import Fraction

    B = C
    for ax in range(C.ndim):
        d = C.shape[ax] - 1
        M = np.array([[Fraction(comb(k, j), comb(d, j)) if j <= k else Fraction(0)
                       for j in range(d + 1)] for k in range(d + 1)], dtype=object)
        B = np.moveaxis(np.tensordot(M, np.moveaxis(B, ax, 0), axes=(1, 0)), 0, ax)
    return B


def _halve_exact(B, ax):
    """de Casteljau at t = 1/2 along ``ax``: Bernstein coefficients of the two halves (exact)."""
    b = [np.take(B, i, axis=ax) for i in range(B.shape[ax])]
    left, right = [b[0]], [b[-1]]
    while len(b) > 1:
        b = [(b[i] + b[i + 1]) / 2 for i in range(len(b) - 1)]
        left.append(b[0])
        right.append(b[-1])
    return np.stack(left, axis=ax), np.stack(right[::-1], axis=ax)


def max_over_unit_box_exact(C, bound, max_level=40, max_boxes=20_000):
    """Prove ``p(x) <= bound`` on ``[0, 1]^m`` in exact rational arithmetic (``C``: exact dense
    coefficients, ``bound``: a float or ``Fraction``, taken exactly).  Returns (proved, boxes
    examined); a vertex value above ``bound`` (a counterexample) or the limits give False."""
    from fractions import Fraction

    bound = Fraction(bound)
    m = C.ndim
    stack, count = [(_to_bernstein_exact(C), 0)], 0
    while stack:
        B, level = stack.pop()
        count += 1
        if count > max_boxes or level > max_level:
            return False, count
        if max(B.flat) <= bound:
            continue
        corners = B[tuple(slice(None, None, max(B.shape[ax] - 1, 1)) for ax in range(m))]
        if max(corners.flat) > bound:
            return False, count
        parts = [B]
        for ax in range(m):
            parts = [h for P in parts for h in _halve_exact(P, ax)]
        stack.extend((P, level + 1) for P in parts)
    return True, count


def boundary_at_least_one_exact(G, E, r=1):
    """:func:`boundary_at_least_one` in exact rational arithmetic (``|F| >= r`` with ``r``, a float
    or ``Fraction``, taken exactly; default 1)."""
    from fractions import Fraction

    C = squared_norm_in_squares(G, E, exact=True)
    r2 = Fraction(r) ** 2
    return C is not None and all(max_over_unit_box_exact(-C.sum(axis=k), -r2)[0] for k in range(C.ndim))
