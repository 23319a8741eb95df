"""Closed-loop simulation on the true nonlinear dynamics, and controller comparison.

The plant integrates ``dx/dt = f(x, sat(u_k), t; p) + E w_k`` over each step with SciPy's DOP853
(``rtol = 1e-10``, ``atol = 1e-12`` by default), with the control and the disturbance held over
the step.  ``E`` selects the velocity states, so ``w`` is an acceleration; per step it is drawn
uniformly from the zonotope ``W xi``, ``|xi|_inf <= 1`` (Patel & Subbarao: ``W = 1e-7 I_3`` in
non-dimensional units).  An initial offset is either given or drawn uniformly from the box
``diag(offset_box) xi`` (Patel & Subbarao's initial set: ``1e-4`` in position, ``5e-4`` in velocity).
All draws come from one seeded generator and are the same for every controller of a comparison.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp
from tqdm.auto import tqdm

from ocreach.control.common import control_scale, saturate, thrust_ratio
from ocreach.control.reference import TrackingReference, reference_from_problem
from ocreach.errors import ProblemError, SolverError


@dataclass
class SimOptions:
    """Closed-loop simulation settings (all quantities in model units).

    dt : control step (default: the problem's grid step; rounded to divide a reference period).
    n_steps : number of control steps (default: the problem's grid span; l2-halo: one period).
    x0_offset : initial state minus reference state (overrides ``offset_box``).
    offset_box : half-widths of the uniform initial-offset box (length ``n_x``), or ``None``.
    disturbance : generator ``W`` (scalar times identity, diagonal, or matrix) of the per-step
        acceleration disturbance on the velocity states; ``0`` or ``None`` for none.
    seed : seed of the offset and disturbance draws.
    rtol, atol : plant integrator tolerances (DOP853).
    n_sub : RK4 substeps per step of the controllers' prediction model, or ``"auto"`` (default):
        doubled from 2 until its one-step error along the reference is <= 1e-6 (l2-halo: 2,
        error 5e-12; nrho-9-2: 32, error 1.5e-7 -- 2 substeps are 5.6e-3 off at perilune).
    progress : show a tqdm progress bar.
    """

    dt: float | None = None
    n_steps: int | None = None
    x0_offset: Any = None
    offset_box: Any = None
    disturbance: Any = 1e-7
    seed: int = 0
    rtol: float = 1e-10
    atol: float = 1e-12
    n_sub: int | str = "auto"
    progress: bool = True


@dataclass
class SimResult:
    """One closed-loop run: states ``X (K+1, n_x)``, commanded ``U (K, n_u)`` (normalised),
    applied (saturated) ``U_applied``, reference ``X_ref``, per-step controller time, fallbacks."""

    name: str
    times: np.ndarray
    X: np.ndarray
    U: np.ndarray
    U_applied: np.ndarray
    X_ref: np.ndarray
    W: np.ndarray
    step_times: np.ndarray
    total_time: float
    fallbacks: int = 0
    events: list = field(default_factory=list)
    metrics: dict = field(default_factory=dict)


def _generator(name: str, W, n: int) -> np.ndarray:
    if W is None:
        return np.zeros((n, n))
    M = np.asarray(W, dtype=float)
    if M.ndim == 0:
        M = float(M) * np.eye(n)
    elif M.ndim == 1:
        if M.size != n:
            raise ProblemError(f"{name} diagonal must have length {n}; got {M.size}")
        M = np.diag(M)
    if M.ndim != 2 or M.shape[0] != n or not np.all(np.isfinite(M)):
        raise ProblemError(f"{name} must be a finite scalar, length-{n} diagonal or {n}xq matrix; "
                           f"got shape {np.shape(W)}")
    return M


class Plant:
    """True dynamics with saturation and an acceleration disturbance (one step at a time)."""

    def __init__(self, reference: TrackingReference, control_set_kind: str,
                 velocity_dims: tuple[int, ...], rtol: float = 1e-10, atol: float = 1e-12) -> None:
        self.model = reference.model
        self.p = reference.params
        self.kind = control_set_kind
        self.E = np.zeros((self.model.n_x, len(velocity_dims)))
        self.E[list(velocity_dims), np.arange(len(velocity_dims))] = 1.0
        self.rtol, self.atol = rtol, atol

    def step(self, x: np.ndarray, u: np.ndarray, w: np.ndarray, t0: float, dt: float) -> np.ndarray:
        f = self.model.f_fun
        ua = saturate(u, self.kind)
        acc = self.E @ w
        p = self.p

        def rhs(t, xx):
            return np.asarray(f(xx, ua, t, p)).ravel() + acc

        sol = solve_ivp(rhs, (t0, t0 + dt), x, method="DOP853", rtol=self.rtol, atol=self.atol)
        if not sol.success:
            raise SolverError(f"plant integration failed at t = {t0:g}: {sol.message}")
        return sol.y[:, -1]


def simulate(reference: TrackingReference, controller, *, control_set_kind: str,
             velocity_dims: tuple[int, ...], options: SimOptions | None = None,
             name: str | None = None, plant=None) -> SimResult:
    """Run ``controller`` (``setup`` already called) in closed loop on the true dynamics.

    ``plant``: an object with ``step(x, u, w, t0, dt)`` (e.g.
    :class:`ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant`); default the reference's own model
    (:class:`Plant`).
    """
    opt = options or SimOptions()
    model = reference.model
    nx = model.n_x
    K = reference.n_default if opt.n_steps is None else int(opt.n_steps)
    if K < 1:
        raise ProblemError(f"n_steps must be >= 1; got {opt.n_steps!r}")
    rng = np.random.default_rng(opt.seed)
    if opt.x0_offset is not None:
        off = model.validate_state(opt.x0_offset, "x0_offset")
    elif opt.offset_box is not None:
        box = model.validate_state(opt.offset_box, "offset_box")
        off = box * rng.uniform(-1.0, 1.0, nx)
    else:
        off = np.zeros(nx)
    Wg = _generator("disturbance", opt.disturbance, len(velocity_dims))
    xi = rng.uniform(-1.0, 1.0, (K, Wg.shape[1]))
    Wdraw = xi @ Wg.T
    if plant is None:
        plant = Plant(reference, control_set_kind, velocity_dims, opt.rtol, opt.atol)
    elif not callable(getattr(plant, "step", None)):
        raise ProblemError(f"plant must have a step(x, u, w, t0, dt) method; got "
                           f"{type(plant).__name__}")
    if hasattr(controller, "reset"):
        controller.reset()
    X = np.empty((K + 1, nx))
    U = np.empty((K, model.n_u))
    X[0] = reference.state(0) + off
    step_times = np.empty(K)
    label = name or getattr(controller, "name", "controller")
    t_all = time.perf_counter()
    for k in tqdm(range(K), desc=label, disable=not opt.progress, leave=False):
        t0 = time.perf_counter()
        U[k] = controller.control(k, X[k])
        step_times[k] = time.perf_counter() - t0
        X[k + 1] = plant.step(X[k], U[k], Wdraw[k], float(reference.time(k)), reference.dt)
        if not np.all(np.isfinite(X[k + 1])):
            raise SolverError(f"closed loop '{label}' produced a non-finite state at step {k + 1}")
    total = time.perf_counter() - t_all
    return SimResult(
        name=label, times=reference.time(np.arange(K + 1)), X=X, U=U,
        U_applied=saturate(U, control_set_kind), X_ref=reference.state(np.arange(K + 1)),
        W=Wdraw, step_times=step_times, total_time=total,
        fallbacks=int(getattr(controller, "fallbacks", 0)),
        events=list(getattr(controller, "events", [])))


def closed_loop_metrics(res: SimResult, reference: TrackingReference, control_set_kind: str,
                        units=None) -> dict[str, float]:
    """Patel & Subbarao Table 2 metrics plus delta-v and the thrust ratio.

    ``effort = sum_k ||a_max u_k||`` (thrust acceleration, DU/TU^2, the paper's non-dimensional
    control) -- or ``sum_k ||u_k||`` for models without ``a_max``; ``effort_normalised`` is
    ``sum_k ||u_k||`` (throttle fractions); ``tracking_error = sum_{k=0}^{K} ||x_k - x_ref_k||``
    (full non-dimensional state); ``delta_v = sum_k ||a_max u_k|| dt`` in m/s (model units without
    ``units``); ``max_thrust_ratio = max_k ||u_k|| / 1`` (commanded control, norm of the set).
    """
    s = control_scale(reference.model, reference.params, "auto")
    un = np.linalg.norm(res.U_applied, axis=1)
    err = np.linalg.norm(res.X - res.X_ref, axis=1)
    dv = float(np.sum(un) * s * reference.dt)
    if units is not None:
        dv *= units.velocity
    pos = list(range(min(3, reference.model.n_x // 2)))
    return {
        "effort": float(np.sum(un) * s),
        "effort_normalised": float(np.sum(un)),
        "tracking_error": float(np.sum(err)),
        "final_position_error": float(np.linalg.norm((res.X - res.X_ref)[-1, pos])),
        "delta_v": dv,
        "time_per_step": float(np.mean(res.step_times)),
        "total_time": float(res.total_time),
        "max_thrust_ratio": float(np.max(thrust_ratio(res.U, control_set_kind))),
        "fallbacks": int(res.fallbacks),
        "n_steps": int(res.U.shape[0]),
    }


def compare_controllers(problem, controllers: dict[str, Any], sim_options: SimOptions | None = None,
                        reference: TrackingReference | None = None) -> dict[str, SimResult]:
    """Set up each controller on the problem's reference and simulate them with the same draws.

    ``controllers`` maps a label to an object with ``setup(reference, control_set_kind)`` and
    ``control(k, x)`` (e.g. :class:`~ocreach.control.LQR`, :class:`~ocreach.control.MPC`).
    Returns ``{label: SimResult}`` with ``metrics`` filled (:func:`closed_loop_metrics`).
    """
    opt = sim_options or SimOptions()
    pad = max([int(getattr(c, "n_p", 0)) for c in controllers.values()] + [0])
    ref = reference or reference_from_problem(problem, dt=opt.dt, n_sub=opt.n_sub, pad=pad)
    kind = problem.control_set.kind
    out = {}
    for label, ctl in controllers.items():
        if not (hasattr(ctl, "setup") and hasattr(ctl, "control")):
            raise ProblemError(f"controller {label!r} must have setup(reference, kind) and "
                               f"control(k, x); got {type(ctl).__name__}")
        ctl.setup(ref, kind)
        res = simulate(ref, ctl, control_set_kind=kind, velocity_dims=problem.velocity_dims,
                       options=opt, name=label)
        res.metrics = closed_loop_metrics(res, ref, kind, problem.units)
        out[label] = res
    return out


__all__ = ["Plant", "SimOptions", "SimResult", "closed_loop_metrics", "compare_controllers",
           "simulate"]
