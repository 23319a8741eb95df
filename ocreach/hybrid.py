"""Hybrid automata: locations with their own dynamics, invariants, guards and reset maps.

A :class:`HybridAutomaton` has :class:`Location` s (a name, a :class:`~ocreach.model.Model` and an
invariant) and :class:`Transition` s (source, target, guard, reset, urgency).  Invariants and
guards are tuples of the constraints of :mod:`ocreach.specs` (half-spaces :class:`~ocreach.specs.Linear`,
balls :class:`~ocreach.specs.InBall` / :class:`~ocreach.specs.OutBall`) over the state names and
the global time ``"t"`` (:data:`CLOCK`): a time window is two half-spaces, :func:`time_window`.
Every location has the same state names (the reset maps states to states).

Semantics (as in the ARCH-COMP hybrid benchmarks, e.g. the spacecraft rendezvous of Chan & Mitra,
ARCH 2017, and the Lotka-Volterra tangential crossing, ARCH-COMP21):

* a run stays in a location while its invariant holds and follows the location's dynamics;
* an *urgent* transition is taken as soon as its guard holds (its guard is usually the
  complement of the source invariant: the run jumps when it reaches the invariant's boundary);
* a *permissive* transition (``urgent=False``) may be taken at any time while its guard holds
  (a nondeterministic choice, e.g. an abort at any time in [120, 150] min); the invariant
  forces a jump before it is left;
* the reset ``x+ = A x + c`` (identity by default) maps the state at the jump.

A :class:`HybridProblem` is a :class:`~ocreach.problem.Problem` (so it is bundled, listed and
loaded like any other) whose ``model`` is the initial location's and which carries the automaton,
the initial location and the horizon.  ``ocreach.reach(problem, "taylor")`` follows the automaton
(:mod:`ocreach.reach.hybrid`): the guaranteed methods intersect their tubes with the guards, the
sampled methods simulate every sample through the same automaton.  A user writes one in Python
next to a ``Problem``, as ``problems/arch.py`` does for the spacecraft rendezvous.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError
from ocreach.model import Model
from ocreach.problem import Problem
from ocreach.specs import TIME, Constraint, InBall, Linear, OutBall, describe_region, ge, le

#: the name of the global time in guards, invariants and the flowpipe's coordinates
CLOCK = TIME


def time_window(t_lo: float, t_hi: float) -> tuple[Linear, Linear]:
    """The guard ``t_lo <= t <= t_hi`` on the global time."""
    if not t_lo <= t_hi:
        raise ProblemError(f"time_window needs t_lo <= t_hi; got ({t_lo}, {t_hi})")
    return ge(CLOCK, t_lo), le(CLOCK, t_hi)


def _region(value: Any, what: str) -> tuple[Constraint, ...]:
    reg = tuple(value) if isinstance(value, (tuple, list)) else (value,)
    bad = [c for c in reg if not isinstance(c, (Linear, InBall, OutBall))]
    if bad:
        raise ProblemError(f"{what} must be constraints of ocreach.specs (Linear, InBall, OutBall); "
                           f"got {bad[0]!r}")
    return reg


@dataclass(frozen=True)
class Reset:
    """The reset ``x+ = A x + c`` (``A`` None: identity; ``c`` None: zero)."""

    A: Any = None
    c: Any = None

    def matrices(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        A = np.eye(n) if self.A is None else np.asarray(self.A, float)
        c = np.zeros(n) if self.c is None else np.asarray(self.c, float).ravel()
        if A.shape != (n, n) or c.shape != (n,):
            raise ProblemError(f"Reset: A must be ({n}, {n}) and c ({n},); got {A.shape}, {c.shape}")
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(c))):
            raise ProblemError("Reset: A and c must be finite")
        return A, c

    @property
    def identity(self) -> bool:
        return self.A is None and self.c is None

    def apply(self, X: np.ndarray) -> np.ndarray:
        """The reset of states ``X`` (n,) or (N, n)."""
        X = np.asarray(X, float)
        A, c = self.matrices(X.shape[-1])
        return X @ A.T + c


@dataclass(frozen=True)
class Location:
    """A location: its ``name``, its dynamics ``model`` and its ``invariant`` (constraints)."""

    name: str
    model: Model
    invariant: tuple[Constraint, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ProblemError(f"Location name must be a non-empty string; got {self.name!r}")
        if not isinstance(self.model, Model):
            raise ProblemError(f"Location {self.name!r}: model must be an ocreach.Model; got "
                               f"{type(self.model).__name__}")
        object.__setattr__(self, "invariant", _region(self.invariant, f"invariant of {self.name!r}"))


@dataclass(frozen=True)
class Transition:
    """A transition ``source -> target`` enabled where ``guard`` holds; ``urgent`` (taken as soon
    as enabled) or permissive; ``reset`` applied to the state; ``label`` names it in results."""

    source: str
    target: str
    guard: tuple[Constraint, ...]
    reset: Reset = field(default_factory=Reset)
    urgent: bool = True
    label: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "guard", _region(self.guard, f"guard {self.source}->{self.target}"))
        if not self.guard:
            raise ProblemError(f"transition {self.source}->{self.target}: the guard needs at least "
                               "one constraint")
        if not isinstance(self.reset, Reset):
            raise ProblemError(f"transition {self.source}->{self.target}: reset must be a Reset; "
                               f"got {self.reset!r}")
        if not isinstance(self.urgent, (bool, np.bool_)):
            raise ProblemError(f"transition {self.source}->{self.target}: urgent must be True or "
                               f"False; got {self.urgent!r}")
        if not self.label:
            object.__setattr__(self, "label", f"{self.source}->{self.target}")

    def describe(self) -> str:
        kind = "urgent" if self.urgent else "permissive"
        return f"{self.label}: {kind}, guard {describe_region(self.guard)}"


@dataclass(frozen=True)
class HybridAutomaton:
    """Locations and transitions (checked: names unique, targets known, the same state names in
    every location, guards and invariants over those names and ``"t"``)."""

    name: str
    locations: tuple[Location, ...]
    transitions: tuple[Transition, ...] = ()

    def __post_init__(self) -> None:
        locs = tuple(self.locations)
        trans = tuple(self.transitions)
        object.__setattr__(self, "locations", locs)
        object.__setattr__(self, "transitions", trans)
        if not locs:
            raise ProblemError(f"automaton {self.name!r} needs at least one location")
        names = [loc.name for loc in locs]
        if len(set(names)) != len(names):
            raise ProblemError(f"automaton {self.name!r}: location names must be unique; got {names}")
        states = locs[0].model.state_names
        for loc in locs:
            if loc.model.state_names != states:
                raise ProblemError(f"automaton {self.name!r}: every location needs the state names "
                                   f"{list(states)}; {loc.name!r} has {list(loc.model.state_names)}")
            if loc.model.n_u != locs[0].model.n_u:
                raise ProblemError(f"automaton {self.name!r}: every location needs "
                                   f"{locs[0].model.n_u} control(s); {loc.name!r} has {loc.model.n_u}")
        if CLOCK in states:
            raise ProblemError(f"automaton {self.name!r}: the state name {CLOCK!r} is reserved for "
                               "the global time; rename that state")
        allowed = set(states) | {CLOCK}
        for loc in locs:
            self._check_names(loc.invariant, allowed, f"invariant of {loc.name!r}")
        for tr in trans:
            for end in (tr.source, tr.target):
                if end not in names:
                    raise ProblemError(f"transition {tr.label!r}: unknown location {end!r}; "
                                       f"locations: {names}")
            self._check_names(tr.guard, allowed, f"guard of {tr.label!r}")
            tr.reset.matrices(len(states))

    @staticmethod
    def _check_names(region, allowed, what) -> None:
        for c in region:
            unknown = sorted(set(c.names) - allowed)
            if unknown:
                raise ProblemError(f"{what} refers to {unknown}; allowed: {sorted(allowed)}")

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.locations[0].model.state_names

    def location(self, name: str) -> Location:
        for loc in self.locations:
            if loc.name == name:
                return loc
        raise ProblemError(f"automaton {self.name!r} has no location {name!r}; "
                           f"locations: {[loc.name for loc in self.locations]}")

    def outgoing(self, name: str) -> list[Transition]:
        return [tr for tr in self.transitions if tr.source == name]

    def describe(self) -> str:
        lines = [f"hybrid automaton {self.name}: states {list(self.state_names)} and time {CLOCK!r}"]
        for loc in self.locations:
            inv = describe_region(loc.invariant) if loc.invariant else "true"
            lines.append(f"  location {loc.name}: model {loc.model.name}, invariant {inv}")
        lines += [f"  transition {tr.describe()}" for tr in self.transitions]
        return "\n".join(lines)


@dataclass
class HybridProblem(Problem):
    """A :class:`~ocreach.problem.Problem` on a hybrid automaton: ``automaton``,
    ``initial_location`` (default the first location), the horizon is the grid's end and
    ``grid`` its step (the time step of the guaranteed methods, per location overridable in
    their options).  ``model`` must be the initial location's model."""

    automaton: HybridAutomaton | None = None
    initial_location: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.automaton, HybridAutomaton):
            raise ProblemError(f"HybridProblem {self.id!r}: automaton must be a HybridAutomaton; "
                               f"got {type(self.automaton).__name__}")
        if not self.initial_location:
            self.initial_location = self.automaton.locations[0].name
        loc = self.automaton.location(self.initial_location)
        if self.model is not loc.model:
            raise ProblemError(f"HybridProblem {self.id!r}: model must be the initial location's "
                               f"model ({loc.model.name}); got {self.model.name}")
        super().__post_init__()
        if self.backward:
            raise ProblemError(f"HybridProblem {self.id!r}: the grid must run forward in time")

    @property
    def t_final(self) -> float:
        return float(self.grid[-1])

    def summary(self) -> str:
        return super().summary() + "\n" + self.automaton.describe()


def clocked(model: Model) -> Model:
    """``model`` with the global time as a last state ``"t"`` (``dt/dt = 1``; ``f`` evaluated at
    that state's time): the flowpipe of a location then carries the time of every state, jump sets
    keep their time spread and time windows are half-spaces (cached on the model)."""

    def build() -> Model:
        tau = ca.SX.sym(CLOCK)
        f = ca.substitute(model.f, model.t, tau)
        return Model.build(f"{model.name}+clock", ca.vertcat(model.x, tau), model.u,
                           ca.vertcat(f, ca.SX(1.0)), p=model.p, p_default=model.p_default,
                           state_names=[*model.state_names, CLOCK],
                           control_names=list(model.control_names),
                           param_names=list(model.param_names), control_set=model.control_set,
                           units=model.units, description=f"{model.description} (with clock)",
                           state_units=[*model.state_units, ""], thrust_param=model.thrust_param)

    return model.cached("clocked", build)


def check_hybrid(problem: Any) -> None:
    """Raise :class:`ProblemError` if ``problem`` is a :class:`HybridProblem` (for methods that
    would ignore its automaton)."""
    if isinstance(problem, HybridProblem):
        raise ProblemError(f"problem {problem.id!r} is a hybrid automaton; call "
                           "ocreach.reach(problem, METHOD), which follows its transitions "
                           "(ocreach.reach.hybrid), not a method's solve() directly")


def region_of(seq: Sequence[Constraint]) -> tuple[Constraint, ...]:
    return _region(seq, "region")
