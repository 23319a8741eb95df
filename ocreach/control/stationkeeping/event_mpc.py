"""Event-triggered MPC on a drift tube (Patel & Subbarao, "Station-keeping in the near
rectilinear halo orbit").

The thrust is off while the state stays in the drift tube ``R(t)`` (:mod:`ocreach.control.stationkeeping.tubes`,
schedules of :mod:`ocreach.control.stationkeeping.drift_tubes`).  When the gauge of the state exceeds 1 the MPC of
Eq. 27 is switched on, its predicted states constrained to the ``beta``-shrunk tube (soft: a
penalised slack keeps the NLP feasible from outside the tube); it stays on until the gauge has been
``<= beta`` for ``m`` consecutive steps (hysteresis, :class:`EventTrigger`), then the thrust is off
again.
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np

from ocreach.control.lqr import LQR
from ocreach.control.mpc import MPC
from ocreach.control.reference import TrackingReference
from ocreach.control.stationkeeping.paper import PAPER_N
from ocreach.control.stationkeeping.tube_mpc import MPCWrapper
from ocreach.control.stationkeeping.tubes import TubeSchedule
from ocreach.errors import ProblemError


class EventTrigger:
    """Hysteresis on the tube gauge: off -> on when ``gamma > threshold`` (default 1: the state
    left the tube); on -> off when ``gamma <= beta`` for ``m`` consecutive steps (back inside the
    shrunk tube).  ``update`` returns the thrust flag for the current step."""

    def __init__(self, beta: float = 0.7, m: int = 3, threshold: float = 1.0) -> None:
        if isinstance(threshold, bool) or not np.isfinite(threshold) or threshold <= 0:
            raise ProblemError(f"threshold (trigger gauge) must be a finite number > 0; got {threshold!r}")
        if isinstance(beta, bool) or not np.isfinite(beta) or not 0 < beta < threshold:
            raise ProblemError(f"beta (release gauge, shrunk tube) must satisfy 0 < beta < threshold "
                               f"= {threshold:g}; got {beta!r}")
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1:
            raise ProblemError(f"m (steps inside the shrunk tube before release) must be an integer "
                               f">= 1; got {m!r}")
        self.beta, self.m, self.threshold = float(beta), int(m), float(threshold)
        self.reset()

    def reset(self) -> None:
        self.active = False
        self.inside = 0
        self.activations = 0

    def update(self, gamma: float) -> bool:
        if np.isnan(gamma):
            raise ProblemError(f"gauge must be a number; got {gamma!r}")
        if not self.active:
            if gamma > self.threshold:
                self.active = True
                self.activations += 1
                self.inside = 0
        else:
            self.inside = self.inside + 1 if gamma <= self.beta else 0
            if self.inside >= self.m:
                self.active = False
                self.inside = 0
        return self.active


def trigger_signal(gammas: Any, beta: float = 0.7, m: int = 3, threshold: float = 1.0) -> np.ndarray:
    """Thrust flags of :class:`EventTrigger` over a gauge sequence (for plots and tests)."""
    trig = EventTrigger(beta, m, threshold)
    return np.array([trig.update(float(g)) for g in np.asarray(gammas, float)], dtype=bool)


def check_anticipate(anticipate: Any) -> bool:
    """``anticipate`` (the trigger fires on the predicted drift at the next refresh) as a bool;
    :class:`ProblemError` unless it is True or False."""
    if not isinstance(anticipate, (bool, np.bool_)):
        raise ProblemError(f"anticipate must be True or False (run_station_keeping also takes None: "
                           f"the problem's default); got {anticipate!r}")
    return bool(anticipate)


class EventTriggeredMPC(MPCWrapper):
    """Thrust off inside the tube; the tube-constrained MPC (soft) when the trigger is on.

    ``schedule`` a :class:`TubeSchedule` on the same reference; ``mpc_options`` for
    :class:`MPC` (``tube`` and ``tube_slack`` are set here); ``trigger`` an :class:`EventTrigger`;
    ``target`` the tube scale the MPC's predicted states are constrained to (default: the
    trigger's ``beta``, so the MPC aims for the release region).  Logs per step: ``gauges``,
    ``active``, ``slacks`` (largest predicted slack, 0 when off), ``excursions`` (steps where the
    gauge exceeds 1, with the thrust flag).

    ``anticipate=True`` (not in the paper): the trigger sees ``max(gamma_now, gamma_next)``,
    ``gamma_next`` the gauge, in the next refresh's tube, of the state's drift predicted to the
    next refresh step by the reference's STMs (:meth:`predicted_gauge`).  A guaranteed tube that
    must restart from the initial set before perilune (``tube_interval="adaptive"``) is a gate the
    state has to pass; this fires while the correction is still cheap, not at the gate.  The
    prediction is linear (an estimate): it decides when to thrust, the tubes stay what they are.
    """

    name = "event-mpc"

    def __init__(self, Q, R, schedule: TubeSchedule, *, trigger: EventTrigger | None = None,
                 n_p: int = PAPER_N, n_c: int | None = None, tube_slack: float = 100.0,
                 target: float | None = None, fallback: LQR | None = None,
                 anticipate: bool = False, **mpc_options: Any) -> None:
        self.anticipate = check_anticipate(anticipate)
        self._to_refresh: dict[tuple[int, int], np.ndarray] = {}
        self.schedule = schedule
        self.trigger = trigger or EventTrigger()
        self.target = self.trigger.beta if target is None else float(target)
        if not np.isfinite(self.target) or self.target <= 0:
            raise ProblemError(f"target (tube scale for the MPC) must be > 0; got {target!r}")
        q = schedule.n_generators
        self.mpc = MPC(Q, R, n_p=n_p, n_c=n_p if n_c is None else n_c, tube=q,
                       tube_slack=tube_slack, fallback=fallback, **mpc_options)
        self.n_p = n_p
        self.reset()

    def setup(self, reference: TrackingReference, control_set_kind: str) -> EventTriggeredMPC:
        self._setup_mpc(reference, control_set_kind)
        self.nu = reference.model.n_u
        self.reset()
        return self

    def reset(self) -> None:
        self.trigger.reset()
        if getattr(self.mpc, "reference", None) is not None:
            self.mpc.reset()
        self.gauges: list[float] = []
        self.predicted_gauges: list[float] = []  # anticipate: gauge at the next refresh
        self.active: list[bool] = []
        self.slacks: list[float] = []
        self.solve_times: list[float] = []

    def predicted_gauge(self, k: int, x: np.ndarray) -> float:
        """Gauge in the next refresh's tube of ``x_ref(r) + Phi(r, k) (x - x_ref(k))``, ``r`` the
        next refresh step after ``k`` and ``Phi`` the product of the reference's one-step STMs
        (along a non-periodic reference, after the last refresh: the tubes' last step)."""
        sched, ref = self.schedule, self.schedule.reference
        r = sched.next_refresh(sched.refresh_step(k))
        if sched.starts is not None:
            r = min(r, sched.end - 1)
        key = (k % ref.n_steps, r - k)  # Phi depends on the phase and the steps to go
        if key not in self._to_refresh:
            ref.linearize()
            idx = ref.gains_index(np.arange(k, r))
            Phi = np.eye(ref.model.n_x)
            for i in idx:
                Phi = ref.A[i] @ Phi
            self._to_refresh[key] = Phi
        d = self._to_refresh[key] @ (np.asarray(x, float) - ref.state(k))
        return sched.gauge(r, ref.state(r) + d)

    def control(self, k: int, x: np.ndarray) -> np.ndarray:
        g = self.schedule.gauge(k, x)
        g_next = self.predicted_gauge(k, x) if self.anticipate else 0.0
        on = self.trigger.update(max(g, g_next))
        self.gauges.append(g)
        self.predicted_gauges.append(g_next)
        self.active.append(on)
        if not on:
            self.slacks.append(0.0)
            return np.zeros(self.nu)
        c, G = self.schedule.window(k, self.n_p, beta=self.target)
        self.mpc.set_tube(c, G)
        t = time.perf_counter()
        u = self.mpc.control(k, x)
        self.solve_times.append(time.perf_counter() - t)
        self.slacks.append(self.mpc.last_tube_slack)
        return u


__all__ = ["EventTrigger", "EventTriggeredMPC", "check_anticipate", "trigger_signal"]
