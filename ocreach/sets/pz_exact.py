"""Set queries on a sparse polynomial zonotope itself, with stated error bounds.

The zonotope enclosure of a polynomial zonotope (Kochdumper & Althoff) can be far larger than
the set (every monomial becomes an independent generator).  The routines here work on the
polynomial of the set instead:

* :func:`support_bounds` -- the support function ``h(d) = max_{a in [-1,1]^p} d^T (c + G m(a)) +
  |d^T GI|_1`` by branch-and-bound over the factor box, vectorised over directions.  A box is a
  polynomial in local factors ``a' in [-1, 1]^p``; splitting factor ``k`` (``a_k = (a'_k -+ 1)/2``)
  re-expands the coefficients by a fixed sparse matrix over the *downward closure* of the
  exponent set (all exponent vectors below a column of ``E``), so every box of every direction is
  one coefficient row.  Upper bound of a box: the zonotope-enclosure bound of its polynomial
  (constant + |odd monomials| + max(0, all-even monomials)); lower bound: the polynomial at the
  box's sign vertex of its linear part and at its centre (attained: a point of the set, the
  *witness*).  Boxes whose upper bound is below the best lower bound are pruned; a direction
  stops when ``upper - lower <= tol * r(d)`` with ``r(d)`` the enclosure radius in ``d``.
  Returned: lower and upper bound per direction and the witness factors (a point of the set
  whose value is the lower bound).
* :func:`membership` -- three-valued membership of points: *inside* with a witness (factor values
  ``a, b`` whose image is within ``tol`` of the point, found by damped minimum-norm Gauss-Newton
  in the factor box, vectorised over points), *outside* with a certificate (a direction ``d``
  with ``d^T x > upper(d)``, the upper bound of the branch-and-bound support), or undecided.
* :func:`hull_polygons` / :func:`hull_area_bounds` -- the convex hull of a 2-D projection bracketed
  by an inner polygon (hull of the witnesses: points of the set) and an outer polygon (the
  half-planes ``d^T x <= upper(d)``); its area is bracketed by their areas.
* :func:`points_at` -- boundary samples: the witness points of the support in given directions
  (maximisers of ``d^T x`` over the set, so they lie on its boundary up to the stated gap).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.errors import SetError

if TYPE_CHECKING:
    from ocreach.sets.polyzonotope import PolyZonotope


# ============================================================================ closure algebra
class _Closure:
    """Downward closure ``M`` of the exponent columns of a PZ with the split operators on it."""

    def __init__(self, E: np.ndarray):
        E = np.asarray(E, dtype=np.int64)
        p, h = E.shape
        self.p = p
        S = np.unique(np.hstack([E, np.zeros((p, 1), dtype=np.int64)]), axis=1)
        for k in range(p):
            ek = S[k]
            emax = int(ek.max()) if ek.size else 0
            if emax == 0:
                continue
            extra = []
            for t in range(1, emax + 1):
                sel = ek >= t
                if np.any(sel):
                    low = S[:, sel].copy()
                    low[k] -= t
                    extra.append(low)
            S = np.unique(np.hstack([S] + extra), axis=1)
        self.M = S                                       # (p, m) exponent columns of the closure
        m = S.shape[1]
        self.m = m
        self._w = np.random.default_rng(7).integers(1, 2**61, size=p, dtype=np.int64)
        keys = self._keys(S)
        self._order = np.argsort(keys)
        self._skeys = keys[self._order]
        if np.unique(keys).size != m:  # pragma: no cover - probability ~ m^2 / 2^64
            raise SetError("pz_exact: monomial hash collision in the closure")
        self.col_of_E = self.index(E)
        deg = S.sum(axis=0)
        self.const = int(np.flatnonzero(deg == 0)[0])
        self.odd = np.any(S % 2 == 1, axis=0)            # ranges over [-1, 1]
        self.even = ~self.odd & (deg > 0)                # ranges over [0, 1]
        self.nonlin = deg >= 2
        self.lin_of = np.full(p, -1, dtype=np.int64)     # closure column of the monomial a_k
        lin = np.flatnonzero(deg == 1)
        self.lin_of[np.argmax(S[:, lin], axis=0)] = lin
        self.parity = (S % 2 == 1).astype(np.float64)    # (p, m)
        self.Ef = S.astype(np.float64)
        self._ops: dict[tuple[int, int], Any] = {}

    def _keys(self, X: np.ndarray) -> np.ndarray:
        return (X.T.astype(np.int64) * self._w).sum(axis=1) if self.p else np.zeros(X.shape[1], np.int64)

    def index(self, X: np.ndarray) -> np.ndarray:
        k = self._keys(X)
        pos = np.searchsorted(self._skeys, k)
        return self._order[np.clip(pos, 0, self.m - 1)]

    def split_op(self, k: int, s: int):
        """Sparse (m, m) map of coefficient columns under ``a_k = (a'_k + s)/2`` (s = -1 or +1)."""
        key = (k, s)
        if key not in self._ops:
            from math import comb

            import scipy.sparse as sp

            ek = self.M[k]
            rows, cols, vals = [], [], []
            for e in np.unique(ek):
                src = np.flatnonzero(ek == e)
                for b in range(int(e) + 1):
                    low = self.M[:, src].copy()
                    low[k] = b
                    rows.append(self.index(low))
                    cols.append(src)
                    vals.append(np.full(src.size, comb(int(e), b) * float(s) ** (int(e) - b) * 0.5 ** int(e)))
            self._ops[key] = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                           shape=(self.m, self.m))
        return self._ops[key]

    def fix_op(self, k: int, s: int):
        """Sparse (m, m) map of coefficient columns under ``a'_k = s`` (s = -1 or +1)."""
        key = (k, 2 * s)
        if key not in self._ops:
            import scipy.sparse as sp

            low = self.M.copy()
            low[k] = 0
            vals = float(s) ** self.M[k]
            self._ops[key] = sp.csr_matrix((vals, (self.index(low), np.arange(self.m))), shape=(self.m, self.m))
        return self._ops[key]

    def upper(self, W: np.ndarray) -> np.ndarray:
        return W[:, self.const] + np.abs(W[:, self.odd]).sum(axis=1) + np.maximum(W[:, self.even], 0).sum(axis=1)

    def vertex_values(self, V: np.ndarray) -> np.ndarray:
        """Monomial values (N, m) at sign vertices V (N, p) in {-1, +1}."""
        cnt = (V < 0).astype(np.float64) @ self.parity
        return 1.0 - 2.0 * np.mod(cnt, 2.0)


_CLOSURES: dict[int, tuple[Any, _Closure]] = {}


def _closure(pz: PolyZonotope) -> _Closure:
    """Closure of ``pz.E`` (cached on the object's identity while it lives)."""
    key = id(pz)
    hit = _CLOSURES.get(key)
    if hit is not None and hit[0] is pz:
        return hit[1]
    cl = _Closure(pz.E)
    if len(_CLOSURES) > 16:
        _CLOSURES.pop(next(iter(_CLOSURES)))
    _CLOSURES[key] = (pz, cl)
    return cl


# ============================================================================ support
@dataclass(frozen=True)
class SupportBounds:
    """Bounds of the support function per direction: ``lower <= h(d) <= upper``.

    ``alpha`` (N, p), ``beta`` (N, q): factor values of a point of the set attaining ``lower``
    (``points`` (N, n) are those points); ``converged``: ``upper - lower <= tol * radius``;
    ``boxes``: boxes processed per call."""

    lower: np.ndarray
    upper: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    points: np.ndarray
    converged: np.ndarray
    boxes: int

    @property
    def gap(self) -> np.ndarray:
        return self.upper - self.lower


def _bb(cl: _Closure, W: np.ndarray, atol: np.ndarray, groups: np.ndarray, n_groups: int,
        max_boxes: int, max_iter: int):
    """Branch and bound on coefficient rows ``W`` (rows, m) of polynomials over ``[-1, 1]^p``.

    Row ``r`` is a box of the problem ``groups[r]``; returns per problem the best lower bound with
    its maximiser (global factor coordinates), the upper bound, convergence flags and the number
    of boxes processed."""
    p = cl.p
    N = n_groups
    W = W.copy()
    dirs = np.asarray(groups)
    lo, hi = -np.ones((W.shape[0], p)), np.ones((W.shape[0], p))
    best = np.full(N, -np.inf)
    best_a = np.zeros((N, p))
    frozen = np.full(N, -np.inf)
    done = np.zeros(N, dtype=bool)
    upper_dir = np.full(N, np.inf)
    boxes = 0
    nl = cl.nonlin
    Enl = cl.Ef[:, nl].T
    for _ in range(int(max_iter)):
        boxes += W.shape[0]
        # monotonicity test (interval global optimisation): where the derivative in a factor has
        # one sign over the whole box, the maximum is on that face -- fix the factor there
        for _rep in range(8):
            dmass = np.abs(W[:, nl]) @ Enl                   # bound of |d(nonlinear part)/da_k|
            lin = np.where(cl.lin_of >= 0, W[:, np.maximum(cl.lin_of, 0)], 0.0)
            fix = np.where(lin > dmass, 1, np.where(lin < -dmass, -1, 0))
            if not np.any(fix):
                break
            for k in np.flatnonzero(np.any(fix != 0, axis=0)):
                for s in (-1, 1):
                    sel = np.flatnonzero(fix[:, k] == s)
                    if sel.size:
                        W[sel] = np.asarray((cl.fix_op(int(k), s) @ W[sel].T).T)
                        v = 0.5 * (lo[sel, k] + hi[sel, k]) + s * 0.5 * (hi[sel, k] - lo[sel, k])
                        lo[sel, k] = v
                        hi[sel, k] = v
        ub = cl.upper(W)
        # lower bounds: sign vertex of the linear part, and the centre (both points of the box)
        lin = np.where(cl.lin_of >= 0, W[:, np.maximum(cl.lin_of, 0)], 0.0)
        V = np.where(lin >= 0, 1.0, -1.0)
        vv = (W * cl.vertex_values(V)).sum(axis=1)
        vc = W[:, cl.const]
        use_v = vv >= vc
        lb = np.where(use_v, vv, vc)
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        a_lb = np.where(use_v[:, None], mid + half * V, mid)
        order = np.lexsort((lb, dirs))
        last = np.r_[dirs[order][1:] != dirs[order][:-1], True]
        rows = order[last]
        better = lb[rows] > best[dirs[rows]]
        best[dirs[rows[better]]] = lb[rows[better]]
        best_a[dirs[rows[better]]] = a_lb[rows[better]]
        # prune boxes that cannot beat the best point; freeze boxes within tolerance
        dead = ub <= best[dirs]
        calm = ~dead & (ub <= best[dirs] + atol[dirs])
        np.maximum.at(frozen, dirs[calm], ub[calm])
        live = ~(dead | calm)
        live_max = np.full(N, -np.inf)
        np.maximum.at(live_max, dirs[live], ub[live])
        upper_dir = np.maximum(np.maximum(best, frozen), live_max)
        done = upper_dir - best <= atol
        live &= ~done[dirs]
        if not np.any(live):
            break
        W, dirs, lo, hi, ub = W[live], dirs[live], lo[live], hi[live], ub[live]
        # best first: per problem split only its boxes with the largest upper bounds
        budget = max(1, max_boxes // (2 * max(1, np.unique(dirs).size)))
        order = np.lexsort((-ub, dirs))
        first = np.r_[True, dirs[order][1:] != dirs[order][:-1]]
        rank = np.arange(order.size) - np.maximum.accumulate(np.where(first, np.arange(order.size), 0))
        top = np.sort(order[rank < budget])
        keep_rest = np.setdiff1d(np.arange(W.shape[0]), top)
        # split factor: the largest exponent-weighted nonlinear coefficient mass
        score = np.abs(W[top][:, nl]) @ Enl
        kk = np.argmax(score, axis=1)
        newW, newd, newlo, newhi = [W[keep_rest]], [dirs[keep_rest]], [lo[keep_rest]], [hi[keep_rest]]
        for k in np.unique(kk):
            sel = top[kk == k]
            Wk = W[sel]
            m_k = 0.5 * (lo[sel, k] + hi[sel, k])
            for s in (-1, 1):
                newW.append(np.asarray((cl.split_op(int(k), s) @ Wk.T).T))
                newd.append(dirs[sel])
                l2, h2 = lo[sel].copy(), hi[sel].copy()
                if s < 0:
                    h2[:, k] = m_k
                else:
                    l2[:, k] = m_k
                newlo.append(l2)
                newhi.append(h2)
        W, dirs = np.vstack(newW), np.concatenate(newd)
        lo, hi = np.vstack(newlo), np.vstack(newhi)
    return best, best_a, upper_dir, done, boxes


def factor_blocks(E: np.ndarray, G: np.ndarray, max_block: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Blocks of factors for the decomposed bound: connected components of the graph linking the
    factors of a monomial, dropping the weakest links (smallest generator norm) until no block
    has more than ``max_block`` factors.  Returns ``(block of each factor (p,), cross (h,))`` with
    ``cross`` marking the monomials whose factors span more than one block."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    p, h = E.shape
    nrm = np.linalg.norm(G, axis=0)
    multi = np.flatnonzero((E > 0).sum(axis=0) >= 2)
    cand = multi[np.argsort(-nrm[multi])]
    def comps(cols):
        r, c = [], []
        for i in cols:
            f = np.flatnonzero(E[:, i])
            r.append(np.repeat(f[0], f.size - 1))
            c.append(f[1:])
        r = np.concatenate(r) if r else np.zeros(0, int)
        c = np.concatenate(c) if c else np.zeros(0, int)
        A = coo_matrix((np.ones(r.size), (r, c)), shape=(p, p))
        return connected_components(A, directed=False)[1]
    lo_n, hi_n = 0, cand.size        # number of strongest links kept (bisection)
    lab = comps(cand)
    if np.bincount(lab).max() > max_block:
        while lo_n < hi_n:
            mid = (lo_n + hi_n + 1) // 2
            if np.bincount(comps(cand[:mid])).max() <= max_block:
                lo_n = mid
            else:
                hi_n = mid - 1
        lab = comps(cand[:lo_n])
    blk_of_col = [np.unique(lab[np.flatnonzero(E[:, i])]) for i in range(h)]
    cross = np.array([b.size > 1 for b in blk_of_col], dtype=bool)
    return lab, cross


class _Slots:
    """Monomials of ``E`` (p, h) as padded factor slots (h, L): factor index and exponent per slot
    (L = most factors in one monomial), for values and gradients without a loop over factors."""

    def __init__(self, E: np.ndarray):
        E = np.asarray(E)
        nz = (E > 0).T                                              # (h, p)
        L = max(1, int(nz.sum(axis=1).max()) if nz.size else 1)
        h = E.shape[1]
        self.k = np.zeros((h, L), dtype=np.int64)
        self.e = np.zeros((h, L))
        rank = np.cumsum(nz, axis=1) - 1
        ii, kk = np.nonzero(nz)
        self.k[ii, rank[ii, kk]] = kk
        self.e[ii, rank[ii, kk]] = E[kk, ii]
        self.p = E.shape[0]
        L = self.k.shape[1]
        self.onehot = np.zeros((L, h, self.p))                      # slot -> factor scatter matrices
        for l in range(L):
            on = self.e[:, l] > 0
            self.onehot[l, np.flatnonzero(on), self.k[on, l]] = 1.0

    def values_grad(self, A: np.ndarray, grad: bool = True):
        """Monomial values (N, h) and, with ``grad``, d m_i / d a_k as (N, h, L) per slot."""
        emax = int(self.e.max()) if self.e.size else 0
        Pw = np.ones((A.shape[0], self.p, emax + 1))                # powers a_k^j, j = 0..emax
        for j in range(1, emax + 1):
            Pw[:, :, j] = Pw[:, :, j - 1] * A
        ei = self.e.astype(np.int64)
        F = Pw[:, self.k, ei]                                       # (N, h, L)
        M = np.prod(F, axis=2)
        if not grad:
            return M, None
        L = F.shape[2]
        dF = np.where(self.e > 0, self.e * Pw[:, self.k, np.maximum(ei - 1, 0)], 0.0)
        dM = np.empty_like(F)
        for l in range(L):                                         # L <= a few
            others = np.prod(F[:, :, [i for i in range(L) if i != l]], axis=2) if L > 1 else 1.0
            dM[:, :, l] = dF[:, :, l] * others
        return M, dM

    def gather_grad(self, coef: np.ndarray, dM: np.ndarray) -> np.ndarray:
        """``sum_i coef[:, i] d m_i / d a`` (N, p) for coefficient rows coef (N, h)."""
        out = np.zeros((coef.shape[0], self.p))
        for l in range(self.k.shape[1]):
            out += (coef * dM[:, :, l]) @ self.onehot[l]
        return out


def _ascent(pz: PolyZonotope, D: np.ndarray, A: np.ndarray, iters: int = 30) -> np.ndarray:
    """Projected-gradient polish of maximisers ``A`` (N, p) of ``d^T G m(a)`` (keeps improvements)."""
    sl = _Slots(pz.E)
    W = D @ pz.G                                                   # (N, h)
    M, dM = sl.values_grad(A)
    f = (M * W).sum(axis=1)
    step = np.full(A.shape[0], 0.25)
    for _ in range(int(iters)):
        g = sl.gather_grad(W, dM)
        gn = np.linalg.norm(g, axis=1)
        cand = np.clip(A + (step / np.where(gn > 0, gn, 1.0))[:, None] * g, -1, 1)
        Mc, dMc = sl.values_grad(cand)
        fc = (Mc * W).sum(axis=1)
        up = fc > f
        A = np.where(up[:, None], cand, A)
        f = np.where(up, fc, f)
        dM = np.where(up[:, None, None], dMc, dM)
        step = np.where(up, step * 1.5, step * 0.5)
    return A


def support_bounds(pz: PolyZonotope, D: Any, tol: float = 1e-3, max_boxes: int = 60_000,
                   max_iter: int = 200, max_block: int = 6) -> SupportBounds:
    """Branch-and-bound support function of ``pz`` in the directions ``D`` (N, n) (module docstring).

    Sets with at most ``max_block`` factors are solved jointly.  Larger ones (e.g. STT sets with a
    few factors per step) are *decomposed*: the factors are grouped into blocks
    (:func:`factor_blocks`), each block's polynomial is maximised by branch and bound, the
    monomials spanning blocks are bounded by their enclosure, so
    ``upper = const + sum_blocks upper_b + enclosure(cross)`` is valid, and the lower bound is the
    polynomial at the joined block maximisers, polished by projected-gradient ascent (a point of
    the set).  ``tol``: stop a (sub-)problem when ``upper - lower <= tol * r(d)``, ``r(d) =
    sum |d^T G_i| + |d^T GI|_1`` (the enclosure radius).  ``max_boxes`` caps the boxes split per
    round and ``max_iter`` the rounds; a direction that has not met ``tol`` keeps valid but wider
    bounds (``converged`` False).  The arithmetic is floating point: the exact support may exceed
    ``upper`` by at most :func:`upper_rounding` (a certificate adds it).
    """
    from ocreach.sets._base import as_directions

    D, _ = as_directions(D, pz.dim)
    if not tol > 0:
        raise SetError(f"support_bounds: tol must be > 0; got {tol!r}")
    orig = pz
    pz = pz.compact()
    N = D.shape[0]
    p, q = pz.n_factors, orig.n_independent
    c0 = D @ pz.c
    wi = D @ orig.GI
    ind = np.abs(wi).sum(axis=1)
    beta = np.sign(wi) if q else np.zeros((N, 0))
    if pz.n_dependent == 0 or p == 0:
        const = c0 + ind
        A0 = np.zeros((N, orig.n_factors))
        pts = np.atleast_2d(orig.evaluate(A0, beta if q else None))
        return SupportBounds(const, const.copy(), A0, beta, pts, np.ones(N, bool), 0)
    WG = D @ pz.G
    radius = np.abs(WG).sum(axis=1) + ind
    atol = tol * np.where(radius > 0, radius, 1.0)
    if p <= max_block:
        cl = _closure(pz)
        W0 = np.zeros((N, cl.m))
        np.add.at(W0.T, cl.col_of_E, WG.T)
        best, best_a, up, done, boxes = _bb(cl, W0, atol, np.arange(N), N, max_boxes, max_iter)
        A = best_a
    else:
        lab, cross = factor_blocks(pz.E, pz.G, max_block)
        nb = int(lab.max()) + 1
        col_blk = lab[np.argmax(pz.E > 0, axis=0)]            # block of a within-block monomial
        A = np.zeros((N, p))
        up = np.zeros(N)
        boxes = 0
        tol_b = atol / (2 * nb)
        cache: dict[bytes, _Closure] = {}
        for b in range(nb):                                    # each block on its own closure
            fb = np.flatnonzero(lab == b)
            cols = np.flatnonzero(~cross & (col_blk == b))
            if cols.size == 0:
                continue
            Eb = pz.E[np.ix_(fb, cols)]
            key = Eb.tobytes() + np.asarray(Eb.shape, dtype=np.int64).tobytes()
            clb = cache.get(key) or cache.setdefault(key, _Closure(Eb))
            Wb = np.zeros((N, clb.m))
            np.add.at(Wb.T, clb.col_of_E, WG[:, cols].T)
            bb, ba, ub_b, _, nbx = _bb(clb, Wb, tol_b, np.arange(N), N, max_boxes, max_iter)
            A[:, fb] = ba
            up += ub_b
            boxes += nbx
        Wc = WG[:, cross]
        Ec = pz.E[:, cross]
        enc = np.abs(Wc[:, np.any(Ec % 2 == 1, axis=0)]).sum(axis=1) + \
            np.maximum(Wc[:, ~np.any(Ec % 2 == 1, axis=0)], 0).sum(axis=1)
        up = up + enc
        A = _ascent(pz, D, A)
        best = (np.prod(A[:, :, None] ** pz.E[None].astype(float), axis=1) * WG).sum(axis=1)
        done = up - best <= atol
    lower = best + c0 + ind
    upper = np.maximum(up + c0 + ind, lower)
    A_orig = np.zeros((N, orig.n_factors))                      # witness in the caller's factor order
    A_orig[:, np.searchsorted(np.sort(orig.id), pz.id)] = A
    A_orig = A_orig[:, np.argsort(np.argsort(orig.id))]
    pts = np.atleast_2d(orig.evaluate(A_orig, beta if q else None))
    return SupportBounds(lower, upper, A_orig, beta, pts, done, boxes)


def upper_rounding(pz: PolyZonotope, D: Any, max_iter: int = 200) -> np.ndarray:
    """A rigorous bound (N,) of how far :func:`support_bounds`' floating-point ``upper`` (with at
    most ``max_iter`` rounds) can lie below the exact support of ``pz`` in the directions ``D``
    (N, n).

    The branch and bound is exact arithmetic on coefficient rows except for rounding: every split
    or monotonicity fix of a box is a sparse map whose absolute column sums are 1 (``sum_b
    C(e, b) 2^-e = 1``) with at most ``emax + 1`` terms per entry, so along the at most
    ``max_iter + p`` maps of a box's lineage each adds at most ``gamma_(emax + 1)`` times the
    coefficients' l1 norm ``<= sum_j |d^T g_j|``; a monotonicity fix decided on a rounded
    derivative bound loses at most twice its rounding, ``2 gamma_m deg`` times that norm over all
    factors (``m`` closure monomials, ``deg`` the largest degree); the box bound adds ``gamma_m``,
    and ``D c``, ``D G``, ``|D GI|_1``, the compaction's merged columns and the final sums
    ``gamma_(n + h + q + p + 8)`` of ``|d|^T (|c| + sum |g_j| + sum |gi_j|)`` (Higham, Lemma 3.1;
    :func:`ocreach.sets.rounding.rounding_radius`).  Certificates compare against
    ``upper + upper_rounding``."""
    from ocreach.sets.rounding import U, rounding_radius

    D = np.atleast_2d(np.asarray(D, dtype=float))
    E = np.asarray(pz.E)
    p, h = E.shape
    emax = int(E.max(initial=0))
    deg = int(E.sum(axis=0).max(initial=0))
    m = 1.0 + float(np.prod(E.astype(float) + 1.0, axis=0).sum()) if h else 1.0
    k = (max_iter + p) * (emax + 1) + 2.0 * m * max(deg, 1) + m + pz.dim + h + pz.n_independent + p + 8
    absval = np.abs(D) @ (np.abs(pz.c) + np.abs(pz.G).sum(axis=1) + np.abs(pz.GI).sum(axis=1))
    if not (2 * k + 2) * U < 0.25:
        return np.full(D.shape[0], np.inf)
    return rounding_radius(absval, int(np.ceil(k)))


# ============================================================================ membership
@dataclass(frozen=True)
class Membership:
    """Three-valued membership: ``status`` +1 inside (witness ``alpha``, ``beta`` with
    ``||x(alpha, beta) - point|| <= tol``), -1 outside (``d^T point > upper(d)`` for the
    certificate direction ``direction`` with bound ``bound``), 0 undecided."""

    status: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    residual: np.ndarray
    direction: np.ndarray
    bound: np.ndarray

    @property
    def inside(self) -> np.ndarray:
        return self.status == 1

    @property
    def outside(self) -> np.ndarray:
        return self.status == -1


def _jacobian_residual(pz: PolyZonotope, A: np.ndarray, B: np.ndarray, X: np.ndarray, sl: _Slots | None = None):
    """Residual (N, n) and Jacobian (N, n, p + q) of ``c + G m(a) + GI b - x``."""
    sl = sl or _Slots(pz.E)
    M, dM = sl.values_grad(A)
    R = pz.c + M @ pz.G.T + B @ pz.GI.T - X
    N, n = A.shape[0], pz.dim
    J = np.zeros((N, n, pz.n_factors + pz.n_independent))
    for j in range(n):
        J[:, j, : pz.n_factors] = sl.gather_grad(np.broadcast_to(pz.G[j], (N, pz.n_dependent)), dM)
    J[:, :, pz.n_factors:] = pz.GI
    return R, J


def find_witnesses(pz: PolyZonotope, X: np.ndarray, tol: float, iters: int = 40, starts: int = 8,
                   seed: int = 0, chunk: int = 512) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Factor values ``(alpha, beta)`` minimising ``||x(alpha, beta) - X||`` over the factor box by
    damped minimum-norm Gauss-Newton steps projected on the box, several starts (vectorised over
    points).  Returns ``alpha (N, p), beta (N, q), residual norms (N,)``."""
    p, q = pz.n_factors, pz.n_independent
    N = X.shape[0]
    rng = np.random.default_rng(seed)
    slots = _Slots(pz.E)
    best_r = np.full(N, np.inf)
    best_a, best_b = np.zeros((N, p)), np.zeros((N, q))
    for s0 in range(0, N, chunk):
        idx_all = np.arange(s0, min(N, s0 + chunk))
        for st in range(starts):
            idx = idx_all[best_r[idx_all] > tol]
            if idx.size == 0:
                break
            Xs = X[idx]
            Z = np.zeros((idx.size, p + q)) if st == 0 else rng.uniform(-1, 1, (idx.size, p + q))
            lam = np.full(idx.size, 1e-6)
            r = np.linalg.norm(_jacobian_residual(pz, Z[:, :p], Z[:, p:], Xs, slots)[0], axis=1)
            for _ in range(iters):
                R, J = _jacobian_residual(pz, Z[:, :p], Z[:, p:], Xs, slots)
                JJ = np.einsum("Nik,Njk->Nij", J, J) + lam[:, None, None] * np.eye(pz.dim)
                step = np.einsum("Nik,Ni->Nk", J, np.linalg.solve(JJ, R[..., None])[..., 0])
                Zc = np.clip(Z - step, -1.0, 1.0)
                rc = np.linalg.norm(_jacobian_residual(pz, Zc[:, :p], Zc[:, p:], Xs, slots)[0], axis=1)
                up = rc < r                                          # Levenberg-Marquardt damping
                Z = np.where(up[:, None], Zc, Z)
                r = np.where(up, rc, r)
                lam = np.where(up, lam * 0.3, lam * 10.0)
                if np.all(r <= tol):
                    break
            imp = r < best_r[idx]
            best_r[idx[imp]] = r[imp]
            best_a[idx[imp]] = Z[imp, :p]
            best_b[idx[imp]] = Z[imp, p:]
    return best_a, best_b, best_r


def membership(pz: PolyZonotope, points: Any, tol: float = 1e-7, directions: Any = None,
               support_tol: float = 1e-3, witness_iters: int = 40) -> Membership:
    """Three-valued membership of ``points`` (N, n) in ``pz`` (see :class:`Membership`).

    Exclusion certificates come from the branch-and-bound upper support bound in ``directions``
    (default: 64 directions on the circle for n = 2, else the 2n axis directions and 64 random
    ones) and in the direction from the nearest witness point found to each point not proved
    inside.  ``tol`` is the distance within which a witness counts as inside, and a certificate
    needs the point beyond the support bound by more than ``tol`` (a point on the boundary, e.g. a
    vertex of a box, is never certified outside by rounding)."""
    from ocreach.sets._base import as_points

    P, _ = as_points("points", points, pz.dim)
    n, N = pz.dim, P.shape[0]
    if directions is None:
        if n == 2:
            t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
            directions = np.c_[np.cos(t), np.sin(t)]
        else:
            rng = np.random.default_rng(1)
            R = rng.normal(size=(64, n))
            directions = np.vstack([np.eye(n), -np.eye(n), R / np.linalg.norm(R, axis=1, keepdims=True)])
    Dd = np.asarray(directions, float)
    sb = support_bounds(pz, Dd, tol=support_tol)
    status = np.zeros(N, dtype=np.int64)
    dirs = np.zeros((N, n))
    bound = np.full(N, np.nan)
    excess = P @ Dd.T - sb.upper[None, :]
    j = np.argmax(excess, axis=1)
    out = excess[np.arange(N), j] > tol
    status[out] = -1
    dirs[out] = Dd[j[out]]
    bound[out] = sb.upper[j[out]]
    alpha = np.full((N, pz.n_factors), np.nan)
    beta = np.full((N, pz.n_independent), np.nan)
    resid = np.full(N, np.nan)
    todo = np.flatnonzero(~out)
    if todo.size:
        a, b, r = find_witnesses(pz, P[todo], tol, iters=witness_iters)
        alpha[todo], beta[todo], resid[todo] = a, b, r
        inside = r <= tol
        status[todo[inside]] = 1
        rest = todo[~inside]
        if rest.size:  # certificate in the direction from the nearest point found
            near = np.atleast_2d(pz.evaluate(a[~inside], b[~inside] if pz.n_independent else None))
            dv = P[rest] - near
            nv = np.linalg.norm(dv, axis=1)
            ok = nv > 0
            if np.any(ok):
                Dr = dv[ok] / nv[ok, None]
                sr = support_bounds(pz, Dr, tol=support_tol)
                ex = np.einsum("ij,ij->i", P[rest[ok]], Dr) > sr.upper + tol
                hit = rest[ok][ex]
                status[hit] = -1
                dirs[hit] = Dr[ex]
                bound[hit] = sr.upper[ex]
    return Membership(status, alpha, beta, resid, dirs, bound)


# ============================================================================ 2-D hull bounds
def _halfplane_polygon(D: np.ndarray, h: np.ndarray, interior: np.ndarray) -> np.ndarray:
    from scipy.spatial import ConvexHull, HalfspaceIntersection

    hs = HalfspaceIntersection(np.c_[D, -h], interior)
    V = hs.intersections
    return V[ConvexHull(V).vertices]


def hull_polygons(pz: PolyZonotope, dims: Any = (0, 1), n_dirs: int = 256,
                  tol: float = 1e-3) -> tuple[np.ndarray, np.ndarray, SupportBounds]:
    """Inner and outer polygon of the convex hull of the 2-D projection (module docstring)."""
    from ocreach.geometry import convex_hull_polygon

    P = pz.project(dims)
    if P.dim != 2:
        raise SetError(f"hull_polygons needs two dims; got {dims!r}")
    t = np.linspace(0, 2 * np.pi, int(n_dirs), endpoint=False)
    D = np.c_[np.cos(t), np.sin(t)]
    sb = support_bounds(P, D, tol=tol)
    inner = convex_hull_polygon(sb.points)
    centre = sb.points.mean(axis=0)
    if inner is None:
        w = 1e-12 * max(1.0, float(np.abs(sb.upper).max()))
        outer = _halfplane_polygon(D, sb.upper + w, centre)
        return np.zeros((0, 2)), outer, sb
    outer = _halfplane_polygon(D, sb.upper, centre)
    return inner, outer, sb


def hull_area_bounds(pz: PolyZonotope, dims: Any = (0, 1), n_dirs: int = 256, tol: float = 1e-3) -> tuple[float, float]:
    """``(lower, upper)`` of the area of the convex hull of the 2-D projection."""
    from ocreach.geometry import polygon_area

    inner, outer, _ = hull_polygons(pz, dims, n_dirs, tol)
    return (polygon_area(inner) if inner.shape[0] >= 3 else 0.0), polygon_area(outer)


def points_at(pz: PolyZonotope, D: Any, tol: float = 1e-3) -> np.ndarray:
    """Boundary samples: for each direction the point of the set maximising ``d^T x`` (up to the
    stated gap ``upper - lower`` of :func:`support_bounds`)."""
    return support_bounds(pz, D, tol=tol).points
