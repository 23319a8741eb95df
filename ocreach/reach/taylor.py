"""``taylor``: guaranteed zonotope reachability by conservative linearisation (Patel & Subbarao
Method 1, Eq. 8-16; Althoff, Stursberg & Buss, CDC 2008).

Continuous time (``alg="ct"``, default): each step linearises at the set's centre moved by
``h/2 f``, bounds the Lagrange remainder (Eq. 10, 13) by the interval Hessian on the step's tube
and closes the fixed-point loop on that tube (:mod:`ocreach.reach.taylor_step`, items 1-4 of its
docstring, :func:`~ocreach.reach.taylor_step.ct_step`).  This module is the driver: the method
and its options, the checks and sets a run starts from (smoothness, initial set, control and
disturbance enclosures, variable mass), the grid loop over parts, and the results.

When the loop cannot close (the set is too large for the local linearisation) the step is halved
(sub-steps inside a grid step, ``max_halvings``), then the part is split in two along the generator
with the largest contribution to the remainder (``split``, ``max_parts``; Patel & Subbarao after
Eq. 16); each part is propagated on its own and the set at a time is the union of the parts
(:class:`ocreach.sets.union.ZonotopeUnion`).  A remainder above ``max_error`` also triggers a split.
If nothing is left to try, :class:`SolverError` names the step and remainder and carries the sets
computed so far in ``err.partial`` (a :class:`ReachResult` with ``meta["truncated"] = True``).

Discrete time (``alg="dt"``): the paper's literal Eq. 8-15 on the RK4 map
``x_{k+1} = g(x_k, u_k)`` of :mod:`ocreach.dynamics.discretize` (control held on each grid step):
``g(z) in g(z*) + J (z - z*) + L`` with ``L`` bounded by the interval Hessian of the RK4 map over
the box of ``R_k x U`` (:func:`~ocreach.reach.taylor_step.dt_step`), parts split like those of
``ct``.  Sound for the discrete model only (``meta["guaranteed_for"]``).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import OcreachError, ProblemError, SolverError, check_count, check_real
from ocreach.problem import ControlSet, Problem
from ocreach.reach.base import Method, requirements
from ocreach.reach.linsys import box_zonotope
from ocreach.reach.result import ReachResult
from ocreach.reach.taylor_step import Context, StepFail, TaylorError, ct_step, dt_step
from ocreach.sets.interval import Interval
from ocreach.sets.rounding import up
from ocreach.sets.union import ZonotopeUnion
from ocreach.sets.zonotope import Zonotope
from ocreach.units import G0  # standard gravity [m/s^2] of the exhaust velocity Isp g0

#: CasADi operations whose derivatives are not continuous: a Lagrange remainder over a box that
#: straddles the kink would be wrong, so models using them are refused (but see
#: :data:`TIME_SWITCH_OPS`).
NONSMOOTH_OPS = ("OP_FABS", "OP_SIGN", "OP_IF_ELSE_ZERO", "OP_FMIN", "OP_FMAX", "OP_FLOOR",
                 "OP_CEIL", "OP_FMOD", "OP_LT", "OP_LE", "OP_EQ", "OP_NE", "OP_COPYSIGN",
                 "OP_NOT", "OP_AND", "OP_OR")
#: The switches among them (piecewise constant results) that are accepted when they depend on
#: time alone: the condition of an ``if_else`` (its branches may depend on anything) and
#: comparisons / logic of time.  Sound because the interval evaluator decides every condition
#: over the step's closed time box ``[t, t + h]`` or raises (``undecided="error"``): on a step
#: that contains no switch time ``f`` is one smooth branch on the whole box and the Lagrange
#: remainder holds; a step whose closed box contains a switch time (also at its end) fails
#: (after the halvings, a :class:`SolverError`), never a wrong bound.  The ``alg="dt"`` RK4 map
#: evaluates ``f`` at fixed times, where every condition is decided.
TIME_SWITCH_OPS = ("OP_IF_ELSE_ZERO", "OP_LT", "OP_LE", "OP_EQ", "OP_NE", "OP_NOT", "OP_AND",
                   "OP_OR")
#: relative enlargement of the outer zonotope of the thrust ball (its facets' rounding)
BALL_MARGIN = 1e-12
#: relative margin on the largest throttle: the builders' ``||u||`` is ``sqrt(|u|^2 + eps)``
#: (``eps = 1e-30``), at most ``1 + eps / 2`` on the unit ball
THROTTLE_MARGIN = 1e-12
ALGS = ("ct", "dt")
REDUCTIONS = ("girard", "pca")
INPUT_SETS = ("auto", "zonotope", "box")


# ------------------------------------------------------------------------------------------------
# options shared by taylor and sdc
# ------------------------------------------------------------------------------------------------
@dataclass
class ZonotopeOptions:
    """Options of the zonotope methods (``taylor``, ``sdc``); every value is checked."""

    #: zonotope order (generators / n) after each step, >= 1
    order: float = 10.0
    #: order reduction: "girard" or "pca"
    reduction: str = "girard"
    #: remainder threshold (a number, or one per state, model units) above which a part is
    #: split (None: split only when the remainder loop cannot close)
    max_error: Any = None
    #: allow splitting a set into parts
    split: bool = True
    #: most parts at one time, >= 1
    max_parts: int = 64
    #: parts the initial set is split into before the first step (each split halves a part the
    #: way a failing part is halved, the part with the largest extent first), 1..max_parts; a
    #: large initial set whose curvature over the horizon no single linearisation follows
    #: (e.g. the coupled Van der Pol of the ARCH-COMP suite) is propagated piece by piece
    initial_parts: int = 1
    #: sub-steps per grid step to start with, >= 1
    substeps: int = 1
    #: how often a failing sub-step may be halved (adaptive steps, e.g. near perilune), >= 0
    max_halvings: int = 6
    #: enclosure of the control set: "zonotope" (outer zonotope of a thrust ball with
    #: input_generators generators), "box" (the box [-1, 1]^m, encloses a ball too), "auto"
    #: (the zonotope for a ball, the box for a box)
    input_set: str = "auto"
    #: generators of the ball's outer zonotope, >= n_u (None: 3 n_u)
    input_generators: int | None = None
    #: additive disturbance on dx/dt: a number w (the box +-w on the velocity rows, the paper's
    #: W_gen = w I_3), a sequence of n_x radii, or an Interval / Zonotope of dimension n_x
    disturbance: Any = None
    #: iterations of the remainder fixed-point loop, >= 1
    max_iter: int = 16
    #: enclose the propellant burn: the thrust acceleration in [0, T / m_min] with m_min = m0 -
    #: T / (Isp g0) t (full thrust all the way), the input set scaled by m0 / m_min (needs
    #: thrust_N, mass_kg, isp_s in problem.extra); False: a_max = T / m0 constant
    mass_varies: bool = False
    #: step-size control: a sub-step whose remainder widens the set by more than this fraction
    #: of its extent (plus the input's reach over the sub-step) is halved (at most max_halvings
    #: times), > 0; None: accept every sub-step whose remainder loop closes (problems with long
    #: grid steps set 0.1 in their method options, e.g. dro)
    growth_tol: float | None = None

    def __post_init__(self) -> None:
        self.order = check_real("order", self.order)
        if self.order < 1:
            raise ProblemError(f"order must be >= 1; got {self.order!r}")
        if self.reduction not in REDUCTIONS:
            raise ProblemError(f"reduction must be one of {REDUCTIONS}; got {self.reduction!r}")
        if self.max_error is not None:
            me = np.atleast_1d(np.asarray(self.max_error, dtype=float))
            if me.ndim != 1 or not np.all(np.isfinite(me)) or np.any(me <= 0):
                raise ProblemError(f"max_error must be None, a number > 0 or one number > 0 per "
                                   f"state; got {self.max_error!r}")
        if not isinstance(self.split, (bool, np.bool_)):
            raise ProblemError(f"split must be True or False; got {self.split!r}")
        self.max_parts = check_count("max_parts", self.max_parts, 1)
        self.initial_parts = check_count("initial_parts", self.initial_parts, 1)
        if self.initial_parts > self.max_parts:
            raise ProblemError(f"initial_parts must be <= max_parts = {self.max_parts}; got "
                               f"{self.initial_parts!r}")
        self.substeps = check_count("substeps", self.substeps, 1)
        self.max_halvings = check_count("max_halvings", self.max_halvings, 0)
        if self.input_set not in INPUT_SETS:
            raise ProblemError(f"input_set must be one of {INPUT_SETS}; got {self.input_set!r}")
        if self.input_generators is not None:
            self.input_generators = check_count("input_generators", self.input_generators, 1)
        self.max_iter = check_count("max_iter", self.max_iter, 1)
        if not isinstance(self.mass_varies, (bool, np.bool_)):
            raise ProblemError(f"mass_varies must be True or False; got {self.mass_varies!r}")
        if self.growth_tol is not None:
            self.growth_tol = check_real("growth_tol", self.growth_tol)
            if not self.growth_tol > 0:
                raise ProblemError(f"growth_tol must be > 0 or None; got {self.growth_tol!r}")


def check_smooth(model) -> None:
    """Raise :class:`ProblemError` if ``f`` uses an operation with a discontinuous derivative,
    other than a switch on time alone (:data:`TIME_SWITCH_OPS`)."""
    why = smoothness_problem(model)
    if why:
        raise ProblemError(why)


def smoothness_problem(model) -> str:
    """Why :func:`check_smooth` refuses ``model`` ("" if it does not)."""
    found = nonsmooth_ops(model)
    if not found:
        return ""
    return (f"model {model.name!r} is not smooth: f uses {found}; the Lagrange remainder of "
            "taylor/sdc needs twice continuously differentiable dynamics (replace "
            "fabs/if_else/fmin/fmax by smooth expressions; an if_else whose condition depends on "
            "time alone is accepted)")


def nonsmooth_ops(model) -> list[str]:
    """Names of the operations of ``f`` that :func:`check_smooth` refuses: every op of
    :data:`NONSMOOTH_OPS` except a switch of :data:`TIME_SWITCH_OPS` whose deciding operands (an
    ``if_else``'s condition, a comparison's or logic op's arguments) depend on ``t`` alone
    (dependencies traced through the instruction list of ``f(x, u, t, p)``)."""
    fun = ca.Function("f_check", [model.x, model.u, model.t, model.p], [model.f])
    codes = {getattr(ca, name): name for name in NONSMOOTH_OPS if hasattr(ca, name)}
    switches = {getattr(ca, name) for name in TIME_SWITCH_OPS if hasattr(ca, name)}
    time_only = frozenset({2})  # input 2 of f_check is t
    deps: dict[int, frozenset] = {}
    found = set()
    for k in range(fun.n_instructions()):
        op, ins, outs = fun.instruction_id(k), fun.instruction_input(k), fun.instruction_output(k)
        if op == ca.OP_OUTPUT:
            continue
        if op == ca.OP_INPUT:
            deps[outs[0]] = frozenset({ins[0]})
            continue
        d = [deps.get(i, frozenset()) for i in ins]
        if op in codes:
            deciding = d[:1] if op == ca.OP_IF_ELSE_ZERO else d
            if op not in switches or any(not s <= time_only for s in deciding):
                found.add(codes[op])
        dep = frozenset().union(*d)
        for o in outs:
            deps[o] = dep
    return sorted(found)


def initial_zonotope(problem: Problem) -> Zonotope:
    """The problem's initial set as a zonotope (the point ``x0`` if it has none)."""
    n = problem.model.n_x
    S = problem.initial_set
    if S is None:
        return Zonotope(problem.x0)
    if isinstance(S, Zonotope):
        Z = S
    elif isinstance(S, Interval):
        Z = S.to_zonotope()
    elif hasattr(S, "interval_hull"):  # e.g. an ellipsoid: its box (a sound enclosure)
        Z = S.interval_hull().to_zonotope()
    else:
        raise ProblemError(f"initial_set must be a Zonotope, Interval or a set with interval_hull; "
                           f"got {type(S).__name__}")
    if Z.dim != n:
        raise ProblemError(f"initial_set has dimension {Z.dim}; the model {problem.model.name!r} "
                           f"has n_x = {n} states {list(problem.model.state_names)}")
    return Z


def mass_scale(problem: Problem) -> float:
    """``m0 / m_min`` with ``m_min = m0 - T / (Isp g0) (t_f - t_0)``: the largest thrust
    acceleration over the horizon relative to the model's ``a_max = T / m0`` (full thrust all the
    time burns the most propellant), rounded up."""
    ex = problem.extra or {}
    vals = {k: ex.get(k) for k in ("thrust_N", "mass_kg", "isp_s")}
    units = problem.model.units
    missing = [k for k, v in vals.items() if v is None]
    if missing or units is None:
        raise ProblemError(f"mass_varies=True needs thrust_N, mass_kg and isp_s in problem.extra and "
                           f"model units; problem {problem.id!r} lacks "
                           f"{missing + ([] if units is not None else ['units'])}")
    if problem.model.throttle is not None or any(name in ("m", "mass")
                                                 for name in problem.model.state_names):
        raise ProblemError(f"mass_varies=True: model {problem.model.name!r} already has a mass "
                           "state (its thrust acceleration varies with it); use mass_varies=False")
    T, m0, isp = (float(vals[k]) for k in ("thrust_N", "mass_kg", "isp_s"))
    if not (T > 0 and m0 > 0 and isp > 0):
        raise ProblemError(f"mass_varies=True needs thrust_N, mass_kg, isp_s > 0; got {vals}")
    horizon_s = abs(float(problem.grid[-1] - problem.grid[0])) * units.time
    m_min = m0 - T / (isp * G0) * horizon_s
    if m_min <= 0:
        raise ProblemError(f"mass_varies=True: the propellant of m0 = {m0:g} kg lasts "
                           f"{m0 * isp * G0 / T / 86400:.4g} d at full thrust, less than the horizon "
                           f"{horizon_s / 86400:.4g} d")
    return float(up(m0 / m_min, 2))


def input_zonotope(problem: Problem, opts: ZonotopeOptions) -> tuple[Zonotope, str]:
    """Enclosure of the normalised control set and its description."""
    from ocreach.sets.convert import unit_ball_zonotope

    cs = problem.control_set
    m = cs.dim
    if cs.kind == "free":
        raise ProblemError(f"problem {problem.id!r} has a 'free' (unbounded) control set; taylor/sdc "
                           "need a bounded one ('ball' or 'box')")
    if opts.mass_varies:
        k = mass_scale(problem)
        V, desc = input_zonotope(problem, dataclasses.replace(opts, mass_varies=False))
        return (Zonotope(k * V.c, k * V.G),
                f"{desc}, scaled by m0/m_min = {k:.6g} (variable mass, mass_varies=True)")
    kind = opts.input_set
    if kind == "auto":
        kind = "zonotope" if cs.kind == "ball" else "box"
    if kind == "zonotope" and cs.kind == "box":
        kind = "box"
    if kind == "box":
        return Zonotope(np.zeros(m), np.eye(m)), f"box [-1, 1]^{m} enclosing the {cs.kind}"
    k = opts.input_generators or 3 * m
    if k < m:
        raise ProblemError(f"input_generators must be >= n_u = {m}; got {k}")
    # the ball touches the zonotope's facets from inside, up to the rounding of the computed facet
    # offsets (~1e-16 relative): a relative margin BALL_MARGIN makes the enclosure rigorous
    Z = unit_ball_zonotope(m, k)
    return (Zonotope(Z.c, Z.G * (1.0 + BALL_MARGIN)),
            f"zonotope ({k} generators) enclosing the unit ball")


def relax_throttle(problem: Problem, V: Zonotope) -> tuple[Problem, Zonotope, str]:
    """The problem with its throttle relaxed, the input set with the throttle's factor and its
    description; ``(problem, V, "")`` for a model without a throttle (:attr:`Model.throttle`).

    The mass flow ``dn/dt = T_max n^2 ||u|| / c`` (Patel & Scheeres Eq. 11) has no second
    derivative at ``u = 0``: the builders' ``sqrt(|u|^2 + 1e-30)`` has ``d^2/du^2 ~ 1e15`` there,
    so the interval Hessian of the remainder (Patel & Subbarao Eq. 13) over any control box
    around 0 is ~1e15 and the remainder loop diverges on the first step.  The step runs instead
    on :meth:`~ocreach.model.Model.throttle_relaxed`: ``||u||`` replaced by an independent input
    ``sigma in [0, sigma_max]`` (``sigma_max = 1`` on the ball, ``sqrt(n_u)`` on the box, plus
    :data:`THROTTLE_MARGIN`), in which ``f`` is smooth (the Hessian rows of ``n`` are then
    ``T_max n sigma / c`` and ``T_max n^2 / c``).  Every admissible control ``u`` is the relaxed
    control ``(u, ||u||)``, so every trajectory of the model is one of the relaxed system and its
    enclosure is an enclosure of the model's (the mass row loses only the coupling of the burn to
    the thrust direction)."""
    model = problem.model
    if model.throttle is None:
        return problem, V, ""
    sigma_max = float(up(problem.control_set.max_norm() * (1.0 + THROTTLE_MARGIN), 2))
    relaxed = model.throttle_relaxed(sigma_max)
    out = dataclasses.replace(problem, model=relaxed, control_set=ControlSet("box", relaxed.n_u))
    VS = V.cartesian(Zonotope(np.zeros(1), np.eye(1)))
    return out, VS, (f"; ||u|| of the mass flow as an independent throttle in [0, {sigma_max:.15g}] "
                     "(the relaxed model)")


def disturbance_zonotope(problem: Problem, W: Any) -> Zonotope | None:
    """The disturbance option as a zonotope in ``dx/dt`` space (see :class:`ZonotopeOptions`)."""
    if W is None:
        return None
    n = problem.model.n_x
    if isinstance(W, Interval):
        W = W.to_zonotope()
    if isinstance(W, Zonotope):
        if W.dim != n:
            raise ProblemError(f"disturbance must have dimension n_x = {n}; got {W.dim}")
        return W
    arr = np.atleast_1d(np.asarray(W, dtype=float))
    if arr.size == 1:
        r = np.zeros(n)
        r[list(problem.velocity_dims)] = float(arr[0])
    elif arr.shape == (n,):
        r = arr
    else:
        raise ProblemError(f"disturbance must be None, a number, {n} radii or an Interval/Zonotope "
                           f"of dimension {n}; got {W!r}")
    if not np.all(np.isfinite(r)) or np.any(r < 0):
        raise ProblemError(f"disturbance radii must be finite and >= 0; got {r!r}")
    return box_zonotope(np.zeros(n), r)


# ------------------------------------------------------------------------------------------------
# the driver: parts, adaptive sub-steps, splitting, results
# ------------------------------------------------------------------------------------------------
@dataclass
class Part:
    Z: Zonotope
    L: np.ndarray | None = None
    level: int = 0


def _as_set(parts: list[Zonotope]):
    return parts[0] if len(parts) == 1 else ZonotopeUnion(parts)


class ZonotopeReach:
    """Propagates parts over the grid with a step function (``ct_step``-like); shared by taylor/sdc."""

    def __init__(self, method: Method, problem: Problem, opts: ZonotopeOptions, error_model,
                 extra_meta: dict[str, Any]):
        """``error_model``: the error model's factory, called with the problem the steps run on
        (the throttle-relaxed one, :func:`relax_throttle`), or None (``poly`` builds its own)."""
        self.method = method
        self.opts = opts
        self.extra_meta = extra_meta
        V, self.input_desc = input_zonotope(problem, opts)
        self.input_kind = problem.control_set.kind
        problem, V, note = relax_throttle(problem, V)
        self.input_desc += note
        self.problem = problem
        self.err = None if error_model is None else error_model(problem)
        W = disturbance_zonotope(problem, opts.disturbance)
        self.ctx = Context(problem, opts, self.err, V, W)
        n = problem.model.n_x
        me = opts.max_error
        self.max_error = None
        if me is not None:
            if np.size(me) not in (1, n):
                raise ProblemError(f"max_error must be one number or {n} numbers (one per state); "
                                   f"got {me!r}")
            self.max_error = np.broadcast_to(np.atleast_1d(np.asarray(me, dtype=float)), (n,)).copy()

    def _reduce(self, Z: Zonotope) -> Zonotope:
        return Z.reduce(self.opts.order, self.opts.reduction)

    # hooks of the set representation (``poly`` propagates polynomial zonotopes through them)
    def step(self, Z, t: float, h: float, L: np.ndarray | None):
        """One sub-step of one part: :class:`StepOK` or :class:`StepFail`."""
        return ct_step(self.ctx, Z, t, h, L)

    def set_radius(self, S) -> np.ndarray:
        """Radius of the interval hull of a part's set, per state."""
        return np.abs(S.G).sum(axis=1)

    def refine(self, Z, h: float, res):
        """``res``, or a :class:`StepFail` to halve a sub-step whose error box widens the set by
        more than ``growth_tol`` of its extent (plus the input's reach over the step): a longer
        step would close the remainder loop, but the linearisation about one point of the step
        then charges the curvature of the step's own motion to the remainder (``1/2 |H| (h v)^2``
        over the tube's box, Patel & Subbarao Eq. 13), far above what shorter steps give (one
        0.1 TU step of the dro from a point: a remainder 100 times the thrust, which the next
        step cannot enclose)."""
        tol = self.opts.growth_tol
        if tol is None:
            return res
        grow = h * res.L
        size = self.set_radius(Z) + h * self.ctx.input_reach
        if np.any(grow > tol * size):
            i = int(np.argmax(grow / np.maximum(size, 1e-300)))
            return StepFail(f"the error box widens state {i} by {grow[i]:.3g}, more than growth_tol "
                            f"= {tol:g} of its extent {size[i]:.3g}")
        return res

    def reduce_point(self, S):
        return self._reduce(S)

    def reduce_tube(self, S):
        return self._reduce(S)

    def initial_set(self):
        return initial_zonotope(self.problem)

    def can_split_set(self, S) -> bool:
        return S.n_generators > 0

    def split_part(self, part: Part) -> tuple[Part, Part]:
        """The two halves of a failing part, split along the generator with the largest
        contribution to the remainder."""
        j = int(np.argmax(self.err.split_scores(part.Z)))
        a, b = part.Z.split(j)
        return Part(Z=a, L=None, level=part.level), Part(Z=b, L=None, level=part.level)

    def as_set(self, parts: list):
        return _as_set(parts)

    def as_tube(self, tubes: list):
        return _as_set(tubes)

    def _advance(self, part: Part, t0: float, t1: float, stats: dict) -> tuple[Part, list, StepFail | None]:
        """Carry ``part`` from ``t0`` to ``t1`` with sub-steps, halving failing ones."""
        opts = self.opts
        level = part.level
        t, Z, L = t0, part.Z, part.L
        tubes: list[Zonotope] = []
        base = (t1 - t0) / opts.substeps
        while t < t1 - 1e-12 * abs(t1 - t0):
            h = min(base / 2**level, t1 - t)
            res = self.step(Z, t, h, L)
            if not isinstance(res, StepFail) and level < opts.max_halvings:
                res = self.refine(Z, h, res)
            if isinstance(res, StepFail):
                if level < opts.max_halvings:
                    level += 1
                    L = None
                    continue
                return part, [], res
            stats["iterations"] = max(stats["iterations"], res.iterations)
            stats["substeps"] += 1
            stats["err"] = np.maximum(stats["err"], res.err_mag)
            if self.max_error is not None and np.any(res.err_mag > self.max_error) and self._can_split(stats):
                return part, [], StepFail(f"remainder {np.array2string(res.err_mag, precision=3)} "
                                          f"exceeds max_error", res.err_mag)
            tubes.append(self.reduce_tube(res.tube))
            Z = self.reduce_point(res.point)
            L = res.L
            t = t + h
        return Part(Z=Z, L=L, level=max(level - 1, 0)), tubes, None

    def _can_split(self, stats: dict) -> bool:
        return self.opts.split and stats["n_parts"] < self.opts.max_parts

    def initial_parts(self) -> list[Part]:
        """The parts :meth:`run` starts from: the problem's initial set, split into
        ``initial_parts`` parts by :meth:`split_part` (the part with the largest extent, the sum
        of its interval hull's widths relative to the initial set's in the states where that has
        a width, halved first; the halves of a split cover the part, so the parts cover the
        initial set)."""
        parts = [Part(Z=self.initial_set())]
        if self.opts.initial_parts == 1:
            return parts
        scale = self._extent(parts[0].Z)
        inv = np.divide(1.0, scale, out=np.zeros_like(scale), where=scale > 0)
        while len(parts) < self.opts.initial_parts:
            sizes = [float(self._extent(p.Z) @ inv) if self.can_split_set(p.Z) else -1.0
                     for p in parts]
            i = int(np.argmax(sizes))
            if sizes[i] < 0:
                break
            parts[i:i + 1] = list(self.split_part(parts[i]))
        return parts

    def _extent(self, S) -> np.ndarray:
        """Widths of the interval hull of a part's set."""
        return 2.0 * np.abs(self.as_set([S]).to_zonotope().G).sum(axis=1)

    def advance_grid_step(self, parts: list[Part], t0: float, t1: float
                          ) -> tuple[list[Part], list[Zonotope], dict[str, Any], StepFail | None]:
        """Carry every part from ``t0`` to ``t1`` (sub-steps, halvings, splits): the parts at
        ``t1``, the sub-step tubes, the step's statistics and the failure that ended it (None if
        the step succeeded).  One grid step of :meth:`run`; the hybrid runner steps with it."""
        stats = {"iterations": 0, "substeps": 0, "err": np.zeros(self.problem.model.n_x),
                 "n_parts": len(parts), "splits": 0}
        queue = list(parts)
        done: list[Part] = []
        step_tubes: list[Zonotope] = []
        while queue:
            part = queue.pop()
            new, tb, fail = self._advance(part, t0, t1, stats)
            if fail is None:
                done.append(new)
                step_tubes.extend(tb)
                continue
            if self._can_split(stats) and self.can_split_set(part.Z):
                queue += list(self.split_part(part))
                stats["n_parts"] += 1
                stats["splits"] += 1
                continue
            return done, step_tubes, stats, fail
        return done, step_tubes, stats, None

    def run(self) -> ReachResult:
        prob = self.problem
        grid = prob.grid
        if prob.backward:
            raise ProblemError(f"problem {prob.id!r} has a backward grid; taylor/sdc propagate "
                               "forward in time only")
        t_start = time.perf_counter()
        parts = self.initial_parts()
        sets: list[Any] = [self.as_set([p.Z for p in parts])]
        tubes: list[Any] = []
        meta_steps: dict[str, list] = {"remainder": [], "iterations": [], "splits": [], "substeps": [],
                                       "parts": []}
        for k in range(grid.size - 1):
            t0, t1 = float(grid[k]), float(grid[k + 1])
            done, step_tubes, stats, fail = self.advance_grid_step(parts, t0, t1)
            if fail is not None:
                self._fail(k, t0, t1, fail, stats, sets, tubes, meta_steps, t_start)
            parts = done
            sets.append(self.as_set([p.Z for p in parts]))
            tubes.append(self.as_tube(step_tubes))
            meta_steps["remainder"].append(stats["err"].tolist())
            meta_steps["iterations"].append(stats["iterations"])
            meta_steps["splits"].append(stats["splits"])
            meta_steps["substeps"].append(stats["substeps"])
            meta_steps["parts"].append(len(parts))
        return self._result(grid, sets, tubes, meta_steps, t_start, truncated=False)

    def _result(self, times, sets, tubes, meta_steps, t_start, truncated: bool) -> ReachResult:
        meta = self.method.base_meta(self.problem, {"propagation": time.perf_counter() - t_start})
        meta.update({
            "guaranteed": True, "truncated": truncated, "input_set": self.input_kind,
            "input_enclosure": self.input_desc, "steps": meta_steps,
            "max_parts_used": max(meta_steps["parts"], default=1),
        })
        meta.update(self.extra_meta)
        if self.opts.disturbance is not None:
            meta["disturbance"] = repr(self.opts.disturbance)
        return ReachResult(times=np.asarray(times)[: len(sets)], sets=sets, tubes=tubes, meta=meta)

    def _fail(self, k, t0, t1, fail: StepFail, stats, sets, tubes, meta_steps, t_start):
        partial = self._result(self.problem.grid, sets, tubes, meta_steps, t_start, truncated=True)
        partial.meta["failure"] = fail.reason
        err = SolverError(
            f"{self.method.name}: step {k} [t = {t0:.6g} .. {t1:.6g}] cannot be enclosed: {fail.reason}; "
            f"{stats['n_parts']} part(s) in use (max_parts = {self.opts.max_parts}, split = "
            f"{self.opts.split}), the sub-step was halved {self.opts.max_halvings} times. "
            f"Sets up to t = {t0:.6g} are in err.partial. To go further: raise max_parts, "
            "max_halvings or order, use a smaller initial set or a shorter grid step")
        err.partial = partial
        raise err


# ------------------------------------------------------------------------------------------------
# discrete time: the paper's literal Eq. 8-15 on the RK4 map
# ------------------------------------------------------------------------------------------------
class DiscreteTaylor:
    """Eq. 8-15 on ``x_{k+1} = g(x_k, u_k)`` (RK4, control held on each grid step): the grid loop
    over parts of :func:`~ocreach.reach.taylor_step.dt_step`, splitting a part whose step fails or
    whose remainder exceeds ``max_error``."""

    def __init__(self, method: Method, problem: Problem, opts, n_sub: int):
        self.method, self.opts, self.n_sub = method, opts, n_sub
        V, self.input_desc = input_zonotope(problem, opts)
        self.input_kind = problem.control_set.kind
        self.problem, self.V, note = relax_throttle(problem, V)
        self.input_desc += note
        self.W = disturbance_zonotope(problem, opts.disturbance)
        n = problem.model.n_x
        if opts.max_error is not None and np.size(opts.max_error) not in (1, n):
            raise ProblemError(f"max_error must be one number or {n} numbers (one per state); "
                               f"got {opts.max_error!r}")

    def run(self) -> ReachResult:
        prob = self.problem
        if prob.backward:
            raise ProblemError(f"problem {prob.id!r} has a backward grid; taylor propagates forward only")
        t_start = time.perf_counter()
        grid = prob.grid
        parts = [initial_zonotope(prob)]
        sets: list[Any] = [parts[0]]
        rem, splits = [], []
        for k in range(grid.size - 1):
            t0, h = float(grid[k]), float(grid[k + 1] - grid[k])
            queue, done, err_k, n_split = list(parts), [], np.zeros(prob.model.n_x), 0
            while queue:
                Z = queue.pop()
                try:
                    out, e = dt_step(prob, self.V, self.W, self.n_sub, Z, t0, h)
                except OcreachError as exc:
                    out, e = None, None
                    reason = str(exc)
                too_big = (e is not None and self.opts.max_error is not None
                           and np.any(e > np.broadcast_to(np.asarray(self.opts.max_error, float),
                                                          e.shape)))
                if (out is None or too_big) and self.opts.split and \
                        len(parts) + n_split < self.opts.max_parts and Z.n_generators:
                    queue += list(Z.split())
                    n_split += 1
                    continue
                if out is None:
                    meta = self._meta(t_start, rem, splits, truncated=True)
                    partial = ReachResult(times=grid[: len(sets)], sets=sets, meta=meta)
                    exc2 = SolverError(f"taylor (alg='dt'): step {k} at t = {t0:.6g}: {reason}; "
                                       "sets so far in err.partial; raise max_parts or shorten the step")
                    exc2.partial = partial
                    raise exc2
                done.append(out.reduce(self.opts.order, self.opts.reduction))
                err_k = np.maximum(err_k, e)
            parts = done
            sets.append(_as_set(parts))
            rem.append(err_k.tolist())
            splits.append(n_split)
        return ReachResult(times=grid, sets=sets, meta=self._meta(t_start, rem, splits, False))

    def _meta(self, t_start, rem, splits, truncated):
        meta = self.method.base_meta(self.problem, {"propagation": time.perf_counter() - t_start})
        meta.update({"guaranteed": True, "guaranteed_for": f"the discrete RK4 model (control held on "
                     f"each grid step, {self.n_sub} RK4 sub-steps); not an enclosure of the "
                     "continuous-time flow", "truncated": truncated, "alg": "dt",
                     "input_set": self.input_kind, "input_enclosure": self.input_desc,
                     "steps": {"remainder": rem, "splits": splits}})
        return meta


class TaylorZonotope(Method):
    """Patel & Subbarao Method 1: zonotopes by conservative linearisation with a Lagrange remainder."""

    name = "taylor"
    guaranteed = True
    description = ("guaranteed zonotope enclosure by conservative linearisation + interval Lagrange "
                   "remainder (Patel & Subbarao Method 1; Althoff CDC 2008)")

    @dataclass
    class Options(ZonotopeOptions):
        """:class:`ZonotopeOptions` plus the time discretisation."""

        #: "ct" (continuous time, sound for the flow) or "dt" (the paper's discrete Eq. 8-15 on
        #: the RK4 map, sound for that map only)
        alg: str = "ct"
        #: RK4 sub-steps per grid step of the "dt" map, >= 1
        rk4_substeps: int = 4

        def __post_init__(self) -> None:
            super().__post_init__()
            if self.alg not in ALGS:
                raise ProblemError(f"alg must be one of {ALGS}; got {self.alg!r}")
            self.rk4_substeps = check_count("rk4_substeps", self.rk4_substeps, 1)

    @classmethod
    def applicable(cls, problem: Problem) -> tuple[bool, str]:
        """A bounded control set, a forward grid and smooth dynamics (:func:`nonsmooth_ops`)."""
        ok, why = requirements(problem, bounded=True)
        if not ok:
            return ok, why
        if problem.backward:
            return False, "the grid runs backward in time; taylor/sdc/poly propagate forward only"
        why = smoothness_problem(problem.model)
        return not why, why

    def solve(self, problem: Problem) -> ReachResult:
        if self.options.alg == "dt":
            check_smooth(problem.model)
            initial_zonotope(problem)  # wrong dimension -> clear error before any work
            return DiscreteTaylor(self, problem, self.options, self.options.rk4_substeps).run()
        return self.reacher(problem).run()

    def reacher(self, problem: Problem) -> ZonotopeReach:
        """The continuous-time propagator of ``problem`` (checked), run by :meth:`solve` and
        stepped grid step by grid step by the hybrid runner (:mod:`ocreach.reach.hybrid`)."""
        if self.options.alg != "ct":
            raise ProblemError(f"taylor: the continuous-time propagator needs alg='ct'; got "
                               f"alg={self.options.alg!r} (the RK4 map of 'dt' has no tubes)")
        check_smooth(problem.model)
        initial_zonotope(problem)  # wrong dimension -> clear error before any work
        return ZonotopeReach(self, problem, self.options,
                             lambda prob: TaylorError(prob.model, prob.params), {"alg": "ct"})

