"""Ellipsoids ``{x : (x-q)^T Q^-1 (x-q) <= 1}`` with symmetric positive semi-definite ``Q``."""
from __future__ import annotations

from typing import Any

import numpy as np

from ocreach.errors import SetError
from ocreach.sets import dispatch
from ocreach.sets._base import (
    SetBase,
    as_dims,
    as_directions,
    as_matrix,
    as_rng,
    as_vector,
    check_linear_map,
    ro,
)
from ocreach.sets.interval import Interval
from ocreach.sets.zonotope import Zonotope


class Ellipsoid(SetBase):
    """Ellipsoid with centre ``q`` and shape matrix ``Q`` (``x = q + L u``, ``||u||_2 <= 1``, ``Q = L L^T``)."""

    def __init__(self, q: Any, Q: Any):
        q_a = as_vector("Ellipsoid centre q", q)
        n = q_a.shape[0]
        Q_a = as_matrix("Ellipsoid shape matrix Q", np.atleast_2d(np.asarray(Q, float)), rows=n, cols=n)
        scale = max(1.0, float(np.abs(Q_a).max(initial=0.0)))
        if not np.allclose(Q_a, Q_a.T, atol=1e-12 * scale, rtol=1e-10):
            raise SetError("Ellipsoid shape matrix Q must be symmetric; got max |Q - Q^T| = "
                           f"{float(np.abs(Q_a - Q_a.T).max()):.3g}")
        Q_a = 0.5 * (Q_a + Q_a.T)
        w, V = np.linalg.eigh(Q_a)
        if w.min(initial=0.0) < -1e-10 * scale:
            raise SetError(f"Ellipsoid shape matrix Q must be positive semi-definite; smallest eigenvalue {w.min():.3g}")
        w = np.clip(w, 0.0, None)
        self.q = ro(q_a)
        self.Q = ro(Q_a)
        self.eig = (ro(w), ro(V))
        self.L = ro(V * np.sqrt(w)[None, :])
        self._freeze()

    @property
    def dim(self) -> int:
        return int(self.q.shape[0])

    def __repr__(self) -> str:
        return f"Ellipsoid(dim={self.dim})"

    def support(self, d: Any) -> np.ndarray | float:
        """Exact support function ``d.q + sqrt(d^T Q d)``."""
        D, single = as_directions(d, self.dim)
        val = D @ self.q + np.sqrt(np.maximum(np.einsum("ka,ab,kb->k", D, self.Q, D), 0.0))
        return float(val[0]) if single else val

    def sample(self, n: int, rng: Any = None, mode: str = "uniform") -> np.ndarray:
        """(n, dim) points: uniform in the ellipsoid, or on its boundary (``mode='extreme'``)."""
        g = as_rng(rng)
        if mode not in ("uniform", "extreme"):
            raise SetError(f"sample: mode must be 'uniform' or 'extreme'; got {mode!r}")
        U = g.standard_normal((int(n), self.dim))
        U /= np.maximum(np.linalg.norm(U, axis=1, keepdims=True), 1e-300)
        if mode == "uniform":
            U *= g.uniform(0.0, 1.0, size=(int(n), 1)) ** (1.0 / self.dim)
        return self.q + U @ self.L.T

    def contains(self, points: Any, tol: float = 1e-9) -> np.ndarray:
        return dispatch.contains(self, points, tol)

    def reduce(self, *args, **kwargs) -> Ellipsoid:
        return self

    def interval_hull(self) -> Interval:
        r = np.sqrt(np.diag(self.Q))
        return Interval(self.q - r, self.q + r)

    def to_zonotope(self, k: int | None = None) -> Zonotope:
        """Outer zonotope with ``k`` generators (default: 2n in 2-D... see
        :func:`ocreach.sets.convert.unit_ball_zonotope`)."""
        return dispatch.to_zonotope(self, k)

    def project(self, dims: Any) -> Ellipsoid:
        idx = as_dims(dims, self.dim)
        return Ellipsoid(self.q[idx], self.Q[np.ix_(idx, idx)])

    def __rmatmul__(self, M) -> Ellipsoid:
        """Linear map ``M @ E = Ellipsoid(M q, M Q M^T)`` (exact)."""
        A = check_linear_map(M, self.dim)
        return Ellipsoid(A @ self.q, A @ self.Q @ A.T)

    def __add__(self, other):
        if isinstance(other, SetBase):
            raise SetError("Minkowski sum of an ellipsoid with a set is not an ellipsoid; "
                           "convert with to_zonotope(k) first")
        v = np.asarray(other, dtype=float)
        if v.ndim == 1:
            return Ellipsoid(self.q + as_vector("translation", v, self.dim), self.Q)
        return NotImplemented

    def outline(self, dims: Any = (0, 1), k: int = 200) -> np.ndarray:
        """(k, 2) points on the boundary of the 2-D projection, counter-clockwise."""
        P = self.project(dims)
        if P.dim != 2:
            raise SetError(f"outline needs two dims; got {dims!r}")
        t = np.linspace(0, 2 * np.pi, k, endpoint=False)
        return P.q + np.column_stack([np.cos(t), np.sin(t)]) @ P.L.T

    def volume(self) -> float:
        from math import gamma, pi

        n = self.dim
        return float(pi ** (n / 2) / gamma(n / 2 + 1) * np.sqrt(max(np.linalg.det(self.Q), 0.0)))
