"""Minimum-norm solutions of small linear systems on a box, batched over many systems.

For each system ``k`` (``J_k`` of shape (n, m), ``n`` small, ``m >= n`` unknowns)

    dz_k = argmin  1/2 |dz|^2 + 1/(2 mu_k) |J_k dz - r_k|^2   s.t.  lo_k <= dz <= hi_k,

with ``lo_k <= 0 <= hi_k``; for ``mu_k = 0`` the misfit term is the constraint ``J_k dz = r_k``
(the minimum-norm point of the system's solutions in the box).  This is the step of a
Levenberg-Marquardt method with the bounds held exactly (``mu`` its damping), and for ``mu = 0``
and a zonotope's generators ``J = G`` the membership of ``r`` in ``{G xi : |xi|_inf <= 1}``.

The dual has only ``n`` unknowns (Bertsekas, *Nonlinear Programming*, Sec. 6.1; the same
construction as the dual of bound-constrained least-norm problems in semismooth Newton methods,
Qi & Sun 1993): stationarity of the Lagrangian gives ``dz(nu) = clip(J^T nu, lo, hi)`` and the
multiplier solves

    F(nu) = J clip(J^T nu, lo, hi) + mu nu - r = 0,

the gradient of the convex, piecewise quadratic, continuously differentiable function
``theta(nu) = sum_i psi_i((J^T nu)_i) + mu/2 |nu|^2 - nu^T r`` with
``psi(s) = max_{lo <= t <= hi} (s t - t^2/2)``.  :func:`box_min_norm` minimises ``theta`` by
semismooth Newton steps (generalised Hessian ``J_F J_F^T + mu I`` over the free components
``lo < (J^T nu)_i < hi``, regularised by ``REG |F|`` times the size of ``J`` where the free
components do not span) with an Armijo backtracking line search (a full step is also taken when
it halves ``|F|``: near the solution the decrease of ``theta`` drowns in its rounding),
vectorised over the systems.  The iterate ``dz(nu)`` lies in the box at every iteration;
when the system has no solution in the box (``mu = 0``), ``theta`` is unbounded below along a
direction ``d`` with ``d^T r > sum_i max(d^T J_i lo_i, d^T J_i hi_i)``, and ``nu`` grows along such
a direction (which the callers test as a separating-hyperplane certificate).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the Newton matrix's regularisation, times |F| and the size of J (Levenberg-Marquardt style:
#: bounded steps where the free components do not span, quadratic convergence as F -> 0)
REG = 1e-3


@dataclass(frozen=True)
class BoxSolution:
    """``dz`` (N, m) in the box, the multipliers ``nu`` (N, n) and the optimality residual
    ``F(nu) = J dz + mu nu - r`` (N, n)."""

    dz: np.ndarray
    nu: np.ndarray
    residual: np.ndarray


class _Shared:
    """One matrix ``J`` (n, m) for every system."""

    def __init__(self, J: np.ndarray):
        self.J = J
        n = J.shape[0]
        self.JJ = (J[:, None, :] * J[None, :, :]).reshape(n * n, -1).T      # (m, n^2)
        self.n = n

    def T(self, nu: np.ndarray, idx: np.ndarray) -> np.ndarray:          # J^T nu, (N, m)
        return nu @ self.J

    def apply(self, dz: np.ndarray, idx: np.ndarray) -> np.ndarray:      # J dz, (N, n)
        return dz @ self.J.T

    def gram(self, w: np.ndarray, idx: np.ndarray) -> np.ndarray:        # J diag(w) J^T, (N, n, n)
        return (w @ self.JJ).reshape(-1, self.n, self.n)


class _Batched:
    """One matrix ``J_k`` (n, m) per system."""

    def __init__(self, J: np.ndarray):
        self.J = J
        self.n = J.shape[1]

    def T(self, nu, idx):
        return np.matmul(nu[:, None, :], self.J[idx])[:, 0]

    def apply(self, dz, idx):
        return np.matmul(self.J[idx], dz[:, :, None])[..., 0]

    def gram(self, w, idx):
        J = self.J[idx]
        return np.matmul(J * w[:, None, :], J.transpose(0, 2, 1))


def _theta(s: np.ndarray, lo: np.ndarray, hi: np.ndarray, nu: np.ndarray, mu: np.ndarray,
           r: np.ndarray) -> np.ndarray:
    t = np.clip(s, lo, hi)
    with np.errstate(over="ignore", invalid="ignore"):        # diverging multipliers: inf, refused
        return ((s * t - 0.5 * t * t).sum(axis=1) + 0.5 * mu * (nu * nu).sum(axis=1)
                - (nu * r).sum(axis=1))


def box_min_norm(J: np.ndarray, r: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 mu: float | np.ndarray = 0.0, nu: np.ndarray | None = None, iters: int = 30,
                 tol: float | np.ndarray = 0.0) -> BoxSolution:
    """Solve the batched problem of the module docstring.

    ``J``: (n, m) shared by all systems, or (N, n, m); ``r``: (N, n); ``lo``, ``hi``: (m,) or
    (N, m) with ``lo <= 0 <= hi``; ``mu``: scalar or (N,), ``>= 0``; ``nu``: starting multipliers
    (N, n) (default 0); at most ``iters`` Newton steps, a system stops when
    ``|F(nu)|_inf <= tol`` (scalar or (N,)).  The returned ``dz`` is in the box whether or not a
    system converged; the caller decides what a solution proves (e.g. by its own residual)."""
    r = np.atleast_2d(np.asarray(r, dtype=float))
    N, n = r.shape
    op = _Shared(np.asarray(J, float)) if np.ndim(J) == 2 else _Batched(np.asarray(J, float))
    m = op.J.shape[-1]
    lo = np.broadcast_to(np.asarray(lo, float), (N, m))
    hi = np.broadcast_to(np.asarray(hi, float), (N, m))
    mu = np.broadcast_to(np.asarray(mu, float), (N,)).copy()
    tol = np.broadcast_to(np.asarray(tol, float), (N,))
    nu = np.zeros((N, n)) if nu is None else np.array(nu, dtype=float)
    scale = op.gram(np.ones((N, m)), np.arange(N))
    ridge = 1e-12 * np.trace(scale, axis1=1, axis2=2) / n + 1e-300
    root = np.sqrt(np.trace(scale, axis1=1, axis2=2) / n)
    s = op.T(nu, np.arange(N))
    dz = np.clip(s, lo, hi)
    F = op.apply(dz, np.arange(N)) + mu[:, None] * nu - r
    active = np.abs(F).max(axis=1) > tol
    eye = np.eye(n)
    for _ in range(int(iters)):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        sa, la, ha = s[idx], lo[idx], hi[idx]
        free = ((sa > la) & (sa < ha)).astype(float)
        reg = mu[idx] + ridge[idx] + REG * np.linalg.norm(F[idx], axis=1) * root[idx]
        H = op.gram(free, idx) + reg[:, None, None] * eye
        step = -np.linalg.solve(H, F[idx][..., None])[..., 0]
        slope = (F[idx] * step).sum(axis=1)               # < 0: H is positive definite
        th0 = _theta(sa, la, ha, nu[idx], mu[idx], r[idx])
        t = np.ones(idx.size)
        new_nu = nu[idx] + step
        new_s = op.T(new_nu, idx)
        ok = _theta(new_s, la, ha, new_nu, mu[idx], r[idx]) <= th0 + 1e-4 * t * slope
        # near the solution the decrease of theta is below its rounding: a full step that halves
        # |F| is taken as well (F is the gradient; the iterate stays in the box either way)
        F1 = op.apply(np.clip(new_s, la, ha), idx) + mu[idx, None] * new_nu - r[idx]
        ok |= np.linalg.norm(F1, axis=1) <= 0.5 * np.linalg.norm(F[idx], axis=1)
        for _half in range(30):                            # Armijo backtracking where needed
            bad = np.flatnonzero(~ok)
            if bad.size == 0:
                break
            t[bad] *= 0.5
            cand = nu[idx[bad]] + t[bad, None] * step[bad]
            cs = op.T(cand, idx[bad])
            good = _theta(cs, la[bad], ha[bad], cand, mu[idx[bad]], r[idx[bad]]) \
                <= th0[bad] + 1e-4 * t[bad] * slope[bad]
            new_nu[bad], new_s[bad] = cand, cs
            ok[bad] = good
        moved = ok
        nu[idx[moved]] = new_nu[moved]
        s[idx[moved]] = new_s[moved]
        dz[idx[moved]] = np.clip(new_s[moved], la[moved], ha[moved])
        F[idx[moved]] = op.apply(dz[idx[moved]], idx[moved]) + mu[idx[moved], None] * nu[idx[moved]] \
            - r[idx[moved]]
        active[idx] = moved & (np.abs(F[idx]).max(axis=1) > tol[idx])
    return BoxSolution(dz, nu, F)
