"""Cannonball solar radiation pressure (SRP) for the DE421 plant.

The spacecraft is a sphere of projected area ``A`` and mass ``m`` with the reflectivity
coefficient ``C_r`` (1 = black body, 2 = perfect mirror):

    a_srp = C_r (A / m) P_1AU (1 AU / |d|)^2 d / |d|,      d = r_spacecraft - r_sun,

pointing away from the Sun (the standard cannonball model, e.g. Montenbruck & Gill, *Satellite
Orbits*, Sec. 3.4, cited from memory).  ``P_1AU = S / c``: the solar constant ``S = 1361 W/m^2``
(total solar irradiance at 1 AU, Kopp & Lean 2011, cited from memory) over the speed of light,
4.54e-6 N/m^2.  No eclipse model: the Earth's and the Moon's shadows are not cut out (the 9:2
NRHO's resonance with the synodic month was chosen to avoid Earth eclipses; the short lunar
shadow passes near perilune are not modelled).

Defaults: ``C_r = 1.3`` and ``A / m = 0.01 m^2/kg`` (10 m^2 on the 1000 kg spacecraft of
Patel & Subbarao's cislunar cases).  No published value for this vehicle was found; a
Gateway-class stack is about 50 m^2 on 25.8 t (1.9e-3 m^2/kg), a cubesat such as CAPSTONE
nearer 0.01-0.02 m^2/kg.  At the Moon the default gives 5.9e-8 m/s^2.

``uncertainty``: the true ``C_r A / m`` of a run is the nominal one times ``1 + delta``, ``delta``
uniform in ``[-uncertainty, +uncertainty]`` (default 0.1: a 5-10 % uncertainty of ``C_r`` and of
the effective area is quoted for NRHO stationkeeping by Muralidharan & Howell, AAS 21-651, via a
secondary summary); the controllers and the reference know only the nominal value.  Bounded,
so a sound drift tube can carry it as a disturbance box (:meth:`SolarRadiationPressure.
dispersion_bound`).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from ocreach.errors import ProblemError, _to_float

#: Total solar irradiance at 1 AU, W/m^2 (Kopp & Lean 2011).
SOLAR_CONSTANT_W_M2 = 1361.0
SPEED_OF_LIGHT_M_S = 299792458.0
#: Solar radiation pressure on a black body at 1 AU, N/m^2.
P_1AU_N_M2 = SOLAR_CONSTANT_W_M2 / SPEED_OF_LIGHT_M_S
AU_KM = 149597870.7
DEFAULT_AREA_TO_MASS = 0.01  # m^2/kg
DEFAULT_CR = 1.3
DEFAULT_UNCERTAINTY = 0.1


def check_nonnegative(name: str, value: Any, allowed: str = "a finite number >= 0") -> float:
    """``value`` as a float ``>= 0``; :class:`ProblemError` naming ``name``, the value and what is
    allowed otherwise."""
    v = _to_float(value)
    if not (math.isfinite(v) and v >= 0):
        raise ProblemError(f"{name} must be {allowed}; got {value!r}")
    return v


@dataclass(frozen=True)
class SolarRadiationPressure:
    """Cannonball SRP (module doc): ``area_to_mass`` (m^2/kg, >= 0; 0 switches SRP off),
    ``cr`` (reflectivity, 1..2), ``uncertainty`` (relative half-width of the per-run dispersion of
    ``C_r A / m``, in [0, 1))."""

    area_to_mass: float = DEFAULT_AREA_TO_MASS
    cr: float = DEFAULT_CR
    uncertainty: float = DEFAULT_UNCERTAINTY

    def __post_init__(self) -> None:
        object.__setattr__(self, "area_to_mass", check_nonnegative(
            "area_to_mass (SRP area over mass, m^2/kg)", self.area_to_mass))
        cr = _to_float(self.cr)
        if not (math.isfinite(cr) and 1.0 <= cr <= 2.0):
            raise ProblemError(f"cr (SRP reflectivity coefficient) must be a number in [1, 2] "
                               f"(1: absorbing, 2: mirror); got {self.cr!r}")
        object.__setattr__(self, "cr", cr)
        u = _to_float(self.uncertainty)
        if not (math.isfinite(u) and 0.0 <= u < 1.0):
            raise ProblemError(f"srp uncertainty (relative half-width of the C_r A/m dispersion) "
                               f"must be a number in [0, 1); got {self.uncertainty!r}")
        object.__setattr__(self, "uncertainty", u)

    @property
    def coefficient(self) -> float:
        """``C_r A / m P_1AU``: the SRP acceleration at 1 AU from the Sun, m/s^2."""
        return self.cr * self.area_to_mass * P_1AU_N_M2

    def acceleration_at(self, distance_km: float) -> float:
        """Magnitude (m/s^2) at ``distance_km`` from the Sun."""
        return self.coefficient * (AU_KM / float(distance_km)) ** 2

    def dispersion_bound(self, min_distance_km: float) -> float:
        """Largest difference (m/s^2) between the true and the nominal SRP acceleration of any run
        (``uncertainty`` times the acceleration at the closest distance from the Sun)."""
        return self.uncertainty * self.acceleration_at(min_distance_km)

    def expression(self, d, du_km: float, acc_unit: float, scale=1.0):
        """CasADi acceleration in model units (``acc_unit`` m/s^2 per unit) for the Sun-to-
        spacecraft vector ``d`` in DU (``du_km`` km per DU), times ``scale`` (a symbol: the run's
        ``C_r A / m`` over the nominal)."""
        import casadi as ca

        au = AU_KM / du_km
        k = self.coefficient / acc_unit * au**2
        return scale * k * d / ca.norm_2(d) ** 3

    def as_dict(self) -> dict[str, float]:
        return {**asdict(self), "p_1au_n_m2": P_1AU_N_M2}


__all__ = ["AU_KM", "DEFAULT_AREA_TO_MASS", "DEFAULT_CR", "DEFAULT_UNCERTAINTY", "P_1AU_N_M2",
           "SolarRadiationPressure", "check_nonnegative"]
