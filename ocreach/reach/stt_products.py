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

Peak memory is then ``O(chunk)`` for the blocks plus the kept products (a few percent).
"""
from __future__ import annotations

from collections.abc import Iterator

import numpy as np

#: memory budget of one block of order-3 products (the default ``chunk`` follows from it)
CHUNK_BYTES = 128 * 2**20
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
        self.T3 = T3
        self.scale = float(np.linalg.norm(T3))
        self.thr = float(thr)
        self.chunk = max(1, int(chunk))
        self.n, self.H = T3.shape[0], Ga.shape[1]
        self.gram = np.zeros((self.n, self.n))
        self.absum = np.zeros(self.n)
        self.count = 0

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
        # multiplicities: 6 inside, 3 on the first column (k = j) and the row i = j, 1 at i = j = k
        Mj = np.tensordot(self.T3, 6.0 * G[:, j], axes=([2], [0]))  # (n, nz, nz): 6 T3[., ., g_j, .]
        B = np.matmul(G[:, i0:i1].T[None], Mj @ G[:, j:])         # (n, rows, w)
        B[:, :, 0] *= 0.5
        if i1 == j + 1:
            B[:, -1, 1:] *= 0.5
            B[:, -1, 0] *= 1.0 / 3.0
        return B.reshape(n, rows * w), self._kept_positions(j, i0, i1)

    def _kept_positions(self, j: int, i0: int, i1: int) -> np.ndarray:
        """Flat positions (row-major in the block) of the products whose bound reaches ``thr``."""
        w, rows = self.H - j, i1 - i0
        if self.thr <= 0.0:
            return np.arange(rows * w)
        gn, s = self.gn, self.scale
        a = gn[i0:i1] * (gn[j] * s)                             # per row, without the multiplicity
        last = i1 == j + 1                                      # the block holds the row i = j
        inner = a[:-1] if last else a
        # interior (mult 6, k > j): gn sorted decreasingly, so the kept columns are a prefix
        with np.errstate(divide="ignore"):
            cnt = np.searchsorted(self.neg[j + 1:], -(self.thr / (6.0 * inner)), side="right")
        r = np.repeat(np.arange(inner.size), cnt)
        start = np.repeat(np.cumsum(cnt) - cnt, cnt)
        pos = [r * w + 1 + (np.arange(r.size) - start)]
        # first column (k = j, mult 3; 1 at i = j) and the row i = j (mult 3)
        m0 = np.full(rows, 3.0)
        if last:
            m0[-1] = 1.0
        pos.append(np.flatnonzero(a * m0 * gn[j] >= self.thr) * w)
        if last:
            pos.append((rows - 1) * w + 1 + np.flatnonzero(a[-1] * 3.0 * gn[j + 1:] >= self.thr))
        return np.sort(np.concatenate(pos))

    def _pruned(self, j: int, i0: int, i1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        B, keep = self._block(j, i0, i1)
        vals = B[:, keep]
        B[:, keep] = 0.0
        return B, vals, keep

    # -- passes ---------------------------------------------------------------------------------
    def kept(self, absum: bool = False) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Yield ``(values (n, r), indices (3, r))`` of the kept products per block (indices into
        the caller's generator order); accumulates ``gram`` (and ``absum`` if asked) of the rest."""
        for j, i0, i1 in self._blocks():
            Bp, vals, keep = self._pruned(j, i0, i1)
            w = self.H - j
            self.count += Bp.shape[1] - keep.size
            if self.count:
                self.gram += Bp @ Bp.T
                if absum:
                    self.absum += np.abs(Bp).sum(axis=1)
            ii, kk = i0 + keep // w, j + keep % w
            tri = np.vstack([self.perm[ii], np.full(keep.size, self.perm[j]), self.perm[kk]])
            yield vals, tri

    def proj_abs(self, U: np.ndarray) -> np.ndarray:
        """``sum_x |U^T x|`` over the pruned products (formed again, block by block)."""
        out = np.zeros(U.shape[1])
        if self.count == 0:
            return out
        for j, i0, i1 in self._blocks():
            X = U.T @ self._pruned(j, i0, i1)[0]
            out += np.abs(X, out=X).sum(axis=1)
        return out
