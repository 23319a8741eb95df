"""Foss, Rosengren & Biria (AMOS 2024) Sec. 4.2: NRHO Moon flyby in the ephemeris synodic model.

Earth-Moon synodic frame with Sun and Venus perturbations (Foss Eq. 6-7), epoch
2024-05-01 12:00:00 TDB, x1 = [0.91, -0.01, 0.16, 0.03, -0.08, 0.01], grid 0:0.05:1 TU,
1.1 mN on 14 kg, ``||u|| <= 1``; Algorithm 1 with n = 2, h_max = 60.
"""
from __future__ import annotations

import numpy as np

from ocreach.errors import ProblemError
from ocreach.problem import Problem, time_grid
from ocreach.units import EARTH_MOON_FOSS

CITATION = "Foss, Rosengren & Biria, AMOS 2024, Sec. 4.2"
EPOCH = "2024-05-01 12:00:00"
BODIES = ("sun", "earth", "moon", "venus")
X0 = np.array([0.91, -0.01, 0.16, 0.03, -0.08, 0.01])
T_MAX_N = 1.1e-3
MASS_KG = 14.0


def nrho_flyby(t_final: float = 1.0, dt: float = 0.05, thrust: float = T_MAX_N, mass: float = MASS_KG,
               input_set: str = "ball") -> Problem:
    """NRHO Moon flyby in the Sun-Earth-Moon-Venus ephemeris synodic model, 1 TU (Foss Sec. 4.2)."""
    if input_set not in ("box", "ball"):  # the STT input set (Foss Eq. 16)
        raise ProblemError(f"input_set must be 'box' or 'ball'; got {input_set!r}")
    from ocreach.models.ephemeris import ephemeris_synodic

    units = EARTH_MOON_FOSS
    a_max = units.thrust_acceleration(thrust, mass)
    span_days = 1.1 * max(t_final, 0.1) * units.time / 86400.0
    model = ephemeris_synodic(BODIES, EPOCH, span_days, a_max, units=units)
    grid = time_grid(t_final, dt)
    return Problem(
        id="nrho-flyby", model=model, x0=X0.copy(), grid=grid, units=units,
        description=f"NRHO Moon flyby, ephemeris synodic model (Sun, Earth, Moon, Venus), epoch "
                    f"{EPOCH} TDB, T_max = {thrust * 1e3:g} mN, m = {mass:g} kg, {t_final:g} TU",
        citation=CITATION, position_dims=(0, 1, 2), velocity_dims=(3, 4, 5),
        method_options={"stt": {"order": 2, "h_max": 60, "input_set": input_set}},
        extra={"thrust_N": thrust, "mass_kg": mass, "epoch": EPOCH, "bodies": list(BODIES)},
    )


PROBLEMS = {"nrho-flyby": nrho_flyby}
