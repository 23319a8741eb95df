"""Multiple shooting with minimum-norm Newton updates (fixed patch times).

Patch states ``X_j`` at fixed times ``t_j``; constraints the arc-end defects
``F_j = phi(X_j; t_j, t_{j+1}) - X_{j+1}``; Jacobian blocks ``[Phi_j, -I]`` with ``Phi_j`` the
arc's STM from the model's variational equations (:func:`ocreach.dynamics.flow.stm_batch`); update the
minimum-norm solution ``dX = -DF^T (DF DF^T)^{-1} F`` of the linearised constraints (T. A.
Pavlak, M.S. thesis, Purdue University, 2010, Ch. 3; Pavlak & Howell, AIAA 2012-4665; cited from
memory).  Used by :mod:`ocreach.control.stationkeeping.ephemeris_reference` to turn a CR3BP orbit into a
continuous orbit of the DE421 model.
"""
from __future__ import annotations

import numpy as np

from ocreach.errors import SolverError, check_count
from ocreach.model import Model

#: Integrator tolerances of the arcs (DOP853).
ARC_RTOL, ARC_ATOL = 1e-12, 1e-14
#: Default bound on every defect component (model units).
DEFECT_TOL = 1e-9


def patch_defects(model: Model, times: np.ndarray, states: np.ndarray,
                  params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Arc-end defects ``F_j = phi(X_j; t_j, t_{j+1}) - X_{j+1}`` (n, n_x) and the arcs' STMs
    (n, n_x, n_x), the arcs integrated as one batch without control
    (:func:`ocreach.dynamics.flow.stm_batch`, DOP853 at ``ARC_RTOL``, ``ARC_ATOL``)."""
    from ocreach.dynamics.flow import stm_batch

    X1, Phi = stm_batch(model, states[:-1], times[:-1], times[1:], p=params, rtol=ARC_RTOL,
                        atol=ARC_ATOL)
    return X1 - states[1:], Phi


def min_norm_update(F: np.ndarray, Phi: np.ndarray) -> np.ndarray:
    """Minimum-norm solution ``dX`` (n + 1, 6) of ``DF dX = -F`` with ``DF`` of blocks
    ``[Phi_j, -I]`` (row block ``j``, column blocks ``j`` and ``j + 1``): Pavlak & Howell's
    ``dX = -DF^T (DF DF^T)^{-1} F``."""
    n, nx = F.shape
    DF = np.zeros((n * nx, (n + 1) * nx))
    for j in range(n):
        DF[j * nx:(j + 1) * nx, j * nx:(j + 1) * nx] = Phi[j]
        DF[j * nx:(j + 1) * nx, (j + 1) * nx:(j + 2) * nx] = -np.eye(nx)
    y = np.linalg.solve(DF @ DF.T, F.ravel())
    return -(DF.T @ y).reshape(n + 1, nx)


def multiple_shooting(model: Model, times: np.ndarray, seed: np.ndarray, params: np.ndarray, *,
                      tol: float = DEFECT_TOL,
                      max_iter: int = 30) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Correct the patch states ``seed`` (n + 1, n_x) at fixed ``times`` until every defect
    component is ``<= tol``: minimum-norm Newton steps (module doc), each halved (down to 1/1024)
    while it does not reduce ``|F|``.  Returns ``(states, defects, history)``, the history the
    largest defect per iteration.  Raises :class:`SolverError` if a step cannot reduce the
    defects or it does not converge in ``max_iter`` iterations."""
    max_iter = check_count("max_iter (Newton iterations)", max_iter, 1)
    X = np.array(seed, float)
    F, Phi = patch_defects(model, times, X, params)
    history = [float(np.max(np.abs(F)))]
    for _ in range(max_iter):
        if history[-1] <= tol:
            return X, F, history
        dX = min_norm_update(F, Phi)
        norm0, lam = np.linalg.norm(F), 1.0
        while True:  # halve the step while it does not reduce |F| (keeps a far seed in hand)
            X_try = X + lam * dX
            try:
                F_try, Phi_try = patch_defects(model, times, X_try, params)
                better = np.linalg.norm(F_try) < norm0
            except SolverError:
                better = False
            if better or lam < 1e-3:
                break
            lam *= 0.5
        if not better:
            raise SolverError(f"multiple shooting stalled at a largest defect of "
                              f"{history[-1]:.3g} (tol {tol:g}): no step of the minimum-norm "
                              f"Newton direction down to 1/1024 reduces the defects")
        X, F, Phi = X_try, F_try, Phi_try
        history.append(float(np.max(np.abs(F))))
    if history[-1] <= tol:
        return X, F, history
    raise SolverError(f"multiple shooting did not converge in {max_iter} iterations: "
                      f"largest defect {history[-1]:.3g} > tol {tol:g} (history "
                      f"{[f'{h:.2g}' for h in history]})")


__all__ = ["ARC_ATOL", "ARC_RTOL", "DEFECT_TOL", "min_norm_update", "multiple_shooting",
           "patch_defects"]
