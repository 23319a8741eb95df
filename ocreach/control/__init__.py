"""Control on a reference: time-varying LQR and nonlinear MPC (Patel & Subbarao Eq. 26-28).

::

    from ocreach.control import LQR, MPC, SimOptions, compare_controllers
    res = compare_controllers(problem, {"lqr": LQR(Q, R), "mpc": MPC(Q, R, n_p=10, n_c=5)},
                              SimOptions(dt=..., offset_box=..., disturbance=1e-7))
    res["mpc"].metrics

* :mod:`~ocreach.control.common` -- weights and thrust saturation;
* :mod:`~ocreach.control.reference` -- reference trajectories (natural, periodic, from a problem);
* :mod:`~ocreach.control.lqr`, :mod:`~ocreach.control.mpc` -- the controllers;
* :mod:`~ocreach.control.simulate` -- closed-loop simulation on the nonlinear dynamics;
* :mod:`~ocreach.control.report` -- ``ocreach report lqr-vs-mpc`` (imported lazily; it needs
  matplotlib);
* :mod:`ocreach.control.stationkeeping` -- station keeping with reachable-set tubes (tubes, drift
  tubes, event-triggered and robust tube MPC, the ephemeris plant and reference, the runs and
  their report); its main names are re-exported here.

The discrete prediction model lives in :mod:`ocreach.dynamics.discretize` (re-exported here).
May import: the methods, problems, sets, dynamics and the helpers; never the command line.
"""
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
from ocreach.control.stationkeeping import (
    EventTrigger,
    EventTriggeredMPC,
    Tube,
    TubeMPC,
    TubeSchedule,
    gauge,
    linear_drift_tube,
    run_station_keeping,
)
from ocreach.dynamics.discretize import Discretization, rk4_expression


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
