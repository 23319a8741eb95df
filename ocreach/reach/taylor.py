"""``taylor``: guaranteed zonotope reachability by conservative linearisation (Patel & Subbarao
Method 1, Eq. 8-16; Althoff, Stursberg & Buss, CDC 2008).

Continuous time (``alg="ct"``, default).  On a step ``[t, t + h]`` from the zonotope ``R``:

1. linearise at ``z* = (x*, v*)`` with ``x* = c + h/2 f(c, v_c)`` (CORA's ``lin`` scheme) and
   ``v* = v_c``, the input set's centre; ``v = u`` (and ``t`` if ``f`` depends on time, with the
   input box ``[t, t + h]``);
2. ``f(x, v) = f(z*) + A (x - x*) + B (v - v*) + L(x, v)`` with the Lagrange remainder
   ``L_i = 1/2 (z - z*)^T H_i(zeta) (z - z*)`` (Eq. 10, 13), bounded over a box by the interval
   Hessian (:mod:`ocreach.intervals`) and interval products (tighter than Eq. 14-15 but the same
   idea: ``|L_i| <= 1/2 gamma^T max|H_i| gamma``);
3. the linear system ``d' = A d + u_c + w``, ``w in B (V - v_c) + W + L``, is stepped exactly up to
   the exponential-matrix remainder (:mod:`ocreach.reach.linsys`), giving the time-point set
   ``R(t + h)`` and the time-interval set ``R([t, t + h])``;
4. the remainder is bounded on the interval hull of ``R([t, t + h]) x V`` -- a set that depends on
   the remainder -- by the fixed-point loop: guess a box ``[-Lbar, Lbar]``, compute the tube with
   it, bound ``L`` on (a slightly inflated box of) that tube, and enlarge ``Lbar`` until the bound
   lies inside it.  Then every trajectory stays in the tube (it cannot leave the inflated box
   first: while inside, its remainder is within ``Lbar``, so it is a solution of the linear
   inclusion and therefore inside the tube), and the final sets are recomputed with the tighter
   bound ``L`` found on the tube.

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
the box of ``R_k x U``.  Sound for the discrete model only (``meta["guaranteed_for"]``).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import OcreachError, ProblemError, SolverError, check_count, check_real
from ocreach.fastcall import FastFunction
from ocreach.problem import Problem
from ocreach.reach.base import Method
from ocreach.reach.linsys import (
    abs_extent,
    all_finite,
    box_zonotope,
    diag_columns,
    expm_terms,
    homogeneous_step,
    input_generators,
    pad,
    set_abs,
    state_maps,
    step_rounding,
    weighted_sum,
)
from ocreach.reach.result import ReachResult
from ocreach.sets.interval import Interval
from ocreach.sets.rounding import rounding_radius, up
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
#: relative inflation of the box on which the remainder is bounded (the continuity argument)
BOX_INFLATE = 1e-9
#: relative enlargement of the outer zonotope of the thrust ball (its facets' rounding)
BALL_MARGIN = 1e-12
#: growth factor of the guessed remainder in the fixed-point loop
GROWTH = 1.25
ALGS = ("ct", "dt")
REDUCTIONS = ("girard", "pca")
INPUT_SETS = ("auto", "zonotope", "box")


# ------------------------------------------------------------------------------------------------
# options shared by taylor and sdc
# ------------------------------------------------------------------------------------------------
@dataclass
class ZonotopeOptions:
    """Options of the zonotope methods (``taylor``, ``sdc``); every value is checked.

    * ``order`` (10): zonotope order (generators / n) after each step, >= 1;
    * ``reduction`` ("girard"): order reduction, ``"girard"`` or ``"pca"``;
    * ``max_error`` (None): remainder threshold (a number, or one per state) above which a part is
      split; None = split only when the remainder loop cannot close;
    * ``split`` (True): allow splitting; ``max_parts`` (64): most parts at one time;
    * ``substeps`` (1): sub-steps per grid step to start with; ``max_halvings`` (6): how often a
      failing sub-step may be halved (adaptive steps, e.g. near perilune);
    * ``input_set`` ("auto"): enclosure of the control set -- ``"zonotope"`` (outer zonotope of the
      thrust ball with ``input_generators`` generators), ``"box"`` (the box ``[-1, 1]^m``, encloses
      the ball too), ``"auto"`` (zonotope for a ball, the box for a box);
    * ``input_generators`` (None): generators of the ball enclosure (default ``3 n_u``, >= n_u);
    * ``disturbance`` (None): additive disturbance on ``dx/dt``: a number ``w`` (the box ``+-w`` on
      the velocity rows, the paper's ``W_gen = w I_3``), a sequence of ``n_x`` radii, or an
      ``Interval``/``Zonotope`` of dimension ``n_x``;
    * ``max_iter`` (16): iterations of the remainder fixed-point loop;
    * ``mass_varies`` (False): the model's thrust acceleration ``a_max = T / m0`` is constant; with
      True the propellant burn is enclosed: the mass stays above ``m_min = m0 - T / (Isp g0) t``
      (full thrust over the whole horizon), so the thrust acceleration is in ``[0, T / m_min]``
      and the input set is scaled by ``m0 / m_min`` (:func:`mass_scale`; needs ``thrust_N``,
      ``mass_kg``, ``isp_s`` in ``problem.extra`` and model units).
    """

    order: float = 10.0
    reduction: str = "girard"
    max_error: Any = None
    split: bool = True
    max_parts: int = 64
    substeps: int = 1
    max_halvings: int = 6
    input_set: str = "auto"
    input_generators: int | None = None
    disturbance: Any = None
    max_iter: int = 16
    mass_varies: bool = False

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
        self.substeps = check_count("substeps", self.substeps, 1)
        self.max_halvings = check_count("max_halvings", self.max_halvings, 0)
        if self.input_set not in INPUT_SETS:
            raise ProblemError(f"input_set must be one of {INPUT_SETS}; got {self.input_set!r}")
        if self.input_generators is not None:
            self.input_generators = check_count("input_generators", self.input_generators, 1)
        self.max_iter = check_count("max_iter", self.max_iter, 1)
        if not isinstance(self.mass_varies, (bool, np.bool_)):
            raise ProblemError(f"mass_varies must be True or False; got {self.mass_varies!r}")


def check_smooth(model) -> None:
    """Raise :class:`ProblemError` if ``f`` uses an operation with a discontinuous derivative,
    other than a switch on time alone (:data:`TIME_SWITCH_OPS`)."""
    found = nonsmooth_ops(model)
    if found:
        raise ProblemError(f"model {model.name!r} is not smooth: f uses {found}; the Lagrange "
                           "remainder of taylor/sdc needs twice continuously differentiable "
                           "dynamics (replace fabs/if_else/fmin/fmax by smooth expressions; an "
                           "if_else whose condition depends on time alone is accepted)")


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
    if any(name in ("m", "mass") for name in problem.model.state_names):
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
# the model functions (built once, cached on the model)
# ------------------------------------------------------------------------------------------------
def time_dependent(model) -> bool:
    return bool(ca.depends_on(model.f, model.t))


def z_symbol(model) -> ca.SX:
    """``z = (x, u)``, plus ``t`` when ``f`` depends on time."""
    return ca.vertcat(model.x, model.u, model.t) if time_dependent(model) else ca.vertcat(model.x, model.u)


def lin_fun(model) -> ca.Function:
    """``(x, u, t, p) -> (f, df/dx, df/dv)`` with ``v = u`` or ``(u, t)``."""
    def build():
        v = ca.vertcat(model.u, model.t) if time_dependent(model) else model.u
        return ca.Function("taylor_lin", [model.x, model.u, model.t, model.p],
                           [model.f, ca.jacobian(model.f, model.x), ca.jacobian(model.f, v)])
    return model.cached(("taylor", "lin"), build)


def hessian_interval(model):
    """Interval extension of ``(f, df/dx, df/dv, H)`` with the Hessian ``H = d^2 f_i / dz_a dz_b``
    (flat ``(n_x n_z, n_z)``), ``v = u`` or ``(u, t)``: one call bounds the Hessian over the tube's
    box and, on a second (point) box, the rounding of the float ``f``, ``A``, ``B`` at ``z*``."""
    from ocreach.intervals import interval_function

    def build():
        z = z_symbol(model)
        v = ca.vertcat(model.u, model.t) if time_dependent(model) else model.u
        J = ca.jacobian(model.f, z)
        H = ca.jacobian(ca.reshape(J.T, -1, 1), z)
        return ca.Function("taylor_hess", [model.x, model.u, model.t, model.p],
                           [model.f, ca.jacobian(model.f, model.x), ca.jacobian(model.f, v), H])

    fun = model.cached(("taylor", "lin_hess_fun"), build)
    return interval_function(fun, model=model, key=("taylor", "lin_hess"), native=True)


def dense(a: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Column ``(rows cols,)`` of a flat column-major interval output as a ``(rows, cols)`` matrix."""
    return a.reshape(cols, rows).T


def eval_error(iv: list, lin: tuple, gx: np.ndarray, gv: np.ndarray) -> np.ndarray:
    """Bound of ``|f(z*) - f0| + |J_x(z*) - A| gx + |J_v(z*) - B| gv``: the error of the float
    linearisation ``(f0, A, B)`` (CasADi, not rounded outward) against the interval enclosures
    ``iv = [(flo, fhi), (Jlo, Jhi), (Blo, Bhi)]`` at the point ``z*`` (column 0 of each), for the
    deviations ``|x - x*| <= gx``, ``|v - v*| <= gv``.  Added to the remainder it makes the
    expansion ``f(z) in f0 + A (x - x*) + B (v - v*) + L`` rigorous."""
    f0, A, B = (np.asarray(a, dtype=float) for a in lin)
    f0 = f0.ravel()
    n = f0.size

    def rad(lo, hi, mid):
        return up(np.maximum(hi - mid, mid - lo), 1)

    (flo, fhi), (Jlo, Jhi), (Blo, Bhi) = iv
    rf = rad(flo[:, 0], fhi[:, 0], f0)
    rA = rad(dense(Jlo[:, 0], n, A.shape[1]), dense(Jhi[:, 0], n, A.shape[1]), A)
    rB = rad(dense(Blo[:, 0], n, B.shape[1]), dense(Bhi[:, 0], n, B.shape[1]), B)
    return up(rf + rA @ gx + rB @ gv, A.shape[1] + B.shape[1] + 2)


def unflatten_hessian(lo: np.ndarray, n_x: int, n_z: int) -> np.ndarray:
    """``(n_x n_z n_z, B)`` column-major flat ``(n_x n_z, n_z)`` -> ``(B, n_x, n_z, n_z)``."""
    B = lo.shape[-1]
    return lo.reshape(n_z, n_x, n_z, B).transpose(3, 1, 2, 0)


def quadratic_interval(Hlo: np.ndarray, Hhi: np.ndarray, dlo: np.ndarray, dhi: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Interval of ``1/2 d^T H_i d`` for ``H_i in [Hlo_i, Hhi_i]`` (n_x, n_z, n_z) and ``d in [dlo, dhi]``
    (n_z,): interval products termwise, the squares on the diagonal; outward margin 1e-12 of the
    magnitude (floating point of these few products).  The corner products of ``d_a d_b`` and of
    ``H_iab [d_a d_b]`` are formed as one stacked array each (the same products; min/max exact)."""
    D = np.stack([dlo, dhi])
    P = (D[:, None, :, None] * D[None, :, None, :]).reshape(4, dlo.size, dlo.size)
    Pp = np.stack([P.min(axis=0), P.max(axis=0)])      # [plo, phi]
    absD = np.abs(D)
    mag = absD.max(axis=0)
    mig = np.where((dlo <= 0) & (dhi >= 0), 0.0, absD.min(axis=0))
    idx = np.arange(dlo.size)
    Pp[0, idx, idx] = mig**2
    Pp[1, idx, idx] = mag**2
    Hs = np.stack([Hlo, Hhi])
    cands = Hs[:, None] * Pp[None, :, None]          # [Hlo plo, Hlo phi, Hhi plo, Hhi phi]
    lo = 0.5 * cands.min(axis=(0, 1)).sum(axis=(1, 2))
    hi = 0.5 * cands.max(axis=(0, 1)).sum(axis=(1, 2))
    Hmag = np.abs(Hs).max(axis=0)
    m = 0.5e-12 * (Hmag * np.outer(mag, mag)[None]).sum(axis=(1, 2))
    return lo - m - 1e-300, hi + m + 1e-300


def interval_box(lo: np.ndarray, hi: np.ndarray) -> Zonotope:
    """The box ``[lo, hi]`` as a zonotope, its centre and radius rounded so that it contains
    ``[lo, hi]`` (the radius is widened by the rounding of the centre)."""
    c = 0.5 * (lo + hi)
    r = up(np.maximum(hi - c, c - lo), 1)
    return box_zonotope(c, r)


def tube_box(tube: Zonotope, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inflated interval hull of ``tube`` and the point ``xs`` (:func:`inflate_box`)."""
    r = np.abs(tube.G).sum(axis=1)
    return inflate_box(np.minimum(tube.c - r, xs), np.maximum(tube.c + r, xs))


def inflate_box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = BOX_INFLATE * (hi - lo) + 1e-15 * np.maximum(np.abs(lo), np.abs(hi)) + 1e-300
    return lo - w, hi + w


# ------------------------------------------------------------------------------------------------
# error models: the set of the nonlinear remainder over a tube
# ------------------------------------------------------------------------------------------------
class TaylorError:
    """Lagrange remainder of the first-order expansion, bounded by the interval Hessian (Eq. 13)."""

    #: :meth:`bound` reads only the interval hull of the tube (the driver may pass a box)
    box_only = True

    def __init__(self, model, p: np.ndarray):
        self.model = model
        self.p = np.asarray(p, dtype=float)
        self.td = time_dependent(model)
        self.H = hessian_interval(model)
        self.n_z = model.n_x + model.n_u + (1 if self.td else 0)
        self.sizes = (model.n_x, model.n_u)
        self.hmag: np.ndarray | None = None

    def bound(self, tube: Zonotope, xs: np.ndarray, vs: np.ndarray, Vbox: tuple, t_box: tuple,
              lin: tuple) -> Zonotope:
        """Box (as a zonotope) enclosing ``f(z) - f0 - A (x - x*) - B (v - v*)`` for every ``x`` in
        the tube's box and ``v`` in ``V``: the Lagrange remainder ``L`` plus the rounding error of
        the float linearisation ``lin = (f0, A, B)`` (:func:`eval_error`)."""
        nx, nu = self.sizes
        xlo, xhi = tube_box(tube, xs)
        ulo, uhi = Vbox
        tlo, thi = t_box
        uc = vs[: nu]
        ts = vs[-1] if self.td else tlo
        out = self.H([np.stack([xs, xlo], axis=1), np.stack([uc, ulo], axis=1), np.array([ts, tlo]),
                      self.p],
                     [np.stack([xs, xhi], axis=1), np.stack([uc, uhi], axis=1), np.array([ts, thi]),
                      self.p], check=False)
        Hlo, Hhi = out[3]
        Hlo = unflatten_hessian(Hlo[:, 1:], nx, self.n_z)[0]
        Hhi = unflatten_hessian(Hhi[:, 1:], nx, self.n_z)[0]
        zs = np.concatenate([xs, vs])
        zlo = np.concatenate([xlo, ulo] + ([[tlo]] if self.td else []))
        zhi = np.concatenate([xhi, uhi] + ([[thi]] if self.td else []))
        dlo, dhi = zlo - zs, zhi - zs
        lo, hi = quadratic_interval(Hlo, Hhi, dlo, dhi)
        gz = up(np.maximum(np.abs(dlo), np.abs(dhi)), 1)
        e = eval_error(out[:3], lin, gz[: nx], gz[nx:])
        lo, hi = lo - e, hi + e
        self.hmag = np.maximum(np.abs(Hlo), np.abs(Hhi))[:, : nx, : nx].sum(axis=0)
        self.gamma = np.maximum(np.abs(dlo), np.abs(dhi))[: nx]
        return interval_box(lo, hi)

    def split_scores(self, Z: Zonotope) -> np.ndarray:
        """Contribution of each generator of ``Z`` to the remainder: ``|g_j|^T sum_i |H_i| gamma``."""
        if self.hmag is None:
            return np.linalg.norm(Z.G, axis=0)
        return np.abs(Z.G).T @ (self.hmag @ self.gamma)


# ------------------------------------------------------------------------------------------------
# one continuous-time step of one part
# ------------------------------------------------------------------------------------------------
@dataclass
class StepOK:
    point: Zonotope
    tube: Zonotope
    L: np.ndarray          # radius of the applied remainder box (for the next warm start)
    err_mag: np.ndarray    # max |error| per state
    iterations: int


@dataclass
class StepFail:
    reason: str
    err_mag: np.ndarray | None = None


class Context:
    """Everything a step needs: model functions, inputs, error model, options."""

    def __init__(self, problem: Problem, opts: ZonotopeOptions, error_model, V: Zonotope,
                 W: Zonotope | None):
        self.problem = problem
        self.model = problem.model
        self.p = np.asarray(problem.params, dtype=float)
        self.opts = opts
        self.err = error_model
        self.V = V
        self.W = W
        self.td = time_dependent(self.model)
        self.lin = FastFunction(lin_fun(self.model))  # one per run: not re-entrant
        hull = V.interval_hull()
        self.Ubox = inflate_box(hull.lo, hull.hi)   # the hull's rounding


def ct_step(ctx: Context, R: Zonotope, t0: float, h: float, L_guess: np.ndarray | None
            ) -> StepOK | StepFail:
    """One continuous-time step (module docstring, items 1-4)."""
    m = ctx.model
    n = m.n_x
    uc = ctx.V.c
    f_c = ctx.lin(R.c, uc, t0, ctx.p)[0].ravel()
    xs = R.c + 0.5 * h * f_c
    ts = t0 + 0.5 * h
    f0, A, Bv = ctx.lin(xs, uc, ts, ctx.p)
    override = getattr(ctx.err, "linearize", None)  # sdc's literal variant linearises differently
    alt = override(xs, uc, ts) if override is not None else None
    if alt is not None:
        f0, A, Bv = (np.asarray(a) for a in alt)
    f0 = f0.ravel()
    if not (np.all(np.isfinite(f0)) and np.all(np.isfinite(A)) and np.all(np.isfinite(Bv))):
        return StepFail(f"f or its Jacobian is not finite at the linearisation point {xs}")
    vs = np.concatenate([uc, [ts]]) if ctx.td else uc
    # uncertain input (centred at 0): B (V - v_c) [x (t - t*)] + (W - w_c)
    Gv = ctx.V.G
    if ctx.td:
        Gv = np.zeros((ctx.V.dim + 1, ctx.V.n_generators + 1))
        Gv[:-1, :-1] = ctx.V.G
        Gv[-1, -1] = 0.5 * h
    Gu = Bv @ Gv
    u_c = f0.copy()
    if ctx.W is not None:
        u_c = u_c + ctx.W.c
        Gu = np.hstack([Gu, ctx.W.G])
    # absolute values of the step's inputs for the floating-point bound (linsys.step_rounding)
    u_abs0 = np.abs(f0) + (np.abs(ctx.W.c) if ctx.W is not None else 0.0)
    W_abs0 = np.abs(Bv) @ np.abs(Gv).sum(axis=1)
    if ctx.W is not None:
        W_abs0 = W_abs0 + np.abs(ctx.W.G).sum(axis=1)
    n_sum = max(R.n_generators, Gu.shape[1] + n) + Gv.shape[0] + 2
    lin = (f0, A, Bv)
    try:
        et = expm_terms(A, h)
    except SolverError as exc:
        return StepFail(str(exc))
    R0 = Zonotope.trusted(R.c - xs, R.G)
    maps = state_maps(R0, et)
    hs = homogeneous_step(R0, u_c, et, maps, with_point=False)
    base_tube = Zonotope.trusted(hs.tube.c, np.concatenate([hs.tube.G, input_generators(Gu, et)],
                                                           axis=1))
    box_only = getattr(ctx.err, "box_only", False)  # the error model reads only the tube's box
    if box_only:  # then its radii suffice: |RU(box(L))| = (sum_i h/(i+1) |T_i| + E h) L
        r_base = np.abs(base_tube.G).sum(axis=1)
        S_L = weighted_sum(h / np.arange(1, et.eta + 2), np.abs(et.T).reshape(et.eta + 1, n * n),
                           n) + et.E * h
    Vbox = (ctx.Ubox[0], ctx.Ubox[1])
    t_box = (t0, t0 + h)
    # warm start: the previous step's remainder, enlarged once (the loop then usually closes at once)
    Lbar = np.zeros(n) if L_guess is None else np.asarray(L_guess, dtype=float) * GROWTH
    err = None
    need = None
    aR = set_abs(R, xs)   # the step's |R - x*| evaluated absolutely (linsys.step_rounding)
    for it in range(1, ctx.opts.max_iter + 1):
        r_fp = step_rounding(et, R, xs, u_abs0, W_abs0 + Lbar, n_sum, aR=aR)
        if box_only:  # a box zonotope with the tube's interval hull (rounding: inflate_box)
            tube = Zonotope.trusted(base_tube.c + xs, np.diag(r_base + S_L @ Lbar + r_fp))
        else:
            # base tube + R_W(box(Lbar)) + x*, padded by r_fp, as one concatenation
            tube = Zonotope.trusted(base_tube.c + 0.0 + xs, np.concatenate(
                [base_tube.G, input_generators(diag_columns(Lbar), et), diag_columns(r_fp)], axis=1))
        if not all_finite(tube):
            return StepFail("the tube is not finite", need)
        try:
            err = ctx.err.bound(tube, xs, vs, Vbox, t_box, lin)
        except OcreachError as exc:  # e.g. IntervalDomainError: a singularity inside the box
            msg = str(exc)
            msg = msg if len(msg) < 300 else msg[:300] + " ..."
            if it > 1:  # the guessed remainder grew until the tube's box reached a singularity
                msg = (f"the remainder loop diverged (iteration {it}, last bound "
                       f"{np.array2string(need, precision=3)}) until: {msg}")
            return StepFail("remainder bound failed: " + msg, need)
        # rounded up: the loop closes only if the error box surely lies in [-Lbar, Lbar]
        need = up(abs_extent(err), err.n_generators + 1)
        if not np.all(np.isfinite(need)):
            return StepFail("the remainder bound is not finite", need)
        if np.all(need <= Lbar):
            break
        Lbar = np.maximum(Lbar, need) * GROWTH + 1e-300
    else:
        return StepFail(f"the remainder loop did not close in {ctx.opts.max_iter} iterations "
                        f"(last bound {np.array2string(need, precision=3)})", need)
    # final sets with the error set found on the tube (valid: every trajectory stays in the tube)
    u_c2 = u_c + err.c
    W2G = np.concatenate([Gu, err.G], axis=1)
    hs2 = homogeneous_step(R0, u_c2, et, maps)
    RU2G = input_generators(W2G, et)
    r_fp = step_rounding(et, R, xs, u_abs0 + np.abs(err.c), W_abs0 + np.abs(err.G).sum(axis=1),
                         max(n_sum, W2G.shape[1] + Gv.shape[0] + 2), aR=aR)
    # (point + R_W + x*) padded by the rounding bound, as one concatenation each
    box_fp = diag_columns(r_fp)
    point = Zonotope.trusted(hs2.point.c + xs, np.concatenate([hs2.point.G, RU2G, box_fp], axis=1))
    tube = Zonotope.trusted(hs2.tube.c + xs, np.concatenate([hs2.tube.G, RU2G, box_fp], axis=1))
    if not all_finite(point, tube):
        return StepFail("the step's sets are not finite", need)
    return StepOK(point=point, tube=tube, L=need, err_mag=need, iterations=it)


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
        self.method = method
        self.problem = problem
        self.opts = opts
        self.err = error_model
        self.extra_meta = extra_meta
        V, self.input_desc = input_zonotope(problem, opts)
        W = disturbance_zonotope(problem, opts.disturbance)
        self.ctx = Context(problem, opts, error_model, V, W)
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

    def _advance(self, part: Part, t0: float, t1: float, stats: dict) -> tuple[Part, list, StepFail | None]:
        """Carry ``part`` from ``t0`` to ``t1`` with sub-steps, halving failing ones."""
        opts = self.opts
        level = part.level
        t, Z, L = t0, part.Z, part.L
        tubes: list[Zonotope] = []
        base = (t1 - t0) / opts.substeps
        while t < t1 - 1e-12 * abs(t1 - t0):
            h = min(base / 2**level, t1 - t)
            res = ct_step(self.ctx, Z, t, h, L)
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
            tubes.append(self._reduce(res.tube))
            Z = self._reduce(res.point)
            L = res.L
            t = t + h
        return Part(Z=Z, L=L, level=max(level - 1, 0)), tubes, None

    def _can_split(self, stats: dict) -> bool:
        return self.opts.split and stats["n_parts"] < self.opts.max_parts

    def run(self) -> ReachResult:
        prob = self.problem
        grid = prob.grid
        if prob.backward:
            raise ProblemError(f"problem {prob.id!r} has a backward grid; taylor/sdc propagate "
                               "forward in time only")
        t_start = time.perf_counter()
        R0 = initial_zonotope(prob)
        parts = [Part(Z=R0)]
        sets: list[Any] = [R0]
        tubes: list[Any] = []
        meta_steps: dict[str, list] = {"remainder": [], "iterations": [], "splits": [], "substeps": [],
                                       "parts": []}
        for k in range(grid.size - 1):
            t0, t1 = float(grid[k]), float(grid[k + 1])
            stats = {"iterations": 0, "substeps": 0, "err": np.zeros(prob.model.n_x),
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
                if self._can_split(stats) and part.Z.n_generators > 0:
                    scores = self.err.split_scores(part.Z)
                    j = int(np.argmax(scores))
                    a, b = part.Z.split(j)
                    queue += [Part(Z=a, L=None, level=part.level), Part(Z=b, L=None, level=part.level)]
                    stats["n_parts"] += 1
                    stats["splits"] += 1
                    continue
                self._fail(k, t0, t1, fail, stats, sets, tubes, meta_steps, t_start)
            parts = done
            sets.append(_as_set([p.Z for p in parts]))
            tubes.append(_as_set(step_tubes))
            meta_steps["remainder"].append(stats["err"].tolist())
            meta_steps["iterations"].append(stats["iterations"])
            meta_steps["splits"].append(stats["splits"])
            meta_steps["substeps"].append(stats["substeps"])
            meta_steps["parts"].append(len(parts))
        return self._result(grid, sets, tubes, meta_steps, t_start, truncated=False)

    def _result(self, times, sets, tubes, meta_steps, t_start, truncated: bool) -> ReachResult:
        meta = self.method.base_meta(self.problem, {"propagation": time.perf_counter() - t_start})
        meta.update({
            "guaranteed": True, "truncated": truncated, "input_set": self.problem.control_set.kind,
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
def rk4_funs(model, h: float, n_sub: int):
    """``(x, u, t, p) -> (g, dg/dz)`` and the interval extension of ``(g, dg/dx, dg/du, H)`` of the
    RK4 map ``g`` over one step (``H`` the Hessian in ``z = (x, u)``)."""
    from ocreach.dynamics.discretize import rk4_expression
    from ocreach.intervals import interval_function

    key = ("taylor", "rk4", float(h), int(n_sub))

    def build():
        g = rk4_expression(model, model.x, model.u, model.t, model.p, h, n_sub)
        z = ca.vertcat(model.x, model.u)
        J = ca.jacobian(g, z)
        H = ca.jacobian(ca.reshape(J.T, -1, 1), z)
        return (ca.Function("rk4_jac", [model.x, model.u, model.t, model.p], [g, J]),
                ca.Function("rk4_hess", [model.x, model.u, model.t, model.p],
                            [g, ca.jacobian(g, model.x), ca.jacobian(g, model.u), H]))

    jac, hess = model.cached(key, build)
    return jac, interval_function(hess, model=model, key=key + ("lin_hess",))


class DiscreteTaylor:
    """Eq. 8-15 on ``x_{k+1} = g(x_k, u_k)`` (RK4, control held on each grid step)."""

    def __init__(self, method: Method, problem: Problem, opts, n_sub: int):
        self.method, self.problem, self.opts, self.n_sub = method, problem, opts, n_sub
        self.V, self.input_desc = input_zonotope(problem, opts)
        self.W = disturbance_zonotope(problem, opts.disturbance)
        n = problem.model.n_x
        if opts.max_error is not None and np.size(opts.max_error) not in (1, n):
            raise ProblemError(f"max_error must be one number or {n} numbers (one per state); "
                               f"got {opts.max_error!r}")

    def step(self, Z: Zonotope, t: float, h: float) -> tuple[Zonotope, np.ndarray]:
        m = self.problem.model
        n, nu = m.n_x, m.n_u
        p = np.asarray(self.problem.params, dtype=float)
        jac, H = rk4_funs(m, h, self.n_sub)
        g, J = (np.asarray(a) for a in jac(Z.c, self.V.c, t, p))
        hz = Z.interval_hull()
        hv = self.V.interval_hull()
        zlo, zhi = inflate_box(hz.lo, hz.hi)
        vlo, vhi = inflate_box(hv.lo, hv.hi)
        tt = np.array([t, t])
        out = H([np.column_stack([Z.c, zlo]), np.column_stack([self.V.c, vlo]), tt, p],
                [np.column_stack([Z.c, zhi]), np.column_stack([self.V.c, vhi]), tt, p])
        Hlo, Hhi = out[3]
        nz = n + nu
        Hlo = unflatten_hessian(Hlo[:, 1:], n, nz)[0]
        Hhi = unflatten_hessian(Hhi[:, 1:], n, nz)[0]
        dlo = np.concatenate([zlo - Z.c, vlo - self.V.c])
        dhi = np.concatenate([zhi - Z.c, vhi - self.V.c])
        lo, hi = quadratic_interval(Hlo, Hhi, dlo, dhi)
        gz = up(np.maximum(np.abs(dlo), np.abs(dhi)), 1)
        g = g.ravel()
        e = eval_error(out[:3], (g, J[:, :n], J[:, n:]), gz[:n], gz[n:])
        lo, hi = lo - e, hi + e
        ZV = Z.cartesian(self.V)
        zc = np.concatenate([Z.c, self.V.c])
        res = J @ (ZV - zc) + g + interval_box(lo, hi)
        # rounding of J (ZV - zc) + g + box (+ W): abs value |J| (2|zc| + sum|G|) + |g| + |box|
        a = (np.abs(J) @ (2 * np.abs(zc) + np.abs(ZV.G).sum(axis=1)) + np.abs(g)
             + np.maximum(np.abs(lo), np.abs(hi)))
        if self.W is not None:
            res = res + self.W
            a = a + np.abs(self.W.c) + np.abs(self.W.G).sum(axis=1)
        r = rounding_radius(a, nz + ZV.n_generators + 4)
        return pad(res, r), np.maximum(np.abs(lo), np.abs(hi))

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
                    out, e = self.step(Z, t0, h)
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
                     "input_set": self.problem.control_set.kind, "input_enclosure": self.input_desc,
                     "steps": {"remainder": rem, "splits": splits}})
        return meta


class TaylorZonotope(Method):
    """Patel & Subbarao Method 1: zonotopes by conservative linearisation with a Lagrange remainder."""

    name = "taylor"
    description = ("guaranteed zonotope enclosure by conservative linearisation + interval Lagrange "
                   "remainder (Patel & Subbarao Method 1; Althoff CDC 2008)")

    @dataclass
    class Options(ZonotopeOptions):
        """:class:`ZonotopeOptions` plus ``alg``: ``"ct"`` (continuous time, default) or ``"dt"``
        (the paper's discrete Eq. 8-15 on the RK4 map, sound for that model only) and
        ``rk4_substeps`` (4): RK4 sub-steps per grid step of the ``dt`` map."""

        alg: str = "ct"
        rk4_substeps: int = 4

        def __post_init__(self) -> None:
            super().__post_init__()
            if self.alg not in ALGS:
                raise ProblemError(f"alg must be one of {ALGS}; got {self.alg!r}")
            self.rk4_substeps = check_count("rk4_substeps", self.rk4_substeps, 1)

    def solve(self, problem: Problem) -> ReachResult:
        check_smooth(problem.model)
        initial_zonotope(problem)  # wrong dimension -> clear error before any work
        if self.options.alg == "dt":
            return DiscreteTaylor(self, problem, self.options, self.options.rk4_substeps).run()
        err = TaylorError(problem.model, problem.params)
        return ZonotopeReach(self, problem, self.options, err, {"alg": "ct"}).run()

