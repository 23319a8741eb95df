"""Problem file of the catalog sweeps: a spacecraft anywhere in the Earth-Moon CR3BP.

Spatial CR3BP with mu = 0.01215 and the units of Patel & Subbarao (l* = 384400 km,
t* = 375200 s); 0.1 N on 1000 kg by default (a_max = thrust / mass in model units, Foss Eq. 7).
The sweep sets each object's initial state (catalog columns) and the horizon; ``dt_hours`` is
the control segment length.  Loaded by ``examples/sweep_catalog.json`` as
``"problem": "sweep_catalog/cislunar.py"``.
"""
from __future__ import annotations

import numpy as np

from ocreach.errors import check_positive
from ocreach.models import cr3bp
from ocreach.orbits import lagrange_points
from ocreach.problem import Problem
from ocreach.units import EARTH_MOON_PATEL

MU = 0.01215


def problem(thrust: float = 0.1, mass: float = 1000.0, dt_hours: float = 3.0,
            t_final_days: float = 1.0) -> Problem:
    """Earth-Moon CR3BP spacecraft (state set by the sweep; default at L2), thrust in N, mass in kg."""
    check_positive("thrust", thrust)
    check_positive("mass", mass)
    check_positive("dt_hours", dt_hours)
    check_positive("t_final_days", t_final_days)
    units = EARTH_MOON_PATEL
    a_max = units.thrust_acceleration(thrust, mass)
    dt = dt_hours * 3600.0 / units.time
    n = max(1, int(round(t_final_days * 24.0 / dt_hours)))
    x0 = np.concatenate([lagrange_points(MU)[1], np.zeros(3)])
    return Problem(id="cislunar", model=cr3bp(MU, a_max=a_max, units=units), x0=x0,
                   grid=np.linspace(0.0, n * dt, n + 1), units=units,
                   description=f"Earth-Moon CR3BP spacecraft, T_max = {thrust:g} N, m = {mass:g} kg",
                   extra={"thrust_N": thrust, "mass_kg": mass})
