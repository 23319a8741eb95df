"""Metrics of a station-keeping closed loop (Patel & Subbarao, "Station-keeping in the near
rectilinear halo orbit": Delta-V in m/s, thrust activations, tube gauges and excursions) and the
deviation from the reference, from a :class:`~ocreach.control.simulate.SimResult`."""
from __future__ import annotations

from typing import Any

import numpy as np

from ocreach.control.common import control_scale
from ocreach.control.reference import TrackingReference
from ocreach.control.simulate import SimResult
from ocreach.control.stationkeeping.tubes import TubeSchedule


def delta_v_si(U: np.ndarray, a_max: float, dt: float, units) -> np.ndarray:
    """Per-step Delta-V in m/s: ``||u_k|| a_max dt`` (model units) times ``l*/t*``."""
    return np.linalg.norm(np.asarray(U, float), axis=1) * a_max * dt * units.velocity


def _edges(on: np.ndarray) -> int:
    on = np.asarray(on, bool)
    return int(on[0]) + int(np.sum(on[1:] & ~on[:-1])) if on.size else 0


def station_keeping_metrics(res: SimResult, reference: TrackingReference,
                            schedule: TubeSchedule | None, problem,
                            controller=None) -> tuple[dict[str, Any], np.ndarray | None]:
    """Metrics of one closed-loop run (units: m/s, km, ms) and the gauge of every state (K+1,)
    (``schedule=None``: no tube, the gauge metrics and the gauges are ``None``).

    ``delta_v_mps`` = sum_k ||a_max u_k|| dt (applied thrust) in m/s, ``delta_v_per_rev_mps`` the
    same over the revolutions flown; ``activations`` off->on switches of the thrust (event-MPC:
    its trigger), ``duty_cycle`` the fraction of steps with thrust on, ``max_gauge`` / RMS of the
    tube gauge of the true state, ``max_gauge_off`` the largest gauge while the thrust is off (None
    if it never is), ``excursions`` the steps with gauge > 1 while the thrust is off, max / RMS
    position and velocity deviation from the reference, ``time_per_step_ms`` (mean controller time
    per step), ``time_per_solve_ms`` (mean over MPC solves), ``solver_failures`` (MPC fallbacks).
    """
    units = problem.units
    model = reference.model
    K = res.U.shape[0]
    a = control_scale(model, reference.params, "auto")
    dv = delta_v_si(res.U_applied, a, reference.dt, units)
    un = np.linalg.norm(res.U_applied, axis=1)
    if controller is not None and hasattr(controller, "active") and len(controller.active) == K:
        on = np.asarray(controller.active, bool)
        activations = int(controller.trigger.activations)
    else:
        on = un > 0
        activations = _edges(on)
    gam = off = None  # no tube (no tube controller on the corrected reference): no gauges
    if schedule is not None:
        ks = np.arange(K + 1)
        refresh = np.array([schedule.refresh_step(int(k)) for k in ks])
        gam = np.empty(K + 1)
        for r in np.unique(refresh):  # one batched gauge call per tube
            sel = refresh == r
            gam[sel] = schedule.tube(int(r)).gauge(ks[sel], res.X[sel])
        off = np.r_[~on, True]  # the final state has no control: off
    return _deviation_metrics(res, reference, problem, controller, dv, on, activations, gam,
                              off), gam


def _deviation_metrics(res: SimResult, reference: TrackingReference, problem, controller,
                       dv: np.ndarray, on: np.ndarray, activations: int, gam: np.ndarray | None,
                       off: np.ndarray | None) -> dict[str, Any]:
    """The metrics of :func:`station_keeping_metrics` from the per-step Delta-V ``dv``, thrust
    flags ``on`` and gauges ``gam`` (``None``: no tube, gauge metrics ``None``)."""
    units = problem.units
    K = res.U.shape[0]
    revs = K / reference.revolution_steps
    un = np.linalg.norm(res.U_applied, axis=1)
    pos, vel = list(problem.position_dims), list(problem.velocity_dims)
    d = res.X - res.X_ref
    dp = np.linalg.norm(d[:, pos], axis=1) * units.length / 1e3
    dvv = np.linalg.norm(d[:, vel], axis=1) * units.velocity
    exc = np.flatnonzero(off & (gam > 1.0)) if gam is not None else None
    solves = getattr(controller, "solve_times", None) or []
    return {
        "revolutions": float(revs),
        "n_steps": int(K),
        "delta_v_mps": float(dv.sum()),
        "delta_v_per_rev_mps": float(dv.sum() / revs),
        "activations": activations,
        "duty_cycle": float(on.mean()),
        "max_gauge": float(gam.max()) if gam is not None else None,
        "max_gauge_off": float(gam[off].max()) if gam is not None and off.any() else None,
        "excursions_off": int(exc.size) if exc is not None else None,
        "excursion_steps": exc.tolist()[:200] if exc is not None else [],
        "max_deviation_km": float(dp.max()),
        "rms_deviation_km": float(np.sqrt(np.mean(dp**2))),
        "max_deviation_mps": float(dvv.max()),
        "rms_deviation_mps": float(np.sqrt(np.mean(dvv**2))),
        "final_deviation_km": float(dp[-1]),
        "max_thrust_ratio": float(un.max()),
        "time_per_step_ms": float(1e3 * np.mean(res.step_times)),
        "time_per_solve_ms": float(1e3 * np.mean(solves)) if len(solves) else None,
        "solves": int(len(solves)),
        "solver_failures": int(res.fallbacks),
        "total_time_s": float(res.total_time),
    }


__all__ = ["delta_v_si", "station_keeping_metrics"]
