"""The soundness harness: every guaranteed method against independent truth, on one test.

Which methods: every method of the registry (:data:`ocreach.reach.base.METHOD_PATHS`) whose class
declares ``guaranteed = True`` (:attr:`ocreach.reach.base.Method.guaranteed`, read before anything
is solved); a new guaranteed method is in the harness by registering, with no test code of its
own.  It runs with its default options (and the problem's ``method_options``), and then its
result must also say ``meta["guaranteed"] = True`` with no narrower ``meta["guaranteed_for"]``.

On what: a :class:`Case` is a problem with an independent right-hand side for the truth --
generated systems (:func:`generated_case`, :mod:`ocreach.testing.strategies`) and every bundled
problem cut to its first grid steps (:func:`bundled_cases`).

What is checked (:func:`run_method`): truth trajectories (:mod:`ocreach.testing.truth`) from
vertices, the centre and the inside of the initial set under constant, bang-bang, random and
directed (extremal for a direction) piecewise-constant inputs; every set at a grid time must contain every truth state at that time,
and every time-interval tube over ``[t_k, t_k+1]`` the states at the interior times of the step
(the midpoint by default) and at both ends (:mod:`ocreach.testing.containment`).  A method that
refuses a problem with :class:`ProblemError` has refused it cleanly (not an escape); one that stops
with :class:`SolverError` has the sets of its ``err.partial`` checked; any other exception, a result
on the wrong time grid, or a guaranteed method whose result is not marked guaranteed, is a failure.
A hybrid automaton (a problem with an ``automaton``) is checked through its transitions: runs of
the automaton (:func:`ocreach.testing.truth.hybrid_truth`: every run alone through SciPy's DOP853
with the guards and invariants as event functions) at the grid and interior times and just
before and after every jump, each against the flowpipe pieces of its location that cover its
time (:func:`check_hybrid`); a hybrid result without pieces is ``no-truth`` (a failure).
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.errors import ProblemError, SolverError
from ocreach.reach.base import Method, available_methods, method_class
from ocreach.testing.containment import Verdict, check_flowpipe, check_points, tolerance
from ocreach.testing.truth import (
    HybridTruth,
    Rhs,
    Truth,
    hybrid_truth,
    integrate,
    model_rhs,
    samples,
    with_disturbance,
)

#: statuses of an :class:`Outcome` that are not failures (escapes aside)
PASSING = ("complete", "partial", "refused")
#: escapes kept in detail per outcome
MAX_DETAILS = 10


def guaranteed_methods() -> list[str]:
    """Names of the installed methods whose class declares ``guaranteed = True``."""
    return [name for name in available_methods()
            if getattr(method_class(name), "guaranteed", False)]


@dataclass
class Case:
    """A problem and the independent right-hand side of its truth (``kind``: generated or
    bundled)."""

    label: str
    problem: Any
    rhs: Rhs
    kind: str
    description: str = ""
    #: additive disturbance ``(w_c, W_G)`` on ``dx/dt`` that the truth integrates (the methods
    #: get it through ``options``)
    disturbance: tuple[np.ndarray, np.ndarray] | None = None
    #: options every method gets on this case (under the caller's own)
    options: dict[str, Any] = field(default_factory=dict)
    _truth: dict = field(default_factory=dict, repr=False)

    def hybrid_truth(self, n_samples: int, seed: int, inner: tuple[float, ...]) -> HybridTruth:
        """The truth of a hybrid automaton's case: runs through its transitions (cached)."""
        key = ("hybrid", n_samples, seed, inner)
        if key not in self._truth:
            self._truth[key] = hybrid_truth(self.problem, n_samples, seed=seed, inner=inner)
        return self._truth[key]

    def truth(self, n_samples: int, seed: int, inner: tuple[float, ...], pieces: int) -> Truth:
        """The truth of this case (computed once per sampling and cached)."""
        key = (n_samples, seed, inner, pieces)
        if key not in self._truth:
            smp = samples(self.problem, n_samples, seed=seed, pieces=pieces, rhs=self.rhs)
            rhs = self.rhs
            if self.disturbance is not None:
                rhs, smp = with_disturbance(rhs, smp, *self.disturbance, seed=seed)
            self._truth[key] = integrate(rhs, self.problem.grid, smp, inner)
        return self._truth[key]


def generated_case(system) -> Case:
    """The case of a :class:`ocreach.testing.strategies.GeneratedSystem` (its numpy truth)."""
    return Case(label=system.label, problem=system.problem(), rhs=system.rhs, kind="generated",
                description=system.describe(), disturbance=system.disturbance,
                options=system.method_options())


def shortened(problem, steps: int):
    """``problem`` on its first ``steps`` grid steps (the same problem otherwise)."""
    if problem.grid.size <= steps + 1:
        return problem
    return dataclasses.replace(problem, grid=problem.grid[: steps + 1])


def bundled_cases(steps: int = 2, ids: Sequence[str] | None = None) -> list[Case]:
    """Every bundled problem (or ``ids``) on its first ``steps`` grid steps, with the model's own
    ``f`` as the truth's right-hand side (:func:`ocreach.testing.truth.model_rhs`)."""
    from ocreach.registry import get_problem, problem_factories

    out = []
    for pid in (sorted(problem_factories()) if ids is None else ids):
        p = shortened(get_problem(pid), steps)
        out.append(Case(label=pid, problem=p, rhs=model_rhs(p), kind="bundled",
                        description=f"{pid}, first {p.n_segments} grid steps "
                                    f"(t = {p.grid[0]:.6g} .. {p.grid[-1]:.6g})"))
    return out


@dataclass
class Escape:
    """A truth point outside a guaranteed set: the set at grid time ``index`` (``where="set"``)
    or the tube of step ``index`` at the fraction ``fraction`` of the step (``where="tube"``)."""

    where: str
    index: int
    fraction: float
    sample: str
    gauge: float
    point: list[float]


@dataclass
class Outcome:
    """One method on one case (``status`` in complete / partial / refused, or a failure:
    crashed / not-guaranteed / bad-grid / no-truth (a hybrid automaton) / no-sets)."""

    method: str
    case: str
    kind: str
    status: str
    reason: str = ""
    sets_checked: int = 0
    tubes_checked: int = 0
    points_checked: int = 0
    max_gauge: float = 0.0
    escapes: int = 0
    undecided: int = 0
    exact: bool = True
    seconds: float = 0.0
    truth_failure: str = ""
    details: list[Escape] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.status in PASSING and self.escapes == 0

    def line(self) -> str:
        s = (f"{self.method} on {self.case}: {self.status}; {self.sets_checked} sets, "
             f"{self.tubes_checked} tubes, {self.points_checked} points, max gauge "
             f"{self.max_gauge:.6g}, {self.escapes} escapes")
        if self.undecided:
            s += f", {self.undecided} undecided"
        if self.reason:
            s += f" ({self.reason[:200]})"
        for e in self.details[:3]:
            s += (f"\n    escape: {e.where} {e.index}" + (f" at {e.fraction:g} of the step"
                  if e.where == "tube" else "") + f", sample {e.sample}, gauge {e.gauge:.6g}")
        return s


def _solve(method: str | type[Method], problem, options: dict[str, Any]):
    """``(result, status, reason)``: the method's result (or ``err.partial``) and how it ended.
    A registered method runs through :func:`ocreach.reach.base.reach` (the problem's options,
    and whatever dispatch ``reach`` does for the problem's kind); a class through its ``solve``."""
    from ocreach import parallel
    from ocreach.reach.base import reach

    try:
        if isinstance(method, str):
            return reach(problem, method, **options), "complete", ""
        merged = {**problem.options_for(method.name), **options}
        with parallel.settings():
            return method(**merged).solve(problem), "complete", ""
    except ProblemError as exc:
        return None, "refused", str(exc)
    except SolverError as exc:
        if exc.partial is None:
            return None, "refused", f"SolverError without a partial result: {exc}"
        return exc.partial, "partial", str(exc)


def _record(out: Outcome, verdict: Verdict, where: str, index: int, fraction: float,
            labels: Sequence[str], points: np.ndarray) -> None:
    out.points_checked += len(points)
    out.max_gauge = max(out.max_gauge, float(np.max(verdict.gauge, initial=0.0)))
    out.undecided += int(verdict.undecided.sum())
    out.exact &= verdict.exact
    for i in np.flatnonzero(verdict.escaped):
        out.escapes += 1
        if len(out.details) < MAX_DETAILS:
            out.details.append(Escape(where, index, fraction, labels[i], float(verdict.gauge[i]),
                                      points[i].tolist()))


def check_result(result, truth: Truth, out: Outcome, tube_samples: int | None = None) -> None:
    """Check the sets and tubes of ``result`` against ``truth`` into ``out``; the tubes against
    ``tube_samples`` of the samples (evenly spread over them, so every kind is among them; None:
    all)."""
    sets = list(result.sets or [])
    K_ok = min(len(sets) - 1, truth.steps)
    labels = truth.labels
    for k in range(K_ok + 1):
        _record(out, check_points(sets[k], truth.states[:, k]), "set", k, 0.0, labels,
                truth.states[:, k])
        out.sets_checked += 1
    tubes = list(result.tubes or [])
    N = truth.states.shape[0]
    sub = (np.arange(N) if tube_samples is None or tube_samples >= N
           else np.unique(np.linspace(0, N - 1, tube_samples).round().astype(int)))
    sub_labels = [labels[i] for i in sub]
    for k in range(min(len(tubes), K_ok)):
        pts = [(0.0, truth.states[sub, k])] + [(f, truth.interior[sub, k, j])
                                               for j, f in enumerate(truth.inner)]
        pts.append((1.0, truth.states[sub, k + 1]))
        for frac, P in pts:
            _record(out, check_points(tubes[k], P), "tube", k, frac, sub_labels, P)
        out.tubes_checked += 1


def check_hybrid(result, truth: HybridTruth, out: Outcome) -> None:
    """Check the flowpipe pieces of a hybrid ``result`` against the runs through the automaton
    (:func:`ocreach.testing.truth.hybrid_truth`): every truth state, with its time, in a piece of
    its location covering that time (:func:`ocreach.testing.containment.check_flowpipe`), up to
    the time the flowpipe encloses every run (``meta["valid_until"]``: the horizon, or less for a
    partial flowpipe)."""
    out.truth_failure = truth.failure
    until = float((result.meta or {}).get("valid_until", np.inf))
    keep = truth.times <= until + tolerance(truth.times)
    P = np.column_stack([truth.points, truth.times])[keep]
    v = check_flowpipe(result.pieces, P, truth.times[keep], np.asarray(truth.locations)[keep])
    _record(out, v, "piece", 0, 0.0, list(np.asarray(truth.labels, dtype=object)[keep]), P)
    out.sets_checked += len(result.pieces)


def run_method(method: str | type[Method], case: Case, *, n_samples: int = 60, seed: int = 0,
               inner: Sequence[float] = (0.5,), pieces: int = 2, tube_samples: int | None = None,
               options: dict[str, Any] | None = None) -> Outcome:
    """Run ``method`` (a registered name or a :class:`Method` class) on ``case`` and check it
    against the case's truth (module docstring); ``tube_samples``: see :func:`check_result`."""
    name = method if isinstance(method, str) else method.name
    t0 = time.perf_counter()
    out = Outcome(method=name, case=case.label, kind=case.kind, status="complete")
    try:
        result, out.status, out.reason = _solve(method, case.problem,
                                                {**case.options, **(options or {})})
    except Exception as exc:
        out.status, out.reason = "crashed", f"{type(exc).__name__}: {exc}"
        out.seconds = time.perf_counter() - t0
        return out
    if result is not None and getattr(case.problem, "automaton", None) is not None:
        if not hasattr(result, "pieces"):
            out.status = "no-truth"
            out.reason = (f"the problem is a hybrid automaton and the result "
                          f"({type(result).__name__}) has no flowpipe pieces to check")
        elif (result.meta or {}).get("guaranteed") is not True:
            out.status = "not-guaranteed"
            out.reason = "the hybrid flowpipe is not marked guaranteed"
        else:
            check_hybrid(result, case.hybrid_truth(n_samples, seed, tuple(inner)), out)
    elif result is not None and not (hasattr(result, "sets") and hasattr(result, "times")):
        out.status = "no-sets"
        out.reason = (f"the result ({type(result).__name__}) has no sets on the time grid that "
                      "the harness could check")
    elif result is not None:
        meta = result.meta or {}
        grid = case.problem.grid
        if meta.get("guaranteed") is not True or meta.get("guaranteed_for"):
            out.status = "not-guaranteed"
            out.reason = (f"the method declares guaranteed = True but its result says guaranteed="
                          f"{meta.get('guaranteed')!r}, "
                          f"guaranteed_for={meta.get('guaranteed_for')!r}")
        elif len(result.times) != len(result.sets or []) or not np.allclose(
                result.times, grid[: len(result.times)], rtol=0,
                atol=1e-12 * max(1.0, abs(grid).max())):
            out.status = "bad-grid"
            out.reason = "the result's times are not the problem's grid times"
        elif len(result.sets or []) > 0:
            truth = case.truth(n_samples, seed, tuple(inner), pieces)
            out.truth_failure = truth.failure
            check_result(result, truth, out, tube_samples)
    out.seconds = time.perf_counter() - t0
    return out


def run_all(cases: Sequence[Case], methods: Sequence[str | type[Method]] | None = None,
            **kw: Any) -> list[Outcome]:
    """:func:`run_method` for every method (default: :func:`guaranteed_methods`) on every case."""
    methods = guaranteed_methods() if methods is None else methods
    return [run_method(m, c, **kw) for c in cases for m in methods]


def summary(outcomes: Sequence[Outcome]) -> dict[str, dict[str, Any]]:
    """Per method: cases by status, sets / tubes / points checked, escapes, undecided points,
    cases checked by support functions only (a set type without an exact test), max gauge."""
    table: dict[str, dict[str, Any]] = {}
    for o in outcomes:
        row = table.setdefault(o.method, {"cases": 0, "complete": 0, "partial": 0, "refused": 0,
                                          "failed": 0, "sets": 0, "tubes": 0, "points": 0,
                                          "escapes": 0, "undecided": 0, "support_only": 0,
                                          "max_gauge": 0.0, "seconds": 0.0})
        row["cases"] += 1
        row[o.status if o.status in PASSING else "failed"] += 1
        row["sets"] += o.sets_checked
        row["tubes"] += o.tubes_checked
        row["points"] += o.points_checked
        row["escapes"] += o.escapes
        row["undecided"] += o.undecided
        row["support_only"] += not o.exact
        row["max_gauge"] = max(row["max_gauge"], o.max_gauge)
        row["seconds"] += o.seconds
    return table
