"""Robust tube MPC by constraint tightening (Chisci, Rossiter & Zappa 2001; Mayne, Seron & Rakovic 2005).

The classical comparison for the reachable-set-triggered MPC of :mod:`ocreach.control.stationkeeping.event_mpc`.
About the reference the error ``e = x - x_ref`` under the ancillary feedback ``u = v - K_k e``
(``K_k`` the periodic LQR gain) and the disturbance ``w in W`` evolves as
``e_{k+1} = (A_k - B_k K_k) e_k + Bw_k w_k``.  The error tube of a prediction started at step ``k``
from the measured state (Chisci et al.: ``E_0 = {0}``) is

    E_0 = {0},   E_{i+1} = (A_{k+i} - B_{k+i} K_{k+i}) E_i (+) Bw_{k+i} W       (zonotopes)

and the nominal MPC (the nonlinear prediction of Eq. 27) is solved on the tightened sets

    x_{k+i|k} in X_{k+i} (-) E_i,      ||u_{k+i|k}|| <= 1 - max_{e in E_i} ||K_{k+i} e||.

``X_k`` is the box of the drift tube at step ``k`` (its interval hull, the paper's Fig. 7 boxes), so
the Pontryagin difference is exact: half widths minus the support function of ``E_i`` along the
axes, ``sum_j |E_i|_{dj}``.  The thrust margin uses the support of ``K E_i`` along the axes (box
set) or ``sum_j ||K g_j||_2 >= max ||K e||_2`` (ball set), both sound for the zonotope ``E_i``.
The margins depend only on the phase of the periodic reference and are computed once for all
``M`` phases (vectorised).  Along a non-periodic reference (the ephemeris-corrected orbit) they
are computed once for every solve step ``k = 0..S-1`` of the run (``S`` = the reference's
``n_track``, at most ``M - N - 1``): a finite horizon, with the finite-horizon Riccati gains.

**Terminal set** (``terminal_set=True``, default; Chisci et al. 2001 Sec. 3, Mayne et al. 2005
Sec. 4): the last nominal deviation must lie in the LQR level set

    X_f(j) = {d : d^T P_j d <= alpha},    j = k + N,

``P_j`` the periodic Riccati solution (the terminal cost), ``alpha`` one constant for all phases,
the largest level with ``X_f(j)`` inside the tightened box at ``j`` (``sqrt(alpha (P_j^-1)_dd) <=``
tightened half width ``d``) and the LQR law within the tightened thrust set there
(``sqrt(alpha lambda_max(K_j P_j^-1 K_j^T))`` ``<=`` radius), over every start phase of the
schedule.  Then the shifted plan with ``-K d_N`` appended is a feasible candidate at the next
step (recursive feasibility) if ``X_f`` is robustly invariant: ``V = d^T P d`` decreases by the
Riccati identity ``P_j = Q + K^T R K + A_cl^T P_{j+1} A_cl``, so ``sqrt V`` contracts by
``c = max_j ||P_{j+1}^{1/2} A_cl,j P_j^{-1/2}||_2 < 1``, and the new measurement moves the
candidate's terminal state by at most ``e = max sum_g ||P^{1/2} Phi_cl g||`` (the disturbance
``Bw W`` propagated over the horizon); the condition ``c sqrt(alpha) + e <= sqrt(alpha)`` is
evaluated at setup (``terminal_robust``, with ``terminal_contraction`` ``c`` and
``terminal_disturbance`` ``e``).  The check needs no periodicity: ``alpha`` is the smallest over
the start steps used, and ``c`` and ``e`` the largest over the steps ``j = k + N`` the terminal
set is imposed at (every phase of a periodic reference; ``N..S-1+N`` along a non-periodic one,
where the finite-horizon Riccati solution satisfies the same identity step by step), so the
invariance holds for the run, not beyond it.  This argument is about the linearised error dynamics; the
plant is nonlinear, the tube a linearisation (not a guaranteed enclosure).  The state and
terminal constraints are softened by the MPC's penalised slack (the measured state may start
outside ``X``) unless ``tube_slack=None``; only the hard form carries the guarantee.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ocreach.control.lqr import LQR
from ocreach.control.mpc import MPC
from ocreach.control.reference import TrackingReference
from ocreach.control.simulate import _generator
from ocreach.control.stationkeeping.tubes import TubeSchedule, disturbance_input
from ocreach.errors import ProblemError

#: smallest fraction of a constraint kept after tightening (a fully consumed set is reported)
MIN_FRACTION = 1e-3


def error_tube_margins(reference: TrackingReference, K: np.ndarray, Bw: np.ndarray, W: np.ndarray,
                       n_p: int, thrust_kind: str, n_starts: int | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Margins of the error tube for every start step ``k = 0..S-1``: every phase ``0..M-1`` of a
    periodic reference (``S = M``, steps taken modulo ``M``), or the ``S = n_starts`` first steps
    of a non-periodic one (a finite horizon: ``n_starts + n_p <= M``).

    Returns ``state (S, n_p + 1, n_x)``: ``h_{E_i}(e_d)`` (support along each axis, ``i = 0..n_p``)
    and ``thrust (S, n_p)``: the bound on ``||K_{k+i} e||`` over ``E_i`` (``i = 0..n_p-1``).
    ``K`` (M, n_u, n_x) the feedback gains, ``Bw`` (M, n_x, n_w), ``W`` (n_w, m) generators.
    """
    S = reference.n_steps if n_starts is None else int(n_starts)
    A, B = reference.A, reference.B
    nx = A.shape[1]
    Acl = A - np.einsum("kxu,kuy->kxy", B, K)
    BW = np.einsum("kxw,wm->kxm", Bw, W)
    ks = np.arange(S)
    E = np.zeros((S, nx, 0))
    state = np.zeros((S, n_p + 1, nx))
    thrust = np.zeros((S, n_p))
    for i in range(n_p):
        j = reference.gains_index(ks + i)
        KE = np.einsum("kux,kxm->kum", K[j], E)
        if thrust_kind == "box":
            thrust[:, i] = np.abs(KE).sum(axis=2).max(axis=1) if E.shape[2] else 0.0
        else:
            thrust[:, i] = np.linalg.norm(KE, axis=1).sum(axis=1) if E.shape[2] else 0.0
        E = np.concatenate([np.einsum("kxy,kym->kxm", Acl[j], E), BW[j]], axis=2)
        state[:, i + 1] = np.abs(E).sum(axis=2)
    return state, thrust


class MPCWrapper:
    """A controller built around an inner :class:`MPC` (``self.mpc``): its failures are the MPC's."""

    mpc: MPC
    schedule: TubeSchedule

    @property
    def fallbacks(self) -> int:
        return self.mpc.fallbacks

    @property
    def events(self) -> list:
        return self.mpc.events

    def _setup_mpc(self, reference: TrackingReference, control_set_kind: str) -> None:
        """Set the inner MPC up on ``reference``, the one ``self.schedule`` was built on."""
        if reference is not self.schedule.reference:
            raise ProblemError(f"{type(self).__name__}: the tube schedule was built on another "
                               f"reference")
        self.mpc.setup(reference, control_set_kind)


class TubeMPC(MPCWrapper):
    """Tube MPC with tightened state (drift-tube box) and thrust sets on the nonlinear prediction.

    ``schedule`` gives the state constraint sets (their interval hulls); ``disturbance`` the
    generators ``W`` of the acceleration disturbance on ``velocity_dims``; ``fallback`` the LQR
    whose gains are the ancillary feedback (default: periodic LQR with ``Q``, ``R``).
    ``tightening_exhausted`` counts constraint components the tube margin consumed completely
    (kept at ``MIN_FRACTION`` of the set).
    """

    name = "tube-mpc"

    def __init__(self, Q, R, schedule: TubeSchedule, *, disturbance: Any,
                 velocity_dims: tuple[int, ...], n_p: int = 15, n_c: int | None = None,
                 tube_slack: float | None = 100.0, terminal_set: bool = True,
                 fallback: LQR | None = None, **mpc_options: Any) -> None:
        self.schedule = schedule
        self.Q_in, self.R_in = Q, R
        self.disturbance = disturbance
        self.velocity_dims = tuple(velocity_dims)
        self.n_p = n_p
        self.lqr = fallback
        self.mpc = MPC(Q, R, n_p=n_p, n_c=n_p if n_c is None else n_c,
                       tube=schedule.reference.model.n_x, tube_slack=tube_slack, fallback=fallback,
                       terminal_set=terminal_set, **mpc_options)
        self.terminal_set = bool(terminal_set)
        self.tightening_exhausted = 0

    def setup(self, reference: TrackingReference, control_set_kind: str) -> TubeMPC:
        self._setup_mpc(reference, control_set_kind)
        self.lqr = self.mpc.lqr
        reference.linearize()
        M = reference.n_steps
        self.n_starts = M if reference.periodic else self._finite_starts(reference)
        K = self.lqr.K[np.arange(M)]
        Bw = disturbance_input(reference, self.velocity_dims)
        W = _generator("disturbance W", self.disturbance, len(self.velocity_dims))
        self.state_margin, self.thrust_margin = error_tube_margins(
            reference, K, Bw, W, self.n_p, self.mpc.kind, self.n_starts)
        self.M = M
        if self.terminal_set:
            self._terminal_ingredients(K, Bw, W)
        self.reset()
        return self

    def _finite_starts(self, reference: TrackingReference) -> int:
        """Start steps ``0..S-1`` of the solves along a non-periodic reference: the run's
        ``n_track`` steps, as far as the reference reaches (a solve at ``k`` and its terminal
        check use the steps up to ``k + n_p + 1``)."""
        room = reference.n_steps - self.n_p - 1
        if room < 1:
            raise ProblemError(f"TubeMPC: the non-periodic reference '{reference.name}' has "
                               f"{reference.n_steps} steps; the horizon n_p = {self.n_p} needs "
                               f"at least {self.n_p + 2}")
        return int(min(reference.n_default, room))

    def _phase(self, k) -> Any:
        """Row of the margins for the solve at step ``k`` (its phase for a periodic reference)."""
        if self.schedule.reference.periodic:
            return np.asarray(k) % self.M
        if np.any(np.asarray(k) >= self.n_starts) or np.any(np.asarray(k) < 0):
            raise ProblemError(f"TubeMPC: the tightened sets along the non-periodic reference "
                               f"cover solves at steps 0..{self.n_starts - 1}; got step {k}")
        return np.asarray(k)

    def _terminal_ingredients(self, K: np.ndarray, Bw: np.ndarray, W: np.ndarray) -> None:
        """``alpha``, the contraction ``c`` and the disturbance term ``e`` of the terminal set
        (module docstring), over every start step ``k = 0..S-1`` of the schedule: every phase of
        a periodic reference, or every solve of the run along a non-periodic one (the Riccati
        identity behind ``c`` holds for the finite-horizon solution too, step by step)."""
        ref, N, M, S = self.schedule.reference, self.n_p, self.M, self.n_starts
        tl = self.mpc.terminal_lqr
        n_P = M if ref.periodic else S + N + 2
        P = np.stack([tl.cost_to_go(j) for j in range(n_P)])
        Pinv = np.linalg.inv(P)
        Acl = ref.A - np.einsum("kxu,kuy->kxy", ref.B, K)
        wrap = (lambda j: j % M) if ref.periodic else (lambda j: j)
        alphas = np.empty(S)
        for k in range(S):
            _, _, hw_t, _ = self._tightened_sets(k)
            j = wrap(k + N)
            a_box = np.min(hw_t[N - 1] ** 2 / np.diag(Pinv[j]))
            # the appended LQR step -K d_N is the last control of the next problem (margin N - 1)
            k_next = wrap(k + 1) if ref.periodic else min(k + 1, S - 1)  # last solve: its own
            r_next = 1.0 - self.thrust_margin[k_next, N - 1]
            KPK = K[j] @ Pinv[j] @ K[j].T
            a_u = max(r_next, 0.0) ** 2 / max(float(np.linalg.eigvalsh(KPK).max()), 1e-300)
            alphas[k] = min(a_box, a_u)
        self.terminal_alpha = float(alphas.min())
        if not self.terminal_alpha > 0:
            raise ProblemError("tube MPC terminal set: the tightened sets leave no room "
                               f"(alpha = {self.terminal_alpha:g}); use a larger tube or smaller W")
        # contraction of sqrt(V) over one closed-loop step
        c = 0.0
        for j in (range(M) if ref.periodic else range(N, S + N)):
            L = np.linalg.cholesky(P[wrap(j + 1)])  # P = L L^T
            Ls = np.linalg.cholesky(Pinv[j])
            c = max(c, float(np.linalg.norm(L.T @ Acl[j] @ Ls, 2)))
        # disturbance at step k moves the candidate's terminal state by Phi_cl(k+1 -> k+N+1) Bw W
        e = 0.0
        for k in range(S):
            G = Bw[k] @ W
            for i in range(1, N + 1):
                G = Acl[wrap(k + i)] @ G
            L = np.linalg.cholesky(P[wrap(k + N + 1)])
            e = max(e, float(np.linalg.norm(L.T @ G, axis=0).sum()))
        self.terminal_contraction, self.terminal_disturbance = c, e
        self.terminal_robust = bool(c < 1 and c * np.sqrt(self.terminal_alpha) + e
                                    <= np.sqrt(self.terminal_alpha))

    def reset(self) -> None:
        if getattr(self.mpc, "reference", None) is not None:
            self.mpc.reset()
        self.tightening_exhausted = 0
        self.solve_times = self.mpc.solve_times

    def _tightened_sets(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(centres, tube half widths, tightened half widths (n_p, n_x), thrust radii (n_c,))``
        of the solve at step ``k``, before the floors of :meth:`tightened`."""
        c, G = self.schedule.window(k, self.n_p)
        hw = np.abs(G).sum(axis=2)
        ph = self._phase(k)
        hw_t = hw - self.state_margin[ph, 1:]
        r = 1.0 - self.thrust_margin[ph, : self.mpc.n_c]
        return c, hw, hw_t, r

    def tightened(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(centres (n_p, n_x), half widths (n_p, n_x), thrust radii (n_c,))`` at step ``k``."""
        c, hw, hw_t, r = self._tightened_sets(k)
        floor_x, floor_u = MIN_FRACTION * hw, MIN_FRACTION
        self.tightening_exhausted += int(np.sum(hw_t < floor_x) + np.sum(r < floor_u))
        return c, np.maximum(hw_t, floor_x), np.clip(r, floor_u, 1.0)

    def terminal_matrix(self, k: int) -> np.ndarray:
        """``P_{k+N} / alpha``: the terminal set of the solve at step ``k``."""
        return self.mpc.terminal_lqr.cost_to_go(k + self.n_p) / self.terminal_alpha

    def control(self, k: int, x: np.ndarray) -> np.ndarray:
        c, hw, r = self.tightened(k)
        self.mpc.set_tube(c, np.einsum("kn,nm->knm", hw, np.eye(hw.shape[1])))
        self.mpc.set_thrust_bound(r)
        if self.terminal_set:
            self.mpc.set_terminal_set(self.terminal_matrix(k))
        u = self.mpc.control(k, x)
        self.solve_times = self.mpc.solve_times
        return u


__all__ = ["MPCWrapper", "TubeMPC", "error_tube_margins"]
