"""Method ``cut``: stochastic reachability by moment propagation (Jain et al. Eq. 4-15, Appendix).

The system is ``x_{k+1} = f(x_k) + G(x_k) h(u_k)`` (Eq. 1) with ``x_k`` and the fresh control
``u_k`` independent.  Independence splits every expectation into an ``x``-integral times a
``u``-integral (Eq. 5, 9, 30), so the ``x``-points and the ``u``-points are never combined into a
product grid: per step, ``f`` and ``G`` are evaluated at the ``N_x`` points of a quadrature rule for
``p(x_k)`` and ``h`` at the ``N_u`` points of a rule for ``p(u_k)`` (Eq. 10-15).

With ``mu(x) = f(x) + G(x) E[h]`` (the mean of ``x_{k+1}`` given ``x_k``), ``C_h = Cov[h]`` and
``M3_h`` the third central moment of ``h``, Eq. 6, 9 and 30 in central form are::

    E[x+]      = E[mu(x)]                                                         (Eq. 6)
    Cov[x+]    = Cov[mu(x)] + E[G(x) C_h G(x)^T]                                  (Eq. 9)
    M3[x+]_abc = E[y_a y_b y_c] + E[y_a (G C_h G^T)_bc] + (2 cyclic) + E[G_ap G_bq G_cs] M3_h,pqs
                                                                                  (Eq. 30)

with ``y = mu(x) - E[x+]``: the same sums as the paper's raw-moment expressions, rearranged so no
large numbers cancel.  Gaussian closure (the paper's "Step 4" with a Gaussian: only the first two
polynomial-chaos coefficients of Eq. 16 are non-zero): the next step's points are drawn from
``N(E[x+], Cov[x+])``.

The result carries ``sets[k] = Ellipsoid(mean_k, s^2 cov_k)`` (the ``s = sigma_level``-sigma
ellipsoid, 3 by default) and, in ``meta``, the arrays ``mean`` (K+1, n), ``cov`` (K+1, n, n),
``std``, ``lower``/``upper`` (mean -/+ s std) and, with ``third_moments=True``, ``m3``
(K+1, n, n, n).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ocreach.errors import ProblemError, SolverError
from ocreach.reach.base import Method, Timer
from ocreach.reach.result import ReachResult

RULES = ("cut", "ut", "gh")
CUT_ORDERS = (4, 6, 8)


# =============================================================================== rules
def standard_rule(rule: str, n: int, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(M, n)`` and weights ``(M,)`` integrating against ``N(0, I_n)``.

    ``rule="cut"``: conjugate unscented transform of ``order`` 4, 6 or 8 (Adurthi, Singla & Singh);
    ``"ut"``: unscented transform (2n+1 points, ``order`` ignored) with ``kappa = max(3 - n, 0)``
    (Julier's ``3 - n`` where it is >= 0; for n > 3 it would make the centre weight negative and the
    propagated covariance can lose definiteness, so ``kappa = 0``); ``"gh"``: tensor Gauss-Hermite
    with ``order // 2 + 1`` points per axis (exact to degree ``2 (order // 2) + 1`` >= ``order``).
    The rules come from :mod:`ocreach.quadrature`.
    """
    if rule not in RULES:
        raise ProblemError(f"rule must be one of {RULES}; got {rule!r}")
    if rule in ("cut", "gh") and order not in CUT_ORDERS:
        raise ProblemError(f"order must be one of {CUT_ORDERS} for rule {rule!r}; got {order!r}")
    if n < 1:
        raise ProblemError(f"rule dimension n must be >= 1; got {n!r}")
    from ocreach import quadrature as q

    if rule == "cut":
        out = q.cut_rule(n, order, "gaussian")
    elif rule == "ut":
        out = q.unscented_rule(n, kappa=float(max(3 - n, 0)))
    else:
        out = q.gauss_hermite_rule(n, order // 2 + 1)
    pts, w = (out.points, out.weights) if hasattr(out, "points") else out
    pts = np.asarray(pts, dtype=float).reshape(-1, n)
    w = np.asarray(w, dtype=float).ravel()
    if pts.shape[0] != w.size:
        raise SolverError(f"quadrature rule {rule!r} returned {pts.shape[0]} points and {w.size} weights")
    return pts, w


# =============================================================================== propagation
def _factor(P: np.ndarray, k: int) -> np.ndarray:
    """Square root of a propagated covariance (symmetrised; round-off negatives clipped)."""
    P = 0.5 * (P + P.T)
    w, V = np.linalg.eigh(P)
    scale = max(float(np.abs(w).max(initial=0.0)), 1e-300)
    if w.size and w.min() < -1e-8 * scale:
        raise SolverError(f"cut: the propagated covariance at step {k} is indefinite (smallest "
                          f"eigenvalue {w.min():.3g} of {scale:.3g}); the rule has negative weights "
                          "or the dynamics produced non-finite values")
    return V * np.sqrt(np.clip(w, 0.0, None))[None, :]


def propagate_moments(step_map, grid: np.ndarray, mean0: np.ndarray, L0: np.ndarray,
                      u_nominal: np.ndarray, Lu: np.ndarray, xi_x: np.ndarray, w_x: np.ndarray,
                      xi_u: np.ndarray, w_u: np.ndarray, third: bool = False) -> dict[str, np.ndarray]:
    """Propagate mean, covariance (and third central moment) of Jain et al. Eq. 1 on ``grid``.

    ``step_map`` is a :class:`ocreach.stochastic_mc.SplitStepMap` (Euler step ``dt f0``,
    ``dt G``); ``L0``, ``Lu`` are square roots of the initial-state and control covariances;
    ``xi_x, w_x`` and ``xi_u, w_u`` the standard-normal rules of dimension ``n_x`` and ``n_u``.
    Returns ``mean (K+1, n)``, ``cov (K+1, n, n)`` and, if ``third``, ``m3 (K+1, n, n, n)``.
    """
    K = grid.size - 1
    n = mean0.size
    mean = np.empty((K + 1, n))
    cov = np.empty((K + 1, n, n))
    m3 = np.zeros((K + 1, n, n, n)) if third else None
    mean[0] = mean0
    cov[0] = L0 @ L0.T
    L = L0
    for k in range(K):
        dt = grid[k + 1] - grid[k]
        X = mean[k] + xi_x @ L.T                                   # points of N(m_k, P_k)
        F, G = step_map.drift_gain(X, grid[k])
        Fd = X + dt * F                                            # f(x) of Eq. 1 (Euler)
        Gd = dt * G                                                # G(x) of Eq. 1 (Euler)
        H = step_map.control(u_nominal[k] + xi_u @ Lu.T)           # h(u) at the control points
        Eh = w_u @ H                                               # Eq. 13
        dH = H - Eh
        Ch = (dH * w_u[:, None]).T @ dH                            # Eq. 15 (central)
        mu = Fd + Gd @ Eh                                          # E[x+ | x]
        m_new = w_x @ mu                                           # Eq. 6 with Eq. 10
        Y = mu - m_new
        GC = Gd @ Ch
        P_new = ((Y * w_x[:, None]).T @ Y                                           # Eq. 9, 11-15
                 + np.tensordot(GC * w_x[:, None, None], Gd, axes=([0, 2], [0, 2])))
        P_new = 0.5 * (P_new + P_new.T)
        if not (np.all(np.isfinite(m_new)) and np.all(np.isfinite(P_new))):
            raise SolverError(f"cut: non-finite moments at t = {grid[k + 1]:g} (step {k + 1})")
        mean[k + 1] = m_new
        cov[k + 1] = P_new
        if third:
            M3h = np.einsum("j,jp,jq,js->pqs", w_u, dH, dH, dH)
            Q = GC @ Gd.transpose(0, 2, 1)
            S = np.tensordot(Y * w_x[:, None], Q, axes=([0], [0]))
            # E[y_a Q_bc] with Q = G C_h G^T, and its two index rotations (Eq. 30 terms 4, 6, 7)
            Q = GC @ Gd.transpose(0, 2, 1)
            S = np.tensordot(Y * w_x[:, None], Q, axes=([0], [0]))
            m3[k + 1] = (np.einsum("i,ia,ib,ic->abc", w_x, Y, Y, Y)
                         + S + S.transpose(1, 0, 2) + S.transpose(1, 2, 0)
                         + np.einsum("i,iap,ibq,ics,pqs->abc", w_x, Gd, Gd, Gd, M3h, optimize=True))
        L = _factor(P_new, k + 1)
    out = {"mean": mean, "cov": cov}
    if third:
        out["m3"] = m3
    return out


# =============================================================================== method
class CUTMoments(Method):
    """Moment propagation with CUT/UT/Gauss-Hermite points and Gaussian closure (Jain et al.)."""

    name = "cut"
    description = ("stochastic reachability: mean/covariance propagation with conjugate unscented "
                   "points, x and u sampled separately (Jain et al.); 3-sigma ellipsoids")

    @dataclass
    class Options:
        """``order``: 4, 6 or 8 (moment order the CUT / Gauss-Hermite rule integrates exactly; the
        paper uses 8); ``rule``: ``"cut"`` | ``"ut"`` | ``"gh"``; ``control_rule``: rule for the
        controls (default: same as ``rule``); ``third_moments``: also propagate the third central
        moment (Appendix Eq. 30); ``sigma_level``: the ellipsoid of ``sets`` is
        ``sigma_level``-sigma (3)."""

        order: int = 8
        rule: str = "cut"
        control_rule: str | None = None
        third_moments: bool = False
        sigma_level: float = 3.0

        def __post_init__(self) -> None:
            if self.rule not in RULES:
                raise ProblemError(f"rule must be one of {RULES}; got {self.rule!r}")
            if self.control_rule is not None and self.control_rule not in RULES:
                raise ProblemError(f"control_rule must be one of {RULES} or None; got {self.control_rule!r}")
            if self.order not in CUT_ORDERS:
                raise ProblemError(f"order must be one of {CUT_ORDERS}; got {self.order!r}")
            if not (np.isfinite(self.sigma_level) and self.sigma_level > 0):
                raise ProblemError(f"sigma_level must be a finite number > 0; got {self.sigma_level!r}")
            self.third_moments = bool(self.third_moments)

    def solve(self, problem) -> ReachResult:
        from ocreach.sets.ellipsoid import Ellipsoid
        from ocreach.stochastic_mc import step_map_for, stochastic_spec

        opt = self.options
        timer = Timer()
        with timer("setup"):
            mean0, L0, u_nom, Lu = stochastic_spec(problem)
            sm = step_map_for(problem)
            xi_x, w_x = standard_rule(opt.rule, problem.model.n_x, opt.order)
            xi_u, w_u = standard_rule(opt.control_rule or opt.rule, problem.model.n_u, opt.order)
        with timer("propagation"):
            mom = propagate_moments(sm, problem.grid, mean0, L0, u_nom, Lu, xi_x, w_x, xi_u, w_u,
                                    third=opt.third_moments)
        with timer("sets"):
            s2 = opt.sigma_level**2
            sets = [Ellipsoid(m, s2 * P) for m, P in zip(mom["mean"], mom["cov"])]
        std = np.sqrt(np.clip(np.einsum("kii->ki", mom["cov"]), 0.0, None))
        meta = self.base_meta(problem, timer.times)
        meta.update({
            "mean": mom["mean"], "cov": mom["cov"], "std": std,
            "lower": mom["mean"] - opt.sigma_level * std, "upper": mom["mean"] + opt.sigma_level * std,
            "points_x": int(w_x.size), "points_u": int(w_u.size), "stochastic": True,
        })
        if "m3" in mom:
            meta["m3"] = mom["m3"]
        return ReachResult(times=problem.grid, sets=sets, meta=meta)
