"""Sampled truth for the ARCH suite: trajectories through the same (hybrid) automaton, checked for
escapes from the guaranteed sets and for counter-examples of the specifications.

A continuous problem's samples (a quarter at vertices of the initial box, the rest uniform) are
integrated by the batch DOP853 of :func:`ocreach.dynamics.flow.propagate` and compared, at every grid time,
with the time-point set there.  A hybrid problem's samples come from
:func:`ocreach.reach.hybrid.simulate_hybrid`; every sampled state (at grid times and before and
after each jump) must lie in a flowpipe piece of its location whose clock range contains its time,
as the point ``(x, t)``.  Membership is the exact gauge of :func:`ocreach.sets.union.gauge`
(certificate first, LP for the rest), with tolerance ``1 + 1e-9``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.sets.union import gauge, union_gauge
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
    time: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return {"samples": self.samples, "points_checked": self.points, "escapes": self.escapes,
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
    """Truth of a continuous instance against the time-point sets of ``result`` (every
    ``stride``-th grid time and the last)."""
    from ocreach.dynamics.flow import propagate

    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    X0 = initial_states(problem, samples, rng)
    U = np.zeros((problem.n_segments, problem.model.n_u))
    traj = np.asarray(propagate(problem.model, X0, U, problem.grid, p=problem.params,
                                rtol=1e-12, atol=1e-14))
    truth = Truth(samples=samples)
    names = problem.model.state_names
    ks = sorted(set(range(0, len(result.sets), stride)) | {len(result.sets) - 1})
    for k in ks:
        g = np.asarray(union_gauge(result.sets[k], traj[:, k]))
        truth.points += g.size
        bad = g > GAUGE_TOL
        truth.worst_gauge = max(truth.worst_gauge, float(g.max()))
        if bad.any():
            truth.escapes += int(bad.sum())
            if truth.escape_example is None:
                s = int(np.flatnonzero(bad)[0])
                truth.escape_example = {"sample": s, "time": float(result.times[k]),
                                        "gauge": float(g[s]), "state": traj[s, k].tolist()}
    smp = Samples(problem.grid[: traj.shape[1]], traj, names)
    _violations(problem, smp, truth)
    ver = problem.extra.get("verification")
    for m in getattr(ver, "measures", ()):
        truth.measures[m.label] = float(m.of_points(traj[:, -1], names))
    truth.time = time.perf_counter() - t0
    return truth


def hybrid_truth(problem, result, samples: int = 2000, seed: int = 0, stride: int = 1) -> Truth:
    """Truth of a hybrid instance against the pieces of the guaranteed flowpipe ``result``."""
    from ocreach.reach.hybrid import simulate_hybrid

    t0 = time.perf_counter()
    hs = simulate_hybrid(problem, samples=samples, seed=seed)
    smp = hs.samples
    truth = Truth(samples=samples, blocked=len(hs.blocked))
    for p in hs.paths:
        key = " -> ".join(p) or "(no jump)"
        truth.paths[key] = truth.paths.get(key, 0) + 1
    S, K, n = smp.states.shape
    G = problem.grid.size
    cols = sorted(set(range(0, G, stride)) | {G - 1} | set(range(G, K)))
    T = smp.times[:, cols].ravel()
    X = smp.states[:, cols].reshape(-1, n)
    L = smp.locations[:, cols].ravel()
    who = np.repeat(np.arange(S), len(cols))
    P = np.column_stack([X, T])
    inside = np.zeros(P.shape[0], dtype=bool)
    by_loc: dict[str, list] = {}
    for pc in result.pieces:
        by_loc.setdefault(pc.location, []).append(pc)
    for loc, pcs in by_loc.items():
        idx = np.flatnonzero(L == loc)
        if idx.size == 0:
            continue
        order = idx[np.argsort(T[idx])]
        ts = T[order]
        for pc in pcs:
            a, b = np.searchsorted(ts, pc.t_lo - 1e-9, "left"), np.searchsorted(ts, pc.t_hi + 1e-9, "right")
            if b <= a:
                continue
            cand = order[a:b]
            I = pc.set.interval_hull()  # a point outside a piece's box is not in the piece
            tol = 1e-9 * (1 + np.maximum(np.abs(I.lo), np.abs(I.hi)))
            cand = cand[~inside[cand] & np.all((P[cand] >= I.lo - tol) & (P[cand] <= I.hi + tol),
                                               axis=1)]
            if cand.size == 0:
                continue
            g = np.atleast_1d(gauge(pc.set, P[cand], lp=False))
            inside[cand[g <= 1.0]] = True
    todo = np.flatnonzero(~inside)
    worst = 0.0
    for i in todo:  # not certified: the exact LP gauge over the candidate pieces
        pcs = [pc for pc in by_loc.get(L[i], []) if pc.t_lo - 1e-9 <= T[i] <= pc.t_hi + 1e-9]
        g = min((float(union_gauge(pc.set, P[i])) for pc in pcs), default=np.inf)
        worst = max(worst, g)
        if g > GAUGE_TOL:
            truth.escapes += 1
            if truth.escape_example is None:
                truth.escape_example = {"sample": int(who[i]), "time": float(T[i]),
                                        "location": str(L[i]), "gauge": g,
                                        "state": X[i].tolist()}
    truth.points = int(P.shape[0])
    truth.worst_gauge = max(worst, 1.0 if inside.any() else 0.0)
    _violations(problem, smp, truth)
    ver = problem.extra.get("verification")
    names = problem.automaton.state_names
    for m in getattr(ver, "measures", ()):
        truth.measures[m.label] = float(m.of_points(hs.final, names))
    truth.time = time.perf_counter() - t0
    return truth
