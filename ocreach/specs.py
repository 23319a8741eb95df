"""Specifications as data: safe and unsafe regions over named states, with time windows and
locations, checked on guaranteed tubes and on sampled trajectories (the verification of the
ARCH-COMP NLN category, Geretti et al., ARCH-COMP20-24 reports).

Building blocks
---------------
A *constraint* is one inequality over named states: :class:`Linear` (``sum_i a_i x_i <= b``),
:class:`InBall` (``||x_S - c||_2 <= r``) or :class:`OutBall` (``||x_S - c||_2 >= r``); helpers
:func:`le`, :func:`ge`, :func:`linear`, :func:`box`, :func:`in_ball`, :func:`out_ball`.  A *region*
is a tuple of constraints (their conjunction).  The same constraints are the invariants and guards
of :mod:`ocreach.hybrid`.  The name ``"t"`` is the time: the global clock of a hybrid automaton
(:data:`ocreach.hybrid.CLOCK`); for a continuous problem time is given by a spec's ``window``.

* :class:`Safe` -- every reachable state in the time ``window`` (and in the ``locations``) lies in
  the region;
* :class:`Unsafe` -- no reachable state in the window enters the region;
* :class:`Attains` -- the enclosure of a linear functional in the window contains a value (the
  conservation check of the production-destruction benchmark, ``10 in x + y + z``).

Checks
------
:func:`check` returns a :class:`SpecResult` with ``status`` ``"verified"``, ``"violated"`` or
``"unknown"``:

* on a guaranteed result (sets that enclose every trajectory), every set that can hold a state of
  the window is tested: the time-point sets at grid times inside the window and the
  time-interval tubes whose open time interval meets it (a tube touching the window only at an end
  point is represented there by the time-point set); for hybrid results the set of each flowpipe
  piece is first cut to the window by its clock coordinate.  ``verified`` means proven for every
  trajectory.  ``violated`` is proven only for a continuous problem (its reachable set is never
  empty, so a set that lies wholly outside a safe region at a time holds real trajectories);
  otherwise a failed test is ``unknown``;
* on sampled trajectories (``mc`` / ``ode`` / the hybrid sampler), a state that breaks the spec is
  a counter-example: ``violated`` with the sample, its time, location and whole trajectory; no
  counter-example is ``unknown`` (samples prove nothing).

Every set test is sound in floating point: support functions are padded by the rounding bound of
:mod:`ocreach.sets.rounding` before they are compared (:func:`support_bound`), and a set is cut by a
constraint (:func:`contract`) by tightening the range of each generator factor with outward
margins.  Measures (:class:`Width`, :class:`BoxVolume`, :class:`Maximum`) are the quantities the
reports tabulate, evaluated on the final sets.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.errors import ProblemError
from ocreach.sets.rounding import rounding_radius
from ocreach.sets.zonotope import Zonotope, zonotope_polygon

#: the name of the time in constraints (the hybrid automaton's global clock)
TIME = "t"
#: facets of the regular polygon circumscribing a disk, used to cut sets by an :class:`InBall`
BALL_FACETS = 16
#: relative outward margin of the factor ranges when a set is cut by a constraint
CUT_MARGIN = 1e-12

STATUSES = ("verified", "violated", "unknown")


# =============================================================================== constraints
def _pairs(coeffs: Mapping[str, float] | Iterable[tuple[str, float]], what: str
           ) -> tuple[tuple[str, float], ...]:
    items = coeffs.items() if isinstance(coeffs, Mapping) else coeffs
    out = []
    for name, val in items:
        v = float(val)
        if not isinstance(name, str) or not name:
            raise ProblemError(f"{what}: state names must be non-empty strings; got {name!r}")
        if not math.isfinite(v):
            raise ProblemError(f"{what}: coefficient of {name!r} must be finite; got {val!r}")
        if v != 0.0:
            out.append((name, v))
    if not out:
        raise ProblemError(f"{what}: needs at least one non-zero coefficient; got {coeffs!r}")
    return tuple(out)


def _index(names: Sequence[str], wanted: Iterable[str], what: str) -> list[int]:
    idx = []
    for w in wanted:
        if w not in names:
            raise ProblemError(f"{what} refers to {w!r}, which is not a state of this set "
                               f"{list(names)}" + ("; the time 't' is a state only in hybrid "
                                                    "results -- use the spec's window" if w == TIME
                                                    else ""))
        idx.append(list(names).index(w))
    return idx


@dataclass(frozen=True)
class Linear:
    """The half-space ``sum_i coeffs[i] * x_i <= bound`` over named states."""

    coeffs: tuple[tuple[str, float], ...]
    bound: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "coeffs", _pairs(self.coeffs, "Linear"))
        b = float(self.bound)
        if not math.isfinite(b):
            raise ProblemError(f"Linear: bound must be finite; got {self.bound!r}")
        object.__setattr__(self, "bound", b)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.coeffs)

    def vector(self, names: Sequence[str]) -> np.ndarray:
        a = np.zeros(len(names))
        for i, (_, v) in zip(_index(names, self.names, "Linear"), self.coeffs):
            a[i] += v
        return a

    def expr(self, sym: Mapping[str, Any]) -> Any:
        """``a.x - b`` as an expression of the symbols ``sym`` (name -> CasADi symbol)."""
        return sum(v * sym[n] for n, v in self.coeffs) - self.bound

    def negated(self) -> Linear:
        """The closed complement ``sum a_i x_i >= bound``."""
        return Linear(tuple((n, -v) for n, v in self.coeffs), -self.bound)

    def describe(self) -> str:
        if len(self.coeffs) == 1:
            n, v = self.coeffs[0]
            return f"{n} <= {self.bound / v:g}" if v > 0 else f"{n} >= {self.bound / v:g}"
        terms = " + ".join(f"{v:g}*{n}" for n, v in self.coeffs)
        return f"{terms} <= {self.bound:g}"

    # -- points
    def value(self, X: np.ndarray, names: Sequence[str]) -> np.ndarray:
        """``a.x - b`` of each row of ``X`` (<= 0 inside)."""
        return np.asarray(X, float) @ self.vector(names) - self.bound

    # -- sets
    def surely_holds(self, Z: Zonotope, names: Sequence[str]) -> bool:
        return support_bound(Z, self.vector(names)) <= self.bound

    def surely_fails(self, Z: Zonotope, names: Sequence[str]) -> bool:
        return -support_bound(Z, -self.vector(names)) > self.bound

    def cut(self, Z: Zonotope, names: Sequence[str]) -> Zonotope | None:
        return contract(Z, self.vector(names), self.bound)


def _ball_parts(names, center, radius, what):
    names = tuple(str(n) for n in names)
    center = tuple(float(c) for c in center)
    r = float(radius)
    if not names or len(names) != len(center):
        raise ProblemError(f"{what}: needs one centre coordinate per name; got names {names}, "
                           f"centre {center}")
    if not (math.isfinite(r) and r > 0) or not all(math.isfinite(c) for c in center):
        raise ProblemError(f"{what}: radius must be finite and > 0 and the centre finite; got "
                           f"radius {radius!r}, centre {center}")
    return names, center, r


def _distance_range(Z: Zonotope, idx: list[int], center: np.ndarray) -> tuple[float, float]:
    """Sound ``(min, max)`` of ``||x_S - c||_2`` over ``Z`` (exact polygon in 2-D, box bounds
    otherwise), widened by the rounding of the computation."""
    P = Z.project(idx)
    scale = float(np.max(np.abs(P.c) + np.abs(P.G).sum(axis=1) + np.abs(center))) + 1e-300
    pad = 1e-12 * scale
    if len(idx) == 2:
        V = zonotope_polygon(P.c, P.G) - center
        dmax = float(np.max(np.linalg.norm(V, axis=1)))
        dmin = _polygon_min_norm(V)
        return max(dmin - pad, 0.0), dmax + pad
    r = np.abs(P.G).sum(axis=1)
    lo, hi = P.c - r - center, P.c + r - center
    far = np.maximum(np.abs(lo), np.abs(hi))
    near = np.where((lo <= 0) & (hi >= 0), 0.0, np.minimum(np.abs(lo), np.abs(hi)))
    return max(float(np.linalg.norm(near)) - pad, 0.0), float(np.linalg.norm(far)) + pad


def _polygon_min_norm(V: np.ndarray) -> float:
    """Distance from the origin to the convex polygon with vertices ``V`` (0 if inside)."""
    k = V.shape[0]
    if k == 1:
        return float(np.linalg.norm(V[0]))
    A, B = V, np.roll(V, -1, axis=0)
    E = B - A
    if k >= 3:
        cross = E[:, 0] * (-A[:, 1]) - E[:, 1] * (-A[:, 0])  # origin left of each ccw edge
        if np.all(cross >= 0):
            return 0.0
    L2 = np.maximum((E * E).sum(axis=1), 1e-300)
    s = np.clip(-(A * E).sum(axis=1) / L2, 0.0, 1.0)
    return float(np.min(np.linalg.norm(A + s[:, None] * E, axis=1)))


@dataclass(frozen=True)
class InBall:
    """The ball ``||x_S - center||_2 <= radius`` in the named coordinates ``S``."""

    names: tuple[str, ...]
    center: tuple[float, ...]
    radius: float

    def __post_init__(self) -> None:
        n, c, r = _ball_parts(self.names, self.center, self.radius, "InBall")
        object.__setattr__(self, "names", n)
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "radius", r)

    def describe(self) -> str:
        return f"||({', '.join(self.names)}) - {self.center}|| <= {self.radius:g}"

    def expr(self, sym: Mapping[str, Any]) -> Any:
        """``||x_S - c||^2 - r^2`` as an expression of the symbols ``sym``."""
        return sum((sym[n] - c) ** 2 for n, c in zip(self.names, self.center)) - self.radius**2

    def value(self, X: np.ndarray, names: Sequence[str]) -> np.ndarray:
        idx = _index(names, self.names, "InBall")
        d = np.asarray(X, float)[:, idx] - np.asarray(self.center)
        return (d * d).sum(axis=1) - self.radius**2

    def surely_holds(self, Z: Zonotope, names: Sequence[str]) -> bool:
        idx = _index(names, self.names, "InBall")
        return _distance_range(Z, idx, np.asarray(self.center))[1] <= self.radius

    def surely_fails(self, Z: Zonotope, names: Sequence[str]) -> bool:
        idx = _index(names, self.names, "InBall")
        return _distance_range(Z, idx, np.asarray(self.center))[0] > self.radius

    def outer_halfspaces(self) -> list[Linear]:
        """Half-spaces whose intersection contains the ball: the bounding box and, in 2-D, the
        facets of the regular :data:`BALL_FACETS`-gon circumscribing the disk."""
        out: list[Linear] = []
        for n, c in zip(self.names, self.center):
            out += [Linear(((n, 1.0),), c + self.radius), Linear(((n, -1.0),), -(c - self.radius))]
        if len(self.names) == 2:
            (n1, n2), (c1, c2) = self.names, self.center
            for th in np.arange(BALL_FACETS) * (2 * np.pi / BALL_FACETS):
                a1, a2 = math.cos(th), math.sin(th)
                if abs(a1) < 1e-15 or abs(a2) < 1e-15:
                    continue  # the box facets
                # the facet's support is r (1 + margin): the computed cos/sin are within 1 ulp
                out.append(Linear(((n1, a1), (n2, a2)), a1 * c1 + a2 * c2 + self.radius * (1 + 1e-12)))
        return out

    def cut(self, Z: Zonotope, names: Sequence[str]) -> Zonotope | None:
        for h in self.outer_halfspaces():
            Z = h.cut(Z, names)
            if Z is None:
                return None
        return Z


@dataclass(frozen=True)
class OutBall:
    """The closed outside ``||x_S - center||_2 >= radius`` of a ball (not convex: a set is never
    cut by it, only tested)."""

    names: tuple[str, ...]
    center: tuple[float, ...]
    radius: float

    def __post_init__(self) -> None:
        n, c, r = _ball_parts(self.names, self.center, self.radius, "OutBall")
        object.__setattr__(self, "names", n)
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "radius", r)

    def describe(self) -> str:
        return f"||({', '.join(self.names)}) - {self.center}|| >= {self.radius:g}"

    def expr(self, sym: Mapping[str, Any]) -> Any:
        """``r^2 - ||x_S - c||^2`` as an expression of the symbols ``sym``."""
        return self.radius**2 - sum((sym[n] - c) ** 2 for n, c in zip(self.names, self.center))

    def value(self, X: np.ndarray, names: Sequence[str]) -> np.ndarray:
        idx = _index(names, self.names, "OutBall")
        d = np.asarray(X, float)[:, idx] - np.asarray(self.center)
        return self.radius**2 - (d * d).sum(axis=1)

    def surely_holds(self, Z: Zonotope, names: Sequence[str]) -> bool:
        idx = _index(names, self.names, "OutBall")
        return _distance_range(Z, idx, np.asarray(self.center))[0] >= self.radius

    def surely_fails(self, Z: Zonotope, names: Sequence[str]) -> bool:
        idx = _index(names, self.names, "OutBall")
        return _distance_range(Z, idx, np.asarray(self.center))[1] < self.radius

    def cut(self, Z: Zonotope, names: Sequence[str]) -> Zonotope | None:
        """``Z`` cut by a half-space containing ``Z`` minus the open ball: in 2-D, when the
        projection of ``Z`` does not contain the centre it lies in an angular sector (bisector
        ``n``, half-angle ``phi < 90 deg``, attained at its vertices) seen from the centre, and every
        point of it at distance ``>= r`` has ``n.(x - c) >= r cos phi``."""
        if self.surely_fails(Z, names):
            return None
        if len(self.names) != 2:
            return Z
        idx = _index(names, self.names, "OutBall")
        P = Z.project(idx)
        V = zonotope_polygon(P.c, P.G) - np.asarray(self.center)
        if V.shape[0] < 3 or _polygon_min_norm(V) <= 0:
            return Z
        ang = np.arctan2(V[:, 1], V[:, 0])
        mid = np.arctan2(np.sin(ang).mean(), np.cos(ang).mean())
        dev = np.abs((ang - mid + np.pi) % (2 * np.pi) - np.pi)
        phi = float(dev.max()) * (1 + 1e-9) + 1e-12
        if phi >= 0.5 * np.pi * 0.999:
            return Z
        n1, n2 = math.cos(mid), math.sin(mid)
        bound = self.radius * math.cos(phi) * (1 - 1e-12) - 1e-12 * self.radius
        (a1, a2), (c1, c2) = self.names, self.center
        # n.(x - c) >= bound  <=>  -n1 x1 - n2 x2 <= -(bound + n1 c1 + n2 c2)
        return Linear(((a1, -n1), (a2, -n2)), -(bound + n1 * c1 + n2 * c2)).cut(Z, names)


Constraint = Linear | InBall | OutBall


def linear(coeffs: Mapping[str, float], bound: float) -> Linear:
    """``sum coeffs[name] * name <= bound``."""
    return Linear(tuple(coeffs.items()), bound)


def le(name: str, value: float) -> Linear:
    """``name <= value``."""
    return Linear(((name, 1.0),), value)


def ge(name: str, value: float) -> Linear:
    """``name >= value``."""
    return Linear(((name, -1.0),), -float(value))


def box(bounds: Mapping[str, tuple[float, float]]) -> tuple[Linear, ...]:
    """The region ``lo <= name <= hi`` for every ``name: (lo, hi)`` (an infinite end is left out)."""
    out: list[Linear] = []
    for name, (lo, hi) in bounds.items():
        if lo > hi:
            raise ProblemError(f"box: bounds of {name!r} must have lo <= hi; got ({lo}, {hi})")
        if math.isfinite(lo):
            out.append(ge(name, lo))
        if math.isfinite(hi):
            out.append(le(name, hi))
    return tuple(out)


def in_ball(center: Mapping[str, float], radius: float) -> InBall:
    return InBall(tuple(center), tuple(center.values()), radius)


def out_ball(center: Mapping[str, float], radius: float) -> OutBall:
    return OutBall(tuple(center), tuple(center.values()), radius)


def complementary(a: Constraint, b: Constraint) -> bool:
    """True if ``b`` is the closed complement of ``a`` (they share only their boundary)."""
    if isinstance(a, Linear) and isinstance(b, Linear):
        return a.negated() == b
    if isinstance(a, (InBall, OutBall)) and isinstance(b, (InBall, OutBall)):
        return (type(a) is not type(b) and a.names == b.names and a.center == b.center
                and a.radius == b.radius)
    return False


def describe_region(region: Sequence[Constraint]) -> str:
    return " and ".join(c.describe() for c in region)


def region_names(region: Sequence[Constraint]) -> set[str]:
    return {n for c in region for n in c.names}


# =============================================================================== set tests
def support_bound(Z: Zonotope, d: np.ndarray) -> float:
    """An upper bound of the support function ``max_{x in Z} d.x = d.c + sum |d.g_j|``, padded by
    the rounding of its floating-point evaluation."""
    d = np.asarray(d, float)
    dg = d @ Z.G
    val = float(d @ Z.c + np.abs(dg).sum())
    absval = np.abs(d) @ (np.abs(Z.c) + np.abs(Z.G).sum(axis=1))
    return val + float(rounding_radius(np.atleast_1d(absval), Z.dim + Z.n_generators + 2)[0])


def contract(Z: Zonotope, a: np.ndarray, b: float) -> Zonotope | None:
    """A zonotope enclosing ``Z ∩ {a.x <= b}``, or None if that intersection is proven empty.

    With ``Z = c + G xi``, ``xi in [-1, 1]^h``, the constraint reads ``w.xi <= beta``
    (``w = G^T a``, ``beta = b - a.c``); every factor with ``w_j != 0`` is then bounded by
    ``|w_j| (xi_j sign w_j) <= beta + sum_{i != j} |w_i|`` (interval constraint propagation on the
    factor box).  The tightened box ``[lo_j, hi_j]`` is mapped back, ``c' = c + G mid``,
    ``G' = G diag(rad)``.  ``beta`` and the sum are widened by :data:`CUT_MARGIN` of their
    magnitudes and the rounding of ``c'`` is added as a box, so the result is a rigorous enclosure.
    """
    a = np.asarray(a, float)
    w = Z.G.T @ a
    beta = float(b - a @ Z.c)
    absw = np.abs(w)
    S = float(absw.sum())
    mag = float(abs(b) + np.abs(a) @ np.abs(Z.c) + S)
    slack = beta + S + CUT_MARGIN * mag + 1e-300      # >= beta + S exactly
    if slack < 0 or (beta + S) < -CUT_MARGIN * mag:  # even the smallest a.x exceeds b
        return None
    if beta - S >= CUT_MARGIN * mag:  # the whole set satisfies the constraint
        return Z
    lo = -np.ones(w.size)
    hi = np.ones(w.size)
    live = absw > 0
    q = np.full(w.size, np.inf)
    q[live] = slack / absw[live] - 1.0
    q = q + 1e-15 * np.abs(q)
    pos, neg = live & (w > 0), live & (w < 0)
    hi[pos] = np.minimum(1.0, q[pos])
    lo[neg] = np.maximum(-1.0, -q[neg])
    if np.any(lo > hi):
        return None
    if np.all((lo == -1.0) & (hi == 1.0)):
        return Z
    mid, rad = 0.5 * (lo + hi), 0.5 * (hi - lo)
    c = Z.c + Z.G @ mid
    G = Z.G * rad
    err = rounding_radius(np.abs(Z.c) + np.abs(Z.G) @ (np.abs(mid) + rad), Z.n_generators + 3)
    G = np.hstack([G[:, rad > 0], np.diag(err)[:, err > 0]])
    return Zonotope(c, G)


def cut_region(Z: Zonotope, region: Sequence[Constraint], names: Sequence[str],
               rounds: int = 2) -> Zonotope | None:
    """``Z`` cut by every constraint of ``region`` (``rounds`` passes), or None if proven empty."""
    for _ in range(rounds):
        for con in region:
            Z = con.cut(Z, names)
            if Z is None:
                return None
    return Z


def _parts(S: Any) -> list[Zonotope]:
    if isinstance(S, Zonotope):
        return [S]
    if hasattr(S, "parts"):
        return [p.to_zonotope() for p in S.parts]
    return [S.to_zonotope()]


def _polygon_separated(P: np.ndarray, Q: np.ndarray, pad: float) -> bool:
    """True if the convex polygons ``P`` and ``Q`` (vertices, (k, 2)) are separated by one of
    their edge normals by more than ``pad`` (the separating axis theorem; exact for polygons)."""
    axes = []
    for V in (P, Q):
        if V.shape[0] >= 2:
            E = np.roll(V, -1, axis=0) - V
            axes.append(np.column_stack([-E[:, 1], E[:, 0]]))
    if not axes:
        return bool(np.linalg.norm(P[0] - Q[0]) > pad)
    for ax in np.vstack(axes):
        nrm = np.linalg.norm(ax)
        if nrm == 0:
            continue
        ax = ax / nrm
        p, q = P @ ax, Q @ ax
        if p.max() + pad < q.min() or q.max() + pad < p.min():
            return True
    return False


def surely_disjoint(Z: Zonotope, region: Sequence[Constraint], names: Sequence[str]) -> bool:
    """True if ``Z`` is proven not to meet the region: some constraint fails on all of ``Z``, the
    cuts by the constraints leave nothing, or (a linear region in two coordinates) the polygons of
    ``Z`` and of the region are separated."""
    if any(c.surely_fails(Z, names) for c in region):
        return True
    if cut_region(Z, region, names) is None:
        return True
    lin = [c for c in region if isinstance(c, Linear)]
    used = sorted(region_names(lin))
    if len(lin) == len(region) and len(used) == 2:
        idx = _index(names, used, "region")
        poly = _region_polygon(lin, used)
        if poly is not None:
            P = Z.project(idx)
            V = zonotope_polygon(P.c, P.G)
            scale = float(np.max(np.abs(V)) + np.max(np.abs(poly))) + 1e-300
            return _polygon_separated(V, poly, 1e-12 * scale)
    return False


def _region_polygon(lin: Sequence[Linear], names: Sequence[str]) -> np.ndarray | None:
    """Vertices of a bounded 2-D polygon ``{A x <= b}`` (None if unbounded or empty)."""
    A = np.array([c.vector(names) for c in lin])
    b = np.array([c.bound for c in lin])
    verts = []
    for i in range(len(lin)):
        for j in range(i + 1, len(lin)):
            M = A[[i, j]]
            if abs(np.linalg.det(M)) < 1e-14:
                continue
            v = np.linalg.solve(M, b[[i, j]])
            if np.all(A @ v <= b + 1e-9 * (1 + np.abs(b))):
                verts.append(v)
    if len(verts) < 3:
        return None
    V = np.array(verts)
    ctr = V.mean(axis=0)
    V = V[np.argsort(np.arctan2(V[:, 1] - ctr[1], V[:, 0] - ctr[0]))]
    # bounded only if every direction is limited: check the region's recession cone is {0}
    if np.linalg.matrix_rank(A) < 2:
        return None
    return V


def surely_inside(Z: Zonotope, region: Sequence[Constraint], names: Sequence[str]) -> bool:
    return all(c.surely_holds(Z, names) for c in region)


# =============================================================================== specs
def _window(window) -> tuple[float, float] | None:
    if window is None:
        return None
    if isinstance(window, (int, float)):
        w = (float(window), float(window))
    else:
        w = tuple(float(v) for v in window)
    if len(w) != 2 or not (w[0] <= w[1]) or any(math.isnan(v) for v in w):
        raise ProblemError(f"window must be None, a time or (t_lo, t_hi) with t_lo <= t_hi; got {window!r}")
    return w  # type: ignore[return-value]


@dataclass(frozen=True)
class _SpecBase:
    region: tuple[Constraint, ...]
    window: tuple[float, float] | None = None
    locations: tuple[str, ...] | None = None
    name: str = ""

    def __post_init__(self) -> None:
        reg = tuple(self.region) if isinstance(self.region, (tuple, list)) else (self.region,)
        if not reg or not all(isinstance(c, (Linear, InBall, OutBall)) for c in reg):
            raise ProblemError(f"{type(self).__name__}: region must be one or more constraints "
                               f"(Linear, InBall, OutBall); got {self.region!r}")
        object.__setattr__(self, "region", reg)
        object.__setattr__(self, "window", _window(self.window))
        if self.locations is not None:
            object.__setattr__(self, "locations", tuple(str(v) for v in self.locations))
        if not self.name:
            object.__setattr__(self, "name", self.describe())

    def where(self) -> str:
        w = "" if self.window is None else (f" at t = {self.window[0]:g}" if self.window[0] == self.window[1]
                                            else f" for t in [{self.window[0]:g}, {self.window[1]:g}]")
        loc = "" if self.locations is None else f" in {'/'.join(self.locations)}"
        return w + loc


@dataclass(frozen=True)
class Safe(_SpecBase):
    """Every reachable state in the window (and locations) lies in ``region``."""

    def describe(self) -> str:
        return f"always {describe_region(self.region)}" + self.where()


@dataclass(frozen=True)
class Unsafe(_SpecBase):
    """No reachable state in the window (and locations) enters ``region``."""

    def describe(self) -> str:
        return f"never {describe_region(self.region)}" + self.where()


@dataclass(frozen=True)
class Attains:
    """The enclosure of ``sum coeffs * x`` over the states in the window contains ``value``
    (a consistency check of an enclosure against a conserved quantity)."""

    coeffs: tuple[tuple[str, float], ...]
    value: float
    window: tuple[float, float] | None = None
    locations: tuple[str, ...] | None = None
    name: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "coeffs", _pairs(self.coeffs, "Attains"))
        object.__setattr__(self, "window", _window(self.window))
        if not self.name:
            terms = " + ".join(n if v == 1 else f"{v:g}*{n}" for n, v in self.coeffs)
            w = "" if self.window is None else f" at t = {self.window[0]:g}" \
                if self.window[0] == self.window[1] else f" for t in {self.window}"
            object.__setattr__(self, "name", f"{self.value:g} in range of {terms}{w}")


Spec = Safe | Unsafe | Attains


@dataclass
class SpecResult:
    """Outcome of one spec: ``status`` (verified / violated / unknown), a readable ``detail``
    (the first set or sample that failed), ``margin`` (verified safety distance where a single
    linear constraint makes it meaningful, else None) and, for sampled results, the
    ``counterexample`` (sample index, time, location, state, the sample's trajectory)."""

    name: str
    status: str
    detail: str = ""
    margin: float | None = None
    counterexample: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        out = {"name": self.name, "status": self.status, "detail": self.detail,
               "margin": self.margin}
        if self.counterexample is not None:
            ce = dict(self.counterexample)
            for k in ("times", "states", "locations"):
                if k in ce and isinstance(ce[k], np.ndarray):
                    ce[k] = ce[k].tolist()
            out["counterexample"] = ce
        return out


# =============================================================================== flowpipe views
@dataclass(frozen=True)
class Piece:
    """One set of a guaranteed flowpipe: ``set`` encloses the states of ``location`` over the
    times ``[t_lo, t_hi]`` (a time-point set has ``t_lo == t_hi``); ``names`` are its coordinates
    (with ``"t"`` for a hybrid flowpipe, whose sets carry the clock)."""

    set: Any
    t_lo: float
    t_hi: float
    names: tuple[str, ...]
    location: str = ""


def pieces(result: Any, names: Sequence[str] | None = None) -> list[Piece]:
    """The flowpipe of a guaranteed result: ``result.pieces`` of a hybrid result, else the
    time-point sets and tubes of a :class:`ReachResult` (``names`` its state names)."""
    if hasattr(result, "pieces"):
        return list(result.pieces)
    if result.sets is None:
        raise ProblemError("pieces: the result has no sets (a sampled result: use its trajectories)")
    names = tuple(names or ())
    out = [Piece(S, float(t), float(t), names) for t, S in zip(result.times, result.sets)]
    for k, T in enumerate(result.tubes or []):
        out.append(Piece(T, float(result.times[k]), float(result.times[k + 1]), names))
    return out


def _in_window(p: Piece, w) -> bool:
    if w is None:
        return True
    if p.t_lo == p.t_hi:
        return w[0] <= p.t_lo <= w[1]
    if TIME in p.names:  # cut to the window by its clock coordinate afterwards
        return p.t_lo <= w[1] and p.t_hi >= w[0]
    # open overlap: a tube touching the window at an end point is represented there by the
    # time-point set of that grid time
    return p.t_lo < w[1] and p.t_hi > w[0]


def _window_cut(Z: Zonotope, p: Piece, w) -> Zonotope | None:
    """The piece's set restricted to the window through its clock coordinate (if it has one)."""
    if w is None or TIME not in p.names:
        return Z
    return cut_region(Z, (ge(TIME, w[0]), le(TIME, w[1])), p.names, rounds=1)


def _fully_in_window(p: Piece, w) -> bool:
    return w is None or (w[0] <= p.t_lo and p.t_hi <= w[1])


def check(spec: Spec, result: Any, names: Sequence[str] | None = None, *,
          continuous: bool | None = None) -> SpecResult:
    """Check ``spec`` on a guaranteed result (sets/tubes or hybrid pieces) or on a sampled one
    (trajectories); ``names`` are the state names of a :class:`ReachResult`; ``continuous``
    (default: the result has no ``pieces``) allows a proven violation (module docstring)."""
    guaranteed = hasattr(result, "pieces") or (getattr(result, "sets", None) is not None
                                               and result.meta.get("guaranteed", False))
    if not guaranteed:
        return check_samples(spec, samples_of(result, names))
    if continuous is None:
        continuous = not hasattr(result, "pieces")
    return check_pieces(spec, pieces(result, names), continuous=continuous)


def check_pieces(spec: Spec, flow: Sequence[Piece], continuous: bool = False) -> SpecResult:
    """:func:`check` on the pieces of a guaranteed flowpipe."""
    checked = 0
    margin = math.inf
    single = (not isinstance(spec, Attains) and len(spec.region) == 1
              and isinstance(spec.region[0], Linear))
    lo_v, hi_v = math.inf, -math.inf
    for p in flow:
        if spec.locations is not None and p.location not in spec.locations:
            continue
        if not _in_window(p, spec.window):
            continue
        for Z0 in _parts(p.set):
            Z = _window_cut(Z0, p, spec.window)
            if Z is None:
                continue
            checked += 1
            where = (f"set over t in [{p.t_lo:.6g}, {p.t_hi:.6g}]"
                     + (f" in {p.location}" if p.location else ""))
            if isinstance(spec, Attains):
                d = Linear(spec.coeffs, 0.0).vector(p.names)
                hi_v = max(hi_v, support_bound(Z, d))
                lo_v = min(lo_v, -support_bound(Z, -d))
                continue
            if isinstance(spec, Safe):
                bad = [c for c in spec.region if not c.surely_holds(Z, p.names)]
                if single and not bad:
                    c = spec.region[0]
                    a = c.vector(p.names)
                    margin = min(margin, c.bound - support_bound(Z, a))
                if bad:
                    proven = continuous and _fully_in_window(p, spec.window) and any(
                        c.surely_fails(Z, p.names) for c in bad)
                    return SpecResult(spec.name, "violated" if proven else "unknown",
                                      f"{where}: not proven inside {describe_region(bad)}"
                                      + (" (it lies wholly outside)" if proven else ""))
            else:  # Unsafe
                if single:
                    c = spec.region[0]
                    a = c.vector(p.names)
                    gap = -support_bound(Z, -a) - c.bound
                    if gap > 0:
                        margin = min(margin, gap)
                        continue
                if not surely_disjoint(Z, spec.region, p.names):
                    proven = continuous and _fully_in_window(p, spec.window) and \
                        surely_inside(Z, spec.region, p.names)
                    return SpecResult(spec.name, "violated" if proven else "unknown",
                                      f"{where}: not proven outside {describe_region(spec.region)}"
                                      + (" (it lies wholly inside)" if proven else ""))
    if isinstance(spec, Attains):
        if checked == 0:
            return SpecResult(spec.name, "unknown", "no set in the window")
        ok = lo_v <= spec.value <= hi_v
        return SpecResult(spec.name, "verified" if ok else ("violated" if continuous else "unknown"),
                          f"enclosure [{lo_v:.9g}, {hi_v:.9g}]")
    if checked == 0:
        return SpecResult(spec.name, "unknown", "no set of the flowpipe lies in the window")
    return SpecResult(spec.name, "verified", f"{checked} sets checked",
                      margin=None if not math.isfinite(margin) else float(margin))


# =============================================================================== samples
@dataclass
class Samples:
    """Sampled trajectories: ``times`` (S, K) (or (K,) shared), ``states`` (S, K, n), optional
    ``locations`` (S, K) location names (None: one location), ``names`` the state names."""

    times: np.ndarray
    states: np.ndarray
    names: tuple[str, ...]
    locations: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.states = np.asarray(self.states, float)
        S, K = self.states.shape[:2]
        t = np.asarray(self.times, float)
        self.times = np.broadcast_to(t, (S, K)) if t.ndim == 1 else t
        self.names = tuple(self.names)


def samples_of(result: Any, names: Sequence[str] | None) -> Samples:
    """The trajectories of a sampled result (``result.samples`` of a hybrid one)."""
    if hasattr(result, "samples") and isinstance(result.samples, Samples):
        return result.samples
    if getattr(result, "trajectories", None) is None:
        raise ProblemError("check: the result has neither guaranteed sets nor trajectories")
    return Samples(result.times, result.trajectories, tuple(names or ()))


def check_samples(spec: Spec, smp: Samples) -> SpecResult:
    """:func:`check` on sampled trajectories: the first state that breaks the spec is the
    counter-example."""
    X = smp.states
    S, K, n = X.shape
    names = smp.names
    T = smp.times
    mask = np.ones((S, K), dtype=bool)
    if spec.window is not None:
        mask &= (T >= spec.window[0]) & (T <= spec.window[1])
    if spec.locations is not None and smp.locations is not None:
        mask &= np.isin(smp.locations, spec.locations)
    if isinstance(spec, Attains):
        return SpecResult(spec.name, "unknown", "a consistency check of enclosures; samples "
                          "neither prove nor refute it")
    flat = X.reshape(-1, n)
    inside = np.ones(S * K, dtype=bool)
    for c in spec.region:
        inside &= c.value(flat, names) <= 0
    inside = inside.reshape(S, K)
    bad = mask & (~inside if isinstance(spec, Safe) else inside)
    if not bad.any():
        return SpecResult(spec.name, "unknown", f"no counter-example in {S} samples "
                          f"({int(mask.sum())} states checked)")
    s, k = np.argwhere(bad)[0]
    loc = None if smp.locations is None else str(smp.locations[s, k])
    ce = {"sample": int(s), "time": float(T[s, k]), "location": loc, "state": X[s, k].tolist(),
          "names": list(names), "times": T[s], "states": X[s]}
    if smp.locations is not None:
        ce["locations"] = np.asarray(smp.locations[s]).astype(str)
    return SpecResult(spec.name, "violated",
                      f"sample {s} at t = {T[s, k]:.6g}" + (f" in {loc}" if loc else "")
                      + f": state {np.array2string(X[s, k], precision=6)}",
                      counterexample=ce)


def overall(results: Sequence[SpecResult]) -> str:
    """``violated`` if any spec is violated, ``verified`` if all are, else ``unknown``."""
    st = [r.status for r in results]
    if "violated" in st:
        return "violated"
    if st and all(s == "verified" for s in st):
        return "verified"
    return "unknown"


# =============================================================================== measures
@dataclass(frozen=True)
class Width:
    """Width ``max - min`` of ``sum coeffs * x`` over the final sets."""

    coeffs: tuple[tuple[str, float], ...]
    label: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "coeffs", _pairs(self.coeffs, "Width"))
        if not self.label:
            terms = "+".join(n for n, _ in self.coeffs)
            object.__setattr__(self, "label", f"width of {terms}")

    def of_sets(self, sets: Sequence[Any], names: Sequence[str]) -> float:
        d = Linear(self.coeffs, 0.0).vector(names)
        zs = [z for S in sets for z in _parts(S)]
        return max(support_bound(z, d) for z in zs) - min(-support_bound(z, -d) for z in zs)

    def of_points(self, X: np.ndarray, names: Sequence[str]) -> float:
        v = np.asarray(X, float) @ Linear(self.coeffs, 0.0).vector(names)
        return float(v.max() - v.min())


@dataclass(frozen=True)
class BoxVolume:
    """Volume (area in 2-D) of the box hull of the final sets in the coordinates ``names``."""

    names: tuple[str, ...]
    label: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "names", tuple(self.names))
        if not self.label:
            object.__setattr__(self, "label", f"{'area' if len(self.names) == 2 else 'volume'} "
                                              f"of the final box ({' x '.join(self.names)})")

    def of_sets(self, sets: Sequence[Any], names: Sequence[str]) -> float:
        out = 1.0
        for nm in self.names:
            out *= Width(((nm, 1.0),)).of_sets(sets, names)
        return out

    def of_points(self, X: np.ndarray, names: Sequence[str]) -> float:
        idx = _index(names, self.names, "BoxVolume")
        X = np.asarray(X, float)[:, idx]
        return float(np.prod(X.max(axis=0) - X.min(axis=0)))


@dataclass(frozen=True)
class Maximum:
    """Largest value of ``sum coeffs * x`` over the final sets."""

    coeffs: tuple[tuple[str, float], ...]
    label: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "coeffs", _pairs(self.coeffs, "Maximum"))
        if not self.label:
            object.__setattr__(self, "label", f"max of {'+'.join(n for n, _ in self.coeffs)}")

    def of_sets(self, sets: Sequence[Any], names: Sequence[str]) -> float:
        d = Linear(self.coeffs, 0.0).vector(names)
        return max(support_bound(z, d) for S in sets for z in _parts(S))

    def of_points(self, X: np.ndarray, names: Sequence[str]) -> float:
        return float((np.asarray(X, float) @ Linear(self.coeffs, 0.0).vector(names)).max())


Measure = Width | BoxVolume | Maximum


@dataclass
class Verification:
    """The specs and measures of a problem (``Problem.extra["verification"]``), as data."""

    specs: tuple[Spec, ...] = ()
    measures: tuple[Measure, ...] = ()
    notes: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
