"""Order-3 products of the fused STT step in bounded-memory blocks (Foss et al. Eq. 22; issue #16).

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

    def _block(self, j: int, i0: int, i1: int) -> tuple[np.ndarray, np.ndarray]:
        """Products of rows ``i0..i1-1`` (flat (n, rows * w), w = H - j) and the kept positions."""
        G, H, n = self.G, self.H, self.n
        w, rows = H - j, i1 - i0
        B = np.matmul(G[:, i0:i1].T[None], self.M[j] @ G[:, j:])  # (n, rows, w)
        B[:, :, 0] *= 0.5
        if i1 == j + 1:
            B[:, -1, 1:] *= 0.5
            B[:, -1, 0] *= 1.0 / 3.0
        return B.reshape(n, rows * w), self._kept_positions(j, i0, i1)

    def _kept_positions(self, j: int, i0: int, i1: int) -> np.ndarray:
        """Flat positions (row-major in the block) of the products whose bound reaches ``thr``.

        The generators are sorted by decreasing norm, so in row ``i`` the kept products
        ``k > j`` are the first ``cnt_i`` columns after the first, and if the first column
        (``k = j``, the largest |g_k|) is pruned they still follow it: a row keeps one range."""
        w, rows = self.H - j, i1 - i0
        if self.thr <= 0.0:
            return np.arange(rows * w)
        gn = self.gn
        a = gn[i0:i1] * (gn[j] * self.scale)                    # bound per row without mult and g_k
        m_in = np.full(rows, 6.0)                               # mult of k > j; 3 in the row i = j
        m_0 = np.full(rows, 3.0)                                # mult of k = j; 1 at i = j = k
        if i1 == j + 1:
            m_in[-1], m_0[-1] = 3.0, 1.0
        with np.errstate(divide="ignore"):
            cnt = np.searchsorted(self.neg[j + 1:], -(self.thr / (m_in * a)), side="right")
        lo = np.where(a * m_0 * gn[j] >= self.thr, 0, 1)
        length = cnt + 1 - lo
        start = np.cumsum(length) - length
        r = np.repeat(np.arange(rows), length)
        return r * w + np.repeat(lo - start, length) + np.arange(r.size)

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
