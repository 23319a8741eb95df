"""Ephemeris-corrected multi-revolution reference orbit for station keeping on the DE421 plant.

The CR3BP periodic orbit of a problem (e.g. the 9:2 NRHO of ``nrho-9-2``) is not an orbit of the
DE421 point-mass model: a perfect tracker of it on the ephemeris plant pays about 40 m/s per
revolution (docs/ephemeris.md).  This module corrects it into a continuous, natural (thrust-free)
trajectory of the plant's own equations, over many revolutions from a given epoch:

1. **Seed.** Patch points ``X_j`` at times ``t_j`` on the CR3BP reference's grid, ``arcs_per_rev``
   per revolution at the phases ``(j + patch_phase) / arcs_per_rev`` of a revolution from apolune,
   plus the first and last apolune.  The default (4 arcs, phase 0.5: 1/8, 3/8, 5/8, 7/8 of a
   revolution) keeps every perilune passage inside an arc.  Patch points *at* perilune were
   tried first: the arc-end velocity defect there is 1.3 DU/TU (a small timing error at the
   perilune speed), and the correction took 24 iterations to an orbit 80,000 km from the seed, no
   longer the NRHO.  Two patch points per revolution (1/4, 3/4) do for the NRHO but not for
   l2-halo over 11 revolutions, which wandered off (epoch 2026-01-01) or did not converge (two of
   four epochs); four converge in 5 iterations for both problems at the four epochs tried
   (docs/ephemeris.md).  The seed states come from the periodic CR3BP reference, read in the
   coordinates of the plant's rotating frame fixed at the epoch
   (:class:`~ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant`: the same map the plant uses, so the
   seed is the mapped CR3BP orbit).
2. **Multiple shooting** (:mod:`ocreach.dynamics.shooting`) in the plant's dynamics in those coordinates
   (:meth:`EphemerisPlant.frame_model`, Moon, Earth, Sun point masses, DE421 refit, Patel &
   Scheeres Eq. 11): with the epoch and all patch times fixed, the free variables are the
   ``6 (n + 1)`` patch states and the constraints the ``6 n`` arc-end defects
   ``F_j = phi(X_j; t_j, t_{j+1}) - X_{j+1}``.  The Jacobian has the blocks ``[Phi_j, -I]``
   (``Phi_j`` the arc's STM from the model's variational equations, :func:`ocreach.dynamics.flow.stm_batch`),
   and the update is the minimum-norm Newton step ``dX = -DF^T (DF DF^T)^{-1} F`` (the multiple
   shooting of T. A. Pavlak, "Mission design applications in the Earth-Moon system: transfer
   trajectories and stationkeeping", M.S. thesis, Purdue University, 2010, Ch. 3, used for
   long-horizon ephemeris references by Pavlak & Howell, "Strategy for optimal, long-term
   stationkeeping of libration point orbits in the Earth-Moon system", AIAA 2012-4665; not
   checked against the texts here, which are not in the repository), halved while it does not
   reduce ``|F|``, until the largest defect component is below ``tol`` (default 1e-9 DU and
   DU/TU: 0.4 m and 1e-6 m/s).  A converged trajectory whose closest or farthest distance from
   the Moon differs from the CR3BP orbit's by more than a factor ``max_distance_ratio`` (2) is
   refused (:func:`check_same_orbit`): it is no longer the orbit asked for.
3. **Sampling.** Each arc is re-integrated from its corrected patch state onto the control grid,
   giving a non-periodic :class:`~ocreach.control.reference.TrackingReference` whose model is the
   frame model (so LQR and MPC linearise and predict with the ephemeris dynamics themselves) and
   whose time is the plant's reference time (0 at the epoch).

The corrected patch points are cached on disk (``$OCREACH_CACHE_DIR/ephemeris_reference``, default
``~/.cache/ocreach``): one ``.npz`` of arrays (loaded with ``allow_pickle=False``) and a ``.json``
of settings and convergence history, written atomically, keyed by problem, orbit, epoch,
revolutions, patch points, bodies and tolerance.  The key does not cover the dynamics' code, so
a cached orbit is used only if its arc-end defects, re-integrated in this run's dynamics, are
still within ``tol``; otherwise it is recomputed.
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.control.reference import TrackingReference, reference_from_problem, verified_substeps
from ocreach.control.stationkeeping.ephemeris_plant import (
    DEFAULT_BODIES,
    DEFAULT_EPOCH,
    EphemerisPlant,
)
from ocreach.dynamics.shooting import (
    ARC_ATOL,
    ARC_RTOL,
    DEFECT_TOL,
    multiple_shooting,
    patch_defects,
)
from ocreach.errors import ProblemError, SolverError, check_count, check_positive, check_real

if TYPE_CHECKING:
    from ocreach.problem import Problem

log = logging.getLogger("ocreach.control.stationkeeping.ephemeris_reference")

_CACHE_VERSION = 1


@dataclass(eq=False)
class EphemerisOrbit:
    """A corrected multi-revolution orbit of the ephemeris plant (module doc).

    ``times`` (n + 1,) patch times (TU, reference time: 0 at the epoch), ``states`` (n + 1, 6)
    patch states in the plant's CR3BP-frame coordinates, ``defects`` (n, 6) the arc-end defects
    left, ``steps`` (n + 1,) the patch times as control-grid indices, ``dt`` the grid step,
    ``meta`` settings and the convergence history.  ``plant`` the plant whose dynamics it follows.
    """

    times: np.ndarray
    states: np.ndarray
    defects: np.ndarray
    steps: np.ndarray
    dt: float
    meta: dict
    plant: EphemerisPlant = field(repr=False)
    _grid_states: np.ndarray | None = field(default=None, repr=False)

    @property
    def max_defect(self) -> float:
        return float(np.max(np.abs(self.defects))) if self.defects.size else 0.0

    def sample(self, n_steps: int | None = None) -> np.ndarray:
        """States on the control grid ``t_k = k dt``, ``k = 0..n_steps`` (default: all), each from
        the arc that contains it: ``(n_steps + 1, 6)``."""
        from ocreach.dynamics.flow import propagate

        last = int(self.steps[-1])
        n = last if n_steps is None else int(n_steps)
        if not 1 <= n <= last:
            raise ProblemError(f"n_steps must be in 1..{last} for this orbit; got {n_steps!r}")
        if self._grid_states is None:
            model = self.plant.frame_model()
            out = np.empty((last + 1, 6))
            for j in range(len(self.steps) - 1):
                a, b = int(self.steps[j]), int(self.steps[j + 1])
                grid = self.dt * np.arange(a, b + 1)
                out[a:b + 1] = propagate(model, self.states[j], np.zeros((b - a, 3)), grid,
                                         rtol=ARC_RTOL, atol=ARC_ATOL)
            out[0] = self.states[0]
            self._grid_states = out
        return self._grid_states[:n + 1].copy()

    def moon_distance_range(self) -> tuple[float, float]:
        """Smallest and largest distance from the Moon on the grid (model units)."""
        return _moon_distance_range(self.sample(), self.plant.mu)


def _moon_distance_range(X: np.ndarray, mu: float) -> tuple[float, float]:
    d = np.linalg.norm(X[:, :3] - np.array([1.0 - mu, 0.0, 0.0]), axis=1)
    return float(d.min()), float(d.max())


def check_same_orbit(orbit: EphemerisOrbit, seed_states: np.ndarray, ratio: float,
                     length_km: float) -> dict[str, float]:
    """Refuse a converged correction that is no longer the seed orbit: its smallest and largest
    distance from the Moon must be within a factor ``ratio`` of the seed orbit's.

    Why: multiple shooting with too few patch points can converge to a continuous trajectory
    that leaves the orbit (l2-halo, 11 revolutions, 2 patch points per revolution, epoch
    2026-01-01: 3718 km from the Moon's centre in revolution 10, the CR3BP halo never closer than
    46,358 km).  Returns the distances (km) for the metadata; raises :class:`SolverError`.
    """
    lo, hi = orbit.moon_distance_range()
    lo0, hi0 = _moon_distance_range(seed_states, orbit.plant.mu)
    out = {"moon_distance_min_km": lo * length_km, "moon_distance_max_km": hi * length_km,
           "seed_moon_distance_min_km": lo0 * length_km,
           "seed_moon_distance_max_km": hi0 * length_km}
    if not (lo0 / ratio <= lo <= lo0 * ratio and hi0 / ratio <= hi <= hi0 * ratio):
        raise SolverError(
            f"ephemeris multiple shooting converged to a trajectory that is not the seed orbit: "
            f"distance from the Moon {lo * length_km:.0f}..{hi * length_km:.0f} km against "
            f"{lo0 * length_km:.0f}..{hi0 * length_km:.0f} km for the CR3BP orbit (allowed "
            f"factor max_distance_ratio = {ratio:g}); use more patch points (arcs_per_rev) or "
            f"fewer revolutions")
    return out


# ------------------------------------------------------------------------------------------------
# validation and cache
# ------------------------------------------------------------------------------------------------
def _check_revolutions(revolutions) -> int:
    if isinstance(revolutions, bool) or not isinstance(revolutions, (int, np.integer)) \
            or revolutions < 1:
        raise ProblemError(f"revolutions (of the ephemeris-corrected reference) must be an integer "
                           f">= 1; got {revolutions!r}")
    return int(revolutions)


def _cache_key(problem: Problem, cr3bp_ref: TrackingReference, epoch_jd: tuple[float, float],
               revolutions: int, arcs: int, phase: float, bodies: tuple[str, ...], tol: float,
               frame_acceleration: str, distance_ratio: float,
               srp: dict | None = None) -> tuple[str, dict]:
    settings = {
        "version": _CACHE_VERSION, "problem": problem.id,
        "orbit_x0": np.asarray(problem.reference.x0, float).tolist(),
        "period": float(problem.reference.period), "params": cr3bp_ref.params.tolist(),
        "length_m": float(problem.units.length), "time_s": float(problem.units.time),
        "dt": float(cr3bp_ref.dt), "steps_per_rev": int(cr3bp_ref.n_steps),
        "epoch_jd": [float(epoch_jd[0]), float(epoch_jd[1])], "revolutions": revolutions,
        "arcs_per_rev": arcs, "patch_phase": float(phase), "bodies": list(bodies),
        "tol": float(tol), "max_distance_ratio": float(distance_ratio),
        "frame_acceleration": frame_acceleration,
    }
    if srp is not None:  # only with SRP: the keys of orbits without it stay what they were
        settings["srp"] = srp
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:20]
    name = f"{problem.id}_rev{revolutions}_{digest}"
    return name, settings


def cache_folder() -> Path:
    """Folder of the cached orbits: ``$OCREACH_CACHE_DIR/ephemeris_reference``."""
    from ocreach.native.compile import cache_dir

    return cache_dir("ephemeris_reference")


def _cache_paths(name: str) -> tuple[Path, Path]:
    d = cache_folder()
    return d / f"{name}.npz", d / f"{name}.json"


def _cache_load(name: str, settings: dict, n_patch: int) -> dict | None:
    npz, js = _cache_paths(name)
    try:
        meta = json.loads(js.read_text())
        with np.load(npz, allow_pickle=False) as data:
            arrays = {k: np.asarray(data[k]) for k in ("times", "states", "defects", "steps")}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):  # absent or damaged: recompute
        return None
    try:  # a foreign or damaged entry (JSON not a dict, arrays not numbers) is recomputed
        ok = (isinstance(meta, dict) and meta.get("settings") == settings
              and arrays["states"].shape == (n_patch, 6)
              and arrays["defects"].shape == (n_patch - 1, 6)
              and all(np.all(np.isfinite(a)) for a in arrays.values())
              and float(np.max(np.abs(arrays["defects"]))) <= settings["tol"])
    except (TypeError, ValueError):
        ok = False
    return {**arrays, "meta": meta} if ok else None


def _cache_store(name: str, arrays: dict, meta: dict) -> None:
    from ocreach.fileio import atomic_write_bytes, atomic_write_text, jsonable

    npz, js = _cache_paths(name)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    try:  # arrays first: a JSON file is only ever next to its arrays
        atomic_write_bytes(npz, buf.getvalue())
        atomic_write_text(js, json.dumps(jsonable(meta), indent=1))
    except OSError as exc:
        log.warning("could not cache the ephemeris reference in %s: %s", npz.parent, exc)


def patch_steps(steps_per_rev: int, revolutions: int, arcs_per_rev: int,
                phase: float = 0.0) -> np.ndarray:
    """Grid indices of the patch points: ``arcs_per_rev`` per revolution at the fractions
    ``(j + phase) / arcs_per_rev`` of a revolution (rounded to the grid), plus the first and the
    last grid point."""
    M = int(steps_per_rev)
    frac = (np.arange(arcs_per_rev) + float(phase)) / arcs_per_rev
    inner = [r * M + np.round(frac * M).astype(int) for r in range(revolutions)]
    steps = np.unique(np.concatenate([[0, revolutions * M]] + inner))
    return steps[(steps >= 0) & (steps <= revolutions * M)]


def correct_orbit(problem: Problem, revolutions: int, *, epoch: Any = DEFAULT_EPOCH,
                  bodies: Sequence[str] = DEFAULT_BODIES, arcs_per_rev: int = 4,
                  tol: float = DEFECT_TOL, max_iter: int = 30, dt: float | None = None,
                  frame_acceleration: str = "modelled", patch_phase: float = 0.5,
                  max_distance_ratio: float = 2.0, use_cache: bool = True,
                  srp: Any = None) -> EphemerisOrbit:
    """The problem's CR3BP periodic orbit corrected into a ``revolutions``-revolution orbit of the
    DE421 plant from ``epoch`` (module doc).  ``arcs_per_rev`` patch points per revolution at the
    phases ``(j + patch_phase) / arcs_per_rev`` (module doc, step 1); ``dt`` the control step
    (default the problem's, rounded to divide the period as in
    :func:`~ocreach.control.reference.reference_from_problem`); ``max_distance_ratio``: the
    corrected orbit's closest and farthest distance from the Moon must be within this factor of
    the CR3BP orbit's (:func:`check_same_orbit`); ``use_cache``: read and write the disk cache
    (a cached orbit is re-checked in the current dynamics); ``srp``: solar radiation pressure of
    the plant (:class:`~ocreach.control.ephemeris_plant.EphemerisPlant`; the orbit is one of the
    plant with it, at the nominal ``C_r A / m``).  Raises :class:`ProblemError` on bad
    input (an epoch outside DE421 included) and :class:`SolverError` if the correction does not
    converge."""
    from ocreach.ephemeris import parse_epoch

    revolutions = _check_revolutions(revolutions)
    arcs = check_count("arcs_per_rev", arcs_per_rev, 1)
    tol = check_positive("tol (defect tolerance)", tol)
    max_iter = check_count("max_iter (Newton iterations)", max_iter, 1)
    if check_real("max_distance_ratio", max_distance_ratio) <= 1:
        raise ProblemError(f"max_distance_ratio must be a number > 1; got {max_distance_ratio!r}")
    max_distance_ratio = float(max_distance_ratio)
    if not 0 <= check_real("patch_phase", patch_phase) < 1:
        raise ProblemError(f"patch_phase (fraction of a patch interval) must be in [0, 1); got "
                           f"{patch_phase!r}")
    patch_phase = float(patch_phase)
    if problem.reference is None:
        raise ProblemError(f"an ephemeris-corrected reference needs a periodic CR3BP reference "
                           f"orbit as its seed; problem {problem.id!r} has none")
    epoch_jd = parse_epoch(epoch)
    cr = reference_from_problem(problem, dt=dt, n_sub=2)
    M = cr.n_steps
    if arcs > M:
        raise ProblemError(f"arcs_per_rev must be at most the {M} grid steps per revolution; got "
                           f"{arcs_per_rev!r}")
    span_days = revolutions * M * cr.dt * problem.units.time / 86400.0
    plant = EphemerisPlant(cr, problem.control_set.kind, problem.velocity_dims,
                           span_days=span_days, epoch=epoch, bodies=bodies,
                           frame_acceleration=frame_acceleration,
                           srp=srp)  # checks the epoch's coverage
    model = plant.frame_model()
    steps = patch_steps(M, revolutions, arcs, patch_phase)
    times = cr.dt * steps
    name, settings = _cache_key(problem, cr, epoch_jd, revolutions, arcs, patch_phase,
                                tuple(plant.bodies), tol, frame_acceleration, max_distance_ratio,
                                None if srp is None else srp.as_dict())
    cached = _cache_load(name, settings, steps.size) if use_cache else None
    if cached is not None and np.array_equal(cached["steps"], steps):
        # the key holds the settings, not the dynamics' code: re-check the stored patch points
        # in the dynamics of this run (one batch of arcs) before trusting them
        F_now, _ = patch_defects(model, times, cached["states"], model.p_default)
        if float(np.max(np.abs(F_now))) <= tol:
            return EphemerisOrbit(times, cached["states"], F_now, steps, cr.dt, cached["meta"],
                                  plant)
        log.warning("cached ephemeris reference %s does not satisfy the current dynamics "
                    "(largest defect %.3g > tol %g): recomputed", name,
                    float(np.max(np.abs(F_now))), tol)
    seed = cr.state(steps % M)
    X, F, history = multiple_shooting(model, times, seed, model.p_default, tol=tol,
                                      max_iter=max_iter)
    shift = X - seed
    meta = {"settings": settings, "epoch": str(epoch), "iterations": len(history) - 1,
            "max_defect_history": history, "max_defect": float(np.max(np.abs(F))),
            "seed_to_corrected_max_position_km": float(
                np.max(np.linalg.norm(shift[:, :3], axis=1)) * problem.units.length / 1e3),
            "seed_to_corrected_max_velocity_mps": float(
                np.max(np.linalg.norm(shift[:, 3:], axis=1)) * problem.units.velocity),
            "algorithm": "multiple shooting, fixed epoch and patch times, minimum-norm Newton "
                         "updates (Pavlak 2010; Pavlak & Howell 2012)"}
    orbit = EphemerisOrbit(times, X, F, steps, cr.dt, meta, plant)
    meta.update(check_same_orbit(orbit, cr.X, max_distance_ratio, problem.units.length / 1e3))
    if use_cache:
        _cache_store(name, {"times": times, "states": X, "defects": F, "steps": steps}, meta)
    return orbit


def ephemeris_reference(problem: Problem, revolutions: float, *, epoch: Any = DEFAULT_EPOCH,
                        bodies: Sequence[str] = DEFAULT_BODIES, lookahead_revolutions: int = 1,
                        n_sub: int | str = "auto", dt: float | None = None,
                        **correct_options: Any) -> tuple[TrackingReference, EphemerisOrbit]:
    """Tracking reference along the ephemeris-corrected orbit, for a closed loop of
    ``revolutions`` revolutions (``n_track``) on the ephemeris plant.

    The orbit is corrected over ``ceil(revolutions) + lookahead_revolutions`` revolutions, so MPC
    windows and the finite-horizon Riccati sweep of the LQR (this reference is not periodic) reach
    past the end of the run.  ``n_sub``: RK4 substeps of the prediction model (``"auto"``: one-step
    error <= 1e-6, :func:`~ocreach.control.reference.verified_substeps`).  Returns
    ``(reference, orbit)``; ``orbit.plant`` is the plant it is an orbit of.
    """
    if check_real("revolutions", revolutions) <= 0:
        raise ProblemError(f"revolutions must be a number > 0; got {revolutions!r}")
    revolutions = float(revolutions)
    extra = check_count("lookahead_revolutions", lookahead_revolutions, 0)
    total = int(np.ceil(revolutions)) + extra
    orbit = correct_orbit(problem, total, epoch=epoch, bodies=bodies, dt=dt, **correct_options)
    M = int(orbit.steps[-1]) // total
    X = orbit.sample()
    model = orbit.plant.frame_model()
    ref = TrackingReference(model, np.asarray(model.p_default, float), 0.0, orbit.dt, X,
                            np.zeros((X.shape[0] - 1, model.n_u)), periodic=False,
                            name=f"{problem.id} (DE421-corrected, epoch {epoch})", n_sub=2)
    if isinstance(n_sub, str):
        if n_sub != "auto":
            raise ProblemError(f"n_sub must be 'auto' or an integer >= 1; got {n_sub!r}")
        ref = verified_substeps(ref)
    else:
        ref = ref.with_substeps(check_count("n_sub", n_sub, 1))
    ref.n_track = int(round(revolutions * M))
    ref.steps_per_rev = M
    return ref, orbit


def reference_settings(orbit: EphemerisOrbit, reference: TrackingReference) -> dict[str, Any]:
    """What metrics.json says about an ephemeris-corrected reference."""
    m = orbit.meta
    return {"reference": "ephemeris", "periodic": False, "epoch": m["epoch"],
            "revolutions_corrected": m["settings"]["revolutions"],
            "patch_points": int(orbit.states.shape[0]),
            "arcs_per_rev": m["settings"]["arcs_per_rev"],
            "patch_phase": m["settings"]["patch_phase"], "tol": m["settings"]["tol"],
            "iterations": m["iterations"], "max_defect": orbit.max_defect,
            "seed_to_corrected_max_position_km": m["seed_to_corrected_max_position_km"],
            "seed_to_corrected_max_velocity_mps": m["seed_to_corrected_max_velocity_mps"],
            "prediction_model": reference.model.name, "rk4_substeps": reference.n_sub,
            "algorithm": m["algorithm"]}


__all__ = ["DEFECT_TOL", "EphemerisOrbit", "check_same_orbit", "correct_orbit",
           "ephemeris_reference", "patch_steps", "reference_settings"]
