"""Station keeping on a reference orbit with reachable-set tubes (Patel & Subbarao Sec. 5).

* :mod:`~ocreach.control.stationkeeping.tubes` -- zonotope tubes along a reference, their gauge
  (LP and CasADi form) and schedules of refreshes;
* :mod:`~ocreach.control.stationkeeping.drift_tubes` -- drift-tube schedules on the CR3BP,
  linearised or guaranteed by ``taylor`` / ``sdc``;
* :mod:`~ocreach.control.stationkeeping.ephemeris_tubes` -- tubes along a non-periodic
  (ephemeris-corrected) reference;
* :mod:`~ocreach.control.stationkeeping.event_mpc` -- event-triggered MPC with hysteresis;
* :mod:`~ocreach.control.stationkeeping.tube_mpc` -- robust tube MPC (Chisci et al. 2001);
* :mod:`~ocreach.control.stationkeeping.ephemeris_plant`,
  :mod:`~ocreach.control.stationkeeping.ephemeris_reference` -- the DE421 plant and the NRHO
  corrected into a multi-revolution orbit of it;
* :mod:`~ocreach.control.stationkeeping.runs`, :mod:`~ocreach.control.stationkeeping.metrics`,
  :mod:`~ocreach.control.stationkeeping.paper`, :mod:`~ocreach.control.stationkeeping.report`
  -- the closed-loop runs, their metrics, the paper's settings and ``ocreach report
  station-keeping``.

May import: :mod:`ocreach.control` (LQR, MPC, references, the simulator), the guaranteed
methods, sets, problems and the helpers.
"""
from ocreach.control.stationkeeping.event_mpc import EventTrigger, EventTriggeredMPC
from ocreach.control.stationkeeping.runs import run_station_keeping
from ocreach.control.stationkeeping.tube_mpc import TubeMPC
from ocreach.control.stationkeeping.tubes import Tube, TubeSchedule, gauge, linear_drift_tube

__all__ = ["EventTrigger", "EventTriggeredMPC", "Tube", "TubeMPC", "TubeSchedule", "gauge",
           "linear_drift_tube", "run_station_keeping"]
