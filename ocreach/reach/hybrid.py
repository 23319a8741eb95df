"""Reachability of hybrid automata (:mod:`ocreach.hybrid`): guaranteed flowpipes through the
guards for ``taylor`` / ``sdc`` / ``poly``, and samples simulated through the same automaton for
``mc``.

Guaranteed (``taylor``, ``sdc``, ``poly``)
------------------------------------------
Every location's model gets the global time as a state (:func:`ocreach.hybrid.clocked`), so each
set carries the times of its states, time windows are half-spaces, and a jump set keeps its spread
of crossing times.  A *branch* is a location with an initial set; it is propagated grid step by grid
step by the method's own propagator (:meth:`ZonotopeReach.advance_grid_step`) until every state has
left the location or passed the horizon:

1. every sub-step tube is cut by the location's invariant (the states of a run in a location
   satisfy it; :func:`ocreach.specs.cut_region`) and becomes a flowpipe piece;
2. for every outgoing transition, the cut tube is cut by the guard: where it is not proven empty it
   encloses the states at which the transition can be taken during that sub-step (the guard
   intersection of Althoff's thesis Sec. 4.2 / CORA's ``guardIntersect``, here by interval
   constraint propagation on the zonotope's factors, which for a half-space guard that is the
   complement of the invariant leaves a thin slab on the boundary);
3. the time-point set is cut by the invariant; a branch ends when nothing is left of it (every run
   has jumped) or its clock passed the horizon;
4. the guard sets of a transition are clustered in time order into ``clusters`` groups, each group
   enclosed by one zonotope (an oriented box, :func:`oriented_hull`; JuliaReach clusters its jump
   sets the same way), cut again by invariant and guard, mapped by the reset, and started as a new
   branch of the target location.

The sub-step tubes of ``poly`` are zonotopes like those of ``taylor``; its time-point sets are
polynomial zonotopes, cut by an invariant through their zonotope enclosure (kept when the
enclosure lies inside, dropped when its cut is empty, else replaced by the cut enclosure).

The final sets are the pieces cut to ``t = T`` by their clock.  Sound: each step of the base method
encloses every run of its branch; cutting by an invariant or guard keeps every state that
satisfies it; the hull of the guard sets contains every jump state; so every run of the automaton
is, at every time, in some piece of its location.

Sampled (``mc``)
----------------
Each sample (initial states at the vertices and inside the initial set) is integrated by SciPy's
DOP853 in its location with the guards and invariant boundaries as events; urgent transitions are
taken at the first time their guard holds, a permissive one at a time drawn when its location is
entered (uniformly in its time window, with its ends drawn more often); a run that reaches an
invariant boundary with no enabled transition is *blocked* (counted, it stops).  States are kept at
the grid times and before and after every jump.
"""
from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.errors import OcreachError, ProblemError, SolverError, check_count
from ocreach.hybrid import CLOCK, HybridProblem, Location, Transition, clocked
from ocreach.problem import Problem
from ocreach.sets.rounding import rounding_radius
from ocreach.sets.zonotope import Zonotope
from ocreach.specs import Linear, Piece, Samples, complementary, cut_region, support_bound

GUARANTEED = ("taylor", "sdc", "poly")
SAMPLED = ("mc",)
ENCLOSURES = ("box", "pca")


# =============================================================================== options
@dataclass
class HybridOptions:
    """Options of the hybrid runner (``method_options["hybrid"]`` of a problem, or
    ``reach(..., hybrid={...})``):

    * ``dt`` (None): time step per location, ``{location: step}`` (default the problem's grid step);
    * ``clusters`` (1): groups each crossing of a guard (a run of consecutive sub-steps whose tubes
      meet it) is clustered into, one number or ``{transition label: number}``;
    * ``enclose`` ("pca"): enclosure of a group, ``"box"`` (axis-aligned) or ``"pca"`` (a box in
      the principal axes of the group, scaled coordinates);
    * ``max_jumps`` (20): jumps along one run before its branch is dropped (the result is then
      flagged truncated); ``max_branches`` (500): branches in all.
    """

    dt: dict[str, float] | None = None
    clusters: Any = 1
    enclose: str = "pca"
    max_jumps: int = 20
    max_branches: int = 500

    def __post_init__(self) -> None:
        if self.dt is not None:
            if not isinstance(self.dt, dict):
                raise ProblemError(f"hybrid dt must be a dict {{location: step}}; got {self.dt!r}")
            for k, v in self.dt.items():
                if not (isinstance(v, (int, float)) and v > 0):
                    raise ProblemError(f"hybrid dt[{k!r}] must be a number > 0; got {v!r}")
        if isinstance(self.clusters, dict):
            for k, v in self.clusters.items():
                check_count(f"hybrid clusters[{k!r}]", v, 1)
        else:
            self.clusters = check_count("hybrid clusters", self.clusters, 1)
        if self.enclose not in ENCLOSURES:
            raise ProblemError(f"hybrid enclose must be one of {ENCLOSURES}; got {self.enclose!r}")
        self.max_jumps = check_count("hybrid max_jumps", self.max_jumps, 0)
        self.max_branches = check_count("hybrid max_branches", self.max_branches, 1)

    def n_clusters(self, label: str) -> int:
        if isinstance(self.clusters, dict):
            return int(self.clusters.get(label, 1))
        return int(self.clusters)


# =============================================================================== results
@dataclass
class Branch:
    """One location entered with one initial set: ``path`` the transition labels that led here."""

    location: str
    initial: Zonotope
    path: tuple[str, ...] = ()
    entered: Transition | None = None
    steps: int = 0
    stop: str = ""
    jumps: dict[str, int] = field(default_factory=dict)


@dataclass(repr=False)
class HybridResult:
    """Guaranteed flowpipe of a hybrid automaton: ``pieces`` (:class:`~ocreach.specs.Piece`,
    sets over the state names and ``"t"``), ``finals`` (``(location, set, path)`` at ``t = T``),
    ``branches`` and ``meta`` (method, options, runtime, ``guaranteed``, ``truncated``)."""

    names: tuple[str, ...]
    pieces: list[Piece]
    finals: list[tuple[str, Zonotope, tuple[str, ...]]]
    branches: list[Branch]
    meta: dict[str, Any]

    def __repr__(self) -> str:
        return (f"HybridResult({len(self.pieces)} pieces, {len(self.branches)} branches, "
                f"{len(self.finals)} final sets, method {self.meta.get('method')!r})")

    @property
    def final_sets(self) -> list[Zonotope]:
        return [Z for _, Z, _ in self.finals]

    def final_paths(self) -> list[tuple[str, ...]]:
        """The distinct jump sequences of the final sets."""
        return sorted({p for _, _, p in self.finals})

    def support(self, d: Any, final: bool = True) -> float:
        """Upper bound of ``max d.x`` over the final sets (or over the whole flowpipe)."""
        d = np.asarray(d, float)
        if d.size == len(self.names) - 1:
            d = np.r_[d, 0.0]
        sets = self.final_sets if final else [p.set for p in self.pieces]
        return max(support_bound(Z, d) for Z in sets)


@dataclass(repr=False)
class HybridSamples:
    """Samples simulated through a hybrid automaton: ``samples`` (states at the grid times and
    before / after every jump, with their locations), ``paths`` (transition labels per sample),
    ``final`` (S, n) states at ``T``, ``blocked`` indices of runs that reached an invariant
    boundary with no enabled transition, ``meta``."""

    names: tuple[str, ...]
    samples: Samples
    paths: list[tuple[str, ...]]
    final: np.ndarray
    final_locations: np.ndarray
    blocked: list[int]
    meta: dict[str, Any]

    def __repr__(self) -> str:
        return f"HybridSamples({self.final.shape[0]} samples, {len(self.blocked)} blocked)"


# =============================================================================== enclosures
def oriented_hull(sets: Sequence[Zonotope], B: np.ndarray) -> Zonotope:
    """A zonotope ``B box + box(e)`` containing every set: ``W = B^-1`` (computed), the box of
    ``W x`` over each set from support functions (rounded outward), and the residual
    ``(I - B W) x`` of the computed inverse as the box ``e = |I - B W| max|x|`` (rounded up)."""
    n = B.shape[0]
    W = np.linalg.inv(B)
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    xmax = np.zeros(n)
    for Z in sets:
        for i in range(n):
            hi[i] = max(hi[i], support_bound(Z, W[i]))
            lo[i] = min(lo[i], -support_bound(Z, -W[i]))
        xmax = np.maximum(xmax, np.abs(Z.c) + np.abs(Z.G).sum(axis=1))
    mid, rad = 0.5 * (lo + hi), 0.5 * (hi - lo)
    rad = rad + rounding_radius(np.abs(mid) + rad, 2)  # mid and rad rounding
    c = B @ mid
    G = B * rad
    R = np.abs(np.eye(n) - B @ W)
    e = R @ xmax * (1 + 1e-10) + rounding_radius(np.abs(B) @ (np.abs(mid) + rad), n + 2)
    return Zonotope(c, np.hstack([G[:, rad > 0], np.diag(e)[:, e > 0]]))


def enclose(sets: Sequence[Zonotope], kind: str) -> Zonotope:
    """One zonotope containing ``sets``: ``"box"`` (their interval hull) or ``"pca"`` (an
    oriented box in the principal axes of their centres and generators, in coordinates scaled by
    the hull's widths)."""
    n = sets[0].dim
    if kind == "box" or len(sets) == 0:
        return oriented_hull(sets, np.eye(n))
    lo = np.min([Z.c - np.abs(Z.G).sum(axis=1) for Z in sets], axis=0)
    hi = np.max([Z.c + np.abs(Z.G).sum(axis=1) for Z in sets], axis=0)
    scale = np.maximum(hi - lo, 1e-12 * np.maximum(1.0, np.abs(hi)))
    C = np.array([Z.c for Z in sets])
    data = [((C - C.mean(axis=0)) / scale).T] + [Z.G / scale[:, None] for Z in sets]
    D = np.hstack(data)
    if D.shape[1] == 0 or not np.all(np.isfinite(D)):
        return oriented_hull(sets, np.eye(n))
    U, _, _ = np.linalg.svd(D, full_matrices=True)
    B = scale[:, None] * U
    if np.linalg.cond(B) > 1e12:
        return oriented_hull(sets, np.eye(n))
    P = oriented_hull(sets, B)
    Q = oriented_hull(sets, np.eye(n))
    # keep the one with the smaller box volume of its generators (both are enclosures)
    return P if _logvol(P) < _logvol(Q) else Q


def _logvol(Z: Zonotope) -> float:
    r = np.abs(Z.G).sum(axis=1)
    return float(np.sum(np.log(np.maximum(r, 1e-300))))


def _groups(items: list[tuple[float, float, Zonotope]], k: int) -> list[list[Zonotope]]:
    """Guard sets ``(t_lo, t_hi, set)`` sorted by time and cut into crossings (maximal runs whose
    time intervals overlap or touch: separate crossings of the guard), each crossing into at most
    ``k`` consecutive groups of (nearly) equal size."""
    items = sorted(items, key=lambda it: (it[0], it[1]))
    runs: list[list[Zonotope]] = []
    reach_t = -np.inf
    for lo, hi, Z in items:
        if not runs or lo > reach_t + 1e-12 * max(1.0, abs(reach_t)):
            runs.append([])
        runs[-1].append(Z)
        reach_t = max(reach_t, hi)
    out = []
    for run in runs:
        m = max(1, min(k, len(run)))
        edges = np.linspace(0, len(run), m + 1).round().astype(int)
        out += [run[a:b] for a, b in itertools.pairwise(edges) if b > a]
    return out


# =============================================================================== guaranteed
def _tau_range(Z: Zonotope, i: int) -> tuple[float, float]:
    e = np.zeros(Z.dim)
    e[i] = 1.0
    return -support_bound(Z, -e), support_bound(Z, e)


def _local_grid(H: float, dt: float) -> np.ndarray:
    n = max(1, int(np.ceil(H / dt - 1e-9)))
    g = np.arange(n + 1) * dt
    g[-1] = H
    if g.size > 2 and g[-1] - g[-2] < 1e-9 * dt:
        g = np.delete(g, -2)
    return g


def reach_guaranteed(problem: HybridProblem, method: str, method_cls: type, **options: Any
                     ) -> HybridResult:
    """The guaranteed flowpipe of ``problem`` (module docstring) with ``taylor``, ``sdc`` or
    ``poly`` (``method_cls`` its class); ``options`` are the method's options plus
    ``hybrid={...}`` (:class:`HybridOptions`).

    ``meta["valid_until"]`` is the time up to which every run lies in the pieces: the horizon,
    or less when branches or jump sets were dropped (``max_branches``, ``max_jumps``:
    ``truncated``).  A branch that cannot be enclosed raises :class:`SolverError` with the flowpipe
    computed so far in ``err.partial`` (``truncated``, ``meta["failure"]``, and ``valid_until``
    the earliest time of what was not propagated)."""
    if method not in GUARANTEED:
        raise ProblemError(f"hybrid guaranteed reachability supports {GUARANTEED}; got {method!r}")
    hraw = {**problem.options_for("hybrid"), **dict(options.pop("hybrid", None) or {})}
    hopts = HybridOptions(**hraw)
    mopts = {**problem.options_for(method), **options}
    meth = method_cls(**mopts)
    aut = problem.automaton
    names = (*aut.state_names, CLOCK)
    it = len(names) - 1
    T = problem.t_final
    t0 = float(problem.grid[0])
    dt0 = float(problem.grid[1] - problem.grid[0])
    S0 = problem.initial_set
    Z0 = (S0.to_zonotope() if S0 is not None else Zonotope(problem.x0))
    Z0 = Zonotope(np.r_[Z0.c, t0], np.vstack([Z0.G, np.zeros((1, Z0.n_generators))]))
    level = [Branch(problem.initial_location, Z0)]
    pieces: list[Piece] = []
    finals: list[tuple[str, Zonotope, tuple[str, ...]]] = []
    done: list[Branch] = []
    truncated = False
    valid = T  # every run of the automaton lies in the pieces up to this time
    t_start = time.perf_counter()

    def start(items) -> float:
        return min((lo for lo, _, _ in items), default=T)

    def result(failure: str = "") -> HybridResult:
        meta = {"method": method, "guaranteed": True, "truncated": truncated or bool(failure),
                "problem": problem.id, "valid_until": valid,
                "options": {k: v for k, v in dataclasses.asdict(meth.options).items()},
                "hybrid": dataclasses.asdict(hopts),
                "runtime": {"propagation": time.perf_counter() - t_start},
                "steps": sum(b.steps for b in done), "branches": len(done)}
        if failure:
            meta["failure"] = failure
        return HybridResult(names=names, pieces=pieces, finals=finals, branches=done, meta=meta)

    while level:  # one generation: the branches reached by the same number of jumps
        pending: dict[tuple, tuple[Transition, list]] = {}
        for j, br in enumerate(level):
            if len(done) >= hopts.max_branches:
                truncated = True
                valid = min(valid, _tau_range(br.initial, it)[0])
                br.stop = f"not propagated: more than max_branches = {hopts.max_branches} branches"
                done.append(br)
                continue
            loc = aut.location(br.location)
            try:
                cands = _propagate_branch(problem, meth, loc, br, names, it, T,
                                          (hopts.dt or {}).get(loc.name, dt0), pieces, finals)
            except SolverError as exc:
                if not hasattr(exc, "valid_until"):
                    raise
                # what is not propagated: the rest of this branch, its guard sets and those of
                # the generation so far, the branches after it
                valid = min([valid, exc.valid_until]
                            + [start(items) for _, items in exc.candidates]
                            + [start(items) for _, items in pending.values()]
                            + [_tau_range(b.initial, it)[0] for b in level[j + 1:]])
                br.stop = f"failed: {exc}"
                done.append(br)
                exc.partial = result(str(exc))
                raise
            done.append(br)
            for tr, items in cands:
                if items:
                    pending.setdefault((br.path, tr.label, id(tr)), (tr, []))[1].extend(items)
        level = []
        for (path, label, _), (tr, items) in pending.items():
            if len(path) + 1 > hopts.max_jumps:
                truncated = True
                valid = min(valid, start(items))
                done[-1].stop += f"; {len(items)} guard set(s) of {label!r} after {path} dropped: " \
                                 f"max_jumps = {hopts.max_jumps} reached"
                continue
            level += _jump_branches(aut, tr, items, path, hopts, names)
    return result()


def _propagate_branch(problem, meth, loc: Location, br: Branch, names, it: int, T: float,
                      dt: float, pieces, finals) -> list[tuple[Transition, list]]:
    """Propagate one branch (module docstring, items 1-3); its guard sets per outgoing
    transition as ``(transition, [(t_lo, t_hi, set), ...])``."""
    aut = problem.automaton
    Z = br.initial
    tau_lo, tau_hi = _tau_range(Z, it)
    H = T - tau_lo
    if H <= 0:
        br.stop = "starts after the horizon"
        return []
    model = clocked(loc.model)
    grid = _local_grid(H, dt)
    sub = Problem(id=f"{problem.id}[{loc.name}]", model=model, x0=Z.c, grid=grid, initial_set=Z,
                  params=problem.params, control_set=problem.control_set)
    reacher = propagator(meth, sub)
    outgoing = aut.outgoing(loc.name)
    cands: dict[str, list[tuple[float, float, Zonotope]]] = {tr.label: [] for tr in outgoing}
    rates = {tr.label: _entry_rates(loc, tr, names) for tr in outgoing}
    # runs that entered through the complement of a guard start on its boundary, leaving it
    leaving = {tr.label: rates[tr.label] is not None and br.entered is not None
               and complementary(br.entered.guard[0], tr.guard[0]) if len(br.entered.guard) == 1
               else False for tr in outgoing} if br.entered is not None else \
        {tr.label: False for tr in outgoing}
    parts = reacher.initial_parts()  # the branch's initial set Z
    pieces.append(Piece(Z, tau_lo, tau_hi, names, loc.name))
    br.stop = "horizon"
    for k in range(grid.size - 1):
        new, tubes, _stats, fail = reacher.advance_grid_step(parts, float(grid[k]), float(grid[k + 1]))
        if fail is not None:
            err = SolverError(f"{meth.name} (hybrid): location {loc.name!r}, branch "
                              f"{' -> '.join(br.path) or 'initial'}, local step {k} "
                              f"[{grid[k]:.6g}, {grid[k + 1]:.6g}] cannot be enclosed: {fail.reason}")
            # the runs of this branch are enclosed up to the earliest clock of its parts
            err.valid_until = min(_tau_range(_enclosure(p.Z), it)[0] for p in parts)
            err.candidates = [(tr, cands[tr.label]) for tr in outgoing]
            raise err
        br.steps += 1
        for tube in tubes:
            tc = cut_region(tube, loc.invariant, names) if loc.invariant else tube
            if tc is None:
                continue
            lo, hi = _tau_range(tc, it)
            if lo > T:
                continue
            pieces.append(Piece(tc, lo, hi, names, loc.name))
            if lo <= T <= hi:
                fin = cut_region(tc, (_tau_le(T), _tau_ge(T)), names, rounds=1)
                if fin is not None:
                    finals.append((loc.name, fin, br.path))
            for tr in outgoing:
                rate = rates[tr.label]
                if leaving[tr.label] and not _positive(rate[1], tc, problem):
                    leaving[tr.label] = False
                J = cut_region(tc, tr.guard, names)
                if J is None or leaving[tr.label]:
                    continue
                if rate is not None and _positive(rate[0], J, problem):
                    continue
                cands[tr.label].append((*_tau_range(J, it), J))
        kept = []
        for p in new:
            Zc = _cut_part(reacher, p.Z, loc.invariant, names) if loc.invariant else p.Z
            if Zc is not None:
                kept.append(dataclasses.replace(p, Z=Zc))
        parts = kept
        if not parts:
            br.stop = "every run has left the location"
            break
        if min(_tau_range(_enclosure(p.Z), it)[0] for p in parts) > T:
            break
    for tr in outgoing:
        br.jumps[tr.label] = len(cands[tr.label])
    return [(tr, cands[tr.label]) for tr in outgoing]


def propagator(meth, problem: Problem):
    """The grid-step propagator (:class:`~ocreach.reach.taylor.ZonotopeReach`) of the method
    instance ``meth`` on ``problem``: ``meth.reacher`` for ``taylor`` / ``sdc``, the
    polynomial-zonotope driver of :mod:`ocreach.reach.poly` for ``poly`` (checked as its
    ``solve`` checks)."""
    if hasattr(meth, "reacher"):
        return meth.reacher(problem)
    from ocreach.reach.poly import PolyReach, PolyReachMethod
    from ocreach.reach.taylor import check_smooth, initial_zonotope

    if not isinstance(meth, PolyReachMethod):
        raise ProblemError(f"hybrid guaranteed reachability supports {GUARANTEED}; got "
                           f"{type(meth).__name__}")
    check_smooth(problem.model)
    initial_zonotope(problem)
    return PolyReach(meth, problem, meth.options)


def _enclosure(S) -> Zonotope:
    """A zonotope containing a part's set (the set itself for the zonotope methods, the sound
    enclosure of a polynomial zonotope of ``poly``)."""
    if isinstance(S, Zonotope):
        return S
    from ocreach.sets import pz_sound as spz

    return spz.to_zonotope(S)


def _cut_part(reacher, S, region, names):
    """A part's time-point set cut by ``region`` (None if that is proven empty).  A polynomial
    zonotope (``poly``) is cut through its zonotope enclosure: kept as it is when the enclosure
    lies in the region, dropped when the enclosure's cut is empty, else replaced by the cut
    enclosure (a zonotope containing the set's part in the region, with fresh factors)."""
    if isinstance(S, Zonotope):
        return cut_region(S, region, names)
    E = _enclosure(S)
    C = cut_region(E, region, names)
    if C is None or C is E:
        return None if C is None else S
    from ocreach.sets import pz_sound as spz

    return spz.from_zonotope(C, reacher.ctx.fid, reacher.ctx.d)


def _entry_rates(loc: Location, tr: Transition, names) -> Any:
    """Interval functions of the first and second time derivatives of the guard value ``v`` along
    the location's dynamics, for an urgent transition whose guard is one constraint that is the
    complement of a constraint of the source invariant (None otherwise).

    A run enters such a guard only where ``v`` falls through 0, so a guard set on which
    ``dv/dt > 0`` holds no entry.  A run that entered the location through the complementary
    guard starts on the boundary with ``dv/dt >= 0``; while it stays where ``d2v/dt2 > 0``,
    ``dv/dt`` keeps growing and ``v`` cannot return to 0: no guard set of the branch holds an
    entry until one of its tubes is not proven to lie in that region.  Both rules drop only the
    states of a run leaving the boundary it has just crossed, which the zonotopes of the jump set
    carry around it (needed at a tangential crossing, the Lotka-Volterra benchmark)."""
    import casadi as ca

    from ocreach.intervals import interval_function

    if not tr.urgent or len(tr.guard) != 1:
        return None
    g = tr.guard[0]
    if not any(complementary(g, c) for c in loc.invariant):
        return None
    model = clocked(loc.model)

    def build():
        sym = {n: model.x[i] for i, n in enumerate(names)}
        v = g.expr(sym)
        vdot = ca.mtimes(ca.jacobian(v, model.x), model.f)
        vddot = ca.mtimes(ca.jacobian(vdot, model.x), model.f)
        args = [model.x, model.u, model.t, model.p]
        out = []
        for name, e in (("guard_rate", vdot), ("guard_curvature", vddot)):
            deps = np.flatnonzero([ca.depends_on(e, model.x[i]) for i in range(model.n_x)])
            out.append((interval_function(ca.Function(name, args, [e])), deps))
        return tuple(out)

    return model.cached(("guard_rate", tr.label, repr(g)), build)


def _positive(rate, Z: Zonotope, problem, splits: int = 4) -> bool:
    """True if the scalar interval function of ``rate = (function, states it depends on)`` is
    proven > 0 on the box of ``Z`` (on each of ``splits^2`` sub-boxes along the two widest of
    those states when the whole box does not suffice)."""
    from ocreach.intervals import split_boxes

    fun, deps = rate
    I = Z.interval_hull()
    nu = problem.model.n_u
    par = np.asarray(problem.params, float)
    lo = [I.lo, np.zeros(nu), np.zeros(1), par]
    hi = [I.hi, np.zeros(nu), np.zeros(1), par]
    for k in (1, splits):
        w = (I.hi - I.lo)[deps]
        dims = [(0, int(deps[j])) for j in np.argsort(-w)[:2] if w[j] > 0] if k > 1 else []
        L, U, _ = split_boxes(lo, hi, k, dims=dims)
        try:
            (vlo, _vhi), = fun(L, U)
        except OcreachError:
            continue
        if bool(np.all(vlo > 0)):
            return True
    return False


def _tau_le(T: float):
    from ocreach.specs import le

    return le(CLOCK, T)


def _tau_ge(T: float):
    from ocreach.specs import ge

    return ge(CLOCK, T)


def _jump_branches(aut, tr: Transition, items: list[tuple[float, float, Zonotope]],
                   path: tuple[str, ...], hopts: HybridOptions, names) -> list[Branch]:
    """The branches of the target location: the guard sets of ``tr`` (from every branch of one
    generation with the same ``path``) clustered by time (:func:`_groups`), each group enclosed,
    cut by the source invariant and the guard, reset and cut by the target invariant."""
    src = aut.location(tr.source)
    target = aut.location(tr.target)
    A, c = tr.reset.matrices(len(names) - 1)
    Aa = np.eye(len(names))
    Aa[:-1, :-1] = A
    ca_ = np.r_[c, 0.0]
    out = []
    for grp in _groups(items, hopts.n_clusters(tr.label)):
        E = enclose(grp, hopts.enclose)
        E = cut_region(E, (*src.invariant, *tr.guard), names)
        if E is None:
            continue
        if not tr.reset.identity:
            mapped = Zonotope(Aa @ E.c + ca_, Aa @ E.G)
            err = rounding_radius(np.abs(Aa) @ (np.abs(E.c) + np.abs(E.G).sum(axis=1)) + np.abs(ca_),
                                  len(names) + E.n_generators + 2)
            E = Zonotope(mapped.c, np.hstack([mapped.G, np.diag(err)[:, err > 0]]))
        if target.invariant:
            E = cut_region(E, target.invariant, names)
            if E is None:
                continue
        out.append(Branch(tr.target, E, (*path, tr.label), entered=tr))
    return out


# =============================================================================== sampled
def _initial_samples(problem: Problem, n: int, rng: np.random.Generator) -> np.ndarray:
    """A quarter at vertices of the initial set, the rest uniform inside."""
    S = problem.initial_set
    if S is None:
        return np.tile(problem.x0, (n, 1))
    Z = S.to_zonotope() if not isinstance(S, Zonotope) else S
    if Z.n_generators == 0:
        return np.tile(Z.c, (n, 1))
    nv = n // 4
    return np.vstack([Z.sample(nv, rng, mode="extreme"), Z.sample(n - nv, rng, mode="uniform")])


def _time_bounds(region) -> tuple[float, float]:
    """The window ``[lo, hi]`` that the clock-only constraints of a region allow."""
    lo, hi = -np.inf, np.inf
    for c in region:
        if isinstance(c, Linear) and c.names == (CLOCK,):
            v = c.coeffs[0][1]
            if v > 0:
                hi = min(hi, c.bound / v)
            else:
                lo = max(lo, c.bound / v)
    return lo, hi


def _state_constraints(region) -> list:
    return [c for c in region if not (isinstance(c, Linear) and c.names == (CLOCK,))]


def _values(cons, X: np.ndarray, t: np.ndarray, names) -> np.ndarray:
    """``(S, len(cons))`` constraint values (<= 0 satisfied) at states ``X`` and times ``t``."""
    if not cons:
        return np.zeros((X.shape[0], 0))
    Xa = np.column_stack([X, t])
    return np.column_stack([c.value(Xa, names) for c in cons])


class _Runs:
    """The state of every run of :func:`simulate_hybrid` (vectorised over samples)."""

    def __init__(self, aut, problem, X0, rng, rtol, atol, T):
        from ocreach.dynamics.flow import flow_rhs

        self.aut, self.rng, self.rtol, self.atol, self.T = aut, rng, rtol, atol, T
        self.names = (*aut.state_names, CLOCK)
        self.locs = [loc.name for loc in aut.locations]
        self.rhs = [flow_rhs(loc.model) for loc in aut.locations]
        nu = aut.locations[0].model.n_u
        self.args = np.r_[np.zeros(nu), np.asarray(problem.params, float)]
        S = X0.shape[0]
        self.X = np.array(X0, float)
        self.t = np.full(S, float(problem.grid[0]))
        self.L = np.full(S, self.locs.index(problem.initial_location))
        self.paths: list[list[str]] = [[] for _ in range(S)]
        self.blocked = np.zeros(S, dtype=bool)
        self.decide = np.full(S, np.inf)        # time of the drawn permissive jump
        self.decide_tr: list[Any] = [None] * S  # and its transition
        self.events: list[tuple[int, float, str, np.ndarray]] = []  # (sample, t, location, state)
        for s in range(S):
            self._draw(s)
        # per location: urgent guards and invariant state constraints (event functions), and
        # the time bound of the invariant
        self.watch = []
        for loc in aut.locations:
            out = aut.outgoing(loc.name)
            urg = [(tr, c) for tr in out if tr.urgent for c in _state_constraints(tr.guard)]
            inv = _state_constraints(loc.invariant)
            self.watch.append((urg, inv, _time_bounds(loc.invariant)[1]))

    def _draw(self, s: int) -> None:
        """Draw the permissive jump of run ``s`` on entering its location: a transition among
        the permissive ones whose time window is still open, at a time uniform in the window
        (each end drawn with probability 0.15)."""
        out = [tr for tr in self.aut.outgoing(self.locs[self.L[s]]) if not tr.urgent]
        best, best_t = None, np.inf
        for tr in out:
            lo, hi = _time_bounds(tr.guard)
            lo, hi = max(lo, self.t[s]), min(hi, self.T)
            if lo > hi:
                continue
            u = self.rng.uniform()
            td = lo if u < 0.15 else hi if u < 0.3 else self.rng.uniform(lo, hi)
            if td < best_t:
                best, best_t = tr, td
        self.decide[s], self.decide_tr[s] = best_t, best

    def integrate(self, idx: np.ndarray, t1: np.ndarray) -> np.ndarray:
        """States of runs ``idx`` carried from their times to ``t1`` in their locations."""
        from ocreach.native.integrator import integrate_batch

        Y = self.X[idx].copy()
        for li in np.unique(self.L[idx]):
            m = self.L[idx] == li
            go = m & (t1 > self.t[idx])
            if go.any():
                Y[go] = integrate_batch(self.rhs[li], self.X[idx][go], self.t[idx][go], t1[go],
                                        self.args, rtol=self.rtol, atol=self.atol)
        return Y

    def advance(self, t_out: float) -> None:
        """Carry every live run to ``t_out``, taking the jumps on the way (module docstring)."""
        for _ in range(100_000):
            live = np.flatnonzero(~self.blocked & (self.t < t_out))
            if live.size == 0:
                return
            inv_t = np.array([self.watch[li][2] for li in self.L[live]])
            tgt = np.minimum.reduce([np.full(live.size, t_out), self.decide[live], inv_t])
            Y1 = self.integrate(live, tgt)
            hit = np.zeros(live.size, dtype=bool)
            for li in np.unique(self.L[live]):
                m = self.L[live] == li
                urg, inv, _ = self.watch[li]
                cons = [c for _, c in urg] + inv
                if not cons:
                    continue
                v1 = _values(cons, Y1[m], tgt[m], self.names)
                nu = len(urg)
                hit[m] = np.any(v1[:, :nu] <= 0, axis=1) | np.any(v1[:, nu:] > 0, axis=1)
            if hit.any():
                te, Ye = self._locate(live[hit], tgt[hit])
                Y1[hit], tgt[hit] = Ye, te
            self.X[live], self.t[live] = Y1, tgt
            for j, s in enumerate(live):
                if hit[j]:
                    self._state_event(s)
                elif self.t[s] >= self.decide[s]:
                    self._decided(s)
                elif self.t[s] >= inv_t[j] and self.t[s] < self.T:
                    self._forced(s)
        raise SolverError("hybrid sampler: more than 100000 event rounds (Zeno behaviour?)")

    def _locate(self, idx: np.ndarray, t1: np.ndarray, iters: int = 60):
        """First time in ``(t, t1]`` at which a watched constraint of each run ``idx`` changes
        (bisection on the integrated state), and the state there (on the changed side)."""
        a = self.t[idx].copy()
        b = t1.copy()
        for _ in range(iters):
            if np.all(b - a <= 1e-13 * np.maximum(1.0, np.abs(b))):
                break
            mid = 0.5 * (a + b)
            Ym = self.integrate(idx, mid)
            changed = self._changed(idx, Ym, mid)
            b = np.where(changed, mid, b)
            a = np.where(changed, a, mid)
        return b, self.integrate(idx, b)

    def _changed(self, idx, Y, t) -> np.ndarray:
        out = np.zeros(idx.size, dtype=bool)
        for li in np.unique(self.L[idx]):
            m = self.L[idx] == li
            urg, inv, _ = self.watch[li]
            cons = [c for _, c in urg] + inv
            v = _values(cons, Y[m], t[m], self.names)
            nu = len(urg)
            out[m] = np.any(v[:, :nu] <= 0, axis=1) | np.any(v[:, nu:] > 0, axis=1)
        return out

    def _jump(self, s: int, tr) -> None:
        self.events.append((s, float(self.t[s]), self.locs[self.L[s]], self.X[s].copy()))
        self.X[s] = tr.reset.apply(self.X[s])
        self.L[s] = self.locs.index(tr.target)
        self.paths[s].append(tr.label)
        self.events.append((s, float(self.t[s]), tr.target, self.X[s].copy()))
        self._draw(s)

    def _enabled(self, s: int, trs) -> Any:
        x, t = self.X[s], self.t[s]
        for tr in trs:
            if _holds(tr.guard, x, t, self.names):
                return tr
        return None

    def _state_event(self, s: int) -> None:
        """A watched constraint changed: take the urgent transition whose guard now holds, else
        (an invariant boundary) any enabled transition, else the run is blocked."""
        out = self.aut.outgoing(self.locs[self.L[s]])
        tr = self._enabled(s, [tr for tr in out if tr.urgent]) or self._enabled(s, out)
        if tr is None:
            # a conjunctive guard with one constraint met and the invariant still holding: go on
            loc = self.aut.location(self.locs[self.L[s]])
            if _holds(loc.invariant, self.X[s], self.t[s], self.names):
                return
            self.blocked[s] = True
            return
        self._jump(s, tr)

    def _decided(self, s: int) -> None:
        tr = self.decide_tr[s]
        self.decide[s], self.decide_tr[s] = np.inf, None
        if tr is not None and _holds(tr.guard, self.X[s], self.t[s], self.names):
            self._jump(s, tr)

    def _forced(self, s: int) -> None:
        """The invariant's time bound is reached: an enabled transition or blocked."""
        tr = self._enabled(s, self.aut.outgoing(self.locs[self.L[s]]))
        if tr is None:
            self.blocked[s] = True
        else:
            self._jump(s, tr)


def _holds(region, x: np.ndarray, t: float, names, tol: float = 1e-9) -> bool:
    xa = np.r_[x, t][None, :]
    return all(float(c.value(xa, names)[0]) <= tol * (1 + abs(getattr(c, "bound", 0.0)))
               for c in region)


def simulate_hybrid(problem: HybridProblem, samples: int = 1000, seed: int | None = 0,
                    rtol: float = 1e-10, atol: float = 1e-12, x0: np.ndarray | None = None
                    ) -> HybridSamples:
    """``samples`` runs of the automaton from the initial set (``x0`` (N, n) gives the initial
    states instead), integrated by the batch DOP853 of :mod:`ocreach.native.integrator`: every
    run is carried from grid time to grid time; a run whose watched constraints (urgent guards,
    invariant) changed on the way is bisected to the first time they change (to ~1e-13 relative)
    and takes its transition there; permissive jumps happen at their drawn times, and a run at
    its invariant's time bound takes an enabled transition or is blocked.  Two changes within one
    grid step (an entry and an exit) are not resolved: use a grid step shorter than the shortest
    stay in a location."""
    aut = problem.automaton
    names = (*aut.state_names, CLOCK)
    T = problem.t_final
    grid = problem.grid
    rng = np.random.default_rng(seed)
    X0 = _initial_samples(problem, check_count("samples", samples, 1), rng) if x0 is None \
        else np.atleast_2d(np.asarray(x0, float))
    t_start = time.perf_counter()
    runs = _Runs(aut, problem, X0, rng, rtol, atol, T)
    S, n = X0.shape
    OUT = np.empty((S, grid.size, n))
    OUTL = np.empty((S, grid.size), dtype=object)
    OUT[:, 0] = runs.X
    OUTL[:, 0] = [runs.locs[i] for i in runs.L]
    for k in range(1, grid.size):
        runs.advance(float(grid[k]))
        OUT[:, k] = runs.X
        OUTL[:, k] = [runs.locs[i] for i in runs.L]
    # the states just before and after every jump, appended to each sample's record
    per: dict[int, list] = {}
    for s, t, loc, x in runs.events:
        per.setdefault(s, []).append((t, loc, x))
    E = max((len(v) for v in per.values()), default=0)
    times = np.empty((S, grid.size + E))
    states = np.empty((S, grid.size + E, n))
    locs = np.empty((S, grid.size + E), dtype=object)
    times[:, :grid.size], states[:, :grid.size], locs[:, :grid.size] = grid, OUT, OUTL
    for s in range(S):
        ev = per.get(s, [])
        for j in range(E):
            t, loc, x = ev[j] if j < len(ev) else (grid[-1], OUTL[s, -1], OUT[s, -1])
            times[s, grid.size + j], locs[s, grid.size + j], states[s, grid.size + j] = t, loc, x
    smp = Samples(times, states, aut.state_names, locs)
    blocked = np.flatnonzero(runs.blocked).tolist()
    meta = {"method": "mc", "guaranteed": False, "problem": problem.id, "samples": S,
            "seed": seed, "rtol": rtol, "atol": atol, "blocked": len(blocked),
            "jumps": len(runs.events) // 2,
            "runtime": {"propagation": time.perf_counter() - t_start}}
    return HybridSamples(names=names, samples=smp, paths=[tuple(p) for p in runs.paths],
                         final=OUT[:, -1].copy(), final_locations=OUTL[:, -1].copy(),
                         blocked=blocked, meta=meta)


# =============================================================================== entry point
def reach_hybrid(problem: HybridProblem, method: str, method_cls: type, **options: Any):
    """``ocreach.reach`` on a :class:`~ocreach.hybrid.HybridProblem`: the guaranteed flowpipe
    (``taylor``, ``sdc``, ``poly``; ``method_cls`` the method's class) or samples through the
    automaton (``mc``: ``samples``, ``seed``, ``rtol``, ``atol``)."""
    if method in GUARANTEED:
        return reach_guaranteed(problem, method, method_cls, **options)
    if method in SAMPLED:
        allowed = {"samples", "seed", "rtol", "atol"}
        merged = {**{k: v for k, v in problem.options_for(method).items() if k in allowed}, **options}
        unknown = sorted(set(merged) - allowed)
        if unknown:
            raise ProblemError(f"method 'mc' on a hybrid automaton has no option(s) {unknown}; "
                               f"allowed: {sorted(allowed)}")
        return simulate_hybrid(problem, **merged)
    raise ProblemError(f"method {method!r} does not follow hybrid automata; for problem "
                       f"{problem.id!r} use one of {GUARANTEED + SAMPLED}")
