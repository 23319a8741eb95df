"""The custody-loss horizon (Tucker et al. Sec. 3 and Algorithm 1).

The custody-loss horizon (:func:`custody_horizon`) is the first time the probability falls below
the requirement, bracketed on a scan and refined by bisection: ``t_safe`` (last time known to
hold the requirement) and ``t_loss`` (first time known to fail) with ``t_loss - t_safe <= tol``
when ``converged``; the start time is evaluated too (custody already lost there is reported as
such, with no horizon).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ocreach.custody.probability import check_probability
from ocreach.errors import ProblemError, SolverError, check_count, check_real


@dataclass(frozen=True)
class Horizon:
    """Custody-loss horizon found by :func:`custody_horizon`.

    ``t_safe``: last time known to hold ``p >= p_required`` (None when custody is already lost at
    ``t_min``: then there is no horizon and ``t_loss = t_min``); ``t_loss``: first time known to
    fail (None if custody holds at every scanned time up to ``t_max``); ``evaluations``: the
    ``(t, p)`` pairs in order.  ``converged``: the search met its tolerance (``t_loss - t_safe
    <= tol``, or no loss up to ``t_max``, or lost at ``t_min``); False when the bisection stopped
    early with the bracket still valid but wider than ``tol`` (the bisection budget ran out, the
    bracket reached the floating-point resolution of ``t``, or an evaluation inside the bracket
    failed, e.g. a bvp continuation); ``message`` says why.
    """

    t_safe: float | None
    t_loss: float | None
    p_required: float
    evaluations: tuple[tuple[float, float], ...]
    converged: bool
    message: str = ""

    @property
    def lost_at_start(self) -> bool:
        """Custody was already lost at ``t_min`` (no horizon)."""
        return self.t_safe is None


def custody_horizon(probability: Callable[[float], float], p_required: float, t_max: float, *,
                    t_step: float, tol: float, t_min: float = 0.0, max_bisections: int = 100) -> Horizon:
    """First time the custody probability drops below ``p_required`` (Tucker Sec. 3, corrected).

    Evaluate ``t_min`` first (custody already lost there: ``Horizon(t_safe=None, t_loss=t_min)``),
    then scan ``t_min + t_step, t_min + 2 t_step, ... <= t_max`` (t_max always included) for the
    first failing time, then bisect the bracket ``[t_safe, t_loss]`` until it is no longer than
    ``tol`` (``converged``), or until ``max_bisections`` halvings, the float resolution of ``t``
    or a :class:`SolverError` of ``probability`` inside the bracket stop it (not ``converged``; the
    bracket is still valid).  A failure before a bracket exists is raised.  Assumes the
    probability does not recover and fail again inside one scan step.  ``p_required`` must be in
    (0, 1]; ``t_step``, ``tol`` > 0.
    """
    p_req = check_probability(p_required)
    t_max, t_step, tol = check_real("t_max", t_max), check_real("t_step", t_step), check_real("tol", tol)
    t_min = check_real("t_min", t_min)
    max_bisections = check_count("max_bisections", max_bisections, 1)
    if not (t_step > 0 and tol > 0 and t_max > t_min):
        raise ProblemError(f"need t_step > 0, tol > 0 and t_max > t_min; got t_step={t_step!r}, "
                           f"tol={tol!r}, t_min={t_min!r}, t_max={t_max!r}")
    evals: list[tuple[float, float]] = []

    def p_at(t: float) -> float:
        val = float(probability(t))
        if not np.isfinite(val):
            raise ProblemError(f"custody probability at t = {t:g} is not finite ({val!r})")
        evals.append((t, val))
        return val

    p0 = p_at(t_min)
    if p0 < p_req:
        return Horizon(None, t_min, p_req, tuple(evals), True,
                       f"custody already lost at t_min = {t_min:g}: p = {p0:.6g} < {p_req:g}")
    scan = list(np.arange(t_min + t_step, t_max, t_step)) + [t_max]
    lo = t_min
    hi = None
    for t in scan:
        if p_at(float(t)) < p_req:
            hi = float(t)
            break
        lo = float(t)
    if hi is None:
        return Horizon(lo, None, p_req, tuple(evals), True)
    message = ""
    for _ in range(max_bisections):
        if hi - lo <= tol:
            break
        mid = 0.5 * (lo + hi)
        if not lo < mid < hi:
            message = (f"bisection stopped at the floating-point resolution of t: bracket "
                       f"[{lo!r}, {hi!r}] is wider than tol = {tol:g}")
            break
        try:
            failed = p_at(mid) < p_req
        except SolverError as exc:
            message = f"probability evaluation failed at t = {mid:g} inside the bracket: {exc}"
            break
        lo, hi = (lo, mid) if failed else (mid, hi)
    converged = hi - lo <= tol
    if not converged and not message:
        message = (f"bisection budget max_bisections = {max_bisections} used up: bracket width "
                   f"{hi - lo:g} > tol = {tol:g}")
    return Horizon(lo, hi, p_req, tuple(evals), converged, message)


def tucker_algorithm1(area: Callable[[float], float], p_c: float, theta: float, rho: float,
                      max_days: int = 1000) -> float:
    """Tucker et al. Algorithm 1 exactly as printed (for comparison only; see module docstring):
    ``A_fov = rho sin(theta)``, ``A_r-cl = (1 - p_c) / A_fov``; ``t = 0``; while
    ``A_r <= A_r-cl``: ``A_r = computeReach(t)``, ``t = t + 1``.  ``area(t)`` is the enclosing
    ball's area after ``t`` days.  Returns the final ``t`` (days)."""
    A_fov = rho * np.sin(theta)
    A_rcl = (1 - p_c) / A_fov
    A_r, t = 0.0, 0
    while A_r <= A_rcl:
        A_r = float(area(t))
        t += 1
        if t > max_days:
            raise ProblemError(f"tucker_algorithm1: no loss within {max_days} days")
    return float(t)
