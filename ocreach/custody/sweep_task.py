"""Custody as a sweep output (``keep.custody`` of :mod:`ocreach.sweep`): one plain JSON-able dict per task."""
from __future__ import annotations

import numpy as np

from ocreach.custody.fov import FOV, make_fov
from ocreach.custody.observers import parse_observer
from ocreach.custody.probability import MODELS, check_probability, custody_probability
from ocreach.errors import ProblemError, check_real
from ocreach.geometry.meb import minimum_enclosing_ball

SWEEP_PARAMS = ("observer", "fov_deg", "fov_shape", "p", "p_required", "t_max_days", "epoch", "model")


def check_sweep_params(params: dict, where: str) -> FOV:
    """The one check of the argument names of :func:`sweep_task` (``keep.custody`` of a sweep,
    checked by the sweep driver before any task runs, and by the task) and of the required
    ``fov_deg`` with ``fov_shape``; returns the FOV.  ``where`` names the caller in the
    message."""
    unknown = sorted(set(params) - set(SWEEP_PARAMS))
    if unknown:
        raise ProblemError(f"{where} has unknown argument(s) {unknown}; allowed: "
                           f"{list(SWEEP_PARAMS)}")
    if "fov_deg" not in params:
        raise ProblemError(f"{where} needs fov_deg (full field-of-view angle in degrees, in "
                           f"(0, 180))")
    return make_fov(check_real("fov_deg", params["fov_deg"]),
                    str(params.get("fov_shape", "circle")))


def sweep_task(problem, result, **params) -> dict:
    """Custody of one sweep task (``keep.custody`` of :mod:`ocreach.sweep`): a plain JSON-able dict.

    ``params``: ``observer`` (``geocentre`` (default) | ``L1`` ... ``L5`` | ``ground:LAT,LON,ALT`` |
    ``orbit:PROBLEM``), ``fov_deg`` (full angle, required), ``fov_shape`` (``circle`` | ``square``),
    ``p`` or ``p_required`` (required probability in (0, 1], default 0.95), ``t_max_days`` (only
    times up to it are used), ``epoch`` (ground sites), ``model`` (``covered`` | ``tucker-eq14``).

    At the start and every time of ``result`` after it, the exact minimum enclosing ball of the result's
    position samples (``result.points_at(k, problem.position_dims)``; an inner estimate of the
    ball of the true set when the samples are points of it) is scored by
    :func:`custody_probability` with the boresight on the ball's centre.  The sweep's result is
    fixed, so the horizon is bracketed on the result's own time grid (no bisection; the
    bracket width is ``horizon_resolution_days``): ``t_safe_days`` is the last grid time before
    the first failing one (custody held at every grid time up to it), ``t_loss_days`` the first
    failing one or None when custody holds at every used time; custody already lost at the start
    gives ``t_safe_days`` None, ``t_loss_days`` 0 and ``lost_at_start``.  Radii in km, times in days.
    """
    fov = check_sweep_params(params, "custody sweep_task")
    shape = str(params.get("fov_shape", "circle"))
    if "p" in params and "p_required" in params and params["p"] != params["p_required"]:
        raise ProblemError(f"custody sweep_task: p={params['p']!r} and p_required={params['p_required']!r} "
                           "disagree; give one of them")
    p_req = check_probability(params.get("p_required", params.get("p", 0.95)))
    model = str(params.get("model", "covered"))
    if model not in MODELS:
        raise ProblemError(f"custody sweep_task: model must be one of {MODELS}; got {model!r}")
    if problem.units is None:
        raise ProblemError(f"custody sweep_task: problem {problem.id!r} has no units (km and days are needed)")
    pos = list(problem.position_dims)
    if len(pos) != 3:
        raise ProblemError(f"custody sweep_task: problem {problem.id!r} needs 3 position dimensions; "
                           f"has {len(pos)}")
    observer = parse_observer(str(params.get("observer", "geocentre")), problem,
                              str(params.get("epoch", "2026-01-01")))
    tu_days = float(problem.units.time) / 86400.0
    km = float(problem.units.length) / 1e3
    times = np.asarray(result.times, dtype=float)
    days = (times - times[0]) * tu_days
    use = np.flatnonzero(days > 0)
    if "t_max_days" in params and params["t_max_days"] is not None:
        t_max = check_real("t_max_days", params["t_max_days"])
        if not t_max > 0:
            raise ProblemError(f"custody sweep_task: t_max_days must be > 0; got {params['t_max_days']!r}")
        use = use[days[use] <= t_max * (1 + 1e-12)]
    if use.size == 0:
        raise ProblemError(f"custody sweep_task: the result has no time after the start within t_max_days "
                           f"(result times {days.tolist()} days)")
    t_safe, t_loss, probs, radii = None, None, [], []
    for k in np.r_[0, use].astype(int):  # the start (k = 0) too: custody may be lost already
        ball = minimum_enclosing_ball(result.points_at(int(k), pos))
        o = observer.position([times[k]])[0]
        pk = custody_probability(ball.center, ball.radius, o, fov, model=model)
        probs.append(float(pk))
        radii.append(float(ball.radius * km))
        if t_loss is None:
            if pk < p_req:
                t_loss = float(days[k])
            else:
                t_safe = float(days[k])
    grid = np.diff(np.r_[0.0, days[use]])
    return {"t_safe_days": t_safe, "t_loss_days": t_loss, "lost": t_loss is not None,
            "lost_at_start": t_safe is None,
            "horizon_resolution_days": float(grid.max()), "t_end_days": float(days[use[-1]]),
            "meb_radius_km": radii[-1], "meb_radius_km_max": float(max(radii)),
            "p_end": probs[-1], "p_min": float(min(probs)), "p_required": p_req,
            "observer": observer.name, "fov_deg": fov.full_deg, "fov_shape": shape, "model": model,
            "ball": "exact MEB of the result's position samples (inner estimate)"}
