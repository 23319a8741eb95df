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

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError, SolverError, check_count, check_real
from ocreach.reach.base import Method, Timer, requirements
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
    The rules come from :mod:`ocreach.dynamics.quadrature`.
    """
    if rule not in RULES:
        raise ProblemError(f"rule must be one of {RULES}; got {rule!r}")
    if rule in ("cut", "gh") and order not in CUT_ORDERS:
        raise ProblemError(f"order must be one of {CUT_ORDERS} for rule {rule!r}; got {order!r}")
    if n < 1:
        raise ProblemError(f"rule dimension n must be >= 1; got {n!r}")
    from ocreach.dynamics import quadrature as q

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
def dependency_dims(sm) -> np.ndarray:
    """States the increment ``f0(x) + G(x) h`` of ``sm`` depends on (structural Jacobian sparsity).

    The Euler step is ``x+ = x + dt (f0 + G h)``: a state outside this set enters only through the
    identity, which lets ``cut`` integrate over the dependency states alone (``reduce=True``).
    """
    x = ca.SX.sym("x", sm.n_x)
    t = ca.SX.sym("t")
    p = ca.SX.sym("p", sm.f0.size1_in(2))
    e = ca.vertcat(ca.vec(sm.f0(x, t, p)), ca.vec(sm.G(x, t, p)))
    cols = np.unique(np.asarray(ca.jacobian(e, x).sparsity().get_col(), dtype=int))
    return cols


def psd_cholesky(P: np.ndarray, k: int = 0) -> np.ndarray:
    """Lower ``L`` with ``L L^T = P`` for a symmetric positive semidefinite ``P`` (row by row).

    A pivot whose remaining variance is <= 1e-12 of the state's own variance gets a zero column
    (that state is, to this precision, an affine function of the earlier ones); the same
    algorithm as the compiled kernel (:mod:`ocreach.native.cut_kernel`).  Raises
    :class:`SolverError` naming step ``k`` if ``P`` is indefinite or not finite.
    """
    n = P.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        pjj = P[j, j]
        d = pjj - L[j, :j] @ L[j, :j]
        if not (pjj >= 0.0) or not np.isfinite(d) or (d <= 1e-12 * pjj and d < -1e-8 * pjj):
            raise SolverError(f"cut: the propagated covariance at step {k} is indefinite or not "
                              f"finite (pivot {j}: {d:.3g} of variance {pjj:.3g}); the rule has "
                              "negative weights or the dynamics produced non-finite values")
        if d <= 1e-12 * pjj:
            continue
        L[j, j] = np.sqrt(d)
        L[j + 1:, j] = (P[j + 1:, j] - L[j + 1:, :j] @ L[j, :j]) / L[j, j]
    return L


def control_moments(sm, u_nominal: np.ndarray, Lu: np.ndarray, xi_u: np.ndarray, w_u: np.ndarray,
                    third: bool = False) -> tuple[np.ndarray, ...]:
    """``E[h(u_k)]`` ``(K, r)``, ``Cov[h(u_k)]`` ``(K, r, r)`` (and the third central moment
    ``(K, r, r, r)``) of every step by the control rule (Jain et al. Eq. 13, 15), one batched call."""
    K, Mu = u_nominal.shape[0], w_u.size
    U = u_nominal[:, None, :] + (xi_u @ Lu.T)[None, :, :]
    H = sm.control(U.reshape(K * Mu, -1)).reshape(K, Mu, -1)
    Eh = np.einsum("j,kjp->kp", w_u, H)
    dH = H - Eh[:, None, :]
    Ch = np.einsum("j,kjp,kjq->kpq", w_u, dH, dH)
    if not third:
        return Eh, Ch
    return Eh, Ch, np.einsum("j,kjp,kjq,kjs->kpqs", w_u, dH, dH, dH)


def propagate_moments(step_map, grid: np.ndarray, mean0: np.ndarray, cov0: np.ndarray,
                      ctrl: tuple[np.ndarray, ...], xi_x: np.ndarray, w_x: np.ndarray,
                      perm: np.ndarray, third: bool = False) -> dict[str, np.ndarray]:
    """Propagate mean, covariance (and third central moment) of Jain et al. Eq. 1 on ``grid``.

    NumPy reference of the compiled kernel (:mod:`ocreach.native.cut_kernel`) and the path for
    ``third_moments``.  ``step_map`` is a :class:`ocreach.dynamics.stochastic_mc.SplitStepMap` (Euler step
    ``dt f0``, ``dt G``); ``ctrl = (Eh, Ch[, M3h])`` from :func:`control_moments`; ``xi_x, w_x`` the
    standard-normal rule of dimension ``n_y``; ``perm`` the states with the ``n_y`` dependency
    states first.  Points are ``m + L[:, :n_y] xi`` with ``L`` the Cholesky factor of the permuted
    covariance: the remaining states sit at their conditional mean given the dependency states,
    and their conditional covariance ``R = L[:, n_y:] L[:, n_y:]^T`` (unchanged by the identity
    part of the step, independent of everything else) is added to the new covariance.  Exact
    under the Gaussian closure; the third moment gets no term from ``R`` (zero-mean Gaussian,
    independent).  Returns ``mean (K+1, n)``, ``cov (K+1, n, n)`` and, if ``third``,
    ``m3 (K+1, n, n, n)``.
    """
    K = grid.size - 1
    n = mean0.size
    ny = xi_x.shape[1]
    inv = np.argsort(perm)
    Eh, Ch = ctrl[0], ctrl[1]
    mean = np.empty((K + 1, n))
    cov = np.empty((K + 1, n, n))
    m3 = np.zeros((K + 1, n, n, n)) if third else None
    mean[0] = mean0
    cov[0] = cov0
    for k in range(K):
        dt = grid[k + 1] - grid[k]
        L = psd_cholesky(cov[k][np.ix_(perm, perm)], k)
        X = mean[k] + (xi_x @ L[:, :ny].T)[:, inv]                 # points of N(m_k, P_k)
        F, G = step_map.drift_gain(X, grid[k])
        Gd = dt * G                                                # G(x) of Eq. 1 (Euler)
        mu = X + dt * F + Gd @ Eh[k]                               # E[x+ | x], Eq. 6
        m_new = w_x @ mu                                           # Eq. 6 with Eq. 10
        Y = mu - m_new
        GC = Gd @ Ch[k]
        Lz = L[:, ny:][inv]                                        # conditional spread, rows in state order
        P_new = ((Y * w_x[:, None]).T @ Y                                           # Eq. 9, 11-15
                 + np.tensordot(GC * w_x[:, None, None], Gd, axes=([0, 2], [0, 2]))
                 + Lz @ Lz.T)
        P_new = 0.5 * (P_new + P_new.T)
        if not (np.all(np.isfinite(m_new)) and np.all(np.isfinite(P_new))):
            raise SolverError(f"cut: non-finite moments at t = {grid[k + 1]:g} (step {k + 1})")
        mean[k + 1] = m_new
        cov[k + 1] = P_new
        if third:
            # E[y_a Q_bc] with Q = G C_h G^T, and its two index rotations (Eq. 30 terms 4, 6, 7)
            Q = GC @ Gd.transpose(0, 2, 1)
            S = np.tensordot(Y * w_x[:, None], Q, axes=([0], [0]))
            m3[k + 1] = (np.einsum("i,ia,ib,ic->abc", w_x, Y, Y, Y)
                         + S + S.transpose(1, 0, 2) + S.transpose(1, 2, 0)
                         + np.einsum("i,iap,ibq,ics,pqs->abc", w_x, Gd, Gd, Gd, ctrl[2][k],
                                     optimize=True))
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
        """Options of the moment propagation (Jain et al.)."""

        #: moment order the CUT / Gauss-Hermite rule integrates exactly: 4, 6 or 8 (the paper: 8)
        order: int = 8
        #: quadrature rule: "cut" (conjugate unscented), "ut" (unscented) or "gh" (Gauss-Hermite)
        rule: str = "cut"
        #: rule for the controls (None: the same as rule)
        control_rule: str | None = None
        #: also propagate the third central moment (Appendix Eq. 30; NumPy path, slower)
        third_moments: bool = False
        #: the ellipsoids of the result's sets are this many sigma, > 0
        sigma_level: float = 3.0
        #: integrate only over the states the step's increment depends on (exact under the
        #: Gaussian closure; on re-entry the longitude drops out and CUT8 needs 355 instead of 745
        #: points); False: the paper's full rule
        reduce: bool = True
        #: run the fused C kernel (ocreach.native.cut_kernel); False or no C compiler: the NumPy
        #: reference, same numbers
        compiled: bool = True

        def __post_init__(self) -> None:
            if self.rule not in RULES:
                raise ProblemError(f"rule must be one of {RULES}; got {self.rule!r}")
            if self.control_rule is not None and self.control_rule not in RULES:
                raise ProblemError(f"control_rule must be one of {RULES} or None; got {self.control_rule!r}")
            order = check_count("order", self.order, 1) if self.order in CUT_ORDERS else None
            if order is None:
                raise ProblemError(f"order must be one of {CUT_ORDERS}; got {self.order!r}")
            self.order = order
            self.sigma_level = check_real("sigma_level", self.sigma_level)
            if not self.sigma_level > 0:
                raise ProblemError(f"sigma_level must be a finite number > 0; got {self.sigma_level!r}")
            self.third_moments = bool(self.third_moments)
            self.reduce = bool(self.reduce)
            self.compiled = bool(self.compiled)

    @classmethod
    def applicable(cls, problem) -> tuple[bool, str]:
        return requirements(problem, stochastic=True)

    def solve(self, problem) -> ReachResult:
        from ocreach.dynamics.stochastic_mc import step_map_for, stochastic_spec
        from ocreach.native.cut_kernel import cut_kernel

        opt = self.options
        timer = Timer()
        n = problem.model.n_x
        with timer("setup"):
            mean0, L0, u_nom, Lu = stochastic_spec(problem)
            sm = step_map_for(problem)
            dep = dependency_dims(sm) if opt.reduce else np.arange(n)
            if dep.size == 0:
                dep = np.arange(n)
            perm = np.concatenate([dep, np.setdiff1d(np.arange(n), dep)])
            xi_x, w_x = standard_rule(opt.rule, int(dep.size), opt.order)
            xi_u, w_u = standard_rule(opt.control_rule or opt.rule, problem.model.n_u, opt.order)
            kern = cut_kernel(sm) if opt.compiled and not opt.third_moments else None
        with timer("propagation"):
            ctrl = control_moments(sm, u_nom, Lu, xi_u, w_u, third=opt.third_moments)
            cov0 = L0 @ L0.T
            if kern is not None:
                mean, cov = kern.run(problem.grid, mean0, cov0, xi_x, w_x, perm, ctrl[0], ctrl[1])
                mom = {"mean": mean, "cov": cov}
            else:
                mom = propagate_moments(sm, problem.grid, mean0, cov0, ctrl, xi_x, w_x, perm,
                                        third=opt.third_moments)
        std = np.sqrt(np.clip(np.einsum("kii->ki", mom["cov"]), 0.0, None))
        meta = self.base_meta(problem, timer.times)
        meta.update({
            "mean": mom["mean"], "cov": mom["cov"], "std": std,
            "lower": mom["mean"] - opt.sigma_level * std, "upper": mom["mean"] + opt.sigma_level * std,
            "points_x": int(w_x.size), "points_u": int(w_u.size), "stochastic": True,
            "rule_dims": dep.tolist(), "compiled": kern is not None,
        })
        if "m3" in mom:
            meta["m3"] = mom["m3"]
        sets = EllipsoidSequence(mom["mean"], mom["cov"], opt.sigma_level**2)
        return ReachResult(times=problem.grid, sets=sets, meta=meta)


class EllipsoidSequence(Sequence):
    """``sets[k] = Ellipsoid(mean[k], s2 cov[k])``, built on first access (a 2000-step horizon
    would otherwise spend longer building ellipsoids than propagating the moments)."""

    def __init__(self, mean: np.ndarray, cov: np.ndarray, s2: float):
        self.mean, self.cov, self.s2 = mean, cov, float(s2)
        self._cache: dict[int, Any] = {}

    def __len__(self) -> int:
        return self.mean.shape[0]

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        n = len(self)
        if not -n <= k < n:
            raise IndexError(f"ellipsoid index {k} out of range for {n} times")
        k = int(k) % n
        if k not in self._cache:
            from ocreach.sets.ellipsoid import Ellipsoid

            self._cache[k] = Ellipsoid(self.mean[k], self.s2 * self.cov[k])
        return self._cache[k]

    def __getstate__(self):
        return {"mean": self.mean, "cov": self.cov, "s2": self.s2}

    def __setstate__(self, state):
        self.__init__(state["mean"], state["cov"], state["s2"])
