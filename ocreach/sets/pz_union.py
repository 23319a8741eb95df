"""Finite unions of polynomial zonotopes: the reachable set of a split ``stt`` run.

When ``stt`` splits a set (``split="factor" | "box"``, :mod:`ocreach.reach.stt_split`; the
splitting Foss, Rosengren & Biria, AMOS 2024, Sec. 5 name as future work) every part is propagated
through its own STT polynomial; the set at a time (and a reachable tube over a segment) is the union
of the parts.  A :class:`PZUnion` keeps the parts and answers each query from the parts' own
queries (:class:`ocreach.sets.PolyZonotope`), so it inherits their guarantees and no more.

The zonotope counterpart of the sound methods is :class:`ocreach.sets.union.ZonotopeUnion`.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.sets._base import check_parts

if TYPE_CHECKING:
    from ocreach.sets.interval import Interval


class PZUnion:
    """Union of polynomial zonotopes ``parts`` (all of one dimension; at least one).

    Offers the set queries used by results and comparisons: ``support`` (max over parts),
    ``contains`` (any part), ``sample``, ``project``, ``outline`` (all parts' polygons),
    ``interval_hull``, ``plot``.
    """

    def __init__(self, parts: Sequence[Any]):
        self.parts = check_parts("PZUnion", list(parts))

    @property
    def dim(self) -> int:
        return int(self.parts[0].dim)

    @property
    def n_generators(self) -> int:
        return int(sum(p.n_generators for p in self.parts))

    def __repr__(self) -> str:
        return f"PZUnion(dim={self.dim}, parts={len(self.parts)})"

    def project(self, dims: Any) -> PZUnion:
        return PZUnion([p.project(dims) for p in self.parts])

    def support(self, d: Any, splits: int = 0) -> float | np.ndarray:
        """Max over the parts of their support upper bounds (:meth:`PolyZonotope.support`): an
        upper bound of the support function of the union of the parts as represented."""
        vals = np.array([np.atleast_1d(p.support(d, splits=splits)) for p in self.parts])
        out = vals.max(axis=0)
        return float(out[0]) if np.ndim(d) == 1 else out

    def contains(self, points: Any, splits: int = 0, tol: float = 1e-7) -> bool | np.ndarray:
        """Membership in the union of the parts *as represented*, each part tested by its own
        :meth:`PolyZonotope.contains` (an outer approximation: the zonotope enclosures of the part's
        pieces after ``splits`` splits, within ``tol``); a point is inside if some part says so.

        What the answer certifies, about the parts:

        * ``False``: the point lies in no part (the parts' tests have no false negatives), so it is
          outside the union of the polynomial zonotopes held here.
        * ``True``: the point lies in the enclosure of some part; it is *not* a proof that it lies
          in a part (the enclosure error shrinks as ``splits`` grows).

        Nothing here is certified about the true reachable set: the parts of an ``stt`` result are
        images of truncated STT polynomials (Foss Sec. 5; the truncation error is estimated, not
        bounded, and reductions add to the parts), so ``True`` does not prove that a trajectory
        reaches the point, and ``False`` does not prove that none does.  Used as a coverage test
        (Monte Carlo endpoints in the set) the coverage of the parts can be overstated, never
        understated.
        """
        P = np.atleast_2d(np.asarray(points, dtype=float))
        ok = np.zeros(P.shape[0], dtype=bool)
        for part in self.parts:
            todo = ~ok
            if not np.any(todo):
                break
            ok[todo] = np.atleast_1d(part.contains(P[todo], splits=splits, tol=tol))
        return bool(ok[0]) if np.ndim(points) == 1 else ok

    def sample(self, n: int, rng: Any = None, mode: str = "uniform") -> np.ndarray:
        """(n, dim) points: each drawn from a part chosen uniformly at random."""
        rng = np.random.default_rng(rng)
        counts = np.bincount(rng.integers(0, len(self.parts), size=int(n)), minlength=len(self.parts))
        return np.vstack([p.sample(int(c), rng, mode) for p, c in zip(self.parts, counts) if c > 0]
                         or [np.zeros((0, self.dim))])

    def outline(self, dims: Any = (0, 1), pieces: int = 64) -> list[np.ndarray]:
        """The parts' outer 2-D outlines (:meth:`PolyZonotope.outline`, ``pieces`` shared among
        the parts, at least 2 each): a list of convex polygons whose union covers the parts."""
        per = max(2, int(pieces) // len(self.parts))
        return [poly for p in self.parts for poly in p.outline(dims, pieces=per)]

    def interval_hull(self) -> Interval:
        from ocreach.sets.interval import Interval

        hulls = [p.interval_hull() for p in self.parts]
        return Interval(np.min([h.lo for h in hulls], axis=0), np.max([h.hi for h in hulls], axis=0))

    def plot(self, ax: Any, dims: Sequence[int] = (0, 1), **kw: Any) -> Any:
        """Draw every part's projection on ``dims`` (one label for the union)."""
        from ocreach.sets.plot import plot_set

        out = None
        for i, p in enumerate(self.parts):
            out = plot_set(p, ax, dims=dims, **(kw if i == 0 else {**kw, "label": None}))
        return out
