"""Scenarios of Jain, Gueho, Singla & Akella, "Stochastic reachability analysis for the hypersonic
re-entry problem" (AAS): the shuttle re-entry (first maneuver) and the glide vehicle (second).

States are in the re-entry model's scaled units (length unit ``h_r``, time unit 1 s, angles in
radians; ``problem.extra["vehicle"].to_physical`` converts back).  Both problems carry a
:class:`~ocreach.problem.StochasticSpec` (Gaussian initial state, Gaussian controls with sigma 3 deg
about a nominal profile, sampled afresh every step) and the split Euler step map of Eq. 21-23
(corrected, ``extra["step_map"]``).  The nominal profiles are our own documented choices: the paper
takes them from Refs. 33-34 without listing them (see docs/reentry.md).
"""
from __future__ import annotations

import numpy as np

from ocreach.errors import ProblemError
from ocreach.models.reentry import GLIDER, SHUTTLE, Vehicle, reentry, step_map
from ocreach.problem import Problem, StochasticSpec, time_grid

CITATION = "Jain, Gueho, Singla & Akella, Stochastic reachability analysis for the hypersonic re-entry problem"
DEG = np.pi / 180.0


def _spec(vehicle: Vehicle, mean_phys, var_phys, u_nom, sigma_u_deg: float) -> StochasticSpec:
    if not (np.isfinite(sigma_u_deg) and sigma_u_deg >= 0):
        raise ProblemError(f"sigma_u_deg must be a finite number >= 0; got {sigma_u_deg!r}")
    return StochasticSpec(
        x0_mean=vehicle.to_model(mean_phys),
        x0_cov=vehicle.cov_to_model(np.diag(var_phys)),
        u_nominal=u_nom,
        u_cov=np.diag([(sigma_u_deg * DEG) ** 2] * 2),
    )


def _problem(pid: str, vehicle: Vehicle, spec: StochasticSpec, grid: np.ndarray,
             report_times: tuple[float, ...], description: str, where: str,
             units: tuple[str, str]) -> Problem:
    """The Problem of one maneuver: re-entry model, Gaussian spec, split Euler map (Eq. 21-23)."""
    return Problem(
        id=pid, model=reentry(vehicle), x0=spec.x0_mean, grid=grid, stochastic=spec,
        units=vehicle.units, description=description, citation=f"{CITATION}, {where}",
        position_dims=(0, 3, 5), velocity_dims=(1, 2, 4),
        method_options={"cut": {"order": 8, "rule": "cut"}},
        extra={"vehicle": vehicle, "step_map": step_map(vehicle),
               "report_times": [t for t in report_times if t <= grid[-1]],
               "physical_units": (*units, "rad", "rad", "rad", "rad")},
    )


def shuttle_reentry(t_final: float = 2000.0, dt: float = 1.0, alpha_deg: float = 21.0,
                    bank0_deg: float = -75.0, bank1_deg: float = -5.0, psi0_deg: float = 90.0,
                    sigma_u_deg: float = 3.0) -> Problem:
    """Shuttle re-entry with Gaussian x0 and controls, 2000 s, alpha 21 deg, bank -75 -> -5 deg (Jain Eq. 24-25).

    Vehicle of Tables 1-2; initial Gaussian of Eq. 24-25 except the azimuth mean ``psi0_deg``:
    default 90 deg (due east), the value of the source problem (Betts, *Practical Methods for
    Optimal Control*, Example 6.1, via the paper's Ref. 33) and the only one that reproduces the
    paper's own description of Fig. 4 (h, v, psi decreasing, latitude and longitude increasing);
    Eq. 24 prints -1 deg (the gamma0 entry repeated), which with the corrected equations sends
    the longitude negative for a left bank or turns psi upward for a right bank.
    ``psi0_deg=-1`` gives the literal Eq. 24 (docs/reentry.md).
    Nominal controls: ``alpha = alpha_deg``, bank linear from ``bank0_deg`` at t = 0 to
    ``bank1_deg`` at ``t_final`` (evaluated at each segment's start), both with sigma
    ``sigma_u_deg``.  Forward-Euler step ``dt`` s.
    Options: ``t_final`` (s, default 2000; a multiple of ``dt``), ``dt`` (s, the Euler step,
    default 1), ``alpha_deg`` (deg, the angle of attack), ``bank0_deg`` (deg), ``bank1_deg`` (deg),
    ``psi0_deg`` (deg), ``sigma_u_deg`` (deg).
    """
    grid = time_grid(t_final, dt, unit="s")
    t = grid[:-1]
    u_nom = np.column_stack([np.full(t.size, alpha_deg * DEG),
                             (bank0_deg + (bank1_deg - bank0_deg) * t / t_final) * DEG])
    mean = [260000.0, 25600.0, -1.0 * DEG, 0.0, psi0_deg * DEG, 0.0]
    var = [3000.0**2, 0.0, 0.0, (0.5 * DEG) ** 2, (0.5 * DEG) ** 2, 0.0]
    spec = _spec(SHUTTLE, mean, var, u_nom, sigma_u_deg)
    return _problem("shuttle-reentry", SHUTTLE, spec, grid, (1.0, 500.0, 1000.0, 2000.0),
                    f"shuttle re-entry, Gaussian x0 (Eq. 24-25) and controls (sigma "
                    f"{sigma_u_deg:g} deg), {t_final:g} s, dt = {dt:g} s",
                    "first maneuver, Tables 1-2, Eq. 24-25", ("ft", "ft/s"))


def glider_reentry(t_final: float = 120.0, dt: float = 0.1, alpha_deg: float = 10.0,
                   bank_deg: float = 80.0, bank_t0: float = 20.0, bank_t1: float = 30.0,
                   sigma_u_deg: float = 3.0) -> Problem:
    """Glide vehicle with Gaussian x0 and controls, 120 s, alpha 10 deg, bank 0 -> 80 deg at 20-30 s (Jain Eq. 26-27).

    Vehicle of Tables 3-4, initial Gaussian of Eq. 26-27 (gamma0 = -35.0822 deg).  The paper's
    optimal profile (its Ref. 34) is not given; the nominal here is ours: ``alpha = alpha_deg``
    (about the maximum L/D of Table 4, 10.8 deg), bank 0 until ``bank_t0`` (pull-up from the
    steep dive), ramping linearly to ``bank_deg`` at ``bank_t1`` and held (the banked lift stops
    the skip and turns the vehicle).  sigma ``sigma_u_deg`` on both; Euler step ``dt`` s.
    Options: ``t_final`` (s, default 120; a multiple of ``dt``), ``dt`` (s, default 0.1),
    ``alpha_deg`` (deg, the angle of attack), ``bank_deg`` (deg), ``bank_t0`` (s), ``bank_t1`` (s),
    ``sigma_u_deg`` (deg).
    """
    if not 0 <= bank_t0 <= bank_t1:
        raise ProblemError(f"need 0 <= bank_t0 <= bank_t1; got bank_t0={bank_t0!r}, bank_t1={bank_t1!r}")
    grid = time_grid(t_final, dt, unit="s")
    t = grid[:-1]
    bank = np.interp(t, [0.0, bank_t0, bank_t1 + 1e-12, max(t_final, bank_t1 + 1.0)],
                     [0.0, 0.0, bank_deg, bank_deg])
    u_nom = np.column_stack([np.full(t.size, alpha_deg * DEG), bank * DEG])
    mean = [80000.0, 5000.0, -35.0822 * DEG, 0.0, 0.0, 0.0]
    var = [1.0, 0.0, 0.0, (0.5 * DEG) ** 2, (0.5 * DEG) ** 2, 0.0]
    spec = _spec(GLIDER, mean, var, u_nom, sigma_u_deg)
    return _problem("glider-reentry", GLIDER, spec, grid, (1.0, 30.0, 60.0, 120.0),
                    f"glide vehicle, Gaussian x0 (Eq. 26-27) and controls (sigma "
                    f"{sigma_u_deg:g} deg), {t_final:g} s, dt = {dt:g} s",
                    "second maneuver, Tables 3-4, Eq. 26-27", ("m", "m/s"))


PROBLEMS = {"shuttle-reentry": shuttle_reentry, "glider-reentry": glider_reentry}
