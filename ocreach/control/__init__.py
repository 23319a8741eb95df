"""Station keeping on a reference: time-varying LQR and nonlinear MPC (Patel & Subbarao Eq. 26-28).

::

    from ocreach.control import LQR, MPC, SimOptions, compare_controllers
    res = compare_controllers(problem, {"lqr": LQR(Q, R), "mpc": MPC(Q, R, n_p=10, n_c=5)},
                              SimOptions(dt=..., offset_box=..., disturbance=1e-7))
    res["mpc"].metrics

The report ``lqr_vs_mpc_report(problem, out_dir, **options)`` lives in
:mod:`ocreach.control.report` (imported lazily; it needs matplotlib).  Reachable-set tubes and
gauges: :mod:`ocreach.control.tube`; event-triggered station keeping:
:mod:`ocreach.control.station_keeping` (closed-loop runs; the controller
:mod:`ocreach.control.event_mpc`, the drift-tube schedules :mod:`ocreach.control.drift_tubes`, the
metrics :mod:`ocreach.control.station_keeping_metrics`, the paper's settings
:mod:`ocreach.control.station_keeping_paper`; report: :mod:`ocreach.control.station_keeping_report`);
robust tube MPC: :mod:`ocreach.control.tube_mpc`.
"""
from ocreach.control.discretize import Discretization, rk4_expression
from ocreach.control.lqr import LQR, dare, periodic_riccati, riccati_backward
from ocreach.control.mpc import MPC
from ocreach.control.reference import (
    TrackingReference,
    natural_reference,
    periodic_reference,
    reference_from_problem,
)
from ocreach.control.simulate import (
    Plant,
    SimOptions,
    SimResult,
    closed_loop_metrics,
    compare_controllers,
    simulate,
)
from ocreach.control.event_mpc import EventTrigger, EventTriggeredMPC
from ocreach.control.station_keeping import run_station_keeping
from ocreach.control.tube import Tube, TubeSchedule, gauge, linear_drift_tube
from ocreach.control.tube_mpc import TubeMPC


def lqr_vs_mpc_report(problem, out_dir, **options) -> dict:
    """See :func:`ocreach.control.report.lqr_vs_mpc_report`."""
    from ocreach.control.report import lqr_vs_mpc_report as _report

    return _report(problem, out_dir, **options)


__all__ = [
    "LQR",
    "MPC",
    "EventTrigger",
    "EventTriggeredMPC",
    "Tube",
    "TubeMPC",
    "TubeSchedule",
    "gauge",
    "linear_drift_tube",
    "run_station_keeping",
    "Discretization",
    "Plant",
    "SimOptions",
    "SimResult",
    "TrackingReference",
    "closed_loop_metrics",
    "compare_controllers",
    "dare",
    "lqr_vs_mpc_report",
    "natural_reference",
    "periodic_reference",
    "periodic_riccati",
    "reference_from_problem",
    "riccati_backward",
    "rk4_expression",
    "simulate",
]
