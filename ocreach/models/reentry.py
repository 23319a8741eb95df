"""Hypersonic re-entry: 3-DOF point mass over a spherical, non-rotating Earth (Jain et al. Eq. 19-20).

State ``x = [h, v, gamma, theta, psi, phi]`` (altitude, speed, flight-path angle, latitude,
azimuth, longitude), control ``u = [alpha, bank]`` in radians.  The paper's Eq. 19 and its
discretisation Eq. 21-23 contain typos; the equations here are the standard spherical-Earth
equations (Vinh, Busemann & Culp, *Hypersonic and Planetary Entry Flight Mechanics*, 1980;
Betts, *Practical Methods for Optimal Control*, shuttle re-entry example) with the azimuth measured
from north::

    h'     = v sin(gamma)
    v'     = -D/m - g sin(gamma)
    gamma' =  L cos(bank) / (m v) + cos(gamma) (v/r - g/v)
    theta' =  v cos(gamma) cos(psi) / r
    psi'   =  L sin(bank) / (m v cos(gamma)) + v cos(gamma) sin(psi) tan(theta) / r
    phi'   =  v cos(gamma) sin(psi) / (r cos(theta))

with ``r = R_e + h``, ``g = mu / r^2``, ``rho = rho_0 exp(-h/h_r)``, ``L, D = rho v^2 S c_{L,D} / 2``,
``c_L = a0 + a1 a``, ``c_D = b0 + b1 a + b2 a^2`` and ``a = alpha_scale * alpha`` (the shuttle
polynomials of Table 2 take the angle of attack in degrees, ``alpha_scale = 180/pi``; the glider
polynomials of Table 4 take radians).  Every correction is listed in docs/reentry.md.

Units (consistent, non-dimensional): the length unit is the density scale height ``h_r`` and the
time unit is one second, so ``h/h_r ~ 11`` and ``v ~ 1`` for both vehicles, angles are radians.
Then ``rho S / (2 m)`` becomes the dimensionless ballistic number ``k = rho_0 S h_r / (2 m)``.

Split form (Jain et al. Eq. 1, 21-23).  The right-hand side is ``f(x, u) = f0(x) + G(x) hu(u)``
with the compact ``r = 3`` control map ``hu(u) = [c_D, c_L cos(bank), c_L sin(bank)]`` and::

    G(x) = k exp(-h) * [[0, 0, 0], [-v^2, 0, 0], [0, v, 0], [0, 0, 0], [0, 0, v / cos(gamma)], [0, 0, 0]]

(scaled units).  The forward-Euler step of the paper, ``x+ = x + dt f0(x) + dt G(x) hu(u)``, keeps
that structure; :func:`split_functions` returns ``f0``, ``G`` and ``hu`` as CasADi Functions.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import casadi as ca
import numpy as np

from ocreach.model import Model
from ocreach.units import Units

FT = 0.3048  # metres per foot

STATE_NAMES = ("h", "v", "gamma", "theta", "psi", "phi")
CONTROL_NAMES = ("alpha", "bank")
PARAM_NAMES = ("mu", "Re", "k", "a0", "a1", "b0", "b1", "b2", "alpha_scale")


@dataclass(frozen=True)
class Vehicle:
    """Physical constants of a re-entry vehicle (Jain et al. Tables 1-4), in one unit system.

    ``length_m`` converts the vehicle's length unit to metres (0.3048 for the shuttle's feet);
    ``rho0 * S * h_r / (2 m)`` must be dimensionless (slug/ft^3, ft^2, ft, slug for the shuttle;
    kg/m^3, m^2, m, kg for the glider).
    """

    name: str
    mu: float
    rho0: float
    Re: float
    h_r: float
    S: float
    m: float
    a0: float
    a1: float
    b0: float
    b1: float
    b2: float
    alpha_in_degrees: bool
    length_m: float = 1.0
    length_name: str = "m"

    @property
    def ballistic(self) -> float:
        """Dimensionless ``k = rho_0 S h_r / (2 m)`` (the drag/lift factor in scaled units)."""
        return self.rho0 * self.S * self.h_r / (2.0 * self.m)

    @property
    def alpha_scale(self) -> float:
        return 180.0 / np.pi if self.alpha_in_degrees else 1.0

    @property
    def scale(self) -> np.ndarray:
        """Physical state = ``scale * model state`` (length unit ``h_r``, time unit 1 s)."""
        return np.array([self.h_r, self.h_r, 1.0, 1.0, 1.0, 1.0])

    @property
    def units(self) -> Units:
        return Units(length=self.h_r * self.length_m, time=1.0, name=f"{self.name}: h_r, 1 s",
                     length_label="h_r", time_label="s")  # plots say seconds, not TU

    def params(self) -> np.ndarray:
        """Model parameter vector in :data:`PARAM_NAMES` order (scaled units)."""
        return np.array([self.mu / self.h_r**3, self.Re / self.h_r, self.ballistic,
                         self.a0, self.a1, self.b0, self.b1, self.b2, self.alpha_scale])

    def to_model(self, x_phys) -> np.ndarray:
        """Physical state (vehicle length unit, s, rad) to model units."""
        return np.asarray(x_phys, dtype=float) / self.scale

    def to_physical(self, x) -> np.ndarray:
        """Model state to physical units (vehicle length unit, s, rad)."""
        return np.asarray(x, dtype=float) * self.scale

    def cov_to_model(self, cov_phys) -> np.ndarray:
        s = 1.0 / self.scale
        return np.asarray(cov_phys, dtype=float) * np.outer(s, s)


#: Jain et al. Tables 1-2 (the space shuttle of Betts' example).  The paper's units "lb/ft^3" and
#: "lb" are slug/ft^3 and slug (m = 203000 lb / 32.174 ft/s^2 = 6309.44 slug).
SHUTTLE = Vehicle(name="shuttle", mu=0.1407654e17, rho0=0.002378, Re=20902900.0, h_r=23800.0,
                  S=2690.0, m=6309.44, a0=-0.20704, a1=0.029244, b0=0.07854, b1=-0.61592e-2,
                  b2=0.621408e-3, alpha_in_degrees=True, length_m=FT, length_name="ft")
#: Jain et al. Tables 3-4 (the glide vehicle of Mansell & Grant), SI units, alpha in radians.
GLIDER = Vehicle(name="glider", mu=3.986e14, rho0=1.2, Re=6.378e6, h_r=7500.0, S=0.30, m=340.0,
                 a0=0.0, a1=1.6, b0=0.06, b1=0.0, b2=1.7, alpha_in_degrees=False)

VEHICLES = {"shuttle": SHUTTLE, "glider": GLIDER}


@cache
def _symbols():
    """Symbols and the split expressions ``f0(x; p)``, ``G(x; p)``, ``hu(u; p)`` (built once)."""
    x = ca.SX.sym("x", 6)
    u = ca.SX.sym("u", 2)
    p = ca.SX.sym("p", len(PARAM_NAMES))
    mu, Re, k, a0, a1, b0, b1, b2, asc = (p[i] for i in range(len(PARAM_NAMES)))
    h, v, gam, th, psi = x[0], x[1], x[2], x[3], x[4]
    r = Re + h
    g = mu / r**2
    f0 = ca.vertcat(
        v * ca.sin(gam),
        -g * ca.sin(gam),
        ca.cos(gam) * (v / r - g / v),
        v * ca.cos(gam) * ca.cos(psi) / r,
        v * ca.cos(gam) * ca.sin(psi) * ca.tan(th) / r,
        v * ca.cos(gam) * ca.sin(psi) / (r * ca.cos(th)),
    )
    q = k * ca.exp(-h)  # rho S / (2 m) in scaled units
    z = ca.SX(1, 1)
    G = ca.vertcat(
        ca.horzcat(z, z, z),
        ca.horzcat(-q * v**2, z, z),
        ca.horzcat(z, q * v, z),
        ca.horzcat(z, z, z),
        ca.horzcat(z, z, q * v / ca.cos(gam)),
        ca.horzcat(z, z, z),
    )
    a = asc * u[0]
    cl = a0 + a1 * a
    cd = b0 + b1 * a + b2 * a**2
    hu = ca.vertcat(cd, cl * ca.cos(u[1]), cl * ca.sin(u[1]))
    return x, u, p, f0, G, hu


@cache
def split_functions() -> tuple[ca.Function, ca.Function, ca.Function]:
    """``f0(x, t, p) -> (6,)``, ``G(x, t, p) -> (6, 3)``, ``hu(u, p) -> (3,)`` (Jain et al. Eq. 1,
    21-23, corrected; continuous time: the Euler step multiplies ``f0`` and ``G`` by ``dt``)."""
    x, u, p, f0, G, hu = _symbols()
    t = ca.SX.sym("t")
    return (ca.Function("reentry_f0", [x, t, p], [f0], ["x", "t", "p"], ["f0"]),
            ca.Function("reentry_G", [x, t, p], [G], ["x", "t", "p"], ["G"]),
            ca.Function("reentry_hu", [u, p], [hu], ["u", "p"], ["hu"]))


def step_map(vehicle: str | Vehicle = "shuttle"):
    """The :class:`ocreach.dynamics.stochastic_mc.SplitStepMap` of ``vehicle`` (Euler step of Eq. 21-23)."""
    from ocreach.dynamics.stochastic_mc import SplitStepMap

    vehicle = _vehicle(vehicle)
    f0, G, hu = split_functions()
    return SplitStepMap(f0, G, hu, vehicle.params(), name=f"reentry-{vehicle.name}")


def _vehicle(vehicle: str | Vehicle) -> Vehicle:
    from ocreach.errors import ProblemError

    if isinstance(vehicle, Vehicle):
        return vehicle
    if vehicle not in VEHICLES:
        raise ProblemError(f"vehicle must be one of {sorted(VEHICLES)} or a Vehicle; got {vehicle!r}")
    return VEHICLES[vehicle]


def reentry(vehicle: str | Vehicle = "shuttle") -> Model:
    """3-DOF re-entry model ``f(x, u) = f0(x) + G(x) hu(u)`` (Jain et al. Eq. 19-20, corrected).

    ``vehicle`` is ``"shuttle"`` (Tables 1-2), ``"glider"`` (Tables 3-4) or a :class:`Vehicle`.
    Controls ``[alpha, bank]`` in radians, ``control_set="free"`` (a prescribed distribution).
    """
    vehicle = _vehicle(vehicle)
    x, u, p, f0, G, hu = _symbols()
    f = f0 + ca.mtimes(G, hu)
    return Model.build(
        f"reentry-{vehicle.name}", x, u, f, p=p, p_default=vehicle.params(),
        state_names=STATE_NAMES, control_names=CONTROL_NAMES, param_names=PARAM_NAMES,
        control_set="free", units=vehicle.units,
        description=f"3-DOF point-mass re-entry ({vehicle.name}), length unit h_r = "
                    f"{vehicle.h_r:g} {vehicle.length_name}, time unit 1 s")
