"""Zonotopes ``Z = {c + G xi : ||xi||_inf <= 1}`` (Patel & Subbarao Eq. 2-3)."""
from __future__ import annotations

import itertools
from math import comb
from typing import Any

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
    ro,
)
from ocreach.sets.interval import Interval

#: largest number of n-subsets summed by :meth:`Zonotope.volume`
VOLUME_MAX_SUBSETS = 3_000_000


class Zonotope(SetBase):
    """Zonotope with centre ``c`` (n,) and generator matrix ``G`` (n, h); ``h = 0`` is a point."""

    def __init__(self, c: Any, G: Any = None):
        c_a = as_vector("Zonotope centre c", c)
        n = c_a.shape[0]
        G_a = np.zeros((n, 0)) if G is None else as_matrix("Zonotope generators G", G, rows=n)
        self.c = ro(c_a)
        self.G = ro(G_a)
        self._freeze()

    @classmethod
    def trusted(cls, c: np.ndarray, G: np.ndarray) -> Zonotope:
        """Fast constructor for internal set arithmetic: ``c`` (n,) and ``G`` (n, h) float arrays
        of matching shape, neither validated nor copied (read-only views).  The caller checks
        finiteness (e.g. the zonotope methods check every step's sets once)."""
        self = object.__new__(cls)
        cv, Gv = c.view(), G.view()
        cv.setflags(write=False)
        Gv.setflags(write=False)
        object.__setattr__(self, "c", cv)
        object.__setattr__(self, "G", Gv)
        self._freeze()
        return self

    @property
    def dim(self) -> int:
        return int(self.c.shape[0])

    @property
    def n_generators(self) -> int:
        return int(self.G.shape[1])

    @property
    def order(self) -> float:
        return self.n_generators / self.dim

    def __repr__(self) -> str:
        return f"Zonotope(dim={self.dim}, generators={self.n_generators})"

    # -- exact operations --------------------------------------------------------------------
    def evaluate(self, xi: Any) -> np.ndarray:
        """Points ``c + G xi`` for factor values xi (h,) or (N, h)."""
        X = np.asarray(xi, dtype=float)
        if X.shape[-1] != self.n_generators:
            raise SetError(f"evaluate: xi must have last dimension {self.n_generators}; got {X.shape}")
        return self.c + X @ self.G.T

    def __rmatmul__(self, M):
        """Linear map ``M @ Z`` with M of shape (m, n) (exact)."""
        A = check_linear_map(M, self.dim)
        return Zonotope(A @ self.c, A @ self.G)

    def __add__(self, other):
        """Minkowski sum with a zonotope/interval (Patel & Subbarao Eq. 3) or a translation vector."""
        if isinstance(other, Interval):
            other = other.to_zonotope()
        if isinstance(other, Zonotope):
            if other.dim != self.dim:
                raise SetError(f"Minkowski sum: dimensions differ ({self.dim} vs {other.dim})")
            return Zonotope(self.c + other.c, np.hstack([self.G, other.G]))
        if isinstance(other, SetBase):
            return NotImplemented
        v = np.asarray(other, dtype=float)
        if v.ndim == 1:
            return Zonotope(self.c + as_vector("translation", v, self.dim), self.G)
        return NotImplemented

    def __neg__(self) -> Zonotope:
        return Zonotope(-self.c, self.G)

    def cartesian(self, other) -> Zonotope:
        """Cartesian product ``Z1 x Z2`` (exact)."""
        if isinstance(other, Interval):
            other = other.to_zonotope()
        if not isinstance(other, Zonotope):
            raise SetError(f"cartesian: expected a Zonotope or Interval; got {type(other).__name__}")
        n1, n2 = self.dim, other.dim
        G = np.zeros((n1 + n2, self.n_generators + other.n_generators))
        G[:n1, : self.n_generators] = self.G
        G[n1:, self.n_generators:] = other.G
        return Zonotope(np.concatenate([self.c, other.c]), G)

    def project(self, dims: Any) -> Zonotope:
        """Exact projection onto the coordinates ``dims`` (rows of ``c`` and ``G``)."""
        idx = as_dims(dims, self.dim)
        return Zonotope(self.c[idx], self.G[idx])

    def remove_zero_generators(self, tol: float = 0.0) -> Zonotope:
        keep = np.any(np.abs(self.G) > tol, axis=0)
        return Zonotope(self.c, self.G[:, keep])

    # -- enclosures / queries ---------------------------------------------------------------
    def interval_hull(self) -> Interval:
        """Tightest enclosing box: ``c -+ sum_i |g_i|`` (the support function along the axes)."""
        r = np.abs(self.G).sum(axis=1)
        return Interval(self.c - r, self.c + r)

    def to_zonotope(self) -> Zonotope:
        return self

    def to_polyzonotope(self, ids: Any = None):
        """Exact conversion to a :class:`~ocreach.sets.polyzonotope.PolyZonotope` (fresh
        identifiers unless ``ids`` are given)."""
        return dispatch.to_polyzonotope(self, ids)

    def support(self, d: Any) -> np.ndarray | float:
        """Exact support function ``d.c + sum_i |d.g_i|``."""
        D, single = as_directions(d, self.dim)
        val = D @ self.c + np.abs(D @ self.G).sum(axis=1)
        return float(val[0]) if single else val

    def sample(self, n: int, rng: Any = None, mode: str = "uniform") -> np.ndarray:
        """(n, dim) points from uniform factors (``'uniform'``) or factors +-1 (``'extreme'``)."""
        return self.evaluate(factor_samples(n, self.n_generators, rng, mode))

    def contains(self, points: Any, tol: float = 1e-7) -> np.ndarray:
        """Exact batched point membership (see :func:`ocreach.sets.contains.points_in_zonotope`)."""
        return dispatch.contains(self, points, tol)

    def reduce(self, order: float = 1.0, method: str = "girard") -> Zonotope:
        """Sound order reduction (Girard 2005 or PCA, Kopetzki et al. 2017); see
        :func:`ocreach.sets.reduce.reduce_zonotope`."""
        return dispatch.reduce(self, order, method)

    def split(self, j: int | None = None) -> tuple[Zonotope, Zonotope]:
        """Split along generator ``j`` (default: the longest); the union of the halves contains ``Z``
        rigorously: the rounding error of the centres ``c -+ g/2`` is computed exactly (TwoSum,
        :func:`ocreach.sets.rounding.two_sum_error`) and, where it is not 0, added to both halves
        as a box (so the halves may have up to ``n`` more generators)."""
        h = self.n_generators
        if h == 0:
            raise SetError("split: the zonotope has no generators")
        if j is None:
            j = int(np.argmax(np.linalg.norm(self.G, axis=0)))
        if not 0 <= int(j) < h:
            raise SetError(f"split: generator index j must lie in 0..{h - 1}; got {j}")
        from ocreach.sets.rounding import two_sum_error

        g = self.G[:, j] / 2.0
        G = self.G.copy()
        G[:, j] = g
        r = np.abs(self.G[:, j] - 2.0 * g)   # halving is exact unless g is subnormal
        ca, ea = two_sum_error(self.c, -g)
        cb, eb = two_sum_error(self.c, g)
        r = np.maximum(r, np.maximum(np.abs(ea), np.abs(eb)))
        if np.any(r > 0):
            r = np.nextafter(r, np.inf) * (r > 0)
            G = np.hstack([G, np.diag(r)[:, r > 0]])
        return Zonotope(ca, G), Zonotope(cb, G)

    def vertices(self) -> np.ndarray:
        """All candidate vertices ``c + G s``, s in {-1, 1}^h (for small h; includes non-extreme points)."""
        h = self.n_generators
        if h > 20:
            raise SetError(f"vertices: 2^h candidates are enumerated; h={h} > 20 is not allowed")
        S = np.array(list(itertools.product([-1.0, 1.0], repeat=h))).reshape(-1, h)
        return self.evaluate(S)

    def outline(self, dims: Any = (0, 1)) -> np.ndarray:
        """Exact counter-clockwise polygon (k, 2) of the 2-D projection on ``dims``."""
        Z = self.project(dims)
        if Z.dim != 2:
            raise SetError(f"outline needs two dims; got {dims!r}")
        return zonotope_polygon(Z.c, Z.G)

    def area(self, dims: Any = (0, 1)) -> float:
        """Exact area of the 2-D projection on ``dims``."""
        return polygon_area(self.outline(dims))

    def volume(self) -> float:
        """Exact volume: ``2^n sum_{n-subsets S} |det G_S|`` (zero if h < n)."""
        n, h = self.dim, self.n_generators
        if h < n:
            return 0.0
        total_subsets = comb(h, n)
        if total_subsets > VOLUME_MAX_SUBSETS:
            raise SetError(f"volume: C(h={h}, n={n}) = {total_subsets} subsets exceeds {VOLUME_MAX_SUBSETS}; "
                           "reduce the zonotope first")
        total = 0.0
        it = itertools.combinations(range(h), n)
        chunk = 200_000
        while True:
            idx = np.fromiter(itertools.chain.from_iterable(itertools.islice(it, chunk)), dtype=np.int64)
            if idx.size == 0:
                break
            idx = idx.reshape(-1, n)
            mats = self.G[:, idx].transpose(1, 0, 2)  # (K, n, n)
            total += float(np.abs(np.linalg.det(mats)).sum())
        return total * 2.0**n


def zonotope_polygon(c: np.ndarray, G: np.ndarray) -> np.ndarray:
    """Vertices of a 2-D zonotope, counter-clockwise, starting at the lowest vertex."""
    G = np.asarray(G, float)
    G = G[:, np.any(G != 0, axis=0)]
    if G.shape[1] == 0:
        return np.asarray(c, float)[None, :]
    flip = (G[1] < 0) | ((G[1] == 0) & (G[0] < 0))
    G = np.where(flip, -G, G)
    ang = np.arctan2(G[1], G[0])
    G = G[:, np.argsort(ang, kind="stable")]
    start = c - G.sum(axis=1)
    steps = np.hstack([2 * G, -2 * G]).T
    verts = start + np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)[:-1]])
    return verts


def polygon_area(P: np.ndarray) -> float:
    """Area of a simple polygon by the shoelace formula (vertices (k, 2), any orientation)."""
    P = np.asarray(P, float)
    if P.ndim != 2 or P.shape[1] != 2:
        raise SetError(f"polygon_area: vertices must have shape (k, 2); got {P.shape}")
    if P.shape[0] < 3:
        return 0.0
    x, y = P[:, 0], P[:, 1]
    return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


@dispatch.to_zonotope.register(Interval)
def _interval_to_zonotope(I: Interval) -> Zonotope:
    """Interval -> zonotope (exact): centre and one axis generator per non-degenerate dimension."""
    r = I.radius
    keep = r > 0
    return Zonotope(I.center, np.diag(r)[:, keep])
