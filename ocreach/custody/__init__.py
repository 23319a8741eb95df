"""Telescope custody of a manoeuvring space object (Tucker et al., Sec. 2.3-2.4 and 3).

How long can a telescope keep an object in its field of view when the object may thrust?  The
reachable positions at a horizon are over-approximated by a ball; custody holds while enough of
that ball stays in the FOV.  One module per step:

* :mod:`~ocreach.custody.observers` -- where the telescope is (geocentre, ground site, Lagrange
  point, another spacecraft) and :func:`parse_observer` for the names users type;
* :mod:`~ocreach.custody.fov` -- fields of view (cone, pyramid), the focal plane, where a ball
  falls in a FOV;
* :mod:`~ocreach.custody.probability` -- the probability of custody at one horizon (Eq. 13-14,
  corrected);
* :mod:`~ocreach.custody.horizon` -- the custody-loss horizon (bracketing and bisection;
  Algorithm 1 as printed, for comparison);
* :mod:`~ocreach.custody.reach_balls` -- reachable-position balls per horizon (``bvp`` boundary
  points, minimum enclosing and outer balls), checked by Monte Carlo;
* :mod:`~ocreach.custody.sweep_task` -- custody as a sweep output;
* :mod:`~ocreach.custody.report` and :mod:`~ocreach.custody.cli` -- ``ocreach custody``: tables,
  ``custody.json``, figures.

May import: the reachability methods (:mod:`ocreach.reach`), problems, geometry and helpers;
nothing here imports the command line, control or sweeps.
"""
from ocreach.custody.fov import (
    FOV,
    ball_in_fov,
    ball_outline,
    boresight_frame,
    covered_fraction,
    gnomonic,
    make_fov,
    points_in_fov,
)
from ocreach.custody.horizon import Horizon, custody_horizon, tucker_algorithm1
from ocreach.custody.observers import (
    TT_MINUS_UT1_S,
    WGS84_A_KM,
    WGS84_F,
    Observer,
    earth_moon_frame,
    earth_rotation_angle,
    geocentre,
    geodetic_to_ecef_km,
    ground_site,
    orbit_observer,
    parse_observer,
)
from ocreach.custody.probability import MODELS, check_probability, custody_probability
from ocreach.custody.sweep_task import SWEEP_PARAMS, check_sweep_params, sweep_task

__all__ = [
    "FOV", "MODELS", "SWEEP_PARAMS", "TT_MINUS_UT1_S", "WGS84_A_KM", "WGS84_F", "Horizon",
    "Observer", "ball_in_fov", "ball_outline", "boresight_frame", "check_probability",
    "check_sweep_params", "covered_fraction", "custody_horizon", "custody_probability",
    "earth_moon_frame", "earth_rotation_angle", "geocentre", "geodetic_to_ecef_km", "gnomonic",
    "ground_site", "make_fov", "orbit_observer", "parse_observer", "points_in_fov", "sweep_task",
    "tucker_algorithm1",
]
