"""Degree-capped sparse polynomial zonotopes with rigorous floating-point arithmetic: the set
representation inside the sound ``poly`` method (:mod:`ocreach.reach.poly`).

A :class:`SoundPZ` is the set ``{c + sum_j G_j m_j(a) + GI b : a in [-1, 1]^p, b in [-1, 1]^q}``
of a sparse polynomial zonotope (Kochdumper & Althoff), with every monomial ``m_j`` stored as the
sorted tuple of its factors' indices (with repetition), at most ``max_degree`` of them, packed
into one exact ``int64`` key (``63 // max_degree`` bits per index, index 0 = none).  Equal
monomials therefore have equal keys exactly (no hashing), the product of two monomials is the
merge of their tuples, and a monomial above the degree cap is enclosed by an independent
generator (it lies in [-1, 1]) -- a reduction that keeps the set an enclosure.  Factor indices are
local to one run (:class:`FactorIds` maps them to the global identifiers of
:class:`ocreach.sets.PolyZonotope` for the results).

Floating point.  Every operation returns an enclosure of the exact result of the operation on
its float inputs: the float result plus a box (independent generators) bounding the rounding
(Higham, Lemma 3.1; :mod:`ocreach.sets.rounding`).  Every coefficient of a result is a sum of
products of input entries with at most ``k`` roundings along a chain, so its error is at most
``gamma_k`` times the same sum on absolute values; since every monomial lies in [-1, 1] the error
of the set in row ``i`` is at most the sum over the row's coefficients, i.e. ``gamma_k`` times the
absolute-value expression summed over all coefficients: ``|M| s`` for a linear map ``M``,
``s^T |H_i| s`` for a quadratic form, with ``s = |c| + sum |g_j| + sum |gI_j|``
(:func:`magnitude`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.errors import SetError
from ocreach.sets._base import new_ids
from ocreach.sets.rounding import TINY, rounding_radius, up
from ocreach.sets.zonotope import Zonotope

#: largest supported degree cap (the packed keys need 63 // max_degree bits per factor index)
MAX_DEGREE = 6


@dataclass(frozen=True)
class SoundPZ:
    """``c`` (n,), ``G`` (n, h), ``I`` (h, d) sorted (descending) factor indices of each monomial
    (0 = none; the constant monomial is kept in ``c``), ``K`` (h,) their packed keys, strictly
    increasing (so the monomials are distinct), ``GI`` (n, q) independent generators and ``r``
    (n,) the radii of a box (the rounding bounds, kept apart from ``GI`` so that they cost no
    generators).  Internal: arrays are owned, not copied; build with :func:`make`."""

    c: np.ndarray
    G: np.ndarray
    I: np.ndarray
    K: np.ndarray
    GI: np.ndarray
    r: np.ndarray

    @property
    def dim(self) -> int:
        return int(self.c.shape[0])

    @property
    def degree_cap(self) -> int:
        return int(self.I.shape[1])

    @property
    def n_dependent(self) -> int:
        return int(self.G.shape[1])

    @property
    def n_independent(self) -> int:
        return int(self.GI.shape[1]) + int(np.count_nonzero(self.r))

    @property
    def n_generators(self) -> int:
        return self.n_dependent + self.n_independent

    def factors(self) -> np.ndarray:
        """Sorted local indices of the factors that occur."""
        f = np.unique(self.I)
        return f[f > 0]

    def with_box(self, r: np.ndarray) -> SoundPZ:
        """The same set plus the box of radii ``r >= 0`` (added to :attr:`r`, rounded up)."""
        return SoundPZ(self.c, self.G, self.I, self.K, self.GI, up(self.r + r, 1))


def make(c: np.ndarray, G: np.ndarray, I: np.ndarray, GI: np.ndarray, r: np.ndarray | None,
         bits: int) -> SoundPZ:
    """A :class:`SoundPZ` from generators with any (repeated) monomials: equal monomials are
    summed, the constant one is folded into the centre and zero generators dropped, with the
    rounding of the sums added to the box."""
    n = c.shape[0]
    r = np.zeros(n) if r is None else r
    h = G.shape[1]
    if h == 0:
        return SoundPZ(c, G, I, np.zeros(0, dtype=np.int64), GI, r)
    K = keys(I, bits)
    order = np.argsort(K, kind="stable")
    Ks = K[order]
    new = np.ones(h, dtype=bool)
    new[1:] = Ks[1:] != Ks[:-1]
    if new.all() and Ks[0] != 0:
        G, I, K = G[:, order], I[order], Ks
    else:
        starts = np.flatnonzero(new)
        big = int(np.diff(np.r_[starts, h]).max())
        r = up(r + rounding_radius(np.abs(c) + np.abs(G).sum(axis=1), big + 1), 1)
        G = np.add.reduceat(G[:, order], starts, axis=1)
        I, K = I[order[starts]], Ks[starts]
        if K[0] == 0:                        # the constant monomial
            c = c + G[:, 0]
            G, I, K = G[:, 1:], I[1:], K[1:]
    nz = np.any(G != 0, axis=0)
    if not nz.all():
        G, I, K = G[:, nz], I[nz], K[nz]
    return SoundPZ(c, G, I, K, GI, r)


class FactorIds:
    """Local factor indices ``1, 2, ...`` of one run and their global identifiers (fresh blocks of
    :func:`ocreach.sets.new_ids`), so that the result sets share identifiers exactly where they
    share factors."""

    def __init__(self, max_degree: int):
        self.bits = 63 // int(max_degree)
        self.limit = (1 << self.bits) - 1
        self._ids = np.zeros(1, dtype=np.int64)   # index 0 unused
        self._local: dict[int, int] = {}

    def new(self, k: int) -> np.ndarray:
        """``k`` fresh local indices."""
        start = self._ids.size
        if start + k - 1 > self.limit:
            raise SetError(f"poly: more than {self.limit} factors in one run (degree cap "
                           f"{63 // self.bits}); lower max_degree or shorten the horizon")
        g = new_ids(k)
        self._ids = np.concatenate([self._ids, g])
        for i, v in enumerate(g):
            self._local[int(v)] = start + i
        return np.arange(start, start + k, dtype=np.int64)

    def global_ids(self, local: np.ndarray) -> np.ndarray:
        return self._ids[np.asarray(local, dtype=np.int64)]

    def local_of(self, ids: np.ndarray) -> np.ndarray:
        """Local indices of global identifiers (new ones registered)."""
        out = np.empty(len(ids), dtype=np.int64)
        for i, v in enumerate(np.asarray(ids, dtype=np.int64)):
            if int(v) not in self._local:
                self._local[int(v)] = self._ids.size
                self._ids = np.concatenate([self._ids, [v]])
            out[i] = self._local[int(v)]
        if out.size and out.max() > self.limit:
            raise SetError(f"poly: more than {self.limit} factors in one run")
        return out


# ------------------------------------------------------------------------------------------------
# monomial keys
# ------------------------------------------------------------------------------------------------
def keys(I: np.ndarray, bits: int) -> np.ndarray:
    """Exact int64 key of every monomial (rows of ``I``)."""
    shifts = (np.arange(I.shape[1], dtype=np.int64) * bits)
    return (I.astype(np.int64) << shifts).sum(axis=1)


def all_even(I: np.ndarray) -> np.ndarray:
    """Monomials whose every factor occurs an even number of times (they range over [0, 1])."""
    d = I.shape[1]
    nz = I > 0
    deg = nz.sum(axis=1)
    ev = (deg % 2 == 0) & (deg > 0)
    for k in range(0, d - 1, 2):
        pair = (I[:, k] == I[:, k + 1]) | ~nz[:, k]
        ev &= pair
    return ev


def products(Ia: np.ndarray, Ib: np.ndarray, d: int) -> tuple[np.ndarray, np.ndarray]:
    """Factor tuples of the products ``m_a m_b`` of the rows of ``Ia``, ``Ib`` (same number of
    rows), capped at degree ``d``, and a mask of the products above the cap."""
    J = -np.sort(-np.hstack([Ia, Ib]), axis=1)
    over = J[:, d] > 0 if J.shape[1] > d else np.zeros(J.shape[0], dtype=bool)
    return J[:, :d], over


# ------------------------------------------------------------------------------------------------
# construction and conversion
# ------------------------------------------------------------------------------------------------
def from_zonotope(Z: Zonotope, fid: FactorIds, d: int) -> SoundPZ:
    """Exact: every generator becomes a dependent generator with a fresh factor."""
    h = Z.n_generators
    I = np.zeros((h, d), dtype=np.int64)
    I[:, 0] = fid.new(h)
    G = np.array(Z.G, dtype=float)
    nz = np.any(G != 0, axis=0)
    return SoundPZ(np.array(Z.c, dtype=float), G[:, nz], I[nz], keys(I[nz], fid.bits),
                   np.zeros((Z.dim, 0)), np.zeros(Z.dim))


def from_generators(G: np.ndarray, fid: FactorIds, d: int) -> SoundPZ:
    """The zonotope ``G xi`` centred at 0 with fresh factors."""
    return from_zonotope(Zonotope.trusted(np.zeros(G.shape[0]), G), fid, d)


def to_polyzonotope(S: SoundPZ, fid: FactorIds):
    """The same set as a :class:`ocreach.sets.PolyZonotope` (exact: exponents are the factor
    multiplicities, identifiers the factors' global ones, the box ``r`` independent generators)."""
    from ocreach.sets.polyzonotope import PolyZonotope

    f = S.factors()
    row = np.searchsorted(f, S.I)
    E = np.zeros((f.size, S.n_dependent), dtype=np.int64)
    cols = np.broadcast_to(np.arange(S.n_dependent)[:, None], S.I.shape)
    nz = S.I > 0
    np.add.at(E, (row[nz], cols[nz]), 1)
    GI = np.hstack([S.GI, np.diag(S.r)[:, S.r > 0]])
    return PolyZonotope._own(S.c.copy(), S.G.copy(), GI, E, fid.global_ids(f))


# ------------------------------------------------------------------------------------------------
# rounded operations
# ------------------------------------------------------------------------------------------------
def magnitude(S: SoundPZ) -> np.ndarray:
    """``|c| + sum_j |g_j| + sum_j |gI_j| + r``: the largest magnitude of each coordinate over
    ``S`` (computed in floating point: callers round it up or use it inside a rounding bound)."""
    return np.abs(S.c) + np.abs(S.G).sum(axis=1) + np.abs(S.GI).sum(axis=1) + S.r


def radius(S: SoundPZ) -> np.ndarray:
    """Half-widths of a box around the centre that contains ``S`` (float, not rounded)."""
    return np.abs(S.G).sum(axis=1) + np.abs(S.GI).sum(axis=1) + S.r


def pad(S: SoundPZ, r: np.ndarray) -> SoundPZ:
    """``S`` plus the box of radii ``r >= 0`` as independent generators (zero radii add none)."""
    r = np.asarray(r, dtype=float)
    keep = r > 0
    if not keep.any():
        return S
    return SoundPZ(S.c, S.G, S.I, S.K, np.hstack([S.GI, np.diag(r)[:, keep]]), S.r)


def translate(S: SoundPZ, v: np.ndarray) -> SoundPZ:
    v = np.asarray(v, dtype=float)
    out = SoundPZ(S.c + v, S.G, S.I, S.K, S.GI, S.r)
    return out.with_box(rounding_radius(np.abs(S.c) + np.abs(v), 1))


def scale(s: float, S: SoundPZ) -> SoundPZ:
    """``s S``; exact for ``s = +-2^k`` (no underflow), else one rounding per entry."""
    out = SoundPZ(s * S.c, s * S.G, S.I, S.K, s * S.GI, abs(s) * S.r)
    if s != 0 and np.frexp(abs(s))[0] == 0.5:      # exact up to underflow
        return out.with_box(np.full(S.dim, TINY))
    return out.with_box(rounding_radius(abs(s) * magnitude(S), 1))


def linear_map(M: np.ndarray, S: SoundPZ, M_rad: np.ndarray | None = None) -> SoundPZ:
    """Enclosure of ``{M' x : x in S, |M' - M| <= M_rad}``: ``M S`` in floating point (the box
    ``r`` mapped to the box ``|M| r``) plus ``M_rad |S| + gamma_n |M| |S|``."""
    mag = magnitude(S)
    absM = np.abs(M)
    r = absM @ S.r + rounding_radius(absM @ mag, S.dim + 1)
    if M_rad is not None:
        r = r + M_rad @ mag
    return SoundPZ(M @ S.c, M @ S.G, S.I, S.K, M @ S.GI, up(r, S.dim + 3))


def project(S: SoundPZ, rows) -> SoundPZ:
    rows = np.asarray(rows)
    return SoundPZ(S.c[rows], S.G[rows], S.I, S.K, S.GI[rows], S.r[rows])


def add(S: SoundPZ, T: SoundPZ, bits: int) -> SoundPZ:
    """Exact Minkowski sum with shared factors (equal monomials merge) plus rounding."""
    if S.dim != T.dim or S.degree_cap != T.degree_cap:
        raise SetError("add: dimensions or degree caps differ")
    c = S.c + T.c
    r = up(S.r + T.r + rounding_radius(np.abs(S.c) + np.abs(T.c), 1), 2)
    GI = np.hstack([S.GI, T.GI]) if T.GI.shape[1] else S.GI
    if T.n_dependent == 0:
        return SoundPZ(c, S.G, S.I, S.K, GI, r)
    if S.n_dependent == 0:
        return SoundPZ(c, T.G, T.I, T.K, GI, r)
    if S.K.size == T.K.size and np.array_equal(S.K, T.K):     # the same monomials
        r = up(r + rounding_radius(np.abs(S.G).sum(axis=1) + np.abs(T.G).sum(axis=1), 2), 1)
        return SoundPZ(c, S.G + T.G, S.I, S.K, GI, r)
    K = np.concatenate([S.K, T.K])
    order = np.argsort(K, kind="stable")
    Ks = K[order]
    G = np.hstack([S.G, T.G])[:, order]
    I = np.vstack([S.I, T.I])[order]
    dup = np.flatnonzero(Ks[1:] == Ks[:-1])          # each key occurs at most twice
    if dup.size:
        G[:, dup] += G[:, dup + 1]
        keep = np.ones(Ks.size, dtype=bool)
        keep[dup + 1] = False
        r = up(r + rounding_radius(np.abs(G[:, dup]).sum(axis=1), 1), 1)
        G, I, Ks = G[:, keep], I[keep], Ks[keep]
    return SoundPZ(c, G, I, Ks, GI, r)


def _aug(S: SoundPZ) -> tuple[np.ndarray, np.ndarray]:
    """Generators with the centre first (as the constant monomial, factor tuple of zeros)."""
    G = np.hstack([S.c[:, None], S.G])
    I = np.vstack([np.zeros((1, S.degree_cap), dtype=np.int64), S.I])
    return G, I


def _poly_products(coef: np.ndarray, Ia: np.ndarray, Ib: np.ndarray, n_out: int, d: int,
                   bits: int) -> SoundPZ:
    """The set ``sum_p coef[:, p] m_a(p) m_b(p)`` (monomials of the pairs' factor tuples); the
    products above the degree cap are enclosed by independent generators (each lies in
    [-1, 1]), boxed."""
    J, over = products(Ia, Ib, d)
    keep = ~over
    S = make(np.zeros(n_out), coef[:, keep], J[keep], np.zeros((n_out, 0)), None, bits)
    if over.any():
        S = pad(S, up(np.abs(coef[:, over]).sum(axis=1), int(over.sum()) + 1))
    return S


def _independent(S: SoundPZ) -> np.ndarray:
    """The independent generators with the box ``r`` as columns."""
    return np.hstack([S.GI, np.diag(S.r)[:, S.r > 0]]) if np.any(S.r) else S.GI


def quadratic(H: np.ndarray, S: SoundPZ, bits: int) -> SoundPZ:
    """Enclosure of ``{(x^T H_i x)_i : x in S}`` for ``H`` (m, n, n), exactly symmetric
    (Kochdumper & Althoff's quadratic map; the static error of Althoff 2013, Eq. 9): the
    polynomial part ``y = c + G m`` is multiplied out (pairs ``j <= k`` with multiplicity
    ``2 - delta_jk``), the terms with the independent part ``z`` (``GI b`` and the box) are
    ``2 c^T H z``, kept as independent generators, and the rest (``2 (G m)^T H z + z^T H z``)
    boxed; plus the rounding, ``gamma_k s^T |H_i| s`` with ``s`` = :func:`magnitude`."""
    d = S.degree_cap
    m = H.shape[0]
    Ga, Ia = _aug(S)
    Hn = Ga.shape[1]
    A = np.einsum("iab,bk->iak", H, Ga)              # (m, n, Hn)
    Bm = np.einsum("aj,iak->ijk", Ga, A)             # (m, Hn, Hn)
    ju, ku = np.triu_indices(Hn)
    coef = Bm[:, ju, ku] * np.where(ju == ku, 1.0, 2.0)
    out = _poly_products(coef, Ia[ju], Ia[ku], m, d, bits)
    Z = _independent(S)
    extra = np.zeros(m)
    newGI = np.zeros((m, 0))
    if Z.shape[1]:
        AI = np.einsum("iab,bl->ial", H, Z)           # (m, n, q)
        newGI = 2.0 * np.einsum("a,ial->il", S.c, AI)
        extra = (2.0 * np.abs(np.einsum("aj,ial->ijl", S.G, AI)).sum(axis=(1, 2))
                 + np.abs(np.einsum("ak,ial->ikl", Z, AI)).sum(axis=(1, 2)))
    s = magnitude(S)
    absq = np.einsum("iab,a,b->i", np.abs(H), s, s)
    k = 2 * S.dim + 6 + 2 * Hn * Hn
    r = up(extra, Z.shape[1] * (Hn + Z.shape[1]) + 2) + rounding_radius(absq, k)
    return SoundPZ(out.c, out.G, out.I, out.K, np.hstack([out.GI, newGI]), up(out.r + r, 1))


def bilinear(H: np.ndarray, S: SoundPZ, T: SoundPZ, bits: int) -> SoundPZ:
    """Enclosure of ``{(x^T H_i y)_i : x in S, y in T}`` with shared factors (``S`` and ``T`` are
    functions of the same factors): all pairs of the polynomial parts multiplied out, the terms
    with either independent part boxed except ``c_S^T H_i z_T`` and ``z_S^T H_i c_T`` (kept as
    independent generators); plus the rounding."""
    d = S.degree_cap
    m = H.shape[0]
    Ga, Ia = _aug(S)
    Gb, Ib = _aug(T)
    A = np.einsum("iab,bk->iak", H, Gb)               # (m, n, Hb)
    Bm = np.einsum("aj,iak->ijk", Ga, A)              # (m, Ha, Hb)
    Ha, Hb = Ga.shape[1], Gb.shape[1]
    ja, kb = np.divmod(np.arange(Ha * Hb), Hb)
    out = _poly_products(Bm.reshape(m, -1), Ia[ja], Ib[kb], m, d, bits)
    ZS, ZT = _independent(S), _independent(T)
    extra = np.zeros(m)
    newGI = [np.zeros((m, 0))]
    if ZT.shape[1]:
        AI = np.einsum("iab,bl->ial", H, ZT)
        newGI.append(np.einsum("a,ial->il", S.c, AI))
        extra = extra + np.abs(np.einsum("aj,ial->ijl", np.hstack([S.G, ZS]), AI)).sum(axis=(1, 2))
    if ZS.shape[1]:
        AI = np.einsum("iab,al->ibl", H, ZS)           # (m, n, q_S): z_S^T H
        newGI.append(np.einsum("b,ibl->il", T.c, AI))
        extra = extra + np.abs(np.einsum("bk,ibl->ikl", T.G, AI)).sum(axis=(1, 2))
    sS, sT = magnitude(S), magnitude(T)
    absq = np.einsum("iab,a,b->i", np.abs(H), sS, sT)
    k = 2 * S.dim + 6 + 2 * Ha * Hb
    r = up(extra, (S.n_generators + 1) * (T.n_generators + 1) + 2) + rounding_radius(absq, k)
    return SoundPZ(out.c, out.G, out.I, out.K, np.hstack([out.GI] + newGI), up(out.r + r, 1))


def times_new_factor(S: SoundPZ, lam: int, bits: int) -> SoundPZ:
    """``lambda S`` for the fresh factor ``lam`` in [-1, 1]: the centre becomes the generator of
    ``lambda``, every monomial gains the factor (above the cap: boxed); independent generators
    and the box stay as they are (``lambda b`` ranges over [-1, 1] like ``b``).  Exact."""
    d = S.degree_cap
    Ga, Ia = _aug(S)
    J, over = products(Ia, np.full((Ia.shape[0], 1), lam, dtype=np.int64), d)
    out = make(np.zeros(S.dim), Ga[:, ~over], J[~over], S.GI, S.r, bits)
    if over.any():
        out = pad(out, up(np.abs(Ga[:, over]).sum(axis=1), int(over.sum()) + 1))
    return out


def to_zonotope(S: SoundPZ) -> Zonotope:
    """Zonotope enclosure: all-even monomials range over [0, 1] (half the generator moves into
    the centre), the others over [-1, 1]; plus the rounding of the centre sum."""
    ev = all_even(S.I)
    c = S.c + 0.5 * S.G[:, ev].sum(axis=1)
    r = S.r + rounding_radius(np.abs(S.c) + np.abs(S.G[:, ev]).sum(axis=1), int(ev.sum()) + 2)
    r = up(r, 1)
    G = np.hstack([0.5 * S.G[:, ev], S.G[:, ~ev], S.GI, np.diag(r)[:, r > 0]])
    return Zonotope.trusted(c, G)


def box(S: SoundPZ) -> tuple[np.ndarray, np.ndarray]:
    """The interval hull of :func:`to_zonotope`, rounded outward."""
    Z = to_zonotope(S)
    r = up(np.abs(Z.G).sum(axis=1), Z.n_generators + 1)
    lo, hi = Z.c - r, Z.c + r
    e = rounding_radius(np.maximum(np.abs(lo), np.abs(hi)), 1)
    return lo - e, hi + e


def _enclose_removed(c: np.ndarray, G: np.ndarray, I: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre, independent generators and rounding box enclosing ``c + sum_j G_j m_j``
    (all-even monomials over [0, 1], others over [-1, 1])."""
    ev = all_even(I)
    c2 = c + 0.5 * G[:, ev].sum(axis=1)
    r = rounding_radius(np.abs(c) + np.abs(G[:, ev]).sum(axis=1), int(ev.sum()) + 2)
    return c2, np.hstack([0.5 * G[:, ev], G[:, ~ev]]), r


def _largest(norms: np.ndarray, k: int) -> np.ndarray:
    keep = np.zeros(norms.size, dtype=bool)
    if k >= norms.size:
        keep[:] = True
    elif k > 0:
        keep[np.argpartition(-norms, k - 1)[:k]] = True
    return keep


def _box_reduce(Z: np.ndarray, h: int, n: int, method: str) -> tuple[np.ndarray, np.ndarray]:
    """Keep mask of the ``h - n`` largest columns of ``Z`` (Girard's ``||g||_1 - ||g||_inf`` or
    the 2-norm for PCA) and the rigorous box (:func:`ocreach.sets.reduce.box_generators`) of the
    others."""
    from ocreach.sets.reduce import box_generators

    absZ = np.abs(Z)
    metric = (absZ.sum(axis=0) - absZ.max(axis=0, initial=0.0) if method == "girard"
              else np.einsum("ij,ij->j", Z, Z))
    keep = _largest(metric, max(h - n, 0))
    B = box_generators(absZ[:, ~keep] if method == "girard" else Z[:, ~keep], method,
                       abs_G=absZ[:, ~keep])
    return keep, B


def reduce(S: SoundPZ, h_lin: int, h_poly: int, method: str = "girard",
           fid: FactorIds | None = None) -> SoundPZ:
    """Sound order reduction in three parts (Kochdumper & Althoff's reduction of sparse polynomial
    zonotopes, with the linear part reduced like a zonotope):

    1. of the monomials of degree >= 2 the ``h_poly`` of largest 2-norm are kept, the others are
       enclosed (all-even monomials over [0, 1], the rest over [-1, 1]) by independent generators;
    2. linear monomials of factors that still occur in a kept monomial stay as they are (their
       dependence is needed);
    3. the other linear monomials -- factors that occur nowhere else, so their sum is a zonotope
       independent of the rest of the set -- the independent generators and the box form one
       zonotope, reduced to ``h_lin >= n`` generators: Girard (keep the ``h_lin - n`` largest by
       ``||g||_1 - ||g||_inf``, box the rest) or PCA (the box in the principal frame), the boxes
       rigorous (:func:`ocreach.sets.reduce.box_generators`).  Kept linear monomials keep their
       factor; with ``fid`` the other generators of the part (independent ones, the box) become
       dependent on fresh factors (exact), else they stay independent.
    """
    n = S.dim
    c, r = S.c, S.r
    lin = S.I[:, 1] == 0 if S.degree_cap > 1 else np.ones(S.n_dependent, dtype=bool)
    hi = ~lin
    Ghi, Ihi, Khi = S.G[:, hi], S.I[hi], S.K[hi]
    keep_hi = _largest(np.einsum("ij,ij->j", Ghi, Ghi), h_poly)
    extra = [S.GI]
    if not keep_hi.all():
        c, box_, rr = _enclose_removed(c, Ghi[:, ~keep_hi], Ihi[~keep_hi])
        extra.append(box_)
        r = up(r + rr, 1)
        Ghi, Ihi, Khi = Ghi[:, keep_hi], Ihi[keep_hi], Khi[keep_hi]
    Glin, Ilin, Klin = S.G[:, lin], S.I[lin], S.K[lin]
    needed = np.isin(Ilin[:, 0], Ihi) if Ihi.size else np.zeros(Ilin.shape[0], dtype=bool)
    free = ~needed
    if np.any(r):
        extra.append(np.diag(r)[:, r > 0])
    Z = np.hstack([Glin[:, free]] + extra)
    nf = int(free.sum())
    rest = Z[:, nf:]
    kf = np.ones(nf, dtype=bool)
    if Z.shape[1] > h_lin:
        keep, B = _box_reduce(Z, h_lin, n, method)
        kf = keep[:nf]
        rest = np.hstack([Z[:, nf:][:, keep[nf:]], B])
    lin_keep = needed | np.isin(np.arange(lin.sum()), np.flatnonzero(free)[kf])
    G = np.hstack([Ghi, Glin[:, lin_keep]])
    I = np.vstack([Ihi, Ilin[lin_keep]])
    K = np.concatenate([Khi, Klin[lin_keep]])
    order = np.argsort(K, kind="stable")
    out = SoundPZ(c, G[:, order], I[order], K[order], rest, np.zeros(n))
    return refactor(out, fid) if fid is not None else out


def reduce_for_map(S: SoundPZ, h: int) -> SoundPZ:
    """An enclosure of ``S`` with at most ``h - n`` dependent generators (the largest in 2-norm;
    their factors kept) and a box of the rest, for the input of a quadratic or bilinear map
    (CORA's ``errorOrder``): the map's cost falls with the square of the generators, and the
    small ones contribute products of small terms.  Sound as a function of the factors: every
    point of ``S`` for factors ``a`` lies in the result for the same ``a`` and some ``b``."""
    from ocreach.sets.reduce import box_generators

    n = S.dim
    k = max(h - n, 0)
    if S.n_dependent <= k and S.GI.shape[1] == 0:
        return S
    keep = _largest(np.einsum("ij,ij->j", S.G, S.G), k)
    c, Grem, rr = _enclose_removed(S.c, S.G[:, ~keep], S.I[~keep])
    Z = np.hstack([Grem, S.GI])
    B = box_generators(np.abs(Z), "girard", abs_G=np.abs(Z)) if Z.shape[1] else np.zeros((n, 0))
    return SoundPZ(c, S.G[:, keep], S.I[keep], S.K[keep], B, up(S.r + rr, 1))


def refactor(S: SoundPZ, fid: FactorIds) -> SoundPZ:
    """The same set with every independent generator (and the box) made dependent on a fresh
    factor (exact: a zonotope is a polynomial zonotope with linear monomials)."""
    Z = _independent(S)
    q = Z.shape[1]
    if q == 0:
        return S
    I = np.zeros((q, S.degree_cap), dtype=np.int64)
    I[:, 0] = fid.new(q)
    K = keys(I, fid.bits)
    # fresh factors have the largest indices: their keys exceed every existing linear key but
    # not necessarily higher-degree ones, so sort
    G = np.hstack([S.G, Z])
    Iall = np.vstack([S.I, I])
    Kall = np.concatenate([S.K, K])
    order = np.argsort(Kall, kind="stable")
    return SoundPZ(S.c, G[:, order], Iall[order], Kall[order], np.zeros((S.dim, 0)), np.zeros(S.dim))


def split(S: SoundPZ, factor: int, bits: int) -> tuple[SoundPZ, SoundPZ]:
    """The exact split along factor ``factor`` (``a = (a' -+ 1) / 2``; every monomial with
    ``a^e`` re-expanded as ``2^-e sum_j C(e, j) (-+1)^(e-j) a'^j``), plus its rounding (the new
    coefficients' absolute values sum to the old one's; one rounding each, then the merges)."""
    from math import comb

    d = S.degree_cap
    e = (S.I == factor).sum(axis=1)
    emax = int(e.max()) if e.size else 0
    if emax == 0:
        raise SetError(f"split: factor {factor} does not occur")
    halves = []
    rest = np.where(S.I == factor, 0, S.I)
    rest = -np.sort(-rest, axis=1)
    for sgn in (-1.0, 1.0):
        Gs, Is = [], []
        for j in range(emax + 1):
            sel = e >= j
            coef = np.array([comb(int(ei), j) * 0.5**int(ei) * sgn ** (int(ei) - j) for ei in e[sel]])
            Gs.append(S.G[:, sel] * coef[None, :])
            Ij = rest[sel].copy()
            if j:
                Ij = -np.sort(-np.hstack([Ij, np.full((Ij.shape[0], j), factor, dtype=np.int64)]),
                              axis=1)[:, :d]
            Is.append(Ij)
        rr = up(S.r + rounding_radius(magnitude(S), S.n_dependent * (emax + 1) + 3), 1)
        halves.append(make(S.c.copy(), np.hstack(Gs), np.vstack(Is), S.GI, rr, bits))
    return halves[0], halves[1]
