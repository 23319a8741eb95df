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

from ocreach.errors import SolverError
from ocreach.reach.directions import resolve_dims
from ocreach.sweep.errors import SweepError


def meb_radius(points: np.ndarray) -> dict[str, Any]:
    """Radius of the minimum enclosing ball of ``points`` (m, d).

    Uses the exact ``ocreach.geometry.minimum_enclosing_ball`` (Welzl; issue #13, returns a ball
    with ``.radius``) when it exists; otherwise the fallback :func:`meb_radius_bounds` brackets it.
    """
    from ocreach import geometry

    exact = getattr(geometry, "minimum_enclosing_ball", None)
    if exact is not None:
        ball = exact(points)
        radius = getattr(ball, "radius", None)
        if radius is None:
            radius = ball[-1] if isinstance(ball, tuple) else ball
        return {"meb_radius": float(radius), "meb_method": "exact (ocreach.geometry)"}
    return meb_radius_bounds(points)


def meb_radius_bounds(points: np.ndarray) -> dict[str, Any]:
    """Fallback MEB bracket: ``diameter / 2 <= r_MEB <= r_grow``.

    ``r_grow`` is the radius of an enclosing ball found by Ritter's construction (start on the
    two far points of a double farthest-point pass, then grow the ball towards the farthest
    outside point until none is left; J. Ritter, "An efficient bounding sphere", Graphics Gems
    1990), an upper bound a few per cent above the minimum; the lower bound is half the largest
    pairwise distance (every enclosing ball contains that segment).  ``meb_radius`` reports the
    upper bound (the ball encloses every point) and ``meb_method`` says so.
    """
    from scipy.spatial.distance import pdist

    P = np.asarray(points, dtype=float)
    a = P[np.argmax(np.linalg.norm(P - P[0], axis=1))]
    b = P[np.argmax(np.linalg.norm(P - a, axis=1))]
    c, r = 0.5 * (a + b), 0.5 * float(np.linalg.norm(b - a))
    for _ in range(10 * len(P)):
        d = np.linalg.norm(P - c, axis=1)
        j = int(np.argmax(d))
        if d[j] <= r * (1 + 1e-12) + 1e-300:
            break
        r_new = 0.5 * (r + d[j])
        c = c + (d[j] - r_new) / d[j] * (P[j] - c)
        r = r_new
    lower = 0.5 * float(pdist(P).max()) if 1 < len(P) <= 5000 else float("nan")
    out = {"meb_radius": r, "meb_method": "ritter-upper-bound (no exact MEB in ocreach.geometry)"}
    if math.isfinite(lower):
        out["meb_radius_lower"] = lower
    return out


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


#: the function of ocreach.custody a sweep calls for keep.custody (see custody_outputs)
CUSTODY_HOOK = "sweep_task"


def custody_hook():
    """``ocreach.custody.sweep_task``, or :class:`SweepError` "custody not available"."""
    try:
        import ocreach.custody as custody
    except ImportError:
        raise SweepError("custody not available: ocreach.custody (issue #13) is not installed in "
                         "this version of ocreach; keep.custody needs it") from None
    fn = getattr(custody, CUSTODY_HOOK, None)
    if fn is None:
        raise SweepError(f"custody not available: ocreach.custody has no {CUSTODY_HOOK}(problem, "
                         "result, **params) hook for sweeps yet")
    return fn


def custody_outputs(problem, result, params: dict[str, Any]) -> dict[str, Any]:
    """Custody horizon of one task: ``ocreach.custody.sweep_task(problem, result, **params)``.

    ``ocreach.custody`` (issue #13) is imported lazily; the hook returns a dict of numbers (e.g.
    ``{"t_safe": ..., "t_loss": ...}``, recorded as ``custody_t_safe`` ...) or one number
    (``custody_horizon``).  Raises :class:`SweepError` "custody not available" when the module or
    the hook is missing, so the task is recorded as failed with that message and the others go on.
    """
    value = custody_hook()(problem, result, **params)
    if isinstance(value, dict):
        return {f"custody_{k}": v for k, v in value.items()}
    return {"custody_horizon": float(value)}


def compute_outputs(result, problem, keep: dict[str, Any]) -> dict[str, Any]:
    """The scalars a task records (see the module docstring); every number is finite."""
    dims = resolve_dims(keep["dims"], problem)
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
        if D.shape[1] != len(dims):
            raise SweepError(f"keep.support directions have {D.shape[1]} entries; keep.dims "
                             f"{keep['dims']!r} has {len(dims)} ({names})")
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
