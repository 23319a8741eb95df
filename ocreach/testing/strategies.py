"""Generated test systems: random polynomial and rational vector fields with bounded inputs.

A :class:`GeneratedSystem` holds the coefficients of

    dx/dt = A x + sum_terms  c  t^q  prod_j x_j^{e_j} / (1 + sum_j w_j x_j^2)  + B u,

(each term on one row; the denominator is absent for a polynomial term and is >= 1 everywhere
for a rational one, so the field is smooth on all of R^n), its input set (the unit box or ball,
``u`` of dimension 1-3), its initial set (a box or a zonotope about ``x0``) and a short time
grid.  From the same coefficients it builds the symbolic CasADi model that the methods get
(:meth:`GeneratedSystem.problem`) and, independently, a numpy right-hand side that the truth
integrator uses (:meth:`GeneratedSystem.rhs`): a mistake in one of the two codings shows as a
disagreement, not as a silently shared error.

:func:`generate` draws a system from a :class:`Draw` -- three primitive draws (integer, real,
choice) -- so that one generator serves both sources of randomness:

* :func:`systems` wraps it as a hypothesis strategy (shrinking works on the primitive draws);
* :class:`SeededDraw` feeds it from ``numpy.random.default_rng(seed)``, so that system
  ``seed`` of a long run is reproducible without hypothesis (``benchmarks/bench_soundness.py``).

The ranges (:class:`Ranges`) keep the systems well posed over the horizon: states of order one,
a linear part of order one, nonlinear coefficients up to ``coef`` and horizons below one time
unit, so that trajectories exist and the second-order remainder of the linearisation is a
visible part of every step (the harness's mutation check relies on that, see
``tests/test_soundness_harness.py``).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import casadi as ca
import numpy as np


class Draw(Protocol):
    """The primitive draws :func:`generate` needs."""

    def integer(self, lo: int, hi: int) -> int:  # inclusive bounds
        ...

    def real(self, lo: float, hi: float) -> float:
        ...

    def choice(self, options: Sequence[Any]) -> Any:
        ...


class SeededDraw:
    """:class:`Draw` from ``numpy.random.default_rng(seed)``."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def integer(self, lo: int, hi: int) -> int:
        return int(self.rng.integers(lo, hi + 1))

    def real(self, lo: float, hi: float) -> float:
        return float(self.rng.uniform(lo, hi))

    def choice(self, options: Sequence[Any]) -> Any:
        return options[int(self.rng.integers(len(options)))]


class HypothesisDraw:
    """:class:`Draw` from hypothesis's ``draw`` inside ``st.composite``."""

    def __init__(self, draw: Any) -> None:
        from hypothesis import strategies as st

        self.draw, self.st = draw, st

    def integer(self, lo: int, hi: int) -> int:
        return self.draw(self.st.integers(lo, hi))

    def real(self, lo: float, hi: float) -> float:
        return self.draw(self.st.floats(lo, hi, allow_nan=False, allow_infinity=False))

    def choice(self, options: Sequence[Any]) -> Any:
        return self.draw(self.st.sampled_from(list(options)))


@dataclass(frozen=True)
class Ranges:
    """Ranges of the generated systems (defaults: the harness's systems)."""

    n: tuple[int, int] = (2, 6)              # states
    n_u: tuple[int, int] = (1, 3)            # inputs (at most n)
    linear: float = 1.0                      # |A_ij| <= linear
    terms: tuple[int, int] = (1, 3)          # nonlinear terms per row
    degree: tuple[int, int] = (2, 3)         # total degree of a term's monomial in x
    coef: float = 0.75                       # |c| <= coef
    rational: float = 0.35                   # probability that a term has a denominator
    time_term: float = 0.15                  # probability that the field depends on t
    input_gain: float = 0.5                  # |B_ij| <= input_gain
    x0: float = 1.0                          # |x0_i| <= x0
    radius: tuple[float, float] = (0.01, 0.1)  # initial set: radius of its box in each state
    initial: tuple[str, ...] = ("box", "zonotope")   # initial set kinds to draw from
    controls: tuple[str, ...] = ("box", "ball")      # input set kinds to draw from
    t_final: tuple[float, float] = (0.2, 0.6)
    steps: tuple[int, int] = (2, 4)
    disturbance: bool = False                # an additive disturbance set W on dx/dt
    disturbance_centre: float = 1.0          # |w_c,i| <= disturbance_centre
    disturbance_radius: tuple[float, float] = (0.05, 0.5)   # row sums of |W_G|
    rotation: float = 0.0                    # > 0: A plus rotations at rates in [rotation/2, rotation]


#: the harness's general population: 2-6 states, polynomial and rational terms of degree 2-3,
#: box or zonotope initial sets, box or ball inputs, some fields depending on t
GENERAL = Ranges()
#: a population whose sets are shaped by the second-order remainder: 2-3 states, one quadratic
#: monomial per row (a constant Hessian, which the interval Hessian bounds exactly), a weak
#: linear part, x0 = 0 (little drift inside a step, so the tube's box is close to the set's),
#: box initial sets of radius 0.1-0.2, weak inputs and 3-6 steps (the remainder accumulates).
#: There a remainder bound that is too small shows as an escape (the mutation check of
#: ``tests/test_soundness_harness.py``); in GENERAL, where the interval bound over the tube's
#: box is loose by more than a factor 2, it often does not.
REMAINDER_DOMINATED = Ranges(n=(2, 3), linear=0.1, terms=(1, 1), degree=(2, 2), coef=3.0,
                             rational=0.0, time_term=0.0, x0=0.0, radius=(0.1, 0.2),
                             initial=("box",), input_gain=0.2, steps=(3, 6))
#: a population whose flow a quadratic expansion nearly captures: one quadratic monomial per row,
#: no linear part, no input, x0 = 0, 1-3 steps.  The third derivatives vanish, so the remainder
#: of a higher-order method (``poly``) is its dynamic error alone, close to the flow terms it
#: has to cover: a dynamic-error bound that is too small shows as an escape (it did, on 20 of
#: seeds 0-24, before the chord term of ``poly``'s dynamic error was added on 2026-12-03),
#: where the inputs and interval-bounded third derivatives of the other populations hide it.
#: a population with an additive disturbance ``w(t) in W = w_c + W_G [-1, 1]^q`` on ``dx/dt``
#: (the methods' ``disturbance`` option; the truth integrates piecewise-constant extreme, bang-bang
#: and random ``w``): rotations of 1.5-3 rad per time unit on a weak linear part turn the
#: disturbance's input solution by up to ~3 rad inside a step (a centre of ``W`` boxed by its
#: solution at the step's end missed such a flow), quadratic terms, a nonzero centre, 1-2 steps.
DISTURBED = Ranges(n=(2, 4), n_u=(1, 2), linear=0.3, terms=(1, 1), degree=(2, 2), coef=0.5,
                   rational=0.0, time_term=0.15, input_gain=0.3, x0=0.5, radius=(0.01, 0.1),
                   t_final=(0.5, 2.0), steps=(1, 2), disturbance=True, rotation=3.0)
QUADRATIC = Ranges(n=(2, 3), n_u=(1, 1), linear=0.0, terms=(1, 1), degree=(2, 2), coef=2.0,
                   rational=0.0, time_term=0.0, input_gain=0.0, x0=0.0, radius=(0.05, 0.25),
                   steps=(1, 3))


@dataclass(frozen=True)
class Term:
    """``coef t^t_power prod_j x_j^powers[j] / (1 + sum_j weights[j] x_j^2)`` on row ``row``."""

    row: int
    coef: float
    powers: tuple[int, ...]
    t_power: int = 0
    weights: tuple[float, ...] | None = None   # None: a polynomial term


@dataclass(frozen=True, eq=False)
class GeneratedSystem:
    """One generated system (module docstring); ``label`` names it in reports."""

    label: str
    A: np.ndarray
    terms: tuple[Term, ...]
    B: np.ndarray
    control: str                   # "box" or "ball"
    x0: np.ndarray
    generators: np.ndarray         # (n, k) initial generators (diagonal for a box)
    initial: str                   # "box" or "zonotope"
    t_final: float
    steps: int
    notes: dict[str, Any] = field(default_factory=dict)
    #: additive disturbance ``w_c + W_G [-1, 1]^q`` on ``dx/dt`` (None: none); the methods get
    #: it as their ``disturbance`` option (:meth:`method_options`), the truth integrates it
    disturbance: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def n_u(self) -> int:
        return self.B.shape[1]

    @property
    def grid(self) -> np.ndarray:
        return np.linspace(0.0, self.t_final, self.steps + 1)

    def describe(self) -> str:
        kinds = {"rational" if tm.weights else "polynomial" for tm in self.terms}
        return (f"{self.label}: n = {self.n}, n_u = {self.n_u} ({self.control}), "
                f"{len(self.terms)} nonlinear terms ({', '.join(sorted(kinds))}"
                f"{', t-dependent' if any(tm.t_power for tm in self.terms) else ''}), "
                f"initial {self.initial}, t in [0, {self.t_final:.3g}] in {self.steps} steps"
                + (f", disturbance of {self.disturbance[1].shape[1]} generators"
                   if self.disturbance is not None else ""))

    def method_options(self) -> dict[str, Any]:
        """Options every method needs on this system: the ``disturbance`` set, if any."""
        if self.disturbance is None:
            return {}
        from ocreach.sets.zonotope import Zonotope

        return {"disturbance": Zonotope(*self.disturbance)}

    # ---------------------------------------------------------------- the two codings
    def expression(self, x: ca.SX, u: ca.SX, t: ca.SX) -> ca.SX:
        """``f(x, u, t)`` as a CasADi expression (what the methods see)."""
        rows = [ca.mtimes(ca.DM(self.A[i:i + 1]), x) + ca.mtimes(ca.DM(self.B[i:i + 1]), u)
                for i in range(self.n)]
        for tm in self.terms:
            val = ca.SX(tm.coef)
            for j, e in enumerate(tm.powers):
                if e:
                    val = val * x[j] ** e
            if tm.t_power:
                val = val * t ** tm.t_power
            if tm.weights is not None:
                val = val / (1 + sum(w * x[j] ** 2 for j, w in enumerate(tm.weights) if w))
            rows[tm.row] = rows[tm.row] + val
        return ca.vertcat(*rows)

    def rhs(self, t: float, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """``f`` for many states at once, in numpy: ``X`` (N, n), ``U`` (N, n_u) -> (N, n)."""
        out = X @ self.A.T + U @ self.B.T
        for tm in self.terms:
            val = np.full(X.shape[0], tm.coef * t ** tm.t_power)
            for j, e in enumerate(tm.powers):
                if e:
                    val = val * X[:, j] ** e
            if tm.weights is not None:
                val = val / (1.0 + (X ** 2) @ np.asarray(tm.weights))
            out[:, tm.row] += val
        return out

    def problem(self):
        """The system as an :class:`ocreach.Problem` (box initial set as an ``Interval``)."""
        from ocreach.model import Model
        from ocreach.problem import Problem
        from ocreach.sets.interval import Interval
        from ocreach.sets.zonotope import Zonotope

        x = ca.SX.sym("x", self.n)
        u = ca.SX.sym("u", self.n_u)
        t = ca.SX.sym("t")
        model = Model.build(f"generated-{self.label}", x, u, self.expression(x, u, t), t=t,
                            control_set=self.control,
                            description="generated polynomial / rational test system")
        if self.initial == "box":
            r = np.abs(self.generators).sum(axis=1)
            S: Any = Interval(self.x0 - r, self.x0 + r)
        else:
            S = Zonotope(self.x0, self.generators)
        return Problem(id=f"generated-{self.label}", model=model, x0=self.x0, grid=self.grid,
                       initial_set=S, description=self.describe())


def _term(draw: Draw, r: Ranges, n: int, row: int) -> Term:
    degree = draw.integer(*r.degree)
    powers = [0] * n
    for _ in range(degree):
        powers[draw.integer(0, n - 1)] += 1
    coef = draw.real(-r.coef, r.coef)
    weights = None
    if draw.real(0.0, 1.0) < r.rational:
        w = [0.0] * n
        for _ in range(draw.integer(1, 2)):
            w[draw.integer(0, n - 1)] = draw.real(0.2, 1.0)
        weights = tuple(w)
    return Term(row=row, coef=coef, powers=tuple(powers), weights=weights)


def generate(draw: Draw, ranges: Ranges | None = None, label: str = "system") -> GeneratedSystem:
    """One system drawn from ``draw`` within ``ranges`` (module docstring)."""
    r = ranges or Ranges()
    n = draw.integer(*r.n)
    m = draw.integer(r.n_u[0], min(r.n_u[1], n))
    control = draw.choice(r.controls)
    A = np.array([[draw.real(-r.linear, r.linear) for _ in range(n)] for _ in range(n)])
    terms = tuple(_term(draw, r, n, i) for i in range(n) for _ in range(draw.integer(*r.terms)))
    if draw.real(0.0, 1.0) < r.time_term:   # a time-dependent field: its first term times t
        terms = (dataclasses.replace(terms[0], t_power=1),) + terms[1:]
    B = np.array([[draw.real(-r.input_gain, r.input_gain) for _ in range(m)] for _ in range(n)])
    x0 = np.array([draw.real(-r.x0, r.x0) for _ in range(n)])
    initial = draw.choice(r.initial)
    lo, hi = r.radius
    if initial == "box":
        G = np.diag([draw.real(lo, hi) for _ in range(n)])
    else:
        k = draw.integer(n, 2 * n)     # at least n generators: a full-dimensional zonotope
        G = np.array([[draw.real(-1.0, 1.0) for _ in range(k)] for _ in range(n)])
        extent = np.array([draw.real(lo, hi) for _ in range(n)])   # row i: sum_j |G_ij|
        G *= (extent / np.maximum(np.abs(G).sum(axis=1), 1e-12))[:, None]
    t_final = draw.real(*r.t_final)
    steps = draw.integer(*r.steps)
    if r.rotation > 0:   # drawn last, so the draws of the other populations are unchanged
        for i in range(0, n - 1, 2):   # x_i' += w x_(i+1), x_(i+1)' -= w x_i
            w = draw.real(0.5 * r.rotation, r.rotation)
            A[i, i + 1] += w
            A[i + 1, i] -= w
    W = None
    if r.disturbance:
        q = draw.integer(1, n)
        wc = np.array([draw.real(-r.disturbance_centre, r.disturbance_centre) for _ in range(n)])
        WG = np.array([[draw.real(-1.0, 1.0) for _ in range(q)] for _ in range(n)])
        extent = np.array([draw.real(*r.disturbance_radius) for _ in range(n)])
        WG *= (extent / np.maximum(np.abs(WG).sum(axis=1), 1e-12))[:, None]
        W = (wc, WG)
    return GeneratedSystem(label=label, A=A, terms=terms, B=B, control=control, x0=x0,
                           generators=G, initial=initial, t_final=t_final, steps=steps,
                           disturbance=W)


def seeded_system(seed: int, ranges: Ranges | None = None) -> GeneratedSystem:
    """System number ``seed``: :func:`generate` fed by :class:`SeededDraw` (reproducible)."""
    return generate(SeededDraw(seed), ranges, label=f"seed-{seed}")


def systems(ranges: Ranges | None = None):
    """A hypothesis strategy of :class:`GeneratedSystem` (needs the test extra, hypothesis)."""
    from hypothesis import strategies as st

    @st.composite
    def _systems(draw):
        return generate(HypothesisDraw(draw), ranges, label="hypothesis")

    return _systems()
