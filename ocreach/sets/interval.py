"""Axis-aligned boxes ``[lo, hi]`` (interval vectors)."""
from __future__ import annotations

from typing import Any

import numpy as np

from ocreach.errors import SetError
from ocreach.sets import dispatch
from ocreach.sets._base import (
    SetBase,
    as_dims,
    as_directions,
    as_points,
    as_vector,
    check_linear_map,
    factor_samples,
    ro,
)


class Interval(SetBase):
    """The box ``{x : lo <= x <= hi}`` (immutable)."""

    def __init__(self, lo: Any, hi: Any):
        lo_a = as_vector("Interval lo", lo)
        hi_a = as_vector("Interval hi", hi, lo_a.shape[0])
        if np.any(lo_a > hi_a):
            bad = np.flatnonzero(lo_a > hi_a)
            raise SetError(f"Interval needs lo <= hi; violated in dimensions {bad.tolist()} "
                           f"(lo={lo_a[bad]}, hi={hi_a[bad]})")
        self.lo = ro(lo_a)
        self.hi = ro(hi_a)
        self._freeze()

    # -- basic properties -------------------------------------------------------------------
    @property
    def dim(self) -> int:
        return int(self.lo.shape[0])

    @property
    def center(self) -> np.ndarray:
        return 0.5 * (self.lo + self.hi)

    @property
    def radius(self) -> np.ndarray:
        return 0.5 * (self.hi - self.lo)

    def __repr__(self) -> str:
        return f"Interval(lo={self.lo.tolist()}, hi={self.hi.tolist()})"

    # -- operations ------------------------------------------------------------------------
    def support(self, d: Any) -> np.ndarray | float:
        """Exact support function ``max_{x in I} d.x = d.c + |d|.r``."""
        D, single = as_directions(d, self.dim)
        val = D @ self.center + np.abs(D) @ self.radius
        return float(val[0]) if single else val

    def sample(self, n: int, rng: Any = None, mode: str = "uniform") -> np.ndarray:
        """(n, dim) samples: uniform in the box or at its vertices (``mode='extreme'``)."""
        f = factor_samples(n, self.dim, rng, mode)
        return self.center + f * self.radius

    def contains(self, points: Any, tol: float = 1e-9) -> np.ndarray:
        """Vectorised exact membership; returns a bool array (a bool for one point)."""
        P, single = as_points("points", points, self.dim)
        ok = np.all((P >= self.lo - tol) & (P <= self.hi + tol), axis=1)
        return bool(ok[0]) if single else ok

    def reduce(self, *args, **kwargs) -> Interval:
        """Intervals need no order reduction; returns ``self``."""
        return self

    def interval_hull(self) -> Interval:
        return self

    def to_zonotope(self):
        """Exact conversion to a :class:`~ocreach.sets.zonotope.Zonotope`: centre and one axis
        generator per non-degenerate dimension."""
        return dispatch.to_zonotope(self)

    def to_polyzonotope(self, ids: Any = None):
        """Exact conversion to a :class:`~ocreach.sets.polyzonotope.PolyZonotope` (fresh
        identifiers unless ``ids`` are given)."""
        return dispatch.to_polyzonotope(self, ids)

    def project(self, dims: Any) -> Interval:
        idx = as_dims(dims, self.dim)
        return Interval(self.lo[idx], self.hi[idx])

    def cartesian(self, other: Interval) -> Interval:
        if isinstance(other, Interval):
            return Interval(np.concatenate([self.lo, other.lo]), np.concatenate([self.hi, other.hi]))
        return self.to_zonotope().cartesian(other)

    def __add__(self, other):
        if isinstance(other, Interval):
            if other.dim != self.dim:
                raise SetError(f"Minkowski sum: dimensions differ ({self.dim} vs {other.dim})")
            return Interval(self.lo + other.lo, self.hi + other.hi)
        if isinstance(other, SetBase):
            return self.to_zonotope() + other
        v = np.asarray(other, dtype=float)
        if v.ndim in (0, 1):
            v = np.broadcast_to(v, (self.dim,)) if v.ndim == 0 else as_vector("translation", v, self.dim)
            return Interval(self.lo + v, self.hi + v)
        return NotImplemented

    def __rmatmul__(self, M):
        """Linear map ``M @ I`` (a zonotope in general)."""
        return check_linear_map(M, self.dim) @ self.to_zonotope()

    def volume(self) -> float:
        return float(np.prod(self.hi - self.lo))

    def outline(self, dims: Any = (0, 1)) -> np.ndarray:
        """Counter-clockwise vertices (4, 2) of the projection on two dimensions."""
        P = self.project(dims)
        if P.dim != 2:
            raise SetError(f"outline needs two dims; got {dims!r}")
        (x0, y0), (x1, y1) = P.lo, P.hi
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
