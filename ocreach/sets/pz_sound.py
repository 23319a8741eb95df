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
from ocreach.sets.rounding import rounding_radius, up
from ocreach.sets.zonotope import Zonotope

#: largest supported degree cap (the packed keys need 63 // max_degree bits per factor index)
MAX_DEGREE = 6


@dataclass(frozen=True)
class SoundPZ:
    """``c`` (n,), ``G`` (n, h), ``I`` (h, d) sorted (descending) factor indices of each monomial
    (0 = none; a row of zeros would be the constant monomial, which is kept in ``c``), ``GI``
    (n, q).  Internal: arrays are owned, not copied or validated."""

    c: np.ndarray
    G: np.ndarray
    I: np.ndarray
    GI: np.ndarray

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
        return int(self.GI.shape[1])

    @property
    def n_generators(self) -> int:
        return self.n_dependent + self.n_independent

    def factors(self) -> np.ndarray:
        """Sorted local indices of the factors that occur."""
        f = np.unique(self.I)
        return f[f > 0]


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
    return SoundPZ(np.array(Z.c, dtype=float), np.array(Z.G, dtype=float), I, np.zeros((Z.dim, 0)))


def from_generators(G: np.ndarray, fid: FactorIds, d: int) -> SoundPZ:
    """The zonotope ``G xi`` centred at 0 with fresh factors."""
    return from_zonotope(Zonotope.trusted(np.zeros(G.shape[0]), G), fid, d)


def to_polyzonotope(S: SoundPZ, fid: FactorIds):
    """The same set as a :class:`ocreach.sets.PolyZonotope` (exact: exponents are the factor
    multiplicities; identifiers the factors' global ones)."""
    from ocreach.sets.polyzonotope import PolyZonotope

    f = S.factors()
    row = np.searchsorted(f, S.I)
    E = np.zeros((f.size, S.n_dependent), dtype=np.int64)
    cols = np.broadcast_to(np.arange(S.n_dependent)[:, None], S.I.shape)
    nz = S.I > 0
    np.add.at(E, (row[nz], cols[nz]), 1)
    return PolyZonotope._own(S.c.copy(), S.G.copy(), S.GI.copy(), E, fid.global_ids(f))


def from_polyzonotope(P, fid: FactorIds, d: int) -> SoundPZ:
    """A :class:`PolyZonotope` as a :class:`SoundPZ`; monomials above the degree cap are enclosed
    by independent generators (exact otherwise)."""
    E = np.asarray(P.E, dtype=np.int64)
    loc = fid.local_of(P.id)
    deg = E.sum(axis=0) if E.size else np.zeros(P.n_dependent, dtype=np.int64)
    keep = deg <= d
    h = int(keep.sum())
    I = np.zeros((h, d), dtype=np.int64)
    for j, col in enumerate(np.flatnonzero(keep)):
        idx = np.repeat(loc, E[:, col])
        I[j, : idx.size] = np.sort(idx)[::-1]
    over = P.G[:, ~keep]
    S = SoundPZ(np.array(P.c, dtype=float), np.array(P.G[:, keep], dtype=float), I,
                np.hstack([np.array(P.GI, dtype=float), over]))
    return merge(S, fid.bits)


# ------------------------------------------------------------------------------------------------
# rounded operations
# ------------------------------------------------------------------------------------------------
def magnitude(S: SoundPZ) -> np.ndarray:
    """``|c| + sum_j |g_j| + sum_j |gI_j|``: the largest magnitude of each coordinate over ``S``."""
    return np.abs(S.c) + np.abs(S.G).sum(axis=1) + np.abs(S.GI).sum(axis=1)


def pad(S: SoundPZ, r: np.ndarray) -> SoundPZ:
    """``S`` plus the box of radii ``r >= 0`` (as independent generators)."""
    r = np.asarray(r, dtype=float)
    keep = r > 0
    if not keep.any():
        return S
    return SoundPZ(S.c, S.G, S.I, np.hstack([S.GI, np.diag(r)[:, keep]]))


def translate(S: SoundPZ, v: np.ndarray) -> SoundPZ:
    v = np.asarray(v, dtype=float)
    return pad(SoundPZ(S.c + v, S.G, S.I, S.GI), rounding_radius(np.abs(S.c) + np.abs(v), 1))


def scale(s: float, S: SoundPZ) -> SoundPZ:
    """``s S``; exact for ``s = +-2^k`` (no underflow), else one rounding per entry."""
    out = SoundPZ(s * S.c, s * S.G, S.I, s * S.GI)
    if s != 0 and np.frexp(abs(s))[0] == 0.5:
        return out
    return pad(out, rounding_radius(abs(s) * magnitude(S), 1))


def linear_map(M: np.ndarray, S: SoundPZ, M_rad: np.ndarray | None = None) -> SoundPZ:
    """Enclosure of ``{M' x : x in S, |M' - M| <= M_rad}``: ``M S`` in floating point plus
    ``M_rad |S| + gamma_n |M| |S|``."""
    mag = magnitude(S)
    r = rounding_radius(np.abs(M) @ mag, S.dim)
    if M_rad is not None:
        r = up(r + M_rad @ mag, S.dim + 1)
    return pad(SoundPZ(M @ S.c, M @ S.G, S.I, M @ S.GI), r)


def project(S: SoundPZ, rows) -> SoundPZ:
    rows = np.asarray(rows)
    return SoundPZ(S.c[rows], S.G[rows], S.I, S.GI[rows])


def merge(S: SoundPZ, bits: int) -> SoundPZ:
    """Sum the generators of equal monomials, fold the constant monomial into the centre, drop
    zero generators (plus the rounding of the sums)."""
    h = S.n_dependent
    if h == 0:
        return S
    k = keys(S.I, bits)
    order = np.argsort(k, kind="stable")
    ks = k[order]
    new = np.ones(h, dtype=bool)
    new[1:] = ks[1:] != ks[:-1]
    starts = np.flatnonzero(new)
    c = S.c
    if starts.size == h and ks[0] != 0:
        G, I = S.G, S.I
        r = None
    else:
        G = np.add.reduceat(S.G[:, order], starts, axis=1)
        I = S.I[order[starts]]
        big = int(np.diff(np.r_[starts, h]).max())
        r = rounding_radius(np.abs(S.c) + np.abs(S.G).sum(axis=1), big + 1)
        if ks[0] == 0:                        # the constant monomial
            c = c + G[:, 0]
            G, I = G[:, 1:], I[1:]
    nz = np.any(G != 0, axis=0)
    if not nz.all():
        G, I = G[:, nz], I[nz]
    out = SoundPZ(c, G, I, S.GI)
    return out if r is None else pad(out, r)


def add(S: SoundPZ, T: SoundPZ, bits: int) -> SoundPZ:
    """Exact Minkowski sum with shared factors (equal monomials merge) plus rounding."""
    if S.dim != T.dim or S.degree_cap != T.degree_cap:
        raise SetError("add: dimensions or degree caps differ")
    out = merge(SoundPZ(S.c + T.c, np.hstack([S.G, T.G]), np.vstack([S.I, T.I]),
                        np.hstack([S.GI, T.GI])), bits)
    return pad(out, rounding_radius(np.abs(S.c) + np.abs(T.c), 1))


def _aug(S: SoundPZ) -> tuple[np.ndarray, np.ndarray]:
    """Generators with the centre first (as the constant monomial, factor tuple of zeros)."""
    G = np.hstack([S.c[:, None], S.G])
    I = np.vstack([np.zeros((1, S.degree_cap), dtype=np.int64), S.I])
    return G, I


def _poly_products(coef: np.ndarray, Ia: np.ndarray, Ib: np.ndarray, n_out: int, d: int,
                   bits: int) -> SoundPZ:
    """The set ``sum_p coef[:, p] m_a(p) m_b(p)`` (monomials of the pairs' factor tuples); the
    products above the degree cap are enclosed by one box (each lies in [-1, 1])."""
    J, over = products(Ia, Ib, d)
    box = np.abs(coef[:, over]).sum(axis=1)
    keep = ~over
    S = merge(SoundPZ(np.zeros(n_out), coef[:, keep], J[keep], np.zeros((n_out, 0))), bits)
    return pad(S, up(box, int(over.sum()) + 1))


def quadratic(H: np.ndarray, S: SoundPZ, bits: int) -> SoundPZ:
    """Enclosure of ``{(x^T H_i x)_i : x in S}`` for ``H`` (m, n, n), exactly symmetric
    (Kochdumper & Althoff's quadratic map; the static error of Althoff 2013, Eq. 9): the
    polynomial part ``y = c + G m`` is multiplied out (pairs ``j <= k`` with multiplicity
    ``2 - delta_jk``), the terms with the independent part ``z = GI b`` are ``2 y_c^T H z`` kept as
    independent generators and the rest (``2 (G m)^T H z + z^T H z``) boxed; plus the rounding."""
    d = S.degree_cap
    m = H.shape[0]
    Ga, Ia = _aug(S)
    Hn = Ga.shape[1]
    A = np.einsum("iab,bk->iak", H, Ga)              # (m, n, Hn)
    Bm = np.einsum("aj,iak->ijk", Ga, A)             # (m, Hn, Hn)
    ju, ku = np.triu_indices(Hn)
    coef = Bm[:, ju, ku] * np.where(ju == ku, 1.0, 2.0)
    out = _poly_products(coef, Ia[ju], Ia[ku], m, d, bits)
    GI = S.GI
    extra = np.zeros(m)
    newGI = np.zeros((m, 0))
    if GI.shape[1]:
        AI = np.einsum("iab,bl->ial", H, GI)          # (m, n, q)
        newGI = 2.0 * np.einsum("a,ial->il", S.c, AI)
        extra = (2.0 * np.abs(np.einsum("aj,ial->ijl", S.G, AI)).sum(axis=(1, 2))
                 + np.abs(np.einsum("ak,ial->ikl", GI, AI)).sum(axis=(1, 2)))
    s = magnitude(S)
    absq = np.einsum("iab,a,b->i", np.abs(H), s, s)
    k = 2 * S.dim + 6 + 2 * Hn * Hn
    r = up(extra, GI.shape[1] * (Hn + GI.shape[1]) + 2) + rounding_radius(absq, k)
    return pad(SoundPZ(out.c, out.G, out.I, np.hstack([out.GI, newGI])), r)


def bilinear(H: np.ndarray, S: SoundPZ, T: SoundPZ, bits: int) -> SoundPZ:
    """Enclosure of ``{(x^T H_i y)_i : x in S, y in T}`` with shared factors (``S`` and ``T`` are
    functions of the same factors): all pairs of the polynomial parts multiplied out, the terms
    with either independent part boxed except ``c_S^T H_i GI_T`` and ``GI_S^T H_i c_T`` (kept as
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
    extra = np.zeros(m)
    newGI = [np.zeros((m, 0))]
    if T.GI.shape[1]:
        AI = np.einsum("iab,bl->ial", H, T.GI)
        newGI.append(np.einsum("a,ial->il", S.c, AI))
        extra = extra + np.abs(np.einsum("aj,ial->ijl", np.hstack([S.G, S.GI]), AI)).sum(axis=(1, 2))
    if S.GI.shape[1]:
        AI = np.einsum("iab,al->ibl", H, S.GI)           # (m, n, q_S): GI_S^T H
        newGI.append(np.einsum("b,ibl->il", T.c, AI))
        extra = extra + np.abs(np.einsum("bk,ibl->ikl", T.G, AI)).sum(axis=(1, 2))
    sS, sT = magnitude(S), magnitude(T)
    absq = np.einsum("iab,a,b->i", np.abs(H), sS, sT)
    k = 2 * S.dim + 6 + 2 * Ha * Hb
    r = up(extra, (S.n_generators + 1) * (T.n_generators + 1) + 2) + rounding_radius(absq, k)
    return pad(SoundPZ(out.c, out.G, out.I, np.hstack([out.GI] + newGI)), r)


def times_new_factor(S: SoundPZ, lam: int, bits: int) -> SoundPZ:
    """``lambda S`` for the factor ``lam`` in [-1, 1]: the centre becomes the generator of
    ``lambda``, every monomial gains the factor (above the cap: boxed); independent generators
    stay as they are (``lambda b`` ranges over [-1, 1] like ``b``).  Exact."""
    d = S.degree_cap
    Ga, Ia = _aug(S)
    J, over = products(Ia, np.full((Ia.shape[0], 1), lam, dtype=np.int64), d)
    box = np.abs(Ga[:, over]).sum(axis=1)
    out = SoundPZ(np.zeros(S.dim), Ga[:, ~over], J[~over], S.GI)
    return pad(out, up(box, int(over.sum()) + 1))


def to_zonotope(S: SoundPZ) -> Zonotope:
    """Zonotope enclosure: all-even monomials range over [0, 1] (half the generator moves into
    the centre), the others over [-1, 1]; plus the rounding of the centre sum."""
    ev = all_even(S.I)
    c = S.c + 0.5 * S.G[:, ev].sum(axis=1)
    r = rounding_radius(np.abs(S.c) + np.abs(S.G[:, ev]).sum(axis=1), int(ev.sum()) + 2)
    G = np.hstack([0.5 * S.G[:, ev], S.G[:, ~ev], S.GI, np.diag(r)[:, r > 0]])
    return Zonotope.trusted(c, G)


def box(S: SoundPZ) -> tuple[np.ndarray, np.ndarray]:
    """The interval hull of :func:`to_zonotope`, rounded outward."""
    Z = to_zonotope(S)
    r = up(np.abs(Z.G).sum(axis=1), Z.n_generators + 1)
    lo, hi = Z.c - r, Z.c + r
    e = rounding_radius(np.maximum(np.abs(lo), np.abs(hi)), 1)
    return lo - e, hi + e


def reduce(S: SoundPZ, h_dep: int, h_ind: int, method: str = "girard",
           weights: np.ndarray | None = None) -> SoundPZ:
    """Sound order reduction to at most ``h_dep`` dependent and ``h_ind`` (>= n) independent
    generators (Kochdumper & Althoff; Foss et al. Sec. 2.4): the dependent generators of largest
    (weighted 2-) norm are kept, the others enclosed like :func:`to_zonotope` and joined to the
    independent ones, which are reduced as a zonotope (:func:`ocreach.sets.reduce.reduce_zonotope`:
    Girard or PCA, rigorous boxes)."""
    from ocreach.sets.reduce import reduce_zonotope

    n = S.dim
    c, G, I, GI = S.c, S.G, S.I, S.GI
    r = None
    if S.n_dependent > h_dep:
        W = G if weights is None else G * weights[:, None]
        norms = np.einsum("ij,ij->j", W, W)
        keep = np.zeros(S.n_dependent, dtype=bool)
        if h_dep > 0:
            keep[np.argpartition(-norms, h_dep - 1)[:h_dep]] = True
        Grem, Irem = G[:, ~keep], I[~keep]
        ev = all_even(Irem)
        c = c + 0.5 * Grem[:, ev].sum(axis=1)
        r = rounding_radius(np.abs(S.c) + np.abs(Grem[:, ev]).sum(axis=1), int(ev.sum()) + 2)
        GI = np.hstack([GI, 0.5 * Grem[:, ev], Grem[:, ~ev], np.diag(r)[:, r > 0]])
        G, I = G[:, keep], I[keep]
    if GI.shape[1] > h_ind:
        Z = reduce_zonotope(Zonotope.trusted(np.zeros(n), GI), h_ind / n, method)
        GI = np.asarray(Z.G)
    return SoundPZ(c, G, I, GI)


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
                Ij = -np.sort(-np.hstack([Ij, np.full((Ij.shape[0], j), factor, dtype=np.int64)]), axis=1)[:, :d]
            Is.append(Ij)
        T = merge(SoundPZ(S.c.copy(), np.hstack(Gs), np.vstack(Is), S.GI), bits)
        halves.append(pad(T, rounding_radius(magnitude(S), S.n_dependent * (emax + 1) + 3)))
    return halves[0], halves[1]
