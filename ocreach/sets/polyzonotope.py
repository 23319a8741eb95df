"""Sparse polynomial zonotopes (Kochdumper & Althoff; Foss et al. Sec. 2.4, Eq. 14, Appendix A).

A polynomial zonotope ``PZ = <c, G, GI, E, id>`` is the set

    { c + sum_i (prod_k a_k^E[k, i]) G[:, i] + GI b  :  a in [-1, 1]^p, b in [-1, 1]^q },

with dependent generators ``G`` (n, h), integer exponent matrix ``E`` (p, h) over the factors
with integer identifiers ``id`` (p,), and independent generators ``GI`` (n, q).  Factors with the
same identifier in two sets are the same variable, so exact sums and products keep dependence.
"""
from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from math import comb
from typing import Any, Union

import numpy as np

from ocreach.errors import SetError
from ocreach.sets import dispatch
from ocreach.sets._base import (
    SetBase,
    as_dims,
    as_directions,
    as_matrix,
    as_vector,
    check_linear_map,
    factor_samples,
    new_ids,
    ro,
)
from ocreach.sets.interval import Interval
from ocreach.sets.zonotope import Zonotope

_HASH_SEED = 20240917


def _hash_weights(p: int) -> np.ndarray:
    """Two fixed random int64 weight rows (2, p) for the monomial hash."""
    rng = np.random.default_rng(_HASH_SEED)
    return rng.integers(1, 2**62, size=(2, max(p, 1)), dtype=np.int64)[:, :p]


def monomial_keys(E: np.ndarray) -> np.ndarray:
    """128-bit linear hash (h, 2) int64 of the exponent columns; keys of ``E_i + E_j`` are sums.

    The hash is linear modulo 2^64, so the key of a product monomial is the (wrapping) sum of the
    keys of its factors; two different columns share both keys with probability ~2^-126.
    """
    E = np.asarray(E, dtype=np.int64)
    if E.shape[0] == 0:
        return np.zeros((E.shape[1], 2), dtype=np.int64)
    return E.T @ _hash_weights(E.shape[0]).T


def exact_keys(E: np.ndarray, bound: np.ndarray) -> np.ndarray | None:
    """One exact int64 key per exponent column, or None if the exponents do not fit one word.

    Mixed radix with base ``bound[r] + 1`` for row ``r``: columns with entries ``<= bound`` have
    equal keys exactly when they are equal, and the key of ``E_i + E_j`` is the sum of the keys
    as long as the sum stays ``<= bound`` (pass ``N * max`` for products of ``N`` columns).
    """
    E = np.asarray(E, dtype=np.int64)
    base = np.asarray(bound, dtype=np.int64) + 1
    if E.shape[0] and float(np.prod(base.astype(float))) >= 2.0 ** 62:
        return None
    w = np.cumprod(np.concatenate([[1], base[:-1]])).astype(np.int64)
    return w @ E if E.shape[0] else np.zeros(E.shape[1], dtype=np.int64)


Exponents = Union[np.ndarray, Callable[[np.ndarray], np.ndarray], None]

#: sorted positions compared per block by the exact re-check of :func:`merge_monomials`
_CHECK_BLOCK = 1 << 18


def _exponent_columns(exponents: Exponents, cols: np.ndarray) -> np.ndarray:
    if callable(exponents):
        return np.asarray(exponents(cols), dtype=np.int64)
    return np.asarray(exponents, dtype=np.int64)[:, cols]


def merge_monomials(G: np.ndarray, keys: np.ndarray, exponents: Exponents = None) -> tuple[np.ndarray, np.ndarray]:
    """Sum the generator columns with equal monomial keys (Kochdumper & Althoff's merge of equal
    exponent columns, used by the exact sum and the tensor map, Foss et al. Eq. 22).

    Returns ``(G_merged, rep)`` where ``rep`` indexes one original column per merged group.
    Sorting based: O(h log h), no Python loop over generators.  ``keys`` of shape (h,) are exact
    (:func:`exact_keys`): one argsort and ``reduceat``, no check needed.  Keys of shape (h, 2)
    are the 128-bit hash of :func:`monomial_keys`; then ``exponents`` (the (p, h) exponent
    matrix, or a callable giving the exponent columns of given column indices) makes the grouping
    exact: every column is compared with its group's representative (in blocks), and if the hash
    ever put two different monomials together the grouping is redone by ``np.unique`` on the
    exponent columns.  Without it the result relies on the 128-bit hash alone.
    """
    h = keys.shape[0]
    if h == 0:
        return G, np.zeros(0, dtype=np.int64)
    if keys.ndim == 1:                       # exact keys: equal keys <=> equal monomials
        order = np.argsort(keys)
        ks = keys[order]
        new = np.ones(h, dtype=bool)
        np.not_equal(ks[1:], ks[:-1], out=new[1:])
        starts = np.flatnonzero(new)
        return _reduce_groups(G, order, starts), order[starts]
    # one argsort on the first hash word (a lexsort on both is ~2x slower); a group needs both
    # words equal.  Equal monomials always share word 0, so they are adjacent unless another key
    # with the same word 0 (probability ~h^2 / 2^64) sorts between them -- then they stay two
    # columns, which is still exact (only not merged).
    order = np.argsort(keys[:, 0], kind="stable")
    k0, k1 = keys[:, 0][order], keys[:, 1][order]
    new = np.ones(h, dtype=bool)
    new[1:] = (k0[1:] != k0[:-1]) | (k1[1:] != k1[:-1])
    starts = np.flatnonzero(new)
    rep = order[starts]
    if exponents is not None and starts.size < h and not _groups_exact(exponents, order, new, rep):
        full = _exponent_columns(exponents, np.arange(h))
        _, inv = np.unique(full, axis=1, return_inverse=True)
        order = np.argsort(inv.ravel(), kind="stable")
        new[1:] = np.diff(inv.ravel()[order]) != 0
        starts = np.flatnonzero(new)
        rep = order[starts]
    return _reduce_groups(G, order, starts), rep


def _reduce_groups(G: np.ndarray, order: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Column sums of ``G[:, order]`` over the groups beginning at ``starts``."""
    if not G.shape[0]:
        return np.zeros((0, starts.size))
    return np.add.reduceat(np.take(G, order, axis=1), starts, axis=1)


def _groups_exact(exponents: Exponents, order: np.ndarray, new: np.ndarray, rep: np.ndarray) -> bool:
    """Do all columns of each hash group have the exponents of the group's representative?"""
    gid = np.cumsum(new) - 1
    dup = np.flatnonzero(~new)  # sorted positions that were merged into an earlier column
    for s0 in range(0, dup.size, _CHECK_BLOCK):
        blk = dup[s0: s0 + _CHECK_BLOCK]
        if not np.array_equal(_exponent_columns(exponents, order[blk]), _exponent_columns(exponents, rep[gid[blk]])):
            return False
    return True


def enclose_monomials(G: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zonotope enclosure of ``sum_i (prod_k a_k^E[k, i]) G[:, i]`` over ``a in [-1, 1]^p``
    (Kochdumper & Althoff's zonotope enclosure of a sparse polynomial zonotope).

    A constant monomial (zero exponent column) is the vector ``G_i``; an all-even monomial ranges
    over [0, 1], i.e. ``G_i / 2 + (G_i / 2) b``; any other ranges over [-1, 1].  Returns the centre
    shift (n,) and the generators ``[G_even / 2, G_other]`` (n, k), each with its own factor.
    """
    E = np.asarray(E)
    const = ~np.any(E, axis=0)
    even = ~np.any(E & 1, axis=0) & ~const
    shift = G[:, const].sum(axis=1) + 0.5 * G[:, even].sum(axis=1)
    return shift, np.hstack([0.5 * G[:, even], G[:, ~(even | const)]])


def monomial_values(A: np.ndarray, E: np.ndarray) -> np.ndarray:
    """``prod_k A[:, k] ** E[k, i]`` (N, h) for factor values ``A`` (N, p) and exponents ``E`` (p, h).

    Small problems use the direct power; large ones the magnitudes ``exp(log|A| @ E)`` (one matrix
    product instead of an (N, p, h) array of powers) with the sign from the parity of the negative
    factors with odd exponents; a zero factor with a positive exponent gives 0 (its log is
    clamped far below any representable magnitude, 0 * log for zero exponents stays 0).  Factor
    values that are not finite take the direct power, so a NaN propagates as it does there.
    """
    N, p = A.shape
    h = E.shape[1]
    if N * p * h <= 50_000 or not np.all(np.isfinite(A)):
        return np.prod(A[:, :, None] ** E[None, :, :], axis=1)
    Ef = E.astype(float)
    absA = np.abs(A)
    logA = np.where(absA > 0, np.log(np.where(absA > 0, absA, 1.0)), -1e4)
    with np.errstate(under="ignore"):
        mag = np.exp(logA @ Ef)
    odd = (E % 2 == 1).astype(float)
    neg = (A < 0).astype(float) @ odd
    return np.where(neg % 2 == 1, -mag, mag)


class PolyZonotope(SetBase):
    """Sparse polynomial zonotope ``<c, G, GI, E, id>`` (immutable, numpy-backed).

    ``E`` defaults to the identity (every dependent generator gets its own linear factor) and
    ``id`` to fresh identifiers from :func:`new_ids`.
    """

    def __init__(self, c: Any, G: Any = None, GI: Any = None, E: Any = None, id: Any = None):
        c_a = as_vector("PolyZonotope centre c", c)
        n = c_a.shape[0]
        G_a = np.zeros((n, 0)) if G is None else as_matrix("PolyZonotope dependent generators G", G, rows=n)
        GI_a = np.zeros((n, 0)) if GI is None else as_matrix("PolyZonotope independent generators GI", GI, rows=n)
        h = G_a.shape[1]
        if E is None:
            E_a = np.eye(h, dtype=np.int64)
        else:
            E_f = np.asarray(E)
            if not np.issubdtype(E_f.dtype, np.integer):
                E_f = E_f.astype(float)
            if E_f.ndim == 1 and E_f.size == 0:
                E_f = E_f.reshape(0, h)
            if E_f.ndim != 2 or E_f.shape[1] != h:
                raise SetError(f"PolyZonotope exponent matrix E must have shape (p, {h}); got {E_f.shape}")
            bad = ~np.isfinite(E_f) | (E_f != np.round(E_f)) | (E_f < 0) if E_f.dtype.kind == "f" else E_f < 0
            if np.any(bad):
                raise SetError("PolyZonotope exponent matrix E must hold non-negative integers; got "
                               f"{E_f[bad].ravel()[:5].tolist()} at (row, column) {np.argwhere(bad)[:5].tolist()}")
            E_a = E_f.astype(np.int64)
        p = E_a.shape[0]
        if id is None:
            id_a = new_ids(p)
        else:
            id_f = np.atleast_1d(np.asarray(id))
            if id_f.ndim != 1 or id_f.shape[0] != p:
                raise SetError(f"PolyZonotope identifiers id must have shape ({p},); got {id_f.shape}")
            if id_f.size and (not np.issubdtype(id_f.dtype, np.number) or np.any(id_f != np.round(id_f))):
                raise SetError(f"PolyZonotope identifiers id must be integers; got {id_f!r}")
            id_a = id_f.astype(np.int64)
            if np.unique(id_a).size != p:
                raise SetError(f"PolyZonotope identifiers id must be unique; got repeated values in {id_a.tolist()}")
        self.c = ro(c_a)
        self.G = ro(G_a)
        self.GI = ro(GI_a)
        self.E = ro(E_a, dtype=np.int64)
        self.id = ro(id_a, dtype=np.int64)
        self._freeze()

    # -- constructors -----------------------------------------------------------------------
    @classmethod
    def _own(cls, c: np.ndarray, G: np.ndarray, GI: np.ndarray, E: np.ndarray, id: np.ndarray) -> PolyZonotope:
        """Internal constructor for arrays an operation has just computed and hands over (no
        copies, no shape checks): used by the exact operations on large sets, where copying and
        re-validating the result cost as much as computing it.  Only finiteness is checked (an
        operation can overflow); everything else holds by construction."""
        for name, M in (("centre c", c), ("dependent generators G", G), ("independent generators GI", GI)):
            if not np.isfinite(M.sum()) and not np.all(np.isfinite(M)):
                raise SetError(f"PolyZonotope {name} must be finite")
        self = object.__new__(cls)
        for key, arr, dt in (("c", c, float), ("G", G, float), ("GI", GI, float), ("E", E, np.int64),
                             ("id", id, np.int64)):
            arr = np.asarray(arr, dtype=dt)
            arr.setflags(write=False)
            object.__setattr__(self, key, arr)
        self._freeze()
        return self

    @classmethod
    def from_zonotope(cls, Z, ids: Any = None) -> PolyZonotope:
        """Exact conversion: each generator becomes a dependent generator with its own factor."""
        h = Z.n_generators
        return cls(Z.c, Z.G, None, np.eye(h, dtype=np.int64), new_ids(h) if ids is None else ids)

    @classmethod
    def from_interval(cls, I, ids: Any = None) -> PolyZonotope:
        return cls.from_zonotope(I.to_zonotope(), ids)

    # -- properties -------------------------------------------------------------------------
    @property
    def dim(self) -> int:
        return int(self.c.shape[0])

    @property
    def n_dependent(self) -> int:
        return int(self.G.shape[1])

    @property
    def n_independent(self) -> int:
        return int(self.GI.shape[1])

    @property
    def n_generators(self) -> int:
        return self.n_dependent + self.n_independent

    @property
    def n_factors(self) -> int:
        return int(self.E.shape[0])

    def __repr__(self) -> str:
        return (f"PolyZonotope(dim={self.dim}, dependent={self.n_dependent}, independent={self.n_independent}, "
                f"factors={self.n_factors})")

    # -- evaluation -------------------------------------------------------------------------
    def monomials(self, alpha: Any) -> np.ndarray:
        """Values ``prod_k a_k^E[k, i]`` (N, h) for factor values alpha (N, p) in the order of ``id``."""
        A = np.atleast_2d(np.asarray(alpha, dtype=float))
        if A.shape[-1] != self.n_factors:
            raise SetError(f"alpha must have last dimension p={self.n_factors}; got {np.shape(alpha)}")
        if self.n_factors == 0:
            return np.ones((A.shape[0], self.n_dependent))
        return monomial_values(A, self.E)

    def evaluate(self, alpha: Any, beta: Any = None) -> np.ndarray:
        """The point(s) for dependent factors ``alpha`` ((p,) or (N, p)) and independent ``beta`` ((q,) or (N, q))."""
        single = np.ndim(alpha) == 1
        M = self.monomials(alpha)
        X = self.c + M @ self.G.T
        if self.n_independent:
            if beta is None:
                raise SetError(f"evaluate: beta is required, the set has {self.n_independent} independent generators")
            B = np.atleast_2d(np.asarray(beta, dtype=float))
            if B.shape[-1] != self.n_independent:
                raise SetError(f"beta must have last dimension q={self.n_independent}; got {np.shape(beta)}")
            X = X + B @ self.GI.T
        return X[0] if single and X.shape[0] == 1 else X

    def sample(self, n: int, rng: Any = None, mode: str = "uniform") -> np.ndarray:
        """(n, dim) points from uniform factors or extreme factors +-1 (``mode='extreme'``)."""
        F = factor_samples(n, self.n_factors + self.n_independent, rng, mode)
        return np.atleast_2d(self.evaluate(F[:, : self.n_factors], F[:, self.n_factors:]))

    # -- structural clean-up --------------------------------------------------------------------
    def compact(self, tol: float = 0.0) -> PolyZonotope:
        """Remove redundant exponents: merge equal columns of E, fold constant monomials into the
        centre, drop zero generators and unused factors (Kochdumper & Althoff, compactGen).

        Exact for ``tol = 0``.  ``tol > 0`` also drops generators whose entries are all at most
        ``tol`` in magnitude: the result is then NOT an over-approximation (use it only to clean
        numerical zeros; :func:`ocreach.sets.reduce.reduce_pz` is the sound way to shrink a set)."""
        G, E = np.asarray(self.G), np.asarray(self.E)
        c = self.c.copy()
        if G.shape[1]:
            keys = exact_keys(E, E.max(axis=1, initial=0))
            Gm, rep = merge_monomials(G, monomial_keys(E) if keys is None else keys, E)
            Em = E[:, rep]
            const = ~np.any(Em, axis=0)
            c = c + Gm[:, const].sum(axis=1)
            keep = (~const) & np.any(np.abs(Gm) > tol, axis=0)
            G, E = Gm[:, keep], Em[:, keep]
        used = np.any(E > 0, axis=1) if E.shape[1] else np.zeros(E.shape[0], dtype=bool)
        GI = np.asarray(self.GI)
        GI = GI[:, np.any(np.abs(GI) > tol, axis=0)]
        return PolyZonotope(c, G, GI, E[used], self.id[used])

    def _expand_to(self, ids: np.ndarray) -> np.ndarray:
        """Exponent matrix with rows re-indexed to the identifier list ``ids`` (a superset of ``id``)."""
        pos = {int(v): k for k, v in enumerate(ids)}
        E = np.zeros((len(ids), self.n_dependent), dtype=np.int64)
        if self.n_factors:
            E[[pos[int(v)] for v in self.id]] = self.E
        return E

    # -- exact operations -------------------------------------------------------------------
    def __rmatmul__(self, M) -> PolyZonotope:
        """Linear map ``M @ PZ = <Mc, MG, M GI, E, id>`` (Foss et al. Sec. 2.4), M of shape (m, n)."""
        A = check_linear_map(M, self.dim)
        return PolyZonotope(A @ self.c, A @ self.G, A @ self.GI, self.E, self.id)

    def __add__(self, other):
        """Exact Minkowski sum; shared identifiers stay dependent and equal monomials merge.

        Zonotopes and intervals are added as independent generators (exact); a vector translates.
        """
        if isinstance(other, Interval):
            other = other.to_zonotope()
        if isinstance(other, Zonotope):
            if other.dim != self.dim:
                raise SetError(f"Minkowski sum: dimensions differ ({self.dim} vs {other.dim})")
            return PolyZonotope(self.c + other.c, self.G, np.hstack([self.GI, other.G]), self.E, self.id)
        if isinstance(other, PolyZonotope):
            if other.dim != self.dim:
                raise SetError(f"Minkowski sum: dimensions differ ({self.dim} vs {other.dim})")
            ids = _union_ids(self.id, other.id)
            E = np.hstack([self._expand_to(ids), other._expand_to(ids)])
            return PolyZonotope(self.c + other.c, np.hstack([self.G, other.G]), np.hstack([self.GI, other.GI]),
                                E, ids).compact()
        if isinstance(other, SetBase):
            return NotImplemented
        v = np.asarray(other, dtype=float)
        if v.ndim == 1:
            return PolyZonotope(self.c + as_vector("translation", v, self.dim), self.G, self.GI, self.E, self.id)
        return NotImplemented

    def cartesian(self, other) -> PolyZonotope:
        """Cartesian product ``self x other`` (Foss et al. Sec. 2.4); see :func:`cartesian_product`."""
        return cartesian_product(self, other)

    def project(self, dims: Any) -> PolyZonotope:
        """Exact projection onto the coordinates ``dims`` (the linear map of Foss et al. Sec. 2.4 with
        rows of the identity); factors and exponents are kept."""
        idx = as_dims(dims, self.dim)
        return PolyZonotope(self.c[idx], self.G[idx], self.GI[idx], self.E, self.id)

    def split(self, factor: int | None = None) -> tuple[PolyZonotope, PolyZonotope]:
        """Exact split along dependent factor with identifier ``factor``: ``a = (a' -+ 1)/2``.

        Every monomial is re-expanded by the binomial theorem, ``((a'+s)/2)^e = 2^-e sum_j C(e,j) s^(e-j) a'^j``;
        the union of the two halves equals the set.  Default factor: the largest total generator norm.
        """
        if self.n_factors == 0:
            raise SetError("split: the polynomial zonotope has no dependent factors")
        if factor is None:
            r = int(np.argmax((self.E > 0) @ np.linalg.norm(self.G, axis=0)))
        else:
            hits = np.flatnonzero(self.id == int(factor))
            if hits.size == 0:
                raise SetError(f"split: factor {factor} is not an identifier of this set; allowed {self.id.tolist()}")
            r = int(hits[0])
        e = self.E[r]
        emax = int(e.max()) if e.size else 0
        j = np.arange(emax + 1)
        binom = np.array([[comb(int(ei), int(jj)) if jj <= ei else 0 for jj in j] for ei in range(emax + 1)], float)
        B = binom[e]  # (h, emax+1)
        scale = 0.5 ** e[:, None]
        E_new = np.repeat(self.E[:, :, None], emax + 1, axis=2)
        E_new[r] = j[None, :]
        valid = (j[None, :] <= e[:, None]).ravel()
        E_new = E_new.reshape(self.n_factors, -1)[:, valid]
        out = []
        for s in (-1.0, 1.0):
            coef = B * scale * s ** (e[:, None] - j[None, :]) * (j[None, :] <= e[:, None])
            G_new = (self.G[:, :, None] * coef[None]).reshape(self.dim, -1)[:, valid]
            out.append(PolyZonotope(self.c, G_new, self.GI, E_new, self.id).compact())
        return out[0], out[1]

    # -- enclosures and queries -------------------------------------------------------------
    def to_zonotope(self) -> Zonotope:
        """Zonotope enclosure (Kochdumper & Althoff): monomials with all-even exponents range over
        [0, 1], so they shift the centre by half the generator and keep half as generator."""
        shift, Gz = enclose_monomials(self.G, self.E)
        return Zonotope(self.c + shift, np.hstack([Gz, self.GI]))

    def interval_hull(self) -> Interval:
        """Interval enclosure (interval hull of the zonotope enclosure)."""
        return self.to_zonotope().interval_hull()

    def _split_pieces(self, n_splits: int, score, monotone: bool = False) -> list[tuple[float, PolyZonotope]]:
        """Best-first splitting: ``n_splits`` times split the piece with the largest ``score``.

        Returns ``(score, piece)`` pairs.  With ``monotone=True`` a child's score is capped by its
        parent's (valid for upper bounds: a child is a subset of its parent, but the zonotope
        enclosure of a child is not always inside the parent's enclosure)."""
        s0 = score(self)
        heap = [(-s0, 0, self)]
        count = itertools.count(1)
        for _ in range(int(n_splits)):
            neg, _, piece = heapq.heappop(heap)
            if piece.n_factors == 0:
                heapq.heappush(heap, (neg, next(count), piece))
                break
            for child in piece.split():
                sc = score(child)
                if monotone:
                    sc = min(sc, -neg)
                heapq.heappush(heap, (-sc, next(count), child))
        return [(-item[0], item[2]) for item in heap]

    def support(self, d: Any, splits: int = 0) -> np.ndarray | float:
        """Guaranteed upper bound of the support function (exact for the zonotope enclosure);
        ``splits=k`` splits the worst piece k times (per direction) and takes the max over pieces
        (never larger than the bound without splitting)."""
        D, single = as_directions(d, self.dim)
        if splits <= 0:
            val = self.to_zonotope().support(D)
        else:
            val = np.array([max(sc for sc, _ in self._split_pieces(
                splits, lambda s, di=di: s.to_zonotope().support(di), monotone=True)) for di in D])
        return float(val[0]) if single else val

    def contains(self, points: Any, splits: int = 0, tol: float = 1e-7) -> np.ndarray:
        """Membership in an OUTER approximation of the set (not exact membership).

        A point is reported inside if it lies (within ``tol``, see
        :func:`ocreach.sets.contains.points_in_zonotope`) in the zonotope enclosure of one of the
        pieces left after ``splits`` best-first splits (:meth:`split`, :meth:`to_zonotope`).
        Guarantee: every point of the set gives ``True`` (no false negatives), so ``False`` proves
        the point is outside.  ``True`` does not prove it is inside: it can be wrong by the
        enclosure error, which shrinks as ``splits`` grows (exact membership in a polynomial
        zonotope is a non-convex problem).  Used as a coverage test (e.g. Monte Carlo samples in a
        reachable set), the coverage can therefore be overstated, never understated."""
        pieces = [pc for _, pc in self._split_pieces(splits, _size_score)] if splits > 0 else [self]
        from ocreach.sets._base import as_points

        P, single = as_points("points", points, self.dim)
        ok = np.zeros(P.shape[0], dtype=bool)
        for piece in pieces:
            todo = ~ok
            if not np.any(todo):
                break
            ok[todo] = piece.to_zonotope().contains(P[todo], tol=tol)
        return bool(ok[0]) if single else ok

    def reduce(self, h_max: int, method: str = "pca") -> PolyZonotope:
        """Sound order reduction to at most ``h_max`` generators (Foss et al. Sec. 2.4 Reduce(PZ,
        h_des)); see :func:`ocreach.sets.reduce.reduce_pz`."""
        return dispatch.reduce(self, h_max, method)

    def outline(self, dims: Any = (0, 1), pieces: int = 64) -> list[np.ndarray]:
        """Outer approximation of the 2-D projection as a list of convex polygons (each (k, 2),
        counter-clockwise) whose union contains the projection: best-first splitting into
        ``pieces`` parts and the exact polygon of each part's zonotope enclosure."""
        P = self.project(dims).compact()
        if P.dim != 2:
            raise SetError(f"outline needs two dims; got {dims!r}")
        return [p.to_zonotope().outline((0, 1)) for _, p in P._split_pieces(max(int(pieces) - 1, 0), _size_score)]

    def outline_union(self, dims: Any = (0, 1), pieces: int = 64) -> list[np.ndarray]:
        """The union of :meth:`outline`'s convex pieces as closed rings (shapely): one
        counter-clockwise exterior ring (k, 2) per connected component and one clockwise ring per
        hole.  The same outer approximation as :meth:`outline`, as a (possibly non-convex) boundary
        for drawing; empty if the projection has no area (then use :meth:`outline`)."""
        from shapely.geometry.polygon import orient

        from ocreach.geometry import union_of_polygons

        geom = union_of_polygons(self.outline(dims, pieces))
        rings = []
        for poly in getattr(geom, "geoms", [geom]):
            if poly.is_empty or poly.geom_type != "Polygon":
                continue
            poly = orient(poly, 1.0)
            rings.append(np.asarray(poly.exterior.coords)[:-1])
            rings.extend(np.asarray(r.coords)[:-1] for r in poly.interiors)
        return rings

    def area(self, dims: Any = (0, 1), pieces: int = 64) -> float:
        """Area of the union of :meth:`outline`'s pieces: an upper bound of the projection's area
        that tightens as ``pieces`` grows (exact union by shapely, not the sum of the pieces)."""
        from ocreach.geometry import outline_area

        return outline_area(self.outline(dims, pieces))


def _size_score(pz: PolyZonotope) -> float:
    return float(np.linalg.norm(pz.G, axis=0).sum())


def _union_ids(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    extra = b[~np.isin(b, a)]
    return np.concatenate([a, extra]).astype(np.int64)


def cartesian_product(a, b) -> PolyZonotope:
    """Cartesian product ``PZ1 x PZ2`` (Foss et al. Sec. 2.4); shared identifiers stay dependent.

    Zonotopes/intervals are converted with fresh identifiers (exact).
    """
    def as_pz(s):
        if isinstance(s, PolyZonotope):
            return s
        if isinstance(s, (Zonotope, Interval)):
            return PolyZonotope.from_zonotope(s.to_zonotope())
        raise SetError(f"cartesian_product: expected PolyZonotope/Zonotope/Interval; got {type(s).__name__}")

    a, b = as_pz(a), as_pz(b)
    ids = _union_ids(a.id, b.id)
    n1, n2 = a.dim, b.dim
    G = np.zeros((n1 + n2, a.n_dependent + b.n_dependent))
    G[:n1, : a.n_dependent] = a.G
    G[n1:, a.n_dependent:] = b.G
    GI = np.zeros((n1 + n2, a.n_independent + b.n_independent))
    GI[:n1, : a.n_independent] = a.GI
    GI[n1:, a.n_independent:] = b.GI
    E = np.hstack([a._expand_to(ids), b._expand_to(ids)])
    return PolyZonotope(np.concatenate([a.c, b.c]), G, GI, E, ids)


def make_dependent(pz: PolyZonotope) -> PolyZonotope:
    """The same set with every independent generator turned into a dependent one with a fresh
    linear factor (exact: an independent generator is a factor that appears in one monomial)."""
    q = pz.n_independent
    if q == 0:
        return pz
    h, p = pz.n_dependent, pz.n_factors
    E = np.zeros((p + q, h + q), dtype=np.int64)
    E[:p, :h] = pz.E
    E[p:, h:] = np.eye(q, dtype=np.int64)
    return PolyZonotope(pz.c, np.hstack([pz.G, pz.GI]), None, E, np.concatenate([pz.id, new_ids(q)]))


def sym_tensor(T: np.ndarray) -> np.ndarray:
    """Average of T over all permutations of its input indices (same multilinear form on x..x)."""
    N = T.ndim - 1
    perms = list(itertools.permutations(range(1, N + 1)))
    return sum(np.transpose(T, (0, *p)) for p in perms) / len(perms)


def tensor_map(T: Any, pz: PolyZonotope, chunk: int = 2_000_000) -> PolyZonotope:
    """Tensor map ``T [x] PZ = {T_{i,a,b(,c)} s_a s_b (s_c) : s in PZ}`` (Foss et al. Eq. 20-22).

    ``T`` has shape (m, n), (m, n, n) or (m, n, n, n).  The centre is treated as a generator with
    zero exponent, so all cross terms c*G, G*G (and c*G*G, ...) are generated as in Eq. 22; the
    contraction is done once with the symmetrised tensor over index combinations i <= j (<= k)
    with multiplicities 2 (3, 6), then equal monomials are merged by a linear hash of E.

    Independent generators: products involving independent factors b cannot stay exact.  They are
    handled soundly by treating b as temporary dependent factors during the map and afterwards
    moving every monomial that contains a b-factor to the independent generators (its value lies
    in [-1, 1], or in [0, 1] for all-even exponents, giving a centre shift of half).  Without GI
    the result is exact.
    """
    T = np.asarray(T, dtype=float)
    if not isinstance(pz, PolyZonotope):
        raise SetError(f"tensor_map: pz must be a PolyZonotope; got {type(pz).__name__}")
    n = pz.dim
    if T.ndim < 2 or T.ndim > 4 or any(s != n for s in T.shape[1:]):
        raise SetError(f"tensor_map: T must have shape (m, n), (m, n, n) or (m, n, n, n) with n={n}; got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise SetError(f"tensor_map: T must be finite; got {int(np.sum(~np.isfinite(T)))} non-finite entries")
    N = T.ndim - 1
    if N == 1:
        return T @ pz
    m = T.shape[0]
    q, p, h = pz.n_independent, pz.n_factors, pz.n_dependent
    # augmented generator list: [centre, dependent, independent-as-temporary-factors]
    Gaug = np.hstack([pz.c[:, None], pz.G, pz.GI])
    Eaug = np.zeros((p + q, 1 + h + q), dtype=np.int64)
    Eaug[:p, 1: 1 + h] = pz.E
    Eaug[p:, 1 + h:] = np.eye(q, dtype=np.int64)
    # one exact int64 key per monomial if the product exponents fit a word, else the 128-bit hash
    keys_aug = exact_keys(Eaug, N * Eaug.max(axis=1, initial=0))
    exact = keys_aug is not None
    if not exact:
        keys_aug = monomial_keys(Eaug)
    H = Gaug.shape[1]
    Ts = sym_tensor(T)
    if N == 2:
        A = Ts @ Gaug  # (m, n, H): A[i, a, k] = Ts[i, a, b] Gaug[b, k]
        B = np.matmul(Gaug.T[None], A)  # (m, H, H)
        iu, ju = np.triu_indices(H)
        Gt = np.take(B.reshape(m, H * H), iu * H + ju, axis=1)
        Gt *= np.where(iu == ju, 1.0, 2.0)
        idx = (iu, ju)
    else:
        combos = np.array(list(itertools.combinations_with_replacement(range(H), 3)), dtype=np.int64).reshape(-1, 3)
        iu, ju, ku = combos.T
        A = Ts @ Gaug  # (m, n, n, H)
        Gt = np.empty((m, combos.shape[0]))
        step = max(1, chunk // max(1, m * n * n))
        for s in range(0, combos.shape[0], step):
            sl = slice(s, s + step)
            Gt[:, sl] = np.einsum("iabt,at,bt->it", A[..., ku[sl]], Gaug[:, iu[sl]], Gaug[:, ju[sl]], optimize=True)
        distinct = (iu != ju).astype(int) + (ju != ku).astype(int)
        Gt *= np.where(distinct == 2, 6.0, np.where(distinct == 1, 3.0, 1.0))
        idx = (iu, ju, ku)
    keys = sum(np.take(keys_aug, i, axis=0) for i in idx)
    Gm, rep = merge_monomials(Gt, keys, None if exact else lambda cols: sum(Eaug[:, i[cols]] for i in idx))
    reps = [i[rep] for i in idx]
    # classification from the factors' columns (exponents are >= 0: a sum is zero iff all are)
    const = np.logical_and.reduce([~np.any(Eaug, axis=0)[r] for r in reps])
    has_b = np.logical_or.reduce([np.any(Eaug[p:] > 0, axis=0)[r] for r in reps]) & ~const
    c = Gm[:, const].sum(axis=1)
    dep = ~(const | has_b)
    shift, GI = enclose_monomials(Gm[:, has_b], sum(np.take(Eaug, r[has_b], axis=1) for r in reps))
    c = c + shift
    dep &= np.any(Gm != 0, axis=0)
    GI = GI[:, np.any(GI != 0, axis=0)]
    Ed = sum(np.take(Eaug[:p], r[dep], axis=1) for r in reps)
    used = np.any(Ed > 0, axis=1)
    if not used.all():
        Ed = Ed[used]
    # columns are already merged (distinct keys); only zero generators/unused factors are dropped
    return PolyZonotope._own(c, Gm[:, dep], GI, Ed, pz.id[used])


@dispatch.to_polyzonotope.register(Interval)
def _interval_to_pz(I: Interval, ids: Any = None) -> PolyZonotope:
    return PolyZonotope.from_interval(I, ids)


@dispatch.to_polyzonotope.register(Zonotope)
def _zonotope_to_pz(Z: Zonotope, ids: Any = None) -> PolyZonotope:
    return PolyZonotope.from_zonotope(Z, ids)
