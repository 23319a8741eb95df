"""Matrix zonotopes ``{C + sum_j lambda_j G_j : lambda in [-1, 1]^q}`` (Althoff; Patel & Subbarao Eq. 21)."""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ocreach.errors import SetError
from ocreach.sets._base import SetBase, as_rng, ro


class MatrixZonotope:
    """Matrix zonotope with centre ``C`` (m, n) and generator matrices ``G_j`` (q, m, n)."""

    def __init__(self, C: Any, gens: Sequence[Any] | np.ndarray = ()):
        C_a = np.asarray(C, dtype=float)
        if C_a.ndim != 2:
            raise SetError(f"MatrixZonotope centre C must be a matrix; got shape {C_a.shape}")
        G_a = np.asarray(gens, dtype=float)
        if G_a.size == 0:
            G_a = np.zeros((0, *C_a.shape))
        if G_a.ndim != 3 or G_a.shape[1:] != C_a.shape:
            raise SetError(f"MatrixZonotope generators must have shape (q, {C_a.shape[0]}, {C_a.shape[1]}); "
                           f"got {G_a.shape}")
        if not (np.all(np.isfinite(C_a)) and np.all(np.isfinite(G_a))):
            raise SetError("MatrixZonotope entries must be finite")
        self.C = ro(C_a)
        self.G = ro(G_a)
        object.__setattr__(self, "_frozen", True)

    def __setattr__(self, key, value):  # immutable after construction, like the sets
        if getattr(self, "_frozen", False):
            raise AttributeError("MatrixZonotope is immutable")
        object.__setattr__(self, key, value)

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.C.shape)

    @property
    def n_generators(self) -> int:
        return int(self.G.shape[0])

    def __repr__(self) -> str:
        return f"MatrixZonotope(shape={self.shape}, generators={self.n_generators})"

    def evaluate(self, lam: Any) -> np.ndarray:
        """Matrices ``C + sum_j lam_j G_j`` for lam (q,) or (N, q)."""
        L = np.asarray(lam, dtype=float)
        return self.C + np.tensordot(L, self.G, axes=([-1], [0]))

    def sample(self, n: int, rng: Any = None, mode: str = "uniform") -> np.ndarray:
        from ocreach.sets._base import factor_samples

        return self.evaluate(factor_samples(n, self.n_generators, as_rng(rng), mode))

    def __add__(self, other: MatrixZonotope) -> MatrixZonotope:
        if isinstance(other, MatrixZonotope):
            if other.shape != self.shape:
                raise SetError(f"MatrixZonotope sum: shapes differ ({self.shape} vs {other.shape})")
            return MatrixZonotope(self.C + other.C, np.concatenate([self.G, other.G]))
        M = np.asarray(other, dtype=float)
        if M.shape == self.shape:
            return MatrixZonotope(self.C + M, self.G)
        return NotImplemented

    def __matmul__(self, other):
        """``MZ @ Z`` (outer approximation, see :func:`matzonotope_times_zonotope`) or ``MZ @ x``."""
        from ocreach.sets.interval import Interval
        from ocreach.sets.zonotope import Zonotope

        if isinstance(other, Interval):
            other = other.to_zonotope()
        if isinstance(other, Zonotope):
            return matzonotope_times_zonotope(self, other)
        if isinstance(other, SetBase):
            raise SetError(f"MatrixZonotope @ {type(other).__name__} is not supported; use a Zonotope")
        x = np.asarray(other, dtype=float)
        if x.ndim == 1:
            return matzonotope_times_zonotope(self, Zonotope(x))
        return NotImplemented


def matzonotope_times_zonotope(MZ: MatrixZonotope, Z) -> Zonotope:  # noqa: F821
    """Outer zonotope of ``{A x : A in MZ, x in Z}`` (Althoff's matrix-zonotope product; Patel &
    Subbarao Eq. 23-24): with ``x = c + G xi`` and ``A = C + sum_j lambda_j A_j``,

        A x = C c + C G xi + sum_j lambda_j A_j c + sum_{j,i} (lambda_j xi_i) A_j g_i,

    and each product ``lambda_j xi_i`` in [-1, 1] becomes its own factor (sound, exact if q = 0).
    Generators: ``[C G, A_j c, A_j G]``.
    """
    from ocreach.sets.zonotope import Zonotope

    m, n = MZ.shape
    if Z.dim != n:
        raise SetError(f"MatrixZonotope @ Zonotope: matrix has {n} columns, zonotope dimension {Z.dim}")
    return Zonotope(*matzonotope_product(MZ.C, MZ.G, Z.c, Z.G))


def matzonotope_product(C: np.ndarray, Gs: np.ndarray, c: np.ndarray, G: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Centre and generators (zero generators removed) of :func:`matzonotope_times_zonotope` for
    the arrays of a matrix zonotope ``(C (m, n), Gs (q, m, n))`` and a zonotope ``(c, G)``, without
    the set objects' validation (for the inner loop of ``sdc``, whose inputs are checked)."""
    m = C.shape[0]
    Ac = Gs @ c  # (q, m)
    AG = np.einsum("jmn,nh->mjh", Gs, G).reshape(m, -1)
    Gout = np.concatenate([C @ G, Ac.T, AG], axis=1)
    return C @ c, Gout[:, np.any(Gout != 0, axis=0)]   # a NaN column is kept (never hidden)
