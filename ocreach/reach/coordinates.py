"""Any method in other coordinates, with the results brought back soundly to the model's own.

:func:`solve_in_coordinates` is what :class:`ocreach.reach.base.Method` runs when a problem (its
``coordinates``) or a method (its common option ``coordinates``) asks for a chart of
:mod:`ocreach.models.coordinates`:

1. the chart is built for the problem's model and checked before any work (it must fit the model;
   a declared unperturbed field must match the model's drift; the initial set must avoid the
   chart's singularities, bounded soundly);
2. the initial set is enclosed in the new coordinates (the second-order image of
   :class:`~ocreach.models.coordinates.convert.MapEnclosure`; a point ``x0`` becomes the box of its
   rounding), and for a time-transformed chart the time is appended as a state and the grid
   becomes a grid of the new independent variable ``s`` (nominal ``s`` at the final time from a
   coast, ``steps`` steps per problem step, ``margin`` beyond it);
3. the method runs on that problem unchanged;
4. its sets and tubes are converted back by the sound enclosure of the inverse map; for a
   time-transformed chart the set at a grid time ``t_k`` is the union, over the ``s``-tubes whose
   time range contains ``t_k``, of their slices at ``t = t_k`` (every trajectory is at ``t_k``
   at some ``s`` of some step, and inside that step's tube there), and the tube of the grid step
   ``[t_k, t_{k+1}]`` the union of the ``s``-tubes whose time range meets it.  A grid time is
   reported only when every trajectory has passed it: the lower time bound of the last ``s``-set
   is at least ``t_k``.  Samples (sample-based methods, time kept) are mapped point by point.

What the result holds: ``sets[k]`` and ``tubes[k]`` in the model's coordinates; for a guaranteed
method they are enclosures of the same states as the method's sets in the new coordinates (the
conversion adds its remainder, never drops a state), ``meta["coordinates"]`` records the chart,
the grid of ``s`` and the conversion (pieces, largest relative quadratic term).
"""
from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.errors import ProblemError, SolverError
from ocreach.models.coordinates import CoordinateSpec, chart_for, parse
from ocreach.models.coordinates.chart import Chart
from ocreach.models.coordinates.convert import ChartDomainError, MapEnclosure, slice_at, time_range
from ocreach.reach.result import ReachResult
from ocreach.sets.interval import Interval
from ocreach.sets.union import ZonotopeUnion
from ocreach.sets.zonotope import Zonotope

if TYPE_CHECKING:
    from ocreach.problem import Problem

#: the method instance (:class:`ocreach.reach.base.Method`, which imports this module)
Method = Any

#: how often a time-transformed run is repeated with a larger margin when its s-grid ended
#: before every trajectory reached the final time
MARGIN_RETRIES = 2
#: points around the initial state at which a declared drift is compared with the model's
DRIFT_CHECK_POINTS = 64


# ------------------------------------------------------------------------------------------------
# the problem in the new coordinates
# ------------------------------------------------------------------------------------------------
@dataclasses.dataclass
class Transformed:
    """A problem carried into a chart, and the maps back."""

    spec: CoordinateSpec
    chart: Chart
    problem: Problem                 # in the new coordinates (and independent variable)
    original: Problem
    back: MapEnclosure               # z -> x
    info: dict[str, Any]


def _enclosures(chart: Chart, p: np.ndarray) -> tuple[MapEnclosure, MapEnclosure]:
    m = chart.model
    fwd = MapEnclosure(f"{chart.name}_phi", m.x, chart.phi, m.p, p, chart.valid_x, chart.valid_why,
                       cache=chart.cached)
    back = MapEnclosure(f"{chart.name}_psi", chart.z, chart.psi, m.p, p, chart.valid_z,
                        chart.valid_why, cache=chart.cached)
    return fwd, back


def _initial_set_x(problem: Problem) -> Zonotope:
    S = problem.initial_set
    if S is None:
        return Zonotope(problem.x0)
    if isinstance(S, Zonotope):
        return S
    if isinstance(S, Interval):
        return S.to_zonotope()
    if hasattr(S, "to_zonotope"):
        return S.to_zonotope()
    if hasattr(S, "interval_hull"):
        return S.interval_hull().to_zonotope()
    raise ProblemError(f"coordinates: initial_set must be a zonotope, box or a set with "
                       f"interval_hull; got {type(S).__name__}")


def _drift_points(chart: Chart, z0: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Points near ``z0``: every coordinate moved by up to 10 % of its size (angles by a turn)."""
    n = z0.size
    scale = np.maximum(np.abs(z0), 1e-2)
    Z = z0 + 0.1 * scale * rng.uniform(-1, 1, (DRIFT_CHECK_POINTS, n))
    for i, unit in enumerate(chart.units):
        if unit == "rad":
            Z[:, i] = z0[i] + rng.uniform(-np.pi, np.pi, DRIFT_CHECK_POINTS)
    return Z


def _s_grid(chart: Chart, problem: Problem, w0: np.ndarray, spec: CoordinateSpec) -> tuple[np.ndarray, float]:
    """Grid of ``s``: nominal (coasting) ``s`` at the final time, ``steps`` steps per grid step,
    ``margin`` beyond; returns ``(grid, s at the final time)``."""
    from scipy.integrate import solve_ivp

    d = chart.dynamics
    fun = d.f_fun
    u0 = np.zeros(d.n_u)
    p = problem.params
    t_f = float(problem.grid[-1])
    s0 = float(w0[chart.independent]) if chart.independent is not None else 0.0

    def rhs(s, w):
        return np.asarray(fun(w, u0, s, p)).ravel()

    def reached(s, w):
        return w[-1] - t_f

    reached.terminal = True
    g0 = float(np.asarray(chart.function("scale")(w0, u0, p)).ravel()[0])
    if not g0 > 0:
        raise ProblemError(f"coordinates {chart.name!r}: dt/ds = {g0:g} <= 0 at the initial "
                           "state; the time cannot be reparametrised there")
    span = 10.0 * (t_f - float(problem.grid[0])) / g0 + 1.0
    sol = solve_ivp(rhs, (s0, s0 + span), w0, method="DOP853", rtol=1e-10, atol=1e-12,
                    events=reached)
    if not sol.t_events[0].size:
        raise ProblemError(f"coordinates {chart.name!r}: the coasting trajectory does not reach "
                           f"t = {t_f:g} within s = {s0 + span:g}")
    s_f = float(sol.t_events[0][0])
    K = problem.n_segments
    n_steps = max(1, int(np.ceil(K * spec.settings["steps"])))
    ds = (s_f - s0) / n_steps
    n_total = int(np.ceil(n_steps * (1 + spec.settings["margin"]))) + 1
    return s0 + ds * np.arange(n_total + 1), s_f


def transform(problem: Problem, spec: CoordinateSpec | str) -> Transformed:
    """``problem`` in the coordinates ``spec`` (module docstring, steps 1-2); every check is
    made here, before any propagation."""
    from ocreach.problem import Problem

    spec = parse(spec)
    if spec.name == "cartesian":
        raise ProblemError("coordinates 'cartesian': nothing to transform")
    if problem.stochastic is not None:
        raise ProblemError(f"coordinates {spec.name!r}: stochastic problems are not supported "
                           "(their Gaussian distributions are given in the model's coordinates)")
    if problem.backward:
        raise ProblemError(f"coordinates {spec.name!r}: problem {problem.id!r} has a backward grid; "
                           "only forward grids are supported")
    chart = chart_for(spec, problem.model, problem.x0, problem.control_set.kind)
    p = np.asarray(problem.params, dtype=float)
    fwd, back = _enclosures(chart, p)
    X0 = _initial_set_x(problem)
    try:
        Z0 = fwd.image(X0, max_pieces=1)
    except ChartDomainError as exc:
        raise ProblemError(f"coordinates {spec.name!r} are singular on the initial set of "
                           f"{problem.id!r}: {exc}") from None
    z0 = np.asarray(chart.function("phi")(problem.x0, p)).ravel()
    chart.check_forms(_drift_points(chart, z0, np.random.default_rng(0)), p, float(problem.grid[0]))
    info: dict[str, Any] = {"name": spec.name, "spec": str(spec), "description": chart.description,
                            "citation": chart.citation, "settings": dict(spec.settings),
                            "state_names": list(chart.dynamics.state_names),
                            "control_frame": "rtn" if chart.control_frame is not None else "model"}
    grid = problem.grid
    if chart.time_transformed:
        t0 = float(problem.grid[0])
        w0 = np.concatenate([z0, [t0]])
        Z0 = Z0.cartesian(Zonotope(np.array([t0])))
        grid, s_f = _s_grid(chart, problem, w0, spec)
        info.update({"independent": chart.s_name, "s_unit": chart.s_unit,
                     "s_grid": [float(grid[0]), float(grid[1] - grid[0]), int(grid.size - 1)],
                     "s_final_nominal": s_f})
    else:
        w0 = z0
    if not (Z0.interval_hull().contains(w0[None])[0]):
        w0 = np.asarray(Z0.c, dtype=float)
    n = chart.dynamics.n_x
    new = Problem(
        id=problem.id, model=chart.dynamics, x0=w0, grid=grid, params=p,
        control_set=problem.control_set, initial_set=Z0, units=problem.units,
        description=f"{problem.description} [in {chart.description}]", citation=problem.citation,
        method_options=problem.method_options, position_dims=tuple(range(min(3, n))),
        velocity_dims=tuple(range(min(3, n), min(6, n))),
        extra={**problem.extra, "coordinates_of": problem.id})
    return Transformed(spec, chart, new, problem, back, info)


# ------------------------------------------------------------------------------------------------
# results back in the model's coordinates
# ------------------------------------------------------------------------------------------------
class _Converter:
    def __init__(self, tr: Transformed):
        self.tr = tr
        self.kw = {"tol": tr.spec.settings["tol"], "max_pieces": tr.spec.settings["pieces"]}
        self.pieces: list[int] = []

    def __call__(self, sets: list) -> list:
        """The sets converted back (one batch of interval evaluations)."""
        out = self.tr.back.images(list(sets), **self.kw) if len(sets) else []
        self.pieces += [S.n_parts if isinstance(S, ZonotopeUnion) else 1 for S in out]
        return out


def _parts(S) -> list:
    if isinstance(S, ZonotopeUnion) or hasattr(S, "parts"):
        return [P if isinstance(P, Zonotope) else P.to_zonotope() for P in S.parts]
    if isinstance(S, Interval):
        return [S.to_zonotope()]
    return [S if isinstance(S, Zonotope) else S.to_zonotope()]


def _union(parts: list):
    flat = []
    for P in parts:
        flat.extend(P.parts if isinstance(P, ZonotopeUnion) else [P])
    return flat[0] if len(flat) == 1 else ZonotopeUnion(flat)


def _initial_x(problem: Problem):
    return problem.initial_set if problem.initial_set is not None else Zonotope(problem.x0)


def _convert_same_time(tr: Transformed, res: ReachResult, conv: _Converter) -> ReachResult:
    orig = tr.original
    sets = tubes = points = trajectories = None
    if res.sets is not None:
        sets = [_initial_x(orig)] + conv(res.sets[1:])
    if res.tubes is not None:
        tubes = conv(res.tubes)
    if res.points is not None:
        points = [tr.back.point(P) for P in res.points]
    if res.trajectories is not None:
        T = np.asarray(res.trajectories)
        trajectories = tr.back.point(T.reshape(-1, T.shape[-1])).reshape(T.shape[:-1] + (-1,))
    # controls of a rotated control frame are u' with u = R(x) u': not the model's piecewise
    # constant controls, so they are not passed on (the samples themselves are admissible states)
    controls = res.controls if tr.chart.control_frame is None else None
    return dataclasses.replace(res, times=orig.grid[: res.times.size], sets=sets, points=points,
                               tubes=tubes, trajectories=trajectories, controls=controls)


def _convert_time_transformed(tr: Transformed, res: ReachResult, conv: _Converter
                              ) -> tuple[ReachResult, bool]:
    """Sets at the grid times from the ``s``-tubes (module docstring, step 4); returns the result
    and whether every grid time was covered."""
    orig = tr.original
    row = tr.chart.model.n_x          # the time state
    if res.tubes is None or res.sets is None:
        raise SolverError(f"coordinates {tr.spec.name!r}: method {res.meta.get('method')!r} "
                          "returned no time-interval sets (tubes); the sets at the grid times of "
                          "a time-transformed chart are cut out of them")
    parts, ranges = [], []
    for T in res.tubes:
        for P in _parts(T):
            parts.append(P)
            ranges.append(time_range(P, row))
    ranges = np.asarray(ranges).reshape(-1, 2)
    t_done = min(time_range(P, row)[0] for P in _parts(res.sets[-1]))
    grid = orig.grid
    n_cov = int(np.searchsorted(grid, t_done, side="right"))   # grid times every trajectory passed
    n_cov = max(1, min(n_cov, grid.size))
    keep = np.arange(orig.model.n_x)
    owners, cuts = [], []
    for k in range(1, n_cov):
        tk = float(grid[k])
        for i in np.flatnonzero((ranges[:, 0] <= tk) & (tk <= ranges[:, 1])):
            C = slice_at(parts[i], row, tk)
            if C is not None:
                owners.append(k)
                cuts.append(C)
    found = set(owners)
    missing = [k for k in range(1, n_cov) if k not in found]
    if missing:
        raise SolverError(f"coordinates {tr.spec.name!r}: no s-tube covers t = {grid[missing[0]]:g}")
    by_time: list[list] = [[] for _ in range(n_cov)]
    for k, X in zip(owners, conv(cuts)):
        by_time[k].append(X)
    sets = [_initial_x(orig)] + [_union(by_time[k]) for k in range(1, n_cov)]
    tube_x = conv([P.project(keep) for P in parts])
    tubes = []
    for k in range(n_cov - 1):
        idx = np.flatnonzero((ranges[:, 0] <= grid[k + 1]) & (grid[k] <= ranges[:, 1]))
        tubes.append(_union([tube_x[i] for i in idx]))
    out = ReachResult(times=grid[:n_cov], sets=sets, tubes=tubes, meta=res.meta)
    return out, n_cov == grid.size


def _run_in_chart(method: Method, tr: Transformed) -> tuple[SolverError | None, ReachResult]:
    """``method`` on the problem in the chart: ``(None, result)`` or ``(error, partial result)``."""
    method._in_chart = True
    try:
        return None, method.solve(tr.problem)
    except SolverError as exc:
        if getattr(exc, "partial", None) is None:
            raise
        return exc, exc.partial
    finally:
        method._in_chart = False


def solve_in_coordinates(method: Method, problem: Problem, spec: str) -> ReachResult:
    """Run ``method`` on ``problem`` in the coordinates ``spec`` and return the result in the
    model's coordinates (module docstring)."""
    t_start = time.perf_counter()
    tr = transform(problem, spec)
    if tr.chart.time_transformed and getattr(method.options, "samples", None) is not None:
        raise ProblemError(f"coordinates {tr.spec.name!r} change the independent variable; the "
                           f"sample-based method {method.name!r} would report states at grid "
                           "points of s, not of t: use coordinates 'mee' (time kept) or "
                           "'cartesian' for sampling")
    if getattr(method.options, "disturbance", None) is not None:
        raise ProblemError(f"coordinates {tr.spec.name!r}: the disturbance option is given on "
                           f"dx/dt in the model's coordinates; it is not transformed (use "
                           "coordinates='cartesian')")
    t_prep = time.perf_counter() - t_start
    for attempt in range(MARGIN_RETRIES + 1):
        failure, res = _run_in_chart(method, tr)
        t_conv = time.perf_counter()
        conv = _Converter(tr)
        try:
            if tr.chart.time_transformed:
                out, complete = _convert_time_transformed(tr, res, conv)
            else:
                out = _convert_same_time(tr, res, conv)
                complete = out.times.size == problem.grid.size
        except ChartDomainError as exc:
            raise SolverError(f"coordinates {tr.spec.name!r}: {exc}") from None
        if complete or failure is not None or attempt == MARGIN_RETRIES:
            break
        # the s-grid ended before every trajectory reached the final time: a longer one
        margin = 2.0 * tr.spec.settings["margin"] + 0.25
        tr = transform(problem, CoordinateSpec(tr.spec.name, {**tr.spec.settings, "margin": margin}))
    meta = dict(out.meta)
    meta["runtime"] = {**meta.get("runtime", {}), "coordinates_setup": t_prep,
                       "coordinates_conversion": time.perf_counter() - t_conv}
    meta["problem"] = problem.id
    meta["coordinates"] = {**tr.info, "pieces_max": max(conv.pieces, default=1),
                           "pieces_total": int(sum(conv.pieces)),
                           "holds": ("sets and tubes in the model's coordinates: sound images of "
                                     "the method's sets in the chart"
                                     + ("; at grid times, slices of the s-tubes covering them"
                                        if tr.chart.time_transformed else ""))}
    if failure is not None or not complete:
        meta["truncated"] = True
    out = dataclasses.replace(out, meta=meta)
    if failure is not None or not complete:
        why = str(failure) if failure is not None else (
            f"the s-grid ended before every trajectory reached t = {problem.grid[-1]:g}; raise "
            f"the margin setting (coordinates={tr.spec.name}:margin=...)")
        err = SolverError(f"{method.name} in coordinates {tr.spec.name!r}: sets up to t = "
                          f"{out.times[-1]:.6g} of {problem.grid[-1]:.6g}: {why}")
        err.partial = out
        raise err
    return out
