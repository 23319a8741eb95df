"""Scenarios of Foss, Rosengren & Biria, "Reachability analysis of low-thrust, cislunar spacecraft
using state-transition tensors" (AMOS 2024): Van der Pol (Sec. 3.1) and the DRO (Sec. 4.1)."""
from __future__ import annotations

from functools import cache

import numpy as np

from ocreach.errors import ProblemError
from ocreach.models import cr3bp, vanderpol
from ocreach.orbits import PeriodicOrbit, correct_symmetric
from ocreach.problem import Problem, time_grid
from ocreach.units import EARTH_MOON_FOSS

CITATION = "Foss, Rosengren & Biria, AMOS 2024"
MU_FOSS = 0.0122
T_MAX_N = 1.1e-3
MASS_KG = 14.0


def vdp(t_final: float = 3.0, dt: float = 0.1, gain: float = 0.05) -> Problem:
    """Van der Pol oscillator with input 0.05 u, |u| <= 1, x1 = [0.5, 0], grid 0:0.1:3 (Foss Sec. 3.1).

    Options (nondimensional, as in the paper): ``t_final`` (time units, default 3; a multiple of
    ``dt``), ``dt`` (time units, default 0.1), ``gain`` (the input gain b in x2' = ... + b u,
    default 0.05).
    """
    return Problem(
        id="vdp", model=vanderpol(gain=gain), x0=np.array([0.5, 0.0]), grid=time_grid(t_final, dt),
        description="Van der Pol oscillator with bounded input (Foss et al. Sec. 3.1)",
        citation=f"{CITATION}, Sec. 3.1, Eq. 20", position_dims=(0, 1), velocity_dims=(0, 1),
        method_options={"stt": {"order": 3, "h_max": 200, "input_set": "box"}},
    )


@cache
def dro_orbit() -> PeriodicOrbit:
    """Foss Sec. 4.1 state [0.2765, 0, 0, 2.1379] corrected with x0 fixed (vy0 = 2.137623, T = 6.2374 TU)."""
    return correct_symmetric(cr3bp(MU_FOSS, planar=True), [0.2765, 0.0, 0.0, 2.1379], fix="x",
                             family="planar DRO")


def dro(t_final: float = 3.0, dt: float = 0.1, thrust: float = T_MAX_N, mass: float = MASS_KG,
        input_set: str = "box") -> Problem:
    """Low-thrust spacecraft on a planar CR3BP DRO, 1.1 mN on 14 kg, 3 TU (Foss Sec. 4.1).

    Options: ``t_final`` (TU of the Earth-Moon system, default 3; a multiple of ``dt``), ``dt``
    (TU, default 0.1), ``thrust`` (N, default 1.1e-3), ``mass`` (kg, default 14; a_max = thrust /
    mass), ``input_set`` (``"box"`` or ``"ball"``: the thrust set of the ``stt`` method, Foss
    Eq. 16).
    """
    if input_set not in ("box", "ball"):  # the STT input set (Foss Eq. 16)
        raise ProblemError(f"input_set must be 'box' or 'ball'; got {input_set!r}")
    units = EARTH_MOON_FOSS
    a_max = units.thrust_acceleration(thrust, mass)
    model = cr3bp(MU_FOSS, planar=True, a_max=a_max, units=units)
    return Problem(
        id="dro", model=model, x0=np.array([0.2765, 0.0, 0.0, 2.1379]), grid=time_grid(t_final, dt),
        units=units, reference=dro_orbit().to_reference(),
        description=f"planar CR3BP DRO, T_max = {thrust * 1e3:g} mN, m = {mass:g} kg, "
                    f"a_max = {a_max:.4g} DU/TU^2, {t_final:g} TU",
        citation=f"{CITATION}, Sec. 4.1",
        # 0.1 TU steps at 2.1 DU/TU, 0.29 DU from the Earth: the guaranteed methods' steps are
        # halved until the remainder no longer dominates the set (growth_tol)
        method_options={"stt": {"order": 2, "h_max": 400, "input_set": input_set},
                        "taylor": {"growth_tol": 0.1}, "sdc": {"growth_tol": 0.1}},
        extra={"thrust_N": thrust, "mass_kg": mass},
    )


PROBLEMS = {"vdp": vdp, "dro": dro}
