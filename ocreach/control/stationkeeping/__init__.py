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
  station-keeping``;
* orbit maintenance as flown (docs/validation/orbit-maintenance.md):
  :mod:`~ocreach.control.stationkeeping.srp` (cannonball SRP),
  :mod:`~ocreach.control.stationkeeping.navigation` (OD errors),
  :mod:`~ocreach.control.stationkeeping.execution` (burn errors, minimum burn, skips),
  :mod:`~ocreach.control.stationkeeping.scenario` (plant, reference, shared data),
  :mod:`~ocreach.control.stationkeeping.xaxis` (x-axis crossing control),
  :mod:`~ocreach.control.stationkeeping.target_point` (STT target point),
  :mod:`~ocreach.control.stationkeeping.corridor` (reachable-set corridor control),
  :mod:`~ocreach.control.stationkeeping.impulsive_tube` (event-triggered impulsive tube MPC),
  :mod:`~ocreach.control.stationkeeping.continuous` (LQR, MPC),
  :mod:`~ocreach.control.stationkeeping.orbit_maintenance` (the loop),
  :mod:`~ocreach.control.stationkeeping.maintenance_mc` (Monte Carlo on the sweep executors),
  :mod:`~ocreach.control.stationkeeping.maintenance_report` (``ocreach report
  orbit-maintenance``), :mod:`~ocreach.control.stationkeeping.published` (published budgets and
  their sources)::

      from ocreach.control.stationkeeping import MaintenanceSettings, make_controller, run_maintenance
      settings = MaintenanceSettings.from_options(years=1.0, area_to_mass=0.01)
      run = run_maintenance(settings, make_controller("xaxis"), run=0)
      run["dv_per_year_mps"], run["burns_per_rev"], run["lost"]

May import: :mod:`ocreach.control` (LQR, MPC, references, the simulator), the guaranteed
methods, sets, problems and the helpers.
"""
from ocreach.control.stationkeeping.event_mpc import EventTrigger, EventTriggeredMPC
from ocreach.control.stationkeeping.execution import ExecutionErrors
from ocreach.control.stationkeeping.maintenance_mc import run_monte_carlo
from ocreach.control.stationkeeping.navigation import NavigationErrors
from ocreach.control.stationkeeping.orbit_maintenance import (
    CONTROLLERS,
    MaintenanceSettings,
    make_controller,
    run_maintenance,
)
from ocreach.control.stationkeeping.runs import run_station_keeping
from ocreach.control.stationkeeping.scenario import Scenario, ScenarioSpec, scenario
from ocreach.control.stationkeeping.srp import SolarRadiationPressure
from ocreach.control.stationkeeping.tube_mpc import TubeMPC
from ocreach.control.stationkeeping.tubes import Tube, TubeSchedule, gauge, linear_drift_tube

__all__ = ["CONTROLLERS", "EventTrigger", "EventTriggeredMPC", "ExecutionErrors",
           "MaintenanceSettings", "NavigationErrors", "Scenario", "ScenarioSpec",
           "SolarRadiationPressure", "Tube", "TubeMPC", "TubeSchedule", "gauge",
           "linear_drift_tube", "make_controller", "run_maintenance", "run_monte_carlo",
           "run_station_keeping", "scenario"]
