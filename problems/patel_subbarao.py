"""Scenarios of Patel & Subbarao, "Set-based reachability for low-thrust spacecraft in two-body and
cislunar dynamical systems": Earth-Mars transfer (Eq. 29, Table 1), L2 halo (Tables 2-3) and the
L2 9:2 NRHO method comparison (76 h horizon).

The periodic reference orbits are corrected by :mod:`ocreach.orbits` once per process
(``functools.lru_cache``), so repeated ``get_problem`` calls are fast.
"""
from __future__ import annotations

from functools import cache

import numpy as np

from ocreach.errors import ProblemError, check_positive
from ocreach.models import cr3bp, twobody
from ocreach.orbits import PeriodicOrbit, correct_symmetric, nrho_9_2
from ocreach.problem import Problem, time_grid
from ocreach.units import EARTH_MOON_PATEL, SUN_AU

CITATION = ("J. Patel & K. Subbarao, \"Set-based reachability for low-thrust spacecraft in two-body "
            "and cislunar dynamical systems\"")
BOWERFIND_TAHERI = ("S. Bowerfind & E. Taheri, \"Rapid approximation of low-thrust spacecraft "
                    "reachable sets within complex two-body and cislunar dynamics\", Aerospace 11(5), 2024")
MU_PATEL = 0.01215
#: Paper's L2 halo initial state (non-dimensional), Patel & Subbarao Sec. "CR3BP results".
HALO_SEED = (1.1720, 0.0, -0.0862, 0.0, -0.1880, 0.0)
#: Paper's quoted halo period (hours).
HALO_PERIOD_PAPER_H = 346.322857
#: Spacecraft of the cislunar cases (Table 3) and of the Earth-Mars case.
CISLUNAR_THRUST_N, EM_THRUST_N = 0.1, 0.3
MASS_KG, ISP_S = 1000.0, 3000.0
#: Eq. 29: heliocentric departure state [km, km/s], epoch 10 April 2007.
EARTH_MARS_STATE_KM = (-140699693.0, -51614428.0, 980.0, 9.774596, -28.07828, 4.337725e-4)
EARTH_MARS_EPOCH = "2007-04-10"
HOUR_TU = 3600.0 / EARTH_MOON_PATEL.time
#: Initial-set generators of the cislunar cases (Patel & Subbarao, NRHO section): G_pos = 1e-4 I_3
#: DU, G_vel = 5e-4 I_3 DU/TU.  The paper gives them for the NRHO and only says "a small generator
#: matrix" for the L2 halo (Fig. 2); the same values are used there.
G_POS_DU, G_VEL_DUTU = 1e-4, 5e-4
INITIAL_SETS = ("paper", "point")


def _initial_set(x0: np.ndarray, kind: str, g_pos: float, g_vel: float):
    """The paper's box initial set about ``x0`` (``"paper"``) or none (``"point"``: ``x0`` only)."""
    from ocreach.sets.zonotope import Zonotope

    if kind not in INITIAL_SETS:
        raise ProblemError(f"initial_set must be one of {INITIAL_SETS}; got {kind!r}")
    if kind == "point":
        return None
    return Zonotope(x0, np.diag([g_pos] * 3 + [g_vel] * 3))


@cache
def halo_orbit() -> PeriodicOrbit:
    """The paper's L2 halo state corrected with ``z0 = -0.0862`` fixed (x0, vy0 free).

    The corrected state rounds to the paper's 4-digit state; its period (349.3 h) is 0.9 % longer
    than the quoted 346.32 h.
    """
    return correct_symmetric(cr3bp(MU_PATEL), HALO_SEED, fix="z", family="L2 southern halo")


@cache
def nrho_orbit() -> PeriodicOrbit:
    """The southern L2 9:2 NRHO at ``mu = 0.01215`` (x0 at apolune), see :func:`ocreach.orbits.nrho_9_2`."""
    return nrho_9_2(MU_PATEL, EARTH_MOON_PATEL)


def _cislunar(pid: str, orbit: PeriodicOrbit, t_final: float, dt: float, thrust: float,
              mass: float, isp: float, description: str, citation: str, fit: bool = False,
              initial_set: str = "paper") -> Problem:
    check_positive("thrust", thrust)
    check_positive("mass", mass)
    check_positive("isp", isp)
    units = EARTH_MOON_PATEL
    a_max = units.thrust_acceleration(thrust, mass)
    model = cr3bp(MU_PATEL, a_max=a_max, units=units)
    return Problem(
        id=pid, model=model, x0=orbit.x0.copy(), grid=time_grid(t_final, dt, fit=fit), units=units,
        reference=orbit.to_reference(orbit.family),
        initial_set=_initial_set(orbit.x0, initial_set, G_POS_DU, G_VEL_DUTU),
        description=(f"{description}; T_max = {thrust:g} N, m0 = {mass:g} kg "
                     f"(a_max = {a_max:.4g} DU/TU^2), Isp = {isp:g} s, "
                     f"{t_final / HOUR_TU:.4g} h in steps of {dt / HOUR_TU:.3g} h"),
        citation=citation,
        extra={"thrust_N": thrust, "mass_kg": mass, "isp_s": isp,
               "period_TU": orbit.period, "period_h": orbit.period_in(units, "h"),
               "stability_indices": orbit.stability_indices},
    )


def l2_halo(t_final: float | None = None, dt: float = HOUR_TU, thrust: float = CISLUNAR_THRUST_N,
            mass: float = MASS_KG, isp: float = ISP_S, initial_set: str = "paper") -> Problem:
    """Earth-Moon L2 halo, 0.1 N on 1000 kg, one period (349.3 h) in 1 h steps (Patel & Subbarao Tables 2-3).

    x0 and the reference are the paper's state corrected with z0 fixed (see :func:`halo_orbit`).
    Options: ``t_final`` (TU, default one period), ``dt`` (TU, default 1 h = 3600/375200 TU; for
    the default one-period horizon the grid has ``round(period/dt)`` equal segments ending exactly
    at the period, an explicit ``t_final`` must be a multiple of ``dt``), ``thrust`` (N),
    ``mass`` (kg), ``isp`` (s; recorded in ``extra``, the model keeps the mass constant),
    ``initial_set`` (``"paper"``: the box ``x0 +- (1e-4 DU, 5e-4 DU/TU)`` of the NRHO section, used
    by ``mc``, ``taylor``, ``sdc``, ``stt``; ``"point"``: ``x0`` only).
    """
    orbit = halo_orbit()
    fit = t_final is None
    t_final = orbit.period if t_final is None else t_final
    return _cislunar(
        "l2-halo", orbit, t_final, dt, thrust, mass, isp, fit=fit,
        description=(f"spatial CR3BP (mu = {MU_PATEL}) L2 southern halo, x0 = paper state "
                     f"{list(HALO_SEED)} corrected with z0 fixed (period {orbit.period:.5f} TU = "
                     f"{orbit.period_in(EARTH_MOON_PATEL):.2f} h; paper quotes "
                     f"{HALO_PERIOD_PAPER_H:.2f} h)"),
        citation=f"{CITATION}, L2 halo station-keeping, Tables 2-3; state from {BOWERFIND_TAHERI}",
        initial_set=initial_set)


def nrho_9_2_problem(t_final: float = 76.0 * HOUR_TU, dt: float = HOUR_TU,
                     thrust: float = CISLUNAR_THRUST_N, mass: float = MASS_KG,
                     isp: float = ISP_S, initial_set: str = "paper") -> Problem:
    """Earth-Moon L2 9:2 NRHO from apolune, 0.1 N on 1000 kg, 76 h in 1 h steps (Patel & Subbarao, Fig. 4-6).

    The paper's method comparison runs 76 h (apolune to just before perilune, which is at half the
    157.5 h period).  Note: the paper's text quotes the halo state [1.1720, 0, -0.0862, ...] for this
    case too; here the actual 9:2 NRHO (period = 2/9 synodic month) is used, as its title and the
    157 h station-keeping period indicate.  Options: ``t_final`` (TU, default 76 h = 0.7292 TU; a
    multiple of ``dt``), ``dt`` (TU, default 1 h = 3600/375200 TU), ``thrust`` (N), ``mass``
    (kg), ``isp`` (s; recorded in ``extra``, the model keeps the mass constant), ``initial_set``
    (``"paper"``: the paper's box G_pos = 1e-4 I_3 DU, G_vel = 5e-4 I_3 DU/TU; ``"point"``: ``x0``
    only).
    """
    orbit = nrho_orbit()
    prob = _cislunar(
        "nrho-9-2", orbit, t_final, dt, thrust, mass, isp,
        description=(f"spatial CR3BP (mu = {MU_PATEL}) southern L2 9:2 NRHO from apolune "
                     f"(period {orbit.period:.5f} TU = {orbit.period_in(EARTH_MOON_PATEL, 'd'):.3f} d)"),
        citation=f"{CITATION}, L2 9:2 NRHO method comparison (76 h) and station-keeping",
        initial_set=initial_set)
    # station keeping: guaranteed drift tubes over whole revolutions (taylor restarted from the
    # initial set where it stops near perilune), and the event trigger that anticipates those
    # restarts (docs/validation/station-keeping.md)
    prob.extra["station_keeping"] = {"tube_source": "taylor", "tube_interval": "adaptive",
                                     "anticipate": True}
    return prob


def earth_mars(t_days: float = 200.0, dt_days: float = 1.0, thrust: float = EM_THRUST_N,
               mass: float = MASS_KG, isp: float = ISP_S) -> Problem:
    """Heliocentric Earth-Mars transfer, 0.3 N on 1000 kg, departure 2007-04-10, 200 d daily grid (Patel & Subbarao Eq. 29).

    Two-body model with mu_sun = 1 in AU and TU = sqrt(AU^3 / GM_sun) (``units.SUN_AU``); the
    Eq. 29 state (km, km/s) is converted to those units.  Options: ``t_days`` (days, default 200;
    the paper also uses 300), ``dt_days`` (days, default 1), ``thrust`` (N), ``mass`` (kg),
    ``isp`` (s, recorded in ``extra``).
    """
    check_positive("thrust", thrust)
    check_positive("mass", mass)
    check_positive("isp", isp)
    check_positive("t_days", t_days)
    check_positive("dt_days", dt_days)
    units = SUN_AU
    day = 86400.0 / units.time
    s = np.asarray(EARTH_MARS_STATE_KM)
    x0 = np.concatenate([s[:3] * 1e3 / units.length, s[3:] * 1e3 / units.velocity])
    a_max = units.thrust_acceleration(thrust, mass)
    model = twobody(mu=1.0, a_max=a_max, units=units)
    return Problem(
        id="earth-mars", model=model, x0=x0, grid=time_grid(t_days, dt_days, unit="d", names=("t_days", "dt_days")) * day, units=units,
        description=(f"heliocentric two-body transfer from Earth (epoch {EARTH_MARS_EPOCH}, "
                     f"v_inf = 0), T_max = {thrust:g} N, m0 = {mass:g} kg (a_max = {a_max:.4g} "
                     f"AU/TU^2), Isp = {isp:g} s, {t_days:g} d in steps of {dt_days:g} d"),
        citation=f"{CITATION}, Eq. 29 and Table 1 (200 d and 300 d); adapted from {BOWERFIND_TAHERI}",
        extra={"thrust_N": thrust, "mass_kg": mass, "isp_s": isp,
               "departure_epoch": EARTH_MARS_EPOCH, "x0_km_kms": list(EARTH_MARS_STATE_KM),
               "day_TU": day},
    )


PROBLEMS = {"l2-halo": l2_halo, "nrho-9-2": nrho_9_2_problem, "earth-mars": earth_mars}
