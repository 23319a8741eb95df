"""Reachable-position balls of a custody problem at any horizon (Tucker et al. Sec. 2.2-2.3).

At a horizon ``t`` the problem (``problems/tucker.py``) is rebuilt with ``t_days = t`` and solved by
``bvp`` on the position subspace (Tucker Eq. 4-12; box thrust through the smoothing continuation
of :mod:`ocreach.reach.bvp`).  Each direction ``z_j`` gives an extremal endpoint ``x_j``; with the
quadratic cost of Eq. 4 the extremal is the farthest point along ``+z_j`` or ``-z_j`` from the
unpowered state, so the supporting direction is ``d_j = sign(z_j . (x_j - x_ref)) z_j`` with support
value ``h_j = d_j . x_j``.  Two balls per horizon:

* ``inner``: the exact minimum enclosing ball of the endpoints (Tucker Sec. 2.3; an inner
  estimate of the ball of the true set, since the endpoints are points of the set);
* ``outer``: the ball around the polytope ``{x : d_j . x <= h_j}`` (:func:`ocreach.geometry.meb.support_outer_ball`),
  which contains the set whenever the ``h_j`` are the true support values (bvp finds local
  extremals; ``validate_with_mc`` checks Monte Carlo endpoints against every ``h_j``).

Horizons are solved in increasing order of need; each solve is warm-started from the costates of
the nearest solved horizon (option ``costate_guess`` of ``bvp``), scaled by ``(t / t_near)^2`` for
the quadratic cost (the reach distance grows like ``a t^2 / 2`` at first).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.errors import ProblemError, SolverError
from ocreach.geometry.meb import EnclosingBall, minimum_enclosing_ball, support_outer_ball


@dataclass
class HorizonBalls:
    """Balls of the reachable positions at ``t_days`` (model units; see the module docstring)."""

    t_days: float
    endpoints: np.ndarray
    directions: np.ndarray
    support: np.ndarray
    inner: EnclosingBall
    outer: EnclosingBall
    nominal: np.ndarray
    costate0: np.ndarray
    result: Any = field(default=None, repr=False)
    warm_started: bool = False


def horizon_balls(result, pos=(0, 1, 2)) -> tuple[np.ndarray, np.ndarray, np.ndarray, EnclosingBall,
                                                  EnclosingBall, np.ndarray]:
    """``(endpoints, d_j, h_j, inner, outer, nominal)`` from a ``bvp`` result on positions ``pos``."""
    pos = list(pos)
    X = np.asarray(result.points[-1])[:, pos]
    Z = np.asarray(result.meta["directions"])[:, pos]
    ref = np.asarray(result.meta["reference_final"])[pos]
    sgn = np.sign(np.einsum("ij,ij->i", Z, X - ref))
    sgn[sgn == 0] = 1.0
    D = Z * sgn[:, None]
    h = np.einsum("ij,ij->i", D, X)
    return X, D, h, minimum_enclosing_ball(X), support_outer_ball(D, h), ref


class ReachableBalls:
    """Cached, warm-started ``bvp`` balls of one custody problem at any horizon (days)."""

    def __init__(self, problem_id: str, *, overrides: dict | None = None, bvp_options: dict | None = None,
                 keep_results: bool = False) -> None:
        from ocreach.registry import get_problem

        self.problem_id = problem_id
        self.overrides = dict(overrides or {})
        self.base = get_problem(problem_id, **self.overrides)
        if "horizons_days" not in self.base.extra:
            raise ProblemError(f"problem {problem_id!r} is not a custody problem (no extra['horizons_days']); "
                               "use custody-l1 ... custody-l5 or custody-gateway")
        self.options = {**self.base.options_for("bvp"), **(bvp_options or {})}
        self.keep_results = keep_results
        self.cache: dict[float, HorizonBalls] = {}
        self.solves = 0

    def start_ball(self) -> tuple[np.ndarray, float]:
        """Centre and radius of the smallest ball around the positions at t = 0: the point ``x0``,
        or, with the initial ellipsoid of Tucker Eq. 6, the ball of its position part (radius
        ``sqrt(lambda_max)`` of the position block of its shape matrix)."""
        pos = list(self.base.position_dims)
        E = self.base.initial_set
        if E is None:
            return np.asarray(self.base.x0, dtype=float)[pos], 0.0
        Q = np.asarray(E.Q, dtype=float)[np.ix_(pos, pos)]
        return np.asarray(E.q, dtype=float)[pos], float(np.sqrt(np.linalg.eigvalsh(Q).max()))

    def problem(self, t_days: float):
        from ocreach.registry import get_problem

        # keep the grid step; at least 4 segments so short horizons are resolved
        dt_h = min(float(self.overrides.get("dt_hours", 2.0)), t_days * 24.0 / 4)
        return get_problem(self.problem_id, **{**self.overrides, "t_days": t_days, "dt_hours": dt_h})

    def at(self, t_days: float) -> HorizonBalls:
        from ocreach.reach.base import reach

        t = float(t_days)
        if not (np.isfinite(t) and t > 0):
            raise ProblemError(f"horizon must be a finite number of days > 0; got {t_days!r}")
        key = round(t, 12)
        if key in self.cache:
            return self.cache[key]
        prob = self.problem(t)
        opts = dict(self.options)
        res, warm = None, False
        if self.cache:
            near = min(self.cache.values(), key=lambda hb: abs(np.log(hb.t_days / t)))
            scale = (t / near.t_days) ** 2 if opts.get("cost", "linear") == "quadratic" else 1.0
            try:
                res = reach(prob, "bvp", **opts, costate_guess=near.costate0 * scale)
                warm = True
            except SolverError:
                res = None
        if res is None:
            res = reach(prob, "bvp", **opts)
        self.solves += 1
        X, D, h, inner, outer, ref = horizon_balls(res, prob.position_dims)
        hb = HorizonBalls(t, X, D, h, inner, outer, ref, np.asarray(res.meta["costate0"]),
                          res if self.keep_results else None, warm)
        self.cache[key] = hb
        return hb


def validate_with_mc(balls: ReachableBalls, t_days: float, samples: int = 10_000, seed: int = 0,
                     rel_tol: float = 1e-6, keep_points: bool = False) -> dict:
    """Monte Carlo endpoints against the balls and support values at ``t_days``.

    Returns the sample count, how many endpoints are outside the outer ball, the largest excess
    over the support values ``max_j (d_j . x - h_j)`` relative to the reach (the outer radius),
    and the largest MC distance from the inner / outer centre relative to the radius
    (``keep_points``: also the MC endpoint positions under ``"points"``).
    """
    from ocreach.reach.base import reach

    hb = balls.at(t_days)
    prob = balls.problem(t_days)
    mc = reach(prob, "mc", samples=samples, seed=seed)  # random / constant / bang-bang box controls
    P = np.asarray(mc.points[-1])[:, list(prob.position_dims)]
    excess = (P @ hb.directions.T - hb.support[None, :]).max()
    scale = hb.outer.radius
    out = {"t_days": float(t_days), "samples": int(samples),
            "outside_outer": int(np.sum(~hb.outer.contains(P, tol=rel_tol))),
            "max_support_excess_rel": float(excess / scale),
            "above_support": int(np.sum((P @ hb.directions.T - hb.support[None, :]).max(axis=1) > rel_tol * scale)),
            "mc_max_dist_inner": float(np.linalg.norm(P - hb.inner.center, axis=1).max() / hb.inner.radius),
            "mc_max_dist_outer": float(np.linalg.norm(P - hb.outer.center, axis=1).max() / hb.outer.radius),
            "inner_km": float(hb.inner.radius * prob.units.length / 1e3),
            "outer_km": float(hb.outer.radius * prob.units.length / 1e3)}
    if keep_points:
        out["points"] = P
    return out
