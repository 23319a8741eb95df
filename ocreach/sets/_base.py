"""Shared helpers of the set library: read-only arrays, argument checks, identifiers, RNGs.

Private module; the public names are re-exported by :mod:`ocreach.sets`.
"""
from __future__ import annotations

import itertools
import threading
from typing import Any

import numpy as np

from ocreach.errors import SetError
from ocreach.sets import dispatch

_ID_COUNTER = itertools.count(1)
_ID_LOCK = threading.Lock()


def new_ids(k: int) -> np.ndarray:
    """Return ``k`` fresh, globally unique integer factor identifiers (module-level counter).

    Polynomial zonotopes created from independent sources must use disjoint identifiers so that
    the exact Minkowski sum / Cartesian product keeps them independent (Foss et al. Sec. 2.4,
    "each input set must have a unique set of identifiers").
    """
    k = int(k)
    if k < 0:
        raise SetError(f"new_ids: k must be >= 0; got {k}")
    with _ID_LOCK:
        return np.array([next(_ID_COUNTER) for _ in range(k)], dtype=np.int64)


def ro(a: Any, dtype=float) -> np.ndarray:
    """A read-only copy of ``a`` as a numpy array."""
    arr = np.array(a, dtype=dtype, copy=True)
    arr.setflags(write=False)
    return arr


def _floats(name: str, v: Any) -> np.ndarray:
    """``np.asarray(v, float)``, or a :class:`SetError` naming ``name`` (ragged lists, text)."""
    try:
        return np.asarray(v, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise SetError(f"{name} must be an array of numbers; got {v!r}") from None


def as_vector(name: str, v: Any, n: int | None = None) -> np.ndarray:
    """Validate a finite 1-D vector (of length ``n`` if given)."""
    arr = _floats(name, v)
    if arr.ndim == 0 and n is None:
        arr = arr.reshape(1)
    if arr.ndim != 1:
        raise SetError(f"{name} must be a 1-D vector; got shape {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise SetError(f"{name} must have length {n}; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise SetError(f"{name} must be finite; got {arr!r}")
    return arr


def as_matrix(name: str, M: Any, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    """Validate a finite 2-D matrix with the given row/column counts."""
    arr = _floats(name, M)
    if arr.ndim == 1 and rows is not None and arr.size == 0:
        arr = arr.reshape(rows, 0)
    if arr.ndim != 2:
        raise SetError(f"{name} must be a 2-D matrix; got shape {arr.shape}")
    if rows is not None and arr.shape[0] != rows:
        raise SetError(f"{name} must have {rows} rows; got shape {arr.shape}")
    if cols is not None and arr.shape[1] != cols:
        raise SetError(f"{name} must have {cols} columns; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise SetError(f"{name} must be finite")
    return arr


def as_points(name: str, points: Any, n: int) -> tuple[np.ndarray, bool]:
    """Points as an (N, n) array; the flag says whether a single point (n,) was given."""
    arr = np.asarray(points, dtype=float)
    single = arr.ndim == 1
    if single:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != n:
        raise SetError(f"{name} must have shape (n,) or (N, n) with n={n}; got {np.shape(points)}")
    if not np.all(np.isfinite(arr)):
        raise SetError(f"{name} must be finite")
    return arr, single


def as_directions(d: Any, n: int) -> tuple[np.ndarray, bool]:
    """Directions as (K, n); flag says whether one direction was given."""
    return as_points("direction d", d, n)


def as_dims(dims: Any, n: int) -> np.ndarray:
    """Validate dimension indices for a projection."""
    idx = np.atleast_1d(np.asarray(dims))
    if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer):
        raise SetError(f"dims must be a non-empty sequence of integers; got {dims!r}")
    if np.any(idx < 0) or np.any(idx >= n):
        raise SetError(f"dims must lie in 0..{n - 1}; got {dims!r}")
    return idx.astype(np.int64)


def as_rng(rng: Any) -> np.random.Generator:
    """``None``/int seed/Generator -> Generator."""
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(rng)


def factor_samples(num: int, k: int, rng: Any, mode: str) -> np.ndarray:
    """(num, k) factor values in [-1, 1]: ``uniform`` or ``extreme`` (each factor +-1)."""
    if int(num) < 0:
        raise SetError(f"sample: n must be >= 0; got {num}")
    g = as_rng(rng)
    if mode == "uniform":
        return g.uniform(-1.0, 1.0, size=(int(num), k))
    if mode == "extreme":
        return g.choice(np.array([-1.0, 1.0]), size=(int(num), k))
    raise SetError(f"sample: mode must be 'uniform' or 'extreme'; got {mode!r}")


def check_parts(kind: str, parts: list) -> tuple:
    """``parts`` as a tuple, or a :class:`SetError` naming ``kind`` if it is empty or the parts'
    dimensions differ (the part check of the union sets)."""
    if not parts:
        raise SetError(f"{kind} needs at least one part")
    dims = {p.dim for p in parts}
    if len(dims) != 1:
        raise SetError(f"{kind} parts must share one dimension; got {sorted(dims)}")
    return tuple(parts)


def check_linear_map(M: Any, n: int) -> np.ndarray:
    """Validate a (m, n) linear map (a scalar is allowed and means s*I)."""
    arr = np.asarray(M, dtype=float)
    if arr.ndim == 0:
        return float(arr) * np.eye(n)
    return as_matrix("linear map M", arr, cols=n)


class SetBase:
    """Common behaviour of every set: immutability, plotting, radd."""

    __slots__ = ()
    __array_ufunc__ = None  # make ``ndarray @ set`` / ``ndarray + set`` defer to the set's operators

    def __setattr__(self, key, value):  # immutable after construction
        if getattr(self, "_frozen", False):
            raise AttributeError(f"{type(self).__name__} is immutable")
        object.__setattr__(self, key, value)

    def _freeze(self) -> None:
        object.__setattr__(self, "_frozen", True)

    def __radd__(self, other):
        return self.__add__(other)

    def __sub__(self, other):
        v = np.asarray(other, dtype=float)
        if v.ndim == 1:
            return self.__add__(-v)
        return NotImplemented

    def plot(self, ax, dims=(0, 1), **kw):
        """Plot the 2-D projection on ``dims`` into matplotlib axes ``ax`` (see :mod:`ocreach.sets.plot`)."""
        return dispatch.plot(self, ax, dims=dims, **kw)

    def containment_constraints(self, x):
        """cvxpy constraints ``x in self`` and the latent factor variable (or None)."""
        return dispatch.containment_constraints(self, x)

    def casadi_containment(self, x_sym):
        """CasADi containment ``g(x, xi)`` with bounds; see :func:`ocreach.sets.contains.casadi_containment`."""
        return dispatch.casadi_containment(self, x_sym)
