"""One guaranteed step of ``taylor`` (Patel & Subbarao Method 1, Eq. 8-16; Althoff, Stursberg &
Buss, CDC 2008): the linearisation point, the Lagrange remainder bound and the fixed-point loop
on one part (zonotope); the driver (:mod:`ocreach.reach.taylor`) carries the parts over the grid.

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

:func:`ct_step` is that step; :class:`Context` holds what it needs (model functions, inputs,
the error model); :class:`TaylorError` is the remainder of item 2 (``sdc`` passes its own error
model, :mod:`ocreach.reach.sdc`); :class:`StepOK` / :class:`StepFail` are its outcomes.

Discrete time (``alg="dt"``, :func:`dt_step`): the paper's literal Eq. 8-15 on the RK4 map
``x_{k+1} = g(x_k, u_k)`` of :mod:`ocreach.dynamics.discretize` (control held on the step):
``g(z) in g(z*) + J (z - z*) + L`` with ``L`` bounded by the interval Hessian of the RK4 map over
the box of ``R_k x U``.  Sound for the discrete model only.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import OcreachError, SolverError
from ocreach.fastcall import FastFunction
from ocreach.problem import Problem
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
from ocreach.sets.rounding import rounding_radius, up
from ocreach.sets.zonotope import Zonotope

#: relative inflation of the box on which the remainder is bounded (the continuity argument)
BOX_INFLATE = 1e-9
#: growth factor of the guessed remainder in the fixed-point loop
GROWTH = 1.25


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
    ``H_iab [d_a d_b]`` are formed as one stacked array each (the same products; min/max exact).
    A set that has blown up gives inf or NaN here, without numpy's overflow warnings: the
    callers refuse a bound that is not finite (``ct_step`` with a :class:`StepFail`, ``dt_step``
    with a :class:`SolverError`)."""
    with np.errstate(over="ignore", invalid="ignore"):
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


def bound_failed(exc: Exception, iteration: int, need: np.ndarray | None) -> StepFail:
    """The failure of a remainder bound that raised at ``iteration`` of the fixed-point loop
    (e.g. IntervalDomainError: the guessed remainder grew until the tube's box reached a
    singularity)."""
    msg = str(exc)
    msg = msg if len(msg) < 300 else msg[:300] + " ..."
    if iteration > 1:
        msg = (f"the remainder loop diverged (iteration {iteration}, last bound "
               f"{np.array2string(need, precision=3)}) until: {msg}")
    return StepFail("remainder bound failed: " + msg, need)


def loop_not_closed(max_iter: int, need: np.ndarray) -> StepFail:
    """The failure of a fixed-point loop whose bound still grew after ``max_iter`` iterations."""
    return StepFail(f"the remainder loop did not close in {max_iter} iterations "
                    f"(last bound {np.array2string(need, precision=3)})", need)


class Context:
    """Everything a step needs: model functions, inputs, error model, options (the method's
    :class:`~ocreach.reach.taylor.ZonotopeOptions`; the step reads ``max_iter``)."""

    def __init__(self, problem: Problem, opts: Any, error_model, V: Zonotope,
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
        #: per state, how far the input moves it per unit time (|B G_v| + W): the scale of a step
        self.input_reach = up(np.abs(self.lin(problem.x0, V.c, 0.0, self.p)[2][:, : V.dim])
                              @ np.abs(V.G).sum(axis=1)
                              + (np.abs(W.G).sum(axis=1) if W is not None else 0.0), 4)


def ct_step(ctx: Context, R: Zonotope, t0: float, h: float, L_guess: np.ndarray | None
            ) -> StepOK | StepFail:
    """One continuous-time step of the part ``R`` over ``[t0, t0 + h]`` (module docstring,
    items 1-4), warm-started with the previous step's remainder radius ``L_guess``."""
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
            return bound_failed(exc, it, need)
        # rounded up: the loop closes only if the error box surely lies in [-Lbar, Lbar]
        need = up(abs_extent(err), err.n_generators + 1)
        if not np.all(np.isfinite(need)):
            return StepFail("the remainder bound is not finite", need)
        if np.all(need <= Lbar):
            break
        Lbar = np.maximum(Lbar, need) * GROWTH + 1e-300
    else:
        return loop_not_closed(ctx.opts.max_iter, need)
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


def dt_step(problem: Problem, V: Zonotope, W: Zonotope | None, n_sub: int, Z: Zonotope, t: float,
            h: float) -> tuple[Zonotope, np.ndarray]:
    """One step of the RK4 map from ``Z`` at ``t`` over ``h`` (module docstring; ``n_sub`` RK4
    sub-steps, the control in ``V``, the disturbance ``W`` added to the image): the enclosure,
    padded by its rounding, and the remainder's magnitude per state."""
    m = problem.model
    n, nu = m.n_x, m.n_u
    p = np.asarray(problem.params, dtype=float)
    jac, H = rk4_funs(m, h, n_sub)
    g, J = (np.asarray(a) for a in jac(Z.c, V.c, t, p))
    hz = Z.interval_hull()
    hv = V.interval_hull()
    zlo, zhi = inflate_box(hz.lo, hz.hi)
    vlo, vhi = inflate_box(hv.lo, hv.hi)
    tt = np.array([t, t])
    out = H([np.column_stack([Z.c, zlo]), np.column_stack([V.c, vlo]), tt, p],
            [np.column_stack([Z.c, zhi]), np.column_stack([V.c, vhi]), tt, p])
    Hlo, Hhi = out[3]
    nz = n + nu
    Hlo = unflatten_hessian(Hlo[:, 1:], n, nz)[0]
    Hhi = unflatten_hessian(Hhi[:, 1:], n, nz)[0]
    dlo = np.concatenate([zlo - Z.c, vlo - V.c])
    dhi = np.concatenate([zhi - Z.c, vhi - V.c])
    lo, hi = quadratic_interval(Hlo, Hhi, dlo, dhi)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise SolverError(f"the remainder bound of the RK4 map at t = {t:.6g} is not finite "
                          "(the set has blown up)")
    gz = up(np.maximum(np.abs(dlo), np.abs(dhi)), 1)
    g = g.ravel()
    e = eval_error(out[:3], (g, J[:, :n], J[:, n:]), gz[:n], gz[n:])
    lo, hi = lo - e, hi + e
    ZV = Z.cartesian(V)
    zc = np.concatenate([Z.c, V.c])
    res = J @ (ZV - zc) + g + interval_box(lo, hi)
    # rounding of J (ZV - zc) + g + box (+ W): abs value |J| (2|zc| + sum|G|) + |g| + |box|
    a = (np.abs(J) @ (2 * np.abs(zc) + np.abs(ZV.G).sum(axis=1)) + np.abs(g)
         + np.maximum(np.abs(lo), np.abs(hi)))
    if W is not None:
        res = res + W
        a = a + np.abs(W.c) + np.abs(W.G).sum(axis=1)
    r = rounding_radius(a, nz + ZV.n_generators + 4)
    return pad(res, r), np.maximum(np.abs(lo), np.abs(hi))
