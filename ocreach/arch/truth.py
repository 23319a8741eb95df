"""Sampled truth for the ARCH suite: trajectories through the same (hybrid) automaton, checked for
escapes from the guaranteed sets and for counter-examples of the specifications.

A continuous problem's samples (a quarter at vertices of the initial box, the rest uniform) are
integrated by the batch DOP853 of :func:`ocreach.dynamics.flow.propagate` and compared at the
checked grid times with the time-point set there, and at the middle of the step after it with
the step's tube.  A hybrid problem's samples come from
:func:`ocreach.reach.hybrid.simulate_hybrid`; every sampled state (at grid times, before and
after each jump, and at the middle of the grid steps, inside the sub-step tubes) must lie in a
flowpipe piece of its location whose clock range contains its time, as the point ``(x, t)``.
A guaranteed run that stopped early is checked up to where it got.  Membership is the exact
gauge of :func:`ocreach.sets.union.gauge` with tolerance ``GAUGE_TOL = 1 + 1e-9``: LP-free
certificates first, on the sets and then on the sets scaled by ``GAUGE_TOL`` (the states from
the vertices of the initial box lie on the sets' boundary), then the LP of the exact membership
test on the scaled sets, the exact gauge LP only for points inside none of those.  A point
settled on a scaled set counts with the gauge ``GAUGE_TOL`` (an upper bound) in the worst
gauge.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.sets.polyzonotope import PolyZonotope
from ocreach.sets.pz_union import PZUnion
from ocreach.sets.union import ZonotopeUnion, gauge, scaled, union_gauge
from ocreach.specs import Samples, check_samples

#: a point is inside a set when its gauge is at most this
GAUGE_TOL = 1 + 1e-9


@dataclass
class Truth:
    """Outcome of the sampled-truth check of one instance."""

    samples: int
    points: int = 0
    escapes: int = 0
    worst_gauge: float = 0.0
    escape_example: dict[str, Any] | None = None
    violations: dict[str, dict[str, Any]] = field(default_factory=dict)
    measures: dict[str, float] = field(default_factory=dict)
    paths: dict[str, int] = field(default_factory=dict)
    blocked: int = 0
    #: the truth is compared with the guaranteed sets up to this time (the horizon, or where a
    #: guaranteed run that stopped early got to)
    checked_to: float = float("nan")
    time: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return {"samples": self.samples, "points_checked": self.points, "escapes": self.escapes,
                "checked_to": self.checked_to,
                "worst_gauge": self.worst_gauge, "escape_example": self.escape_example,
                "violations": self.violations, "measures": self.measures, "paths": self.paths,
                "blocked": self.blocked, "time_s": self.time}


def initial_states(problem, n: int, rng: np.random.Generator) -> np.ndarray:
    """A quarter of ``n`` at vertices of the initial set, the rest uniform inside."""
    from ocreach.reach.hybrid import _initial_samples

    return _initial_samples(problem, n, rng)


def _violations(problem, smp: Samples, truth: Truth) -> None:
    ver = problem.extra.get("verification")
    for spec in getattr(ver, "specs", ()):
        r = check_samples(spec, smp)
        if r.status == "violated":
            ce = dict(r.counterexample or {})
            truth.violations[spec.name] = {"detail": r.detail, "sample": ce.get("sample"),
                                           "time": ce.get("time"), "location": ce.get("location"),
                                           "state": ce.get("state")}


def continuous_truth(problem, result, samples: int = 2000, seed: int = 0,
                     stride: int = 1) -> Truth:
    """Truth of a continuous instance against ``result``: at every ``stride``-th grid time ``t_k``
    (and the last computed) the samples must lie in the time-point set there, and at the middle
    of the step after it in the step's tube.  A polynomial zonotope (``poly``) is checked through
    its zonotope enclosure, the set the specifications and measures are computed on (the
    witness test of the polynomial itself costs seconds per point on these sets).  A run that
    stopped early is checked as far as it got.  The samples are integrated over the whole
    horizon (their counter-examples and measures do not depend on how far the run got)."""
    from ocreach.dynamics.flow import propagate

    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    X0 = initial_states(problem, samples, rng)
    grid = problem.grid
    fine = np.empty(2 * grid.size - 1)
    fine[0::2], fine[1::2] = grid, 0.5 * (grid[:-1] + grid[1:])
    U = np.zeros((fine.size - 1, problem.model.n_u))
    traj = np.asarray(propagate(problem.model, X0, U, fine, p=problem.params, rtol=1e-12,
                                atol=1e-14))
    truth = Truth(samples=samples)
    names = problem.model.state_names
    K = len(result.sets)
    tubes = result.tubes or []
    truth.checked_to = float(result.times[K - 1])
    for k in sorted(set(range(0, K, stride)) | {K - 1}):
        checks = [(result.sets[k], traj[:, 2 * k], float(grid[k]))]
        if k < min(K - 1, len(tubes)):
            checks.append((tubes[k], traj[:, 2 * k + 1], float(fine[2 * k + 1])))
        for S, Xk, tk in checks:
            g = np.asarray(union_gauge(_zonotopes(S), Xk, within=GAUGE_TOL))
            truth.points += g.size
            truth.worst_gauge = max(truth.worst_gauge, float(g.max()))
            bad = g > GAUGE_TOL
            if bad.any():
                truth.escapes += int(bad.sum())
                if truth.escape_example is None:
                    s = int(np.flatnonzero(bad)[0])
                    truth.escape_example = {"sample": s, "time": tk, "gauge": float(g[s]),
                                            "state": Xk[s].tolist()}
    smp = Samples(fine, traj, names)
    _violations(problem, smp, truth)
    ver = problem.extra.get("verification")
    for m in getattr(ver, "measures", ()):
        truth.measures[m.label] = float(m.of_points(traj[:, -1], names))
    truth.time = time.perf_counter() - t0
    return truth


def _zonotopes(S):
    """``S`` as a zonotope or union of zonotopes (a polynomial zonotope by its enclosure)."""
    if isinstance(S, PZUnion):
        return ZonotopeUnion([p.to_zonotope() for p in S.parts])
    if isinstance(S, PolyZonotope):
        return S.to_zonotope()
    return S


def hybrid_truth(problem, result, samples: int = 2000, seed: int = 0, stride: int = 1) -> Truth:
    """Truth of a hybrid instance against the pieces of the guaranteed flowpipe ``result``: the
    states at every ``stride``-th grid time and the last, at the middle of the grid step after
    each of those (inside the sub-step tubes, not only where they meet), and just before and
    after every jump, up to the time the flowpipe encloses every run (``meta["valid_until"]``:
    the horizon, or less for a flowpipe that stopped early).  The runs are simulated on the grid
    with its midpoints added (which only refines the event search)."""
    import dataclasses

    from ocreach.reach.hybrid import simulate_hybrid

    t0 = time.perf_counter()
    grid = problem.grid
    fine = np.empty(2 * grid.size - 1)
    fine[0::2], fine[1::2] = grid, 0.5 * (grid[:-1] + grid[1:])
    hs = simulate_hybrid(dataclasses.replace(problem, grid=fine), samples=samples, seed=seed)
    smp = hs.samples
    truth = Truth(samples=samples, blocked=len(hs.blocked))
    for p in hs.paths:
        key = " -> ".join(p) or "(no jump)"
        truth.paths[key] = truth.paths.get(key, 0) + 1
    S, K, n = smp.states.shape
    G = grid.size
    ks = set(range(0, G, stride)) | {G - 1}
    cols = sorted({2 * k for k in ks} | {2 * k + 1 for k in ks if k < G - 1}
                  | set(range(fine.size, K)))
    T = smp.times[:, cols].ravel()
    X = smp.states[:, cols].reshape(-1, n)
    L = smp.locations[:, cols].ravel()
    who = np.repeat(np.arange(S), len(cols))
    # a flowpipe that was cut short encloses every run up to valid_until only
    truth.checked_to = float(result.meta.get("valid_until", problem.t_final))
    keep = T <= truth.checked_to + 1e-9 * max(1.0, abs(truth.checked_to))
    T, X, L, who = T[keep], X[keep], L[keep], who[keep]
    P = np.column_stack([X, T])
    inside = np.zeros(P.shape[0], dtype=bool)
    by_loc: dict[str, list] = {}
    for pc in result.pieces:
        by_loc.setdefault(pc.location, []).append(pc)
    # membership in some piece of the point's location whose clock range holds its time: first
    # the LP-free certificates, then the same on the pieces scaled by GAUGE_TOL about their
    # centres (gauge <= GAUGE_TOL: the states on the boundary, which the unscaled tests miss by
    # rounding), then the exact test on the scaled pieces; each piece tried only on the points in
    # its time range and its box (a point outside a piece's box is not in the piece)
    scaled_hit = False
    for lp, scale in (("certificates", 1.0), ("certificates", GAUGE_TOL),
                      ("membership-lp", GAUGE_TOL)):
        for loc, pcs in by_loc.items():
            idx = np.flatnonzero((L == loc) & ~inside)
            if idx.size == 0:
                continue
            order = idx[np.argsort(T[idx])]
            ts = T[order]
            for pc in pcs:
                a = np.searchsorted(ts, pc.t_lo - 1e-9, "left")
                b = np.searchsorted(ts, pc.t_hi + 1e-9, "right")
                if b <= a:
                    continue
                cand = order[a:b]
                I = pc.set.interval_hull()
                tol = 1e-9 * (1 + np.maximum(np.abs(I.lo), np.abs(I.hi)))
                inb = np.all((P[cand] >= I.lo - tol) & (P[cand] <= I.hi + tol), axis=1)
                cand = cand[~inside[cand] & inb]
                if cand.size:
                    Z = pc.set if scale == 1.0 else scaled(pc.set, scale)
                    hit = cand[np.atleast_1d(gauge(Z, P[cand], lp=lp)) <= 1.0]
                    inside[hit] = True
                    scaled_hit |= scale != 1.0 and hit.size > 0
    worst = 0.0
    for i in np.flatnonzero(~inside):  # in no piece: the exact LP gauge over the candidate pieces
        pcs = [pc for pc in by_loc.get(L[i], []) if pc.t_lo - 1e-9 <= T[i] <= pc.t_hi + 1e-9]
        g = min((float(union_gauge(pc.set, P[i], exact=True)) for pc in pcs), default=np.inf)
        worst = max(worst, g)
        if g > GAUGE_TOL:
            truth.escapes += 1
            if truth.escape_example is None:
                truth.escape_example = {"sample": int(who[i]), "time": float(T[i]),
                                        "location": str(L[i]), "gauge": g,
                                        "state": X[i].tolist()}
    truth.points = int(P.shape[0])
    truth.worst_gauge = max(worst, GAUGE_TOL if scaled_hit else float(inside.any()))
    _violations(problem, smp, truth)
    ver = problem.extra.get("verification")
    names = problem.automaton.state_names
    for m in getattr(ver, "measures", ()):
        truth.measures[m.label] = float(m.of_points(hs.final, names))
    truth.time = time.perf_counter() - t0
    return truth
