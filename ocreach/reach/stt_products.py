"""Order-3 products of the fused STT step in bounded-memory blocks (Foss et al. Eq. 22).

The order-3 tensor map forms ``mult * T3[g_i, g_j, g_k]`` for every multiset ``i <= j <= k`` of
the ``H`` augmented generators of ``dZ`` -- ``C(H + 2, 3)`` products, 87 M at ``H = 800`` -- and
most of them are too small to keep: with pruning on, a product whose bound
``mult ||T3||_F |g_i| |g_j| |g_k|`` is below a threshold goes into the reduction's box instead of
being merged (:func:`ocreach.reach.stt.fused_step`).  Materialising all of them first grew as
``H^3`` in memory (10 GB at ``h_max = 800``); here they are formed block by block:

* blocks by the middle index ``j``: for a fixed ``j`` the products ``(i, j, k)`` with
  ``i <= j <= k`` fill a full rectangle ``[0, j] x [j, H)``, so each is one matrix product
  ``G[:, :j+1]^T (T3 g_j) G[:, j:]`` (no wasted triangle); a rectangle larger than ``chunk``
  products is split into row blocks;
* the generators are sorted by decreasing norm, so the kept products of a row form a prefix of
  its columns (found by a binary search, no pass over the pruned ones);
* the pruned products enter the box only through ``X X^T`` and ``sum |X|`` (one pass) and, for the
  PCA box, ``sum |U^T X|`` once the frame ``U`` is known (a second pass that forms them again):
  the box is the one of the stored columns (:func:`ocreach.sets.reduce.box_generators`), up to
  round-off.

Peak memory is then ``O(chunk)`` for the blocks, ``CACHE_BYTES`` for the pruned products of the
first blocks (``CACHE_BLOCKS * chunk`` products; the second pass reuses them) and the kept products (a few percent).

The time still grows with the products formed (~H^3 / 6 per step; 99.7 % of them pruned on vdp).
:class:`BoundedOrder3Products` (option ``pruned_box="bound"``) forms only the kept ones and boxes
the pruned ones from per-pair bounds, ``O(H^2)`` per step, at the cost of a slightly looser box
(docs/stt.md, "Pruned order-3 products").
"""
from __future__ import annotations

from collections.abc import Iterator

import numpy as np

#: memory budget of one block of order-3 products (the default ``chunk`` follows from it)
CHUNK_BYTES = 128 * 2**20
#: the pruned products of the first blocks are kept, up to this many blocks' worth of memory, so
#: the second pass need not form them again (all of them up to h_max ~ 400 on a 2-row image)
CACHE_BLOCKS = 8
#: more products than this switch pruning on (below it every product is merged, as before)
PRUNE_MIN_PRODUCTS = 50_000


def default_chunk(n: int) -> int:
    """Products per block for an ``n``-row image: ``CHUNK_BYTES`` over the bytes a product needs
    in a block (its ``n`` values, ``U^T X`` and its absolute value in the second pass)."""
    return max(1 << 12, CHUNK_BYTES // ((3 * n + 2) * 8))


def n_products(H: int) -> int:
    """Number of order-3 multisets ``i <= j <= k`` over ``H`` generators."""
    return H * (H + 1) * (H + 2) // 6


class Order3Products:
    """``mult * T3[g_i, g_j, g_k]`` (``mult`` = 1, 3, 6 distinct orderings) over ``i <= j <= k``.

    ``T3`` (n, nz, nz, nz) symmetric in its inputs, ``Ga`` (nz, H) the augmented generators,
    ``thr``: products with bound ``mult ||T3||_F |g_i| |g_j| |g_k| < thr`` are pruned (``thr = 0``:
    none), ``chunk``: products per block.  :meth:`kept` yields the kept products block by block
    and accumulates the statistics of the pruned ones (``gram``, ``absum``, ``count``);
    :meth:`proj_abs` forms the pruned ones again for ``sum |U^T X|``.
    """

    def __init__(self, T3: np.ndarray, Ga: np.ndarray, thr: float, chunk: int):
        gn = np.linalg.norm(Ga, axis=0)
        self.perm = np.argsort(-gn, kind="stable")          # decreasing norm
        self.G = np.ascontiguousarray(Ga[:, self.perm])
        self.gn = gn[self.perm]
        self.neg = -self.gn                                  # ascending, for searchsorted
        # multiplicities: 6 inside, 3 on the first column (k = j) and the row i = j, 1 at i = j = k
        self.M = np.einsum("mabc,bj->jmac", 6.0 * T3, self.G, optimize=True)  # 6 T3[., ., g_j, .]
        self.scale = float(np.linalg.norm(T3))
        self.thr = float(thr)
        self.chunk = max(1, int(chunk))
        self.n, self.H = T3.shape[0], Ga.shape[1]
        self.gram = np.zeros((self.n, self.n))
        self.absum = np.zeros(self.n)
        self.count = 0
        self._cache: list[np.ndarray] = []
        self._cached = 0                                # products, not bytes

    # -- blocks ---------------------------------------------------------------------------------
    def _blocks(self) -> Iterator[tuple[int, int, int]]:
        """``(j, i0, i1)``: rows ``i0 <= i < i1 <= j + 1`` of the rectangle of middle index ``j``."""
        H = self.H
        for j in range(H):
            rows = max(1, self.chunk // (H - j))
            for i0 in range(0, j + 1, rows):
                yield j, i0, min(i0 + rows, j + 1)

    def _rect(self, j: int, i0: int, i1: int, W: int) -> np.ndarray:
        """Products (n, rows, W) of rows ``i0..i1-1`` and columns ``j..j+W-1`` of the rectangle
        of middle index ``j``, with their multiplicities."""
        B = np.matmul(self.G[:, i0:i1].T[None], self.M[j] @ self.G[:, j:j + W])
        B[:, :, 0] *= 0.5
        if i1 == j + 1:
            B[:, -1, 1:] *= 0.5
            B[:, -1, 0] *= 1.0 / 3.0
        return B

    def _block(self, j: int, i0: int, i1: int) -> tuple[np.ndarray, np.ndarray]:
        """Products of rows ``i0..i1-1`` (flat (n, rows * w), w = H - j) and the kept positions."""
        w = self.H - j
        B = self._rect(j, i0, i1, w)
        I = np.arange(i0, i1)
        return B.reshape(self.n, -1), _positions(*self._ranges(I, np.full(I.size, j)), w)

    def _ranges(self, I: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per row ``(i, j)``, ``i <= j``: the kept columns are the offsets ``lo..cnt`` from
        ``k = j`` (``lo`` = 1 when ``k = j`` is pruned; ``cnt`` kept ``k > j``).

        The generators are sorted by decreasing norm, so in row ``i`` the kept products
        ``k > j`` are the first ``cnt`` columns after the first, and if the first column
        (``k = j``, the largest |g_k|) is pruned they still follow it: a row keeps one range."""
        if self.thr <= 0.0:
            return np.zeros(I.size, dtype=np.int64), self.H - 1 - J
        gn = self.gn
        a = gn[I] * gn[J] * self.scale                  # bound per row without mult and g_k
        diag = I == J
        m_in = np.where(diag, 3.0, 6.0)                 # mult of k > j; 3 in the row i = j
        m_0 = np.where(diag, 1.0, 3.0)                  # mult of k = j; 1 at i = j = k
        with np.errstate(divide="ignore"):
            n_ge = np.searchsorted(self.neg, -(self.thr / (m_in * a)), side="right")  # gn_k >= t
        cnt = np.maximum(n_ge - J - 1, 0)
        lo = np.where(a * m_0 * gn[J] >= self.thr, 0, 1)
        return lo.astype(np.int64), cnt.astype(np.int64)

    def _pruned(self, j: int, i0: int, i1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        B, keep = self._block(j, i0, i1)
        vals = B[:, keep]
        B[:, keep] = 0.0
        return B, vals, keep

    # -- passes ---------------------------------------------------------------------------------
    def kept(self, absum: bool = False) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Yield ``(values (n, r), indices (3, r))`` of the kept products per block (indices into
        the caller's generator order); accumulates ``gram`` (and ``absum`` if asked) of the rest."""
        caching = True
        for j, i0, i1 in self._blocks():
            Bp, vals, keep = self._pruned(j, i0, i1)
            w = self.H - j
            self.count += Bp.shape[1] - keep.size
            if self.count:
                self.gram += Bp @ Bp.T
                if absum:
                    self.absum += np.abs(Bp).sum(axis=1)
            caching = caching and self._cached + Bp.shape[1] <= CACHE_BLOCKS * self.chunk
            if caching:
                self._cache.append(Bp)
                self._cached += Bp.shape[1]
            ii, kk = i0 + keep // w, j + keep % w
            tri = np.vstack([self.perm[ii], np.full(keep.size, self.perm[j]), self.perm[kk]])
            yield vals, tri

    def proj_abs(self, U: np.ndarray) -> np.ndarray:
        """``sum_x |U^T x|`` over the pruned products (formed again, block by block)."""
        out = np.zeros(U.shape[1])
        if self.count == 0:
            return out
        for b, (j, i0, i1) in enumerate(self._blocks()):
            X = U.T @ (self._cache[b] if b < len(self._cache) else self._pruned(j, i0, i1)[0])
            out += np.abs(X, out=X).sum(axis=1)
        return out


class BoundedOrder3Products(Order3Products):
    """The order-3 products of :class:`Order3Products` with the pruned ones never formed.

    Only the kept products are formed (row blocks of the kept staircase, whose widths stay within
    a factor 2, so at most about twice the kept count); the pruned ones enter the box through
    bounds computed per pair ``(i, j)``, ``i <= j``, from ``A_ij = T3[g_i, g_j, .]`` (n, nz) and
    suffix sums over the sorted generators (the pruned ``k`` of a pair are the suffix
    ``k >= s_ij``, plus possibly ``k = j``, whose product is formed):

    * ``gram`` exact: ``sum_{k >= s} x x^T = A_ij (sum_{k >= s} g_k g_k^T) A_ij^T``;
    * ``sum_{k >= s} |D^T x| <= min(|D^T A_ij| sum_{k >= s} |g_k|,
      ||D^T A_ij||_2 sum_{k >= s} ||g_k||_2)`` per direction (triangle inequality,
      Cauchy-Schwarz) for the box's directions ``D`` (``U`` in :meth:`proj_abs`, the unit vectors
      for ``absum``), so the box of :func:`ocreach.sets.reduce.box_generators` still contains
      every pruned product.

    Cost ``O(H^2 n nz^2)`` for the bounds instead of ``O(H^3 n nz)`` for forming every product;
    the box is looser than the exact one by what the triangle inequality loses on the pruned
    products (docs/stt.md, "Pruned order-3 products").
    """

    #: pair terms ``A_ij`` formed at once (floats), bounding the memory of the pair passes
    PAIR_FLOATS = 1 << 22
    #: pair terms kept from the first pass for the second (floats; 8 M = 64 MB, every pair up to
    #: H ~ 1,000 on a 2-row image with 3 factors)
    PAIR_CACHE_FLOATS = 1 << 23

    def __init__(self, T3: np.ndarray, Ga: np.ndarray, thr: float, chunk: int):
        super().__init__(T3, Ga, thr, chunk)
        G, H = self.G, self.H
        nz = G.shape[0]
        # suffix sums over the sorted generators: X[m] = sum_{k >= m} ...  (X[H] = 0)
        self._Q = np.zeros((H + 1, nz, nz))
        self._Q[:-1] = np.cumsum(np.einsum("ak,bk->kab", G, G)[::-1], axis=0)[::-1]
        self._S = np.zeros((H + 1, nz))
        self._S[:-1] = np.cumsum(np.abs(G).T[::-1], axis=0)[::-1]
        self._N = np.zeros(H + 1)
        self._N[:-1] = np.cumsum(self.gn[::-1])[::-1]
        # every pair i <= j, grouped by j: pairs of j are off[j]..off[j+1]-1 with i = 0..j
        self._off = np.concatenate([[0], np.cumsum(np.arange(1, H + 1))])
        J = np.repeat(np.arange(H), np.arange(1, H + 1))
        I = np.arange(J.size) - self._off[J]
        self._lo, self._cnt = self._ranges(I, J)
        self._pair_cache: list[tuple[np.ndarray, ...]] | None = None

    # -- kept products: only the staircase is formed ---------------------------------------------
    def kept(self, absum: bool = False) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """As :meth:`Order3Products.kept`; ``gram``, ``absum`` and ``count`` of the pruned
        products come from the pair bounds (``absum`` always)."""
        off = self._off
        width = self._cnt + 1
        width[(self._lo == 1) & (self._cnt == 0)] = 0          # nothing kept in the row
        for j in range(self.H):
            wj = width[off[j]:off[j + 1]]                        # non-increasing in i
            if wj[0] == 0:
                continue
            nrows = int(np.count_nonzero(wj))
            i = 0
            while i < nrows:                                     # rows of widths within 2x
                W = int(wj[i])
                i1 = min(nrows, i + max(1, self.chunk // W), int(np.searchsorted(-2 * wj, -W - 1)))
                i1 = max(i1, i + 1)
                sl = slice(off[j] + i, off[j] + i1)
                B = self._rect(j, i, i1, W)
                keep = _positions(self._lo[sl], self._cnt[sl], W)
                ii, kk = i + keep // W, j + keep % W
                yield (B.reshape(self.n, -1)[:, keep],
                       np.vstack([self.perm[ii], np.full(keep.size, self.perm[j]), self.perm[kk]]))
                i = i1
        self.absum = self._pair_bounds(np.eye(self.n), gram=True)

    # -- pruned products: bounds per pair -------------------------------------------------------
    def _pair_chunks(self) -> Iterator[tuple[np.ndarray, ...]]:
        """``(A, rf, cf, s, gJ)`` over the pairs with a pruned product, in chunks of middle
        indices: ``A_ij`` (n, P, nz) (with the factor 6 of :attr:`M`), row factor (1/2 at
        ``i = j``), the factor of a pruned ``k = j`` product (0 if kept, 1/2, 1/6 at ``i = j``),
        first pruned ``k > j`` (``H``: none) and ``g_j`` (P, nz).  The first pass keeps them for the
        second when they fit in :attr:`PAIR_CACHE_FLOATS`."""
        if self._pair_cache is not None:
            yield from self._pair_cache
            return
        cache: list[tuple[np.ndarray, ...]] | None = []
        size = 0                                                 # floats of the cached A_ij
        for chunk in self._pair_terms():
            if cache is not None:
                cache.append(chunk)
                size += chunk[0].size
                if size > self.PAIR_CACHE_FLOATS:
                    cache = None
            yield chunk
        self._pair_cache = cache

    def _pair_terms(self) -> Iterator[tuple[np.ndarray, ...]]:
        """The chunks of :meth:`_pair_chunks`, computed."""
        H, off, G = self.H, self._off, self.G
        per_pair = self.n * G.shape[0] * 2
        j0 = 0
        while j0 < H:
            j1 = j0 + 1
            while j1 < H and (j1 + 1 - j0) * (j1 + 1) * per_pair <= self.PAIR_FLOATS:
                j1 += 1
            sl = slice(off[j0], off[j1])
            J = np.repeat(np.arange(j0, j1), np.arange(j0 + 1, j1 + 1))
            I = np.arange(off[j0], off[j1]) - off[J]
            lo, s = self._lo[sl], J + 1 + self._cnt[sl]
            pick = np.flatnonzero((s < H) | (lo == 1))
            if pick.size:
                I, J, lo, s = I[pick], J[pick], lo[pick], s[pick]
                Afull = np.einsum("ai,jmac->mjic", G[:, :j1], self.M[j0:j1], optimize=True)
                A = Afull[:, J - j0, I]                                   # (n, P, nz)
                diag = I == J
                rf = np.where(diag, 0.5, 1.0)
                cf = np.where(lo == 1, np.where(diag, 1.0 / 6.0, 0.5), 0.0)
                yield A, rf, cf, s, np.ascontiguousarray(G[:, J].T)
            j0 = j1

    def _pair_bounds(self, D: np.ndarray, gram: bool = False) -> np.ndarray:
        """``sum |D^T x|`` bounded over the pruned products (and ``gram``, ``count`` if asked)."""
        out = np.zeros(D.shape[1])
        Dt = np.ascontiguousarray(D.T)
        n, d = self.n, Dt.shape[0]
        for A, rf, cf, s, gJ in self._pair_chunks():
            P, nz = A.shape[1:]
            V = (Dt @ A.reshape(n, -1)).reshape(d, P, nz)
            b1 = np.einsum("dpc,pc->dp", np.abs(V), self._S[s])          # S[H] = 0: no tail
            b2 = np.sqrt(np.einsum("dpc,dpc->dp", V, V)) * self._N[s]
            x0 = np.einsum("dpc,pc->dp", V, gJ)                            # the k = j product
            out += np.minimum(b1, b2) @ rf + np.abs(x0) @ cf
            if gram:
                At = A * rf[:, None]
                AQ = np.einsum("mpc,pcd->mpd", At, self._Q[s])            # (n, P, nz)
                self.gram += AQ.reshape(n, -1) @ At.reshape(n, -1).T
                X0 = np.einsum("mpc,pc->mp", A, gJ) * cf
                self.gram += X0 @ X0.T
                self.count += int((self.H - s).sum() + np.count_nonzero(cf))
        return out

    def proj_abs(self, U: np.ndarray) -> np.ndarray:
        """An upper bound of ``sum_x |U^T x|`` over the pruned products (never formed)."""
        if self.count == 0:
            return np.zeros(U.shape[1])
        return self._pair_bounds(U)


def _positions(lo: np.ndarray, cnt: np.ndarray, W: int) -> np.ndarray:
    """Flat positions (row-major, ``W`` columns) of the kept offsets ``lo..cnt`` of each row."""
    length = cnt + 1 - lo
    start = np.cumsum(length) - length
    r = np.repeat(np.arange(lo.size), length)
    return r * W + np.repeat(lo - start, length) + np.arange(r.size)


def order3_products(T3: np.ndarray, Ga: np.ndarray, thr: float, chunk: int,
                    pruned_box: str = "exact") -> Order3Products:
    """The order-3 products with the pruned ones boxed ``"exact"`` (:class:`Order3Products`,
    every product formed) or by ``"bound"`` (:class:`BoundedOrder3Products`, only the kept ones
    formed)."""
    if pruned_box == "exact":
        return Order3Products(T3, Ga, thr, chunk)
    if pruned_box == "bound":
        return BoundedOrder3Products(T3, Ga, thr, chunk)
    raise ValueError(f"pruned_box must be 'exact' or 'bound'; got {pruned_box!r}")
