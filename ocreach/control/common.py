"""Shared pieces of the controllers: weight validation, control units, thrust saturation.

Control units
-------------
Models use a *normalised* control ``u`` (``||u||_2 <= 1`` or ``|u_i| <= 1``) and a thrust
acceleration parameter ``a_max``.  Patel & Subbarao give ``Q`` and ``R`` in non-dimensional units
("state vectors ... as well as control inputs, are expressed in these nondimensional units"), i.e.
``R`` weighs the thrust *acceleration* ``a = a_max u`` in DU/TU^2.  With
``weights_in="acceleration"`` the controllers therefore use ``R_u = a_max^2 R`` on the normalised
control; ``weights_in="normalised"`` uses ``R`` as given.  ``"auto"`` picks ``"acceleration"``
when the model has an ``a_max`` parameter.
"""
from __future__ import annotations

import numpy as np

from ocreach.errors import ProblemError

WEIGHT_UNITS = ("auto", "acceleration", "normalised")


def as_weight(name: str, W, n: int, *, definite: bool) -> np.ndarray:
    """Validate a weight matrix (or its diagonal) of size ``n``; symmetric PSD (PD if ``definite``)."""
    try:
        M = np.asarray(W, dtype=float)
    except (TypeError, ValueError):
        raise ProblemError(f"{name} must be a numeric {n}x{n} matrix or a length-{n} diagonal; "
                           f"got {W!r}") from None
    if M.ndim == 1:
        M = np.diag(M)
    if M.shape != (n, n):
        raise ProblemError(f"{name} must be {n}x{n} (or a length-{n} diagonal); got shape "
                           f"{np.shape(W)}: {np.asarray(W).tolist()!r}")
    if not np.all(np.isfinite(M)):
        raise ProblemError(f"{name} must be finite; got {M.tolist()!r}")
    if not np.allclose(M, M.T, rtol=1e-10, atol=1e-12 * max(1.0, np.abs(M).max())):
        raise ProblemError(f"{name} must be symmetric; got {M.tolist()!r}")
    M = 0.5 * (M + M.T)
    lam_min = float(np.linalg.eigvalsh(M).min())
    scale = max(1.0, float(np.abs(M).max()))
    if definite and lam_min <= 1e-14 * scale:
        raise ProblemError(f"{name} must be positive definite; got {M.tolist()!r} "
                           f"(smallest eigenvalue {lam_min:.3g})")
    if not definite and lam_min < -1e-12 * scale:
        raise ProblemError(f"{name} must be positive semidefinite; got {M.tolist()!r} "
                           f"(smallest eigenvalue {lam_min:.3g})")
    return M


def check_thrust(model, params) -> None:
    """Raise :class:`ProblemError` if a thrust parameter (``a_max`` or ``T_max``) is not > 0."""
    for name in ("a_max", "T_max"):
        if name in model.param_names:
            val = model.param(name, params)
            if not np.isfinite(val) or val <= 0:
                raise ProblemError(f"{name} (thrust) must be a finite number > 0; got {val!r}")


def control_scale(model, params, weights_in: str = "auto") -> float:
    """Factor ``s`` with ``a = s u``: ``a_max`` for ``"acceleration"``, 1 for ``"normalised"``."""
    if weights_in not in WEIGHT_UNITS:
        raise ProblemError(f"weights_in must be one of {WEIGHT_UNITS}; got {weights_in!r}")
    has = "a_max" in model.param_names
    if weights_in == "normalised" or (weights_in == "auto" and not has):
        return 1.0
    if not has:
        raise ProblemError(f"weights_in='acceleration' needs a model with an 'a_max' parameter; "
                           f"model {model.name} has {list(model.param_names)}")
    a = model.param("a_max", params)
    if not np.isfinite(a) or a <= 0:
        raise ProblemError(f"a_max (thrust acceleration) must be > 0; got {a!r}")
    return float(a)


def thrust_ratio(u: np.ndarray, kind: str) -> np.ndarray:
    """``||u||`` over the limit, row-wise: Euclidean norm for ``"ball"``, max-norm for ``"box"``."""
    u = np.asarray(u, dtype=float)
    return np.linalg.norm(u, axis=-1) if kind == "ball" else np.max(np.abs(u), axis=-1)


def saturate(u: np.ndarray, kind: str) -> np.ndarray:
    """Project a normalised control onto the admissible set (radial scaling / clipping)."""
    u = np.asarray(u, dtype=float)
    if kind == "box":
        return np.clip(u, -1.0, 1.0)
    n = np.linalg.norm(u, axis=-1, keepdims=True)
    return u / np.maximum(n, 1.0)
