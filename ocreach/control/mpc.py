"""Nonlinear model predictive control with CasADi and IPOPT (Patel & Subbarao Eq. 26-28).

At step ``k`` the controller solves, with ``N = n_p``,

    min  sum_{i=0}^{N-1} dx_i^T Q dx_i + du_i^T R du_i + dx_N^T P dx_N,   dx_i = x_{k+i|k} - x_ref_{k+i}
    s.t. x_{k+i+1|k} = f_d(x_{k+i|k}, u_{k+i|k})        (Eq. 26, RK4 substeps, multiple shooting)
         u_{k+i|k} in U                                   (Eq. 28 box, or the Euclidean ball Eq. 5)
         u_{k+i|k} = u_{k+n_c-1|k} for i >= n_c           (control horizon: inputs held)
         x_{k+i|k} in R_{k+i}                             (Eq. 27 tube, optional)

and applies ``u_{k|k}``.  The terminal weight ``P`` defaults to the LQR Riccati solution
``P_{k+N}`` (so without active constraints the MPC reproduces the LQR on the linearised dynamics).
``du_i = u_i - u_ref_i``.  The NLP is built once (``nlpsol`` with parameters: current state,
reference window, model parameters, terminal weight and optional tube), expanded to SX, and
warm-started from the shifted previous solution.

Decision variables are the controls of the control horizon and the *deviations*
``d_i = x_{k+i|k} - x_ref_{k+i}``, ``i = 1..N`` (well scaled near the reference); the objective is
divided by the largest eigenvalue of the control weight so IPOPT's tolerances are meaningful.

Tube constraints (Eq. 27, last line): with ``tube=q`` the NLP gets ``x_{k+i|k} = c_i + G_i xi_i``,
``|xi_i|_inf <= 1`` with ``c_i`` (``n_x``) and ``G_i`` (``n_x x q``) passed per solve
(:meth:`MPC.set_tube`), e.g. a zonotope tube from an SDC reachability run.  With
``tube_slack=rho`` the tube is soft: ``-(1 + s_i) <= xi_i <= 1 + s_i`` with a slack ``s_i >= 0`` per
step and the exact penalty ``rho (s_i + s_i^2 / 2)`` added to the (scaled) objective, so the NLP stays
feasible from a state outside the tube (:mod:`ocreach.control.stationkeeping.tubes`, gauge form with ``t = 1 + s``);
``last_tube_slack`` is the largest slack of the last successful solve.  :meth:`MPC.set_thrust_bound`
tightens the thrust set per solve and per control-horizon step (robust tube MPC).

Defect correction (``defect_correction=True``): the prediction is ``x_{i+1} = f_d(x_i, u_i) + d_i``
with ``d_i = x_ref_{k+i+1} - f_d(x_ref_{k+i}, u_ref_{k+i})`` the one-step error of the RK4 model
along the (DOP853) reference, so the prediction is exact on the reference and only the deviation
dynamics carry the discretisation error; this lets a few RK4 substeps do where the uncorrected
model needs many (nrho-9-2 at 1 h: 4 instead of 32, controls within 5e-4).  ``extra_constraints``
is a callable ``(X, U, params) -> [(g, lbg, ubg), ...]`` with ``X`` the ``n_x x (N+1)`` predicted
states and ``U`` the ``n_u x N`` controls (CasADi SX), for any other constraint.

Failure handling: if IPOPT does not report success (including ``max_cpu_time`` / ``max_iter``
exhaustion, non-finite values or an exception), the event is logged, counted in ``fallbacks`` and
recorded in ``events``; the controller applies the shifted previous plan while it is within the
control horizon of a successful solve, otherwise the LQR law.  Before that, a failed *warm-started*
solve (not a time-out or an exception) is retried once from the cold LQR roll-out guess with
IPOPT's default barrier start (a second solver, built on first use); the retry is recorded in
``events`` (``"cold restart"``) but is not a fallback when it succeeds.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np

from ocreach.control.common import as_weight, check_thrust, control_scale, saturate, thrust_ratio
from ocreach.control.lqr import LQR
from ocreach.control.reference import TrackingReference
from ocreach.errors import ProblemError, check_count

log = logging.getLogger("ocreach.control.mpc")

THRUST_SETS = ("plant", "ball", "box")
_OK = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


class MPC:
    """Nonlinear MPC tracking a :class:`TrackingReference` (Patel & Subbarao Eq. 27).

    Parameters
    ----------
    Q, R : state and control weights (``R`` in the units of ``weights_in``, see
        :mod:`ocreach.control.common`).  Table 3: ``diag(1000, 1000, 1000, 100, 100, 100)``, ``I``.
    n_p, n_c : prediction and control horizon (``1 <= n_c <= n_p``); Table 3: 10 and 5.
    P : terminal weight; ``None`` uses the LQR Riccati solution ``P_{k+n_p}`` for this MPC's ``Q``
        and ``R`` (from ``fallback`` when it has the same weights, else from its own LQR).
    thrust_set : ``"plant"`` (the problem's control set), ``"ball"`` (``u^T u <= 1``) or ``"box"``
        (Eq. 28; ``|u_i| <= 1``, or the inscribed box ``|u_i| <= 1/sqrt(n_u)`` when the plant's
        set is a ball, so the plant limit still holds).
    max_cpu_time, max_iter : IPOPT limits per solve (a hit is a failure, see module docstring).
    ipopt_options : extra IPOPT options (without the ``"ipopt."`` prefix).
    tube : number of generators ``q`` of per-step tube constraints, or ``None``.
    tube_slack : penalty weight ``rho > 0`` of the soft tube (scaled objective units), or ``None``
        (hard tube, ``|xi| <= 1``).
    defect_correction : add the reference's one-step model error to the prediction (see above).
    prediction_substeps : RK4 substeps of the prediction model (default: the reference's
        ``n_sub``); fewer substeps with ``defect_correction`` make the NLP cheaper.
    extra_constraints : callable ``(X, U, params) -> [(g, lbg, ubg), ...]`` or ``None``.
    terminal_set : constrain the last predicted deviation to ``d_N^T Pf d_N <= 1`` with ``Pf``
        passed per solve (:meth:`set_terminal_set`; soft with the last tube slack if the tube is
        soft), the terminal ingredient of robust tube MPC (:mod:`ocreach.control.stationkeeping.tube_mpc`).
    fallback : an :class:`LQR` (default: one with the same weights).
    """

    name = "mpc"

    def __init__(self, Q, R, *, n_p: int = 10, n_c: int = 5, P=None, thrust_set: str = "plant",
                 weights_in: str = "auto", max_cpu_time: float = 1.0, max_iter: int = 100,
                 ipopt_options: dict | None = None, warm_start: bool = True,
                 tube: int | None = None, tube_slack: float | None = None,
                 defect_correction: bool = False, prediction_substeps: int | None = None,
                 extra_constraints: Callable[..., list] | None = None,
                 terminal_set: bool = False, fallback: LQR | None = None) -> None:
        self.n_p = check_count("n_p (prediction horizon)", n_p, 1)
        self.n_c = check_count("n_c (control horizon)", n_c, 1)
        if self.n_c > self.n_p:
            raise ProblemError(f"n_c (control horizon) must be <= n_p = {self.n_p}; got {n_c!r}")
        if thrust_set not in THRUST_SETS:
            raise ProblemError(f"thrust_set must be one of {THRUST_SETS}; got {thrust_set!r}")
        if not np.isfinite(max_cpu_time) or max_cpu_time <= 0:
            raise ProblemError(f"max_cpu_time must be > 0 (s); got {max_cpu_time!r}")
        self.max_iter = check_count("max_iter", max_iter, 0)
        self.tube_q = None if tube is None else check_count("tube (generators)", tube, 1)
        if tube_slack is not None:
            if self.tube_q is None:
                raise ProblemError("tube_slack needs tube=q (a tube to soften)")
            if isinstance(tube_slack, bool) or not np.isfinite(tube_slack) or tube_slack <= 0:
                raise ProblemError(f"tube_slack (penalty weight) must be a finite number > 0; got "
                                   f"{tube_slack!r}")
        self.tube_slack = None if tube_slack is None else float(tube_slack)
        self.terminal_set = bool(terminal_set)
        self.defect_correction = bool(defect_correction)
        self.prediction_substeps = (None if prediction_substeps is None else
                                    check_count("prediction_substeps", prediction_substeps, 1))
        self.Q_in, self.R_in, self.P_in = Q, R, P
        self.thrust_set = thrust_set
        self.weights_in = weights_in
        self.max_cpu_time = float(max_cpu_time)
        self.ipopt_options = dict(ipopt_options or {})
        self.warm_start = warm_start
        self.extra_constraints = extra_constraints
        self.lqr = fallback
        self.reference: TrackingReference | None = None
        self.solver: ca.Function | None = None
        self._tube_values: tuple[np.ndarray, np.ndarray] | None = None
        self._terminal_value: np.ndarray | None = None
        self.reset()

    # ------------------------------------------------------------------ setup
    def setup(self, reference: TrackingReference, control_set_kind: str) -> MPC:
        """Validate, build the fallback LQR and the NLP (once per reference)."""
        model = reference.model
        check_thrust(model, reference.params)
        nx, nu = model.n_x, model.n_u
        self.Q = as_weight("Q", self.Q_in, nx, definite=False)
        R = as_weight("R", self.R_in, nu, definite=True)
        self.u_scale = control_scale(model, reference.params, self.weights_in)
        self.R = self.u_scale**2 * R
        self.P_fixed = None if self.P_in is None else as_weight("P", self.P_in, nx, definite=False)
        self.plant_kind = control_set_kind
        self.kind = control_set_kind if self.thrust_set == "plant" else self.thrust_set
        if self.kind == "box":
            self.u_bound = 1.0 / np.sqrt(nu) if control_set_kind == "ball" else 1.0
        else:
            self.u_bound = 1.0
        if self.lqr is None:
            self.lqr = LQR(self.Q_in, self.R_in, weights_in=self.weights_in)
        if self.lqr.reference is not reference:
            self.lqr.setup(reference, control_set_kind)
        self.terminal_lqr = self.lqr
        if self.P_fixed is None and not (np.allclose(self.lqr.Q, self.Q, rtol=1e-12, atol=0)
                                         and np.allclose(self.lqr.R, self.R, rtol=1e-12, atol=0)):
            # the fallback has other weights: its Riccati P is not this cost's cost-to-go
            self.terminal_lqr = LQR(self.Q_in, self.R_in, weights_in=self.weights_in).setup(
                reference, control_set_kind)
        self.reference = reference
        self.prediction = (reference if self.prediction_substeps in (None, reference.n_sub)
                           else reference.with_substeps(self.prediction_substeps))
        self._build(self.prediction)
        self.reset()
        return self

    def _build(self, ref: TrackingReference) -> None:
        model = ref.model
        nx, nu, N, Nc = model.n_x, model.n_u, self.n_p, self.n_c
        F = ref.discretization.F
        U = ca.SX.sym("U", nu, Nc)
        D = ca.SX.sym("D", nx, N)
        x0 = ca.SX.sym("x0", nx)
        Xr = ca.SX.sym("Xr", nx, N + 1)
        Ur = ca.SX.sym("Ur", nu, N)
        t0 = ca.SX.sym("t0")
        pm = ca.SX.sym("p", model.n_p)
        Pt = ca.SX.sym("P", nx, nx)
        Dd = ca.SX.sym("Dd", nx, N) if self.defect_correction else ca.SX.zeros(nx, N)
        q = self.tube_q
        Uall = ca.horzcat(*[U[:, min(i, Nc - 1)] for i in range(N)])
        X = ca.horzcat(x0, Xr[:, 1:] + D)
        obj_scale = 1.0 / float(np.linalg.eigvalsh(self.R).max())
        Qs, Rs = self.Q * obj_scale, self.R * obj_scale
        J = 0
        g, lbg, ubg = [], [], []
        for i in range(N):
            dx = X[:, i] - Xr[:, i]
            du = Uall[:, i] - Ur[:, i]
            J += ca.bilin(Qs, dx, dx) + ca.bilin(Rs, du, du)
            g.append(X[:, i + 1] - F(X[:, i], Uall[:, i], t0 + i * ref.dt, pm) - Dd[:, i])
            lbg += [0.0] * nx
            ubg += [0.0] * nx
        J += obj_scale * ca.bilin(Pt, D[:, -1], D[:, -1])
        self._n_dyn = N * nx
        self._ball_rows = None
        if self.kind == "ball":
            self._ball_rows = np.arange(len(lbg), len(lbg) + Nc)
            for j in range(Nc):
                g.append(ca.sumsqr(U[:, j]))
                lbg.append(-ca.inf)
                ubg.append(1.0)
        w = [ca.vec(U), ca.vec(D)]
        params = [x0, ca.vec(Xr), ca.vec(Ur), t0, pm, ca.vec(Pt)]
        if self.defect_correction:
            params.append(ca.vec(Dd))
        sym = {"x0": x0, "Xr": Xr, "Ur": Ur, "t0": t0, "p": pm, "P": Pt}
        if q is not None:
            XI = ca.SX.sym("XI", q, N)
            C = ca.SX.sym("C", nx, N)
            G = ca.SX.sym("G", nx * q, N)
            for i in range(N):
                Gi = ca.reshape(G[:, i], nx, q)
                g.append(X[:, i + 1] - C[:, i] - ca.mtimes(Gi, XI[:, i]))
                lbg += [0.0] * nx
                ubg += [0.0] * nx
            w.append(ca.vec(XI))
            if self.tube_slack is not None:
                S = ca.SX.sym("S", N)
                for i in range(N):
                    g.append(ca.vertcat(XI[:, i] - S[i], -XI[:, i] - S[i]))
                    lbg += [-ca.inf] * (2 * q)
                    ubg += [1.0] * (2 * q)
                J += self.tube_slack * (ca.sum1(S) + 0.5 * ca.sumsqr(S))
                w.append(S)
            params += [ca.vec(C), ca.vec(G)]
            sym.update({"tube_c": C, "tube_G": G})
        if self.terminal_set:
            # terminal set {d : d^T Pf d <= 1} on the last deviation; softened with the last
            # tube slack when the tube is soft (the ellipsoid scaled like the tube, by 1 + s_N)
            Pf = ca.SX.sym("Pf", nx, nx)
            lvl = (1 + S[N - 1]) ** 2 if (q is not None and self.tube_slack is not None) else 1.0
            g.append(ca.bilin(Pf, D[:, -1], D[:, -1]) - lvl)
            lbg.append(-ca.inf)
            ubg.append(0.0)
            params.append(ca.vec(Pf))
            sym["Pf"] = Pf
        if self.extra_constraints is not None:
            for item in self.extra_constraints(X, Uall, sym):
                ge, lo, hi = item
                ge = ca.vec(ca.SX(ge))
                n = ge.numel()
                g.append(ge)
                lbg += list(np.broadcast_to(np.asarray(lo, float), (n,)))
                ubg += list(np.broadcast_to(np.asarray(hi, float), (n,)))
        wv = ca.vertcat(*w)
        nlp = {"x": wv, "p": ca.vertcat(*params), "f": J, "g": ca.vertcat(*g)}
        opts: dict[str, Any] = {
            "expand": True, "print_time": False, "error_on_fail": False,
            "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_cpu_time": self.max_cpu_time,
            "ipopt.max_iter": self.max_iter, "ipopt.tol": 1e-10,
            "ipopt.acceptable_tol": 1e-7,
        }
        user = {f"ipopt.{k}": v for k, v in self.ipopt_options.items()}
        self._nlp, self._cold_opts = nlp, {**opts, **user}
        self._cold_solver = None
        if self.warm_start:
            opts.update({"ipopt.warm_start_init_point": "yes", "ipopt.mu_init": 1e-4,
                         "ipopt.warm_start_bound_push": 1e-9, "ipopt.warm_start_mult_bound_push": 1e-9})
        opts.update(user)
        self.solver = ca.nlpsol("mpc", "ipopt", nlp, opts)
        n_w = wv.numel()
        lbx = -np.inf * np.ones(n_w)
        ubx = np.inf * np.ones(n_w)
        if self.kind == "box":
            lbx[: nu * Nc] = -self.u_bound
            ubx[: nu * Nc] = self.u_bound
        if q is not None and self.tube_slack is None:
            lbx[nu * Nc + nx * N:] = -1.0
            ubx[nu * Nc + nx * N:] = 1.0
        elif q is not None:
            lbx[nu * Nc + nx * N + q * N:] = 0.0  # slacks >= 0; xi bounded through g
        self._lbx, self._ubx = lbx, ubx
        self._lbg, self._ubg = np.array(lbg, float), np.array(ubg, float)
        self._n_w = n_w

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget plans, warm starts and counters (a new closed-loop run)."""
        self.fallbacks = 0
        self.events: list[dict] = []
        self.solve_times: list[float] = []
        self.plan: np.ndarray | None = None
        self.plan_k = -1
        self._w = None
        self._lam_g = None
        self._lam_x = None
        self.last_status = ""
        self.last_tube_slack = 0.0
        self._thrust_radii: np.ndarray | None = None

    def set_tube(self, centers: np.ndarray, generators: np.ndarray) -> None:
        """Tube for the next solve: ``centers (n_p, n_x)``, ``generators (n_p, n_x, q)``."""
        if self.tube_q is None:
            raise ProblemError("set_tube needs an MPC built with tube=q (number of generators)")
        nx = self.reference.model.n_x
        c = np.asarray(centers, float)
        G = np.asarray(generators, float)
        if c.shape != (self.n_p, nx) or G.shape != (self.n_p, nx, self.tube_q):
            raise ProblemError(f"tube centers must be ({self.n_p}, {nx}) and generators "
                               f"({self.n_p}, {nx}, {self.tube_q}); got {c.shape}, {G.shape}")
        self._tube_values = (c, G)

    def set_terminal_set(self, Pf) -> None:
        """Terminal set ``{d_N : d_N^T Pf d_N <= 1}`` (``d_N`` the last predicted deviation from
        the reference) for the next solve; needs ``terminal_set=True``.  ``Pf`` symmetric
        positive semidefinite ``n_x x n_x``."""
        if not self.terminal_set:
            raise ProblemError("set_terminal_set needs an MPC built with terminal_set=True")
        nx = self.reference.model.n_x
        P = np.asarray(Pf, float)
        if P.shape != (nx, nx) or not np.all(np.isfinite(P)):
            raise ProblemError(f"terminal set matrix Pf must be a finite {nx}x{nx} matrix; got "
                               f"shape {P.shape}")
        self._terminal_value = 0.5 * (P + P.T)

    def set_thrust_bound(self, radii) -> None:
        """Thrust set for the next solves scaled per control-horizon step: ``||u_j|| <= r_j u_bound``
        (ball: ``u^T u <= r_j^2``; box: ``|u_ji| <= r_j u_bound``), ``0 < r_j <= 1`` (robust tube
        MPC constraint tightening); ``None`` restores the full set."""
        if self.solver is None:
            raise ProblemError("MPC.setup(reference, control_set_kind) must be called first")
        if radii is None:
            self._thrust_radii = None
            return
        r = np.broadcast_to(np.asarray(radii, dtype=float), (self.n_c,)).copy()
        if not np.all(np.isfinite(r)) or np.any(r <= 0) or np.any(r > 1):
            raise ProblemError(f"thrust bound radii must lie in (0, 1]; got {np.asarray(radii).tolist()!r}")
        self._thrust_radii = r

    def _bounds(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(lbx, ubx, ubg)`` of the next solve (thrust radii applied)."""
        if self._thrust_radii is None:
            return self._lbx, self._ubx, self._ubg
        r = self._thrust_radii
        lbx, ubx, ubg = self._lbx.copy(), self._ubx.copy(), self._ubg.copy()
        nu, Nc = self.reference.model.n_u, self.n_c
        if self.kind == "box":
            b = np.repeat(r, nu) * self.u_bound
            lbx[: nu * Nc], ubx[: nu * Nc] = -b, b
        else:
            ubg[self._ball_rows] = r**2
        return lbx, ubx, ubg

    def terminal_weight(self, k: int) -> np.ndarray:
        """Terminal weight at step ``k``: ``P`` if given, else the Riccati ``P_{k+n_p}`` of an LQR
        with this MPC's ``Q`` and ``R`` (the fallback's, when its weights are the same)."""
        return self.P_fixed if self.P_fixed is not None else self.terminal_lqr.cost_to_go(k + self.n_p)

    # ------------------------------------------------------------------ solve
    def _parameters(self, k: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ref = self.reference
        Xr, Ur = ref.window(k, self.n_p)
        parts = [x, Xr.ravel(), Ur.ravel(), [ref.time(k)], ref.params,
                 self.terminal_weight(k).ravel(order="F")]
        if self.defect_correction:
            pred = self.prediction
            parts.append(pred.defect_vectors()[pred.gains_index(np.arange(k, k + self.n_p))].ravel())
        if self.tube_q is not None:
            if self._tube_values is None:
                raise ProblemError("MPC built with tube=q needs set_tube(...) before each solve")
            c, G = self._tube_values
            parts += [c.ravel(), G.reshape(self.n_p, -1, order="F").ravel()]
        if self.terminal_set:
            if self._terminal_value is None:
                raise ProblemError("MPC built with terminal_set=True needs set_terminal_set(Pf) "
                                   "before each solve")
            parts.append(self._terminal_value.ravel(order="F"))
        return np.concatenate([np.ravel(v) for v in parts]), Xr

    def _initial_guess(self, k: int, x: np.ndarray, Xr: np.ndarray, cold: bool = False) -> np.ndarray:
        """Shifted previous plan (warm), or the LQR law held and rolled out (cold)."""
        nx, nu = self.reference.model.n_x, self.reference.model.n_u
        N, Nc = self.n_p, self.n_c
        F = self.prediction.discretization.F
        p = self.reference.params
        if not cold and self._w is not None and self.warm_start and self.plan_k == k - 1:
            U = self._w[: nu * Nc].reshape(Nc, nu)
            U = np.vstack([U[1:], U[-1:]]) if Nc > 1 else U
            Xprev = self._X_abs
            x_end = F(Xprev[-1], self.plan[-1], self.reference.time(k + N - 1), p)
            Xs = np.vstack([Xprev[1:], np.asarray(x_end).ravel()])
        else:
            U = np.tile(self.lqr.control(k, x), (Nc, 1))
            Xs = np.empty((N, nx))
            xi = x
            for i in range(N):
                xi = np.asarray(F(xi, U[min(i, Nc - 1)], self.reference.time(k + i), p)).ravel()
                Xs[i] = xi
        D = Xs - Xr[1:]
        w = np.concatenate([U.ravel(), D.ravel()])
        if self.tube_q is not None:
            w = np.concatenate([w, np.zeros(self.tube_q * N)])
        if self.tube_slack is not None:
            w = np.concatenate([w, np.zeros(N)])
        return w

    def control(self, k: int, x: np.ndarray) -> np.ndarray:
        """First control of the optimal plan at step ``k`` from state ``x`` (normalised)."""
        if self.solver is None:
            raise ProblemError("MPC.setup(reference, control_set_kind) must be called first")
        x = np.asarray(x, float)
        nx, nu = self.reference.model.n_x, self.reference.model.n_u
        N, Nc = self.n_p, self.n_c
        pv, Xr = self._parameters(k, x)
        w0 = self._initial_guess(k, x, Xr)
        lbx, ubx, ubg = self._bounds()
        args = {"x0": w0, "p": pv, "lbx": lbx, "ubx": ubx, "lbg": self._lbg, "ubg": ubg}
        if self.warm_start and self._lam_g is not None and self.plan_k == k - 1:
            lam_g = self._lam_g.copy()
            dyn = lam_g[: self._n_dyn].reshape(N, nx)
            lam_g[: self._n_dyn] = np.vstack([dyn[1:], dyn[-1:]]).ravel()
            args["lam_g0"] = lam_g
            args["lam_x0"] = self._lam_x
        t_start = time.perf_counter()
        sol, status, err = self._attempt(self.solver, args)
        if sol is None and "lam_g0" in args and not err and "CpuTime" not in status:
            # a warm start from a plan the state has left can stall IPOPT (small mu_init); one
            # cold restart (LQR roll-out guess, default barrier start) before falling back
            self.events.append({"step": int(k), "reason": status, "fallback": "cold restart"})
            log.info("MPC step %d: warm-started IPOPT failed (%s); cold restart", k, status)
            cold = {key: v for key, v in args.items() if key not in ("lam_g0", "lam_x0")}
            cold["x0"] = self._initial_guess(k, x, Xr, cold=True)
            sol, status, err = self._attempt(self.cold_solver, cold)
        self.solve_times.append(time.perf_counter() - t_start)
        self.last_status = status or err
        ok = sol is not None
        if ok:
            w = np.asarray(sol["x"]).ravel()
            Uc = w[: nu * Nc].reshape(Nc, nu)
            self._w = w
            self._lam_g = np.asarray(sol["lam_g"]).ravel()
            self._lam_x = np.asarray(sol["lam_x"]).ravel()
            D = w[nu * Nc: nu * Nc + nx * N].reshape(N, nx)
            self._X_abs = Xr[1:] + D
            self.plan = np.array([Uc[min(i, Nc - 1)] for i in range(N)])
            self.plan_k = k
            self.last_tube_slack = float(w[-N:].max()) if self.tube_slack is not None else 0.0
            return saturate(Uc[0], self.plant_kind)
        return self._fallback(k, x, status or err or "non-finite solution")

    @property
    def cold_solver(self) -> ca.Function:
        """The NLP solver without warm-start options (built on first use, then re-used)."""
        if not self.warm_start:
            return self.solver
        if self._cold_solver is None:
            self._cold_solver = ca.nlpsol("mpc_cold", "ipopt", self._nlp, self._cold_opts)
        return self._cold_solver

    def _attempt(self, solver, args: dict) -> tuple[dict | None, str, str]:
        """One IPOPT call: ``(solution or None, return status, exception text)``; a solution is
        returned only if IPOPT succeeded, it is finite and the controls respect the thrust set."""
        try:
            sol = solver(**args)
            status = solver.stats().get("return_status", "")
        except RuntimeError as exc:  # evaluation errors inside IPOPT
            return None, "", str(exc)
        if status not in _OK:
            return None, status, ""
        w = np.asarray(sol["x"]).ravel()
        if not np.all(np.isfinite(w)):
            return None, f"{status} (non-finite solution)", ""
        nu, Nc = self.reference.model.n_u, self.n_c
        ratio = thrust_ratio(w[: nu * Nc].reshape(Nc, nu), "ball" if self.kind == "ball" else "box")
        radii = 1.0 if self._thrust_radii is None else self._thrust_radii
        if np.any(ratio > radii * self.u_bound * (1 + 1e-6)):
            return None, f"{status} (thrust bound violated)", ""
        return sol, status, ""

    def _fallback(self, k: int, x: np.ndarray, reason: str) -> np.ndarray:
        self.fallbacks += 1
        age = k - self.plan_k
        if self.plan is not None and 0 < age < self.n_c:
            u, used = self.plan[age], "shifted plan"
        else:
            u, used = self.lqr.control(k, x), "lqr"
            self._w = None  # cold start next time
            self._lam_g = self._lam_x = None
        self.events.append({"step": int(k), "reason": reason, "fallback": used})
        log.warning("MPC step %d: IPOPT failed (%s); using %s", k, reason, used)
        return saturate(u, self.plant_kind)
