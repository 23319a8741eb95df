"""Scenarios of Tucker, Aguilar-Marsillach, Montgomery & Holzinger, "Agile space object custody for
electro-optical sensors" (AMOS): a Lunar IceCube-like 6U CubeSat (14 kg, 0.8 mN, Sec. 4) at each
Earth-Moon Lagrange point (Sec. 4.1, Figs. 3-12) and at apolune of the Gateway 9:2 NRHO (Sec. 4.2,
Figs. 13-15), in the spatial CR3BP (Eq. 15-16).

Control set (Sec. 4): "this thrust could be exerted independently in a three-thruster configuration
where each is aligned with an axis in the rotating frame", i.e. the box ``|u_i| <= 1`` with
``a_max = 0.8 mN / 14 kg`` per axis (default ``control_set="box"``); ``control_set="ball"`` gives
the single steerable thruster of the same magnitude.

The paper gives no units, mass ratio or uncertainty.  Choices made here: Earth-Moon
``mu = 0.012150585609624`` and ``l* = 384400 km``, ``t* = 375200 s`` (``units.EARTH_MOON_PATEL``),
so ``a_max = 0.020926 DU/TU^2`` and one day is ``0.23028 TU``.  Horizons (``extra["horizons_days"]``)
are 1 and 5 days at the Lagrange points and 1, 2, 3 days on the NRHO, where the paper stops before
perilune; the problem's grid ends at ``t_days`` (default: the largest horizon) in steps of
``dt_hours``.

Initial manifold (Eq. 6, ``x0^T E x0 = 1`` about the nominal state): off by default (the paper's
figures start from one state).  ``uncertain=True`` uses the ellipsoid with semi-axes
``sigma_pos_km`` (default 1 km) in position and ``sigma_vel_mps`` (default 1 cm/s) in velocity,
``E = diag(1/sigma^2)`` in model units: a typical cislunar orbit-determination uncertainty,
small against the thrust reach (213 km after one day, ``a t^2/2``), so the custody numbers are
dominated by the manoeuvre capability as in the paper.  It is a ``sets.Ellipsoid`` initial set
(``Q = E^-1``), which ``mc`` samples and ``bvp`` / ``ffoe`` turn into the transversality point of
Patel & Scheeres Eq. 21-23.
"""
from __future__ import annotations

from functools import cache

import numpy as np

from ocreach.errors import ProblemError, check_positive
from ocreach.models import cr3bp
from ocreach.orbits import MU_EARTH_MOON, PeriodicOrbit, lagrange_points, nrho_9_2
from ocreach.problem import Problem
from ocreach.units import EARTH_MOON_PATEL

CITATION = ("J. Tucker, D. Aguilar-Marsillach, A. Montgomery & M. J. Holzinger, \"Agile space object "
            "custody for electro-optical sensors\", AMOS")
MU = MU_EARTH_MOON
UNITS = EARTH_MOON_PATEL
THRUST_N = 0.8e-3
MASS_KG = 14.0
DAY_TU = 86400.0 / UNITS.time
LAGRANGE_HORIZONS_DAYS = (1.0, 5.0)
GATEWAY_HORIZONS_DAYS = (1.0, 2.0, 3.0)
#: bvp options of the custody problems: position subspace, 40 Fibonacci directions.  The linear
#: cost (support function) is used: Tucker's quadratic index (Eq. 4, ``cost="quadratic"``) has the
#: same extremals (its costate is the linear one scaled by ``z . (x_f - x_ref)``; tests check the
#: radii agree) but also the trivial root ``lam = 0`` at ``x_f = x_ref``, which warm starts across
#: horizons can fall into.
BVP_OPTIONS = {"cost": "linear", "dims": "position", "samples": 40, "smooth": 1e-9}


@cache
def gateway_orbit() -> PeriodicOrbit:
    """The southern L2 9:2 NRHO at ``mu = 0.012150585609624`` (x0 at apolune), :func:`ocreach.orbits.nrho_9_2`."""
    return nrho_9_2(MU, UNITS)


def _problem(pid: str, x0: np.ndarray, where: str, horizons: tuple[float, ...], t_days: float | None,
             dt_hours: float, control_set: str, thrust: float, mass: float, uncertain: bool,
             sigma_pos_km: float, sigma_vel_mps: float, reference=None) -> Problem:
    if control_set not in ("box", "ball"):
        raise ProblemError(f"control_set must be 'box' (three axis thrusters, Tucker Sec. 4) or 'ball'; "
                           f"got {control_set!r}")
    check_positive("thrust", thrust)
    check_positive("mass", mass)
    t_days = max(horizons) if t_days is None else check_positive("t_days", t_days)
    check_positive("dt_hours", dt_hours)
    n = max(1, int(round(t_days * 24.0 / dt_hours)))
    grid = np.linspace(0.0, t_days * DAY_TU, n + 1)
    a_max = UNITS.thrust_acceleration(thrust, mass)
    model = cr3bp(MU, a_max=a_max, control_set=control_set, units=UNITS)
    initial_set = None
    if uncertain:
        from ocreach.sets import Ellipsoid

        sp = check_positive("sigma_pos_km", sigma_pos_km) * 1e3 / UNITS.length
        sv = check_positive("sigma_vel_mps", sigma_vel_mps) / UNITS.velocity
        initial_set = Ellipsoid(x0, np.diag([sp**2] * 3 + [sv**2] * 3))
    law = ("three axis-aligned thrusters (box |u_i| <= 1)" if control_set == "box"
           else "one steerable thruster (ball |u| <= 1)")
    return Problem(
        id=pid, model=model, x0=np.asarray(x0, float), grid=grid, units=UNITS,
        initial_set=initial_set, reference=reference,
        description=(f"Lunar IceCube-like CubeSat {where}: spatial CR3BP (mu = {MU:.6f}), "
                     f"{thrust * 1e3:g} mN on {mass:g} kg (a_max = {a_max:.5g} DU/TU^2), {law}, "
                     f"{t_days:g} d in {dt_hours:g} h steps"
                     + (f", initial ellipsoid {sigma_pos_km:g} km / {sigma_vel_mps:g} m/s" if uncertain else "")),
        citation=CITATION,
        method_options={"bvp": dict(BVP_OPTIONS)},
        extra={"thrust_N": thrust, "mass_kg": mass, "horizons_days": tuple(horizons),
               "day_TU": DAY_TU, "t_days": t_days, "control_set": control_set,
               "sigma_pos_km": sigma_pos_km if uncertain else 0.0,
               "sigma_vel_mps": sigma_vel_mps if uncertain else 0.0},
    )


#: the options paragraph of every custody problem's docstring (read by ``ocreach problem ID``)
OPTIONS_DOC = ("Options: ``t_days`` (days, {t_days}), ``dt_hours`` (hours, default 2), "
               "``control_set`` (``'box'`` or ``'ball'`` thrust), ``thrust`` (N), ``mass`` (kg), "
               "``uncertain`` (True: the initial ellipsoid of Eq. 6 instead of a point), "
               "``sigma_pos_km`` (km, that ellipsoid's position semi-axis), ``sigma_vel_mps`` "
               "(m/s, its velocity semi-axis).")


def _lagrange(i: int):
    def factory(t_days: float | None = None, dt_hours: float = 2.0, control_set: str = "box",
                thrust: float = THRUST_N, mass: float = MASS_KG, uncertain: bool = False,
                sigma_pos_km: float = 1.0, sigma_vel_mps: float = 0.01) -> Problem:
        x0 = np.concatenate([lagrange_points(MU)[i - 1], np.zeros(3)])
        return _problem(f"custody-l{i}", x0, f"at Earth-Moon L{i}", LAGRANGE_HORIZONS_DAYS, t_days,
                        dt_hours, control_set, thrust, mass, uncertain, sigma_pos_km, sigma_vel_mps)

    factory.__doc__ = (f"Lunar IceCube (0.8 mN, 14 kg, box thrust) at rest at Earth-Moon L{i}, horizons 1 "
                       f"and 5 d (Tucker et al. Sec. 4.1, Figs. {3 + 2 * (i - 1)}-{4 + 2 * (i - 1)}).\n\n"
                       + OPTIONS_DOC.format(t_days="default 5 d"))
    factory.__name__ = f"custody_l{i}"
    return factory


def custody_gateway(t_days: float | None = None, dt_hours: float = 2.0, control_set: str = "box",
                    thrust: float = THRUST_N, mass: float = MASS_KG, uncertain: bool = False,
                    sigma_pos_km: float = 1.0, sigma_vel_mps: float = 0.01) -> Problem:
    """Lunar IceCube (0.8 mN, 14 kg, box thrust) at apolune of the 9:2 NRHO (Gateway), horizons 1, 2, 3 d (Tucker et al. Sec. 4.2, Figs. 13-15).

    The NRHO period is 6.56 d, perilune at 3.28 d.
    """
    orb = gateway_orbit()
    return _problem("custody-gateway", orb.x0.copy(), "at apolune of the southern L2 9:2 NRHO (Gateway)",
                    GATEWAY_HORIZONS_DAYS, t_days, dt_hours, control_set, thrust, mass, uncertain,
                    sigma_pos_km, sigma_vel_mps, reference=orb.to_reference(orb.family))


custody_gateway.__doc__ += "\n    " + OPTIONS_DOC.format(t_days="default 3 d") + "\n"
PROBLEMS = {f"custody-l{i}": _lagrange(i) for i in range(1, 6)}
PROBLEMS["custody-gateway"] = custody_gateway
