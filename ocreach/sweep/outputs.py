"""Post-processing a task keeps: extents, support values, MEB radius, hull volume, custody horizon.

Everything is evaluated at the final time of the result, in the state subspace ``keep["dims"]``
("position" by default) and in model units (the table carries ``units_length_m`` and
``units_time_s`` to convert).  For sample-based results (ffoe, mc, ...) extents and support values
are maxima over the samples, i.e. estimates from inside; for set results they are the set's
support function.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ocreach.errors import ProblemError, SolverError
from ocreach.geometry.directions import resolve_dims
from ocreach.geometry.meb import minimum_enclosing_ball
from ocreach.sweep.errors import SweepError


def meb_radius(points: np.ndarray) -> dict[str, Any]:
    """Radius of the exact minimum enclosing ball of ``points`` (m, d).

    :func:`ocreach.geometry.meb.minimum_enclosing_ball` (Welzl's algorithm in a core-set loop, Tucker et
    al. Sec. 2.3; exact to machine precision, with a certificate).  For sample-based results
    this is the ball of the samples, an inner estimate of the ball of the true set.
    """
    return {"meb_radius": float(minimum_enclosing_ball(points).radius)}


def hull_volume(points: np.ndarray) -> float:
    """Convex-hull volume (area in 2-D, length in 1-D) of ``points``; 0 for a degenerate (flat) set."""
    from scipy.spatial import ConvexHull, QhullError

    P = np.asarray(points, dtype=float)
    if P.shape[1] == 1:
        return float(np.ptp(P[:, 0]))
    if P.shape[0] <= P.shape[1]:
        return 0.0
    try:
        return float(ConvexHull(P).volume)
    except QhullError:
        return 0.0


def custody_outputs(problem, result, params: dict[str, Any]) -> dict[str, Any]:
    """Custody horizon of one task: :func:`ocreach.custody.sweep_task` ``(problem, result, **params)``.

    The hook returns a dict of numbers (``{"t_safe_days": ..., "t_loss_days": ...}``, recorded as
    ``custody_t_safe_days`` ...) or one number (``custody_horizon``).
    """
    from ocreach.custody import sweep_task

    value = sweep_task(problem, result, **params)
    if isinstance(value, dict):
        return {f"custody_{k}": v for k, v in value.items()}
    return {"custody_horizon": float(value)}


def check_keep(keep: dict[str, Any], problem) -> tuple[int, ...]:
    """``keep`` against the task's problem (the driver checks it before any task runs): ``dims``
    indices of its state, ``support`` directions of that length, custody argument names.  Returns
    the dims."""
    dims = resolve_dims(keep["dims"], problem)
    if keep["support"] and len(keep["support"][0]) != len(dims):
        names = [problem.model.state_names[d] for d in dims]
        raise SweepError(f"keep.support directions have {len(keep['support'][0])} entries; keep.dims "
                         f"{keep['dims']!r} of problem {problem.id!r} has {len(dims)} ({names})")
    if keep["custody"] is not None:
        from ocreach.custody import check_sweep_params

        try:
            check_sweep_params(keep["custody"], "keep.custody")
        except ProblemError as err:
            raise SweepError(str(err)) from err
    return dims


def compute_outputs(result, problem, keep: dict[str, Any]) -> dict[str, Any]:
    """The scalars a task records (see the module docstring); every number is finite."""
    dims = check_keep(keep, problem)
    names = [problem.model.state_names[d] for d in dims]
    out: dict[str, Any] = {"t_final": float(result.times[-1])}
    if problem.units is not None:
        out.update(units_length_m=float(problem.units.length), units_time_s=float(problem.units.time))
    if keep["extent"]:
        eye = np.eye(len(dims))
        hi = np.atleast_1d(result.support(eye, k=-1, dims=dims))
        lo = -np.atleast_1d(result.support(-eye, k=-1, dims=dims))
        for n, a, b in zip(names, lo, hi):
            out[f"{n}_min"], out[f"{n}_max"], out[f"extent_{n}"] = float(a), float(b), float(b - a)
    if keep["support"]:
        D = np.asarray(keep["support"], dtype=float)
        vals = np.atleast_1d(result.support(D, k=-1, dims=dims))
        out.update({f"support_{i}": float(v) for i, v in enumerate(vals)})
    if keep["meb"] or keep["volume"]:
        pts = result.points_at(-1, dims)
        if keep["meb"]:
            out.update(meb_radius(pts))
        if keep["volume"]:
            out["hull_volume"] = hull_volume(pts)
            out["hull_volume_note"] = ("hull of the samples" if result.points is not None
                                       else "hull of 2000 samples of the set")
    if keep["custody"] is not None:
        out.update(custody_outputs(problem, result, keep["custody"]))
    bad = [k for k, v in out.items() if isinstance(v, float) and not math.isfinite(v)]
    if bad:
        raise SolverError(f"non-finite outputs {bad} from method {result.method!r}")
    return out
