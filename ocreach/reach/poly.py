"""``poly``: guaranteed reachable sets by conservative polynomialization (Althoff, "Reachability
analysis of nonlinear systems using conservative polynomialization and non-convex sets", HSCC
2013; CORA ``nonlinearSys`` with ``alg = 'poly'``, ``tensorOrder = 3``).

The sets are sparse polynomial zonotopes (:class:`ocreach.sets.PolyZonotope`); the time-interval
tubes are zonotopes.  On a step ``[t, t + h]`` from the set ``R`` (local time ``tau`` in ``[0, h]``,
``d = x - x*``):

1. expansion point ``z* = (x*, v*)``: ``x* = c + h/2 f(c, u_c)`` (``c`` the centre of ``R``'s
   zonotope enclosure), ``v* = u_c`` (and ``t* = t + h/2`` when ``f`` depends on time, ``v = (u,
   t)``); ``f0``, ``A = df/dx``, ``B = df/dv`` and the Hessian ``H`` at ``z*`` from the one CasADi
   model (:func:`ocreach.reach.taylor_step.hessian_interval` gives their interval enclosures at the
   point, which bound the rounding of the float values);
2. third-order expansion (Althoff 2013, Eq. 6): ``f(z) = f0 + A d + B dv + 1/2 d^T H_xx d + rho``
   where ``rho`` holds the second-order terms in ``v`` (``d^T H_xv dv + 1/2 dv^T H_vv dv``, zero for
   control-affine models with a constant input matrix) and the Lagrange remainder
   ``1/6 T(zeta)[dz, dz, dz]``, ``T`` the third-derivative tensor bounded over the tube's box by the
   interval evaluator (:mod:`ocreach.intervals`);
3. the **static error** ``V_stat = f0 + 1/2 d0^T H_xx d0`` on the step's initial set ``D0 = R - x*``
   is computed exactly as a polynomial zonotope (the quadratic map keeps the dependence on ``R``'s
   factors; Althoff 2013 Sec. 4.1) and enters the linear system as a constant input, so
   ``R(t + h) = x* + Phi D0 + Gamma V_stat`` is again a polynomial in the same factors -- the
   curvature of the flow is carried, not boxed;
4. the **dynamic error** ``1/2 [d(tau)^T H_xx d(tau) - d0^T H_xx d0]`` (the set moves during the
   step; Althoff 2013 Sec. 4.2) is bounded by ``1/2 |d(tau) - d0|^T |H_i| (|d(tau)| + |d0|)`` with
   ``d(tau) - d0`` in the box of ``lambda (P - D0)`` plus the deviation of the flow from that
   chord (``P`` the linear image, ``lambda = tau / h``): the terms ``g1``, ``g2`` of the first
   part of the error (linear and quadratic in ``lambda``) move the end point from ``P`` to
   ``P_end``, so the deviation holds ``lambda (P_end - P)``, the curvature of the linear flow
   ``F D0 + F~ V_stat`` and of the ``g`` terms' solutions, ``R_W`` and the response to the error
   box itself; added to ``rho``: the time-varying error box ``[-Lbar, Lbar]``;
5. the linear system ``d' = A d + V_stat + B dv(tau) + w(tau)``, ``w in [-Lbar, Lbar] (+ W)`` is
   stepped as in :mod:`ocreach.reach.linsys` (the exponential-matrix remainder ``E``, the
   curvature matrices ``F``, ``F~``; the input solution ``R_W`` of ``B dv`` and ``w``).  The
   input's solution ``R_W`` of the thrust is a zonotope whose generators become new dependent
   factors of the set (``input_factors=True``), so later steps map the thrust's contribution
   through the quadratic term as well;
6. ``Lbar`` depends on the tube, which depends on ``Lbar``: the fixed-point loop of ``taylor``
   (guess, bound on the inflated box of the tube, enlarge until the bound lies in the guess; the
   continuity argument of :mod:`ocreach.reach.taylor_step` then shows every trajectory stays in the
   tube), and the final sets are recomputed with the bound found.

Failing steps are halved (``max_halvings``) and failing parts split in two along the factor with
the largest contribution to the remainder (:func:`ocreach.sets.pz_sound.split`, exact up to
rounding); ``max_error`` splits proactively.  Every set operation is rounded outward
(:mod:`ocreach.sets.pz_sound`, :mod:`ocreach.sets.rounding`), so the sets are enclosures of
the continuous-time flow for every admissible (measurable) control, not only for the sampled ones.
"""
from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import casadi as ca
import numpy as np

from ocreach.errors import OcreachError, ProblemError, SolverError, check_count, check_real
from ocreach.problem import Problem
from ocreach.reach.base import Method
from ocreach.reach.linsys import (
    all_finite,
    diag_columns,
    expm_terms,
    input_generators,
    weighted_sum,
)
from ocreach.reach.result import ReachResult
from ocreach.reach.taylor import (
    Part,
    TaylorZonotope,
    ZonotopeOptions,
    ZonotopeReach,
    check_smooth,
    initial_zonotope,
)
from ocreach.reach.taylor_step import (
    GROWTH,
    Context,
    StepFail,
    bound_failed,
    eval_error,
    hessian_interval,
    inflate_box,
    loop_not_closed,
    unflatten_hessian,
    z_symbol,
)
from ocreach.sets import pz_sound as spz
from ocreach.sets.pz_sound import FactorIds, SoundPZ
from ocreach.sets.pz_union import PZUnion
from ocreach.sets.rounding import rounding_radius, up
from ocreach.sets.union import ZonotopeUnion
from ocreach.sets.zonotope import Zonotope

OUTPUTS = ("pz", "zonotope")


# ------------------------------------------------------------------------------------------------
# the model functions (built once, cached on the model)
# ------------------------------------------------------------------------------------------------
def third_interval(model):
    """Interval extension of ``T = d^3 f_i / dz_a dz_b dz_c`` over ``z = (x, u[, t])`` (flat
    ``(n_x n_z^2, n_z)``): the Lagrange remainder of the third-order expansion over the tube."""
    from ocreach.intervals import interval_function

    def build():
        z = z_symbol(model)
        J = ca.jacobian(model.f, z)
        H = ca.jacobian(ca.reshape(J.T, -1, 1), z)
        T = ca.jacobian(ca.reshape(H.T, -1, 1), z)
        return ca.Function("poly_third", [model.x, model.u, model.t, model.p], [T])

    fun = model.cached(("poly", "third_fun"), build)
    return interval_function(fun, model=model, key=("poly", "third"), native=True)


def third_dependence(model) -> np.ndarray:
    """The states ``x_a`` that some third derivative of ``f`` depends on (structural sparsity of
    ``d T / d x``): where sub-boxes of the remainder's box can tighten its bound."""
    def build():
        fun = model.cached(("poly", "third_fun"), lambda: None)
        T = fun(model.x, model.u, model.t, model.p)
        dep = [a for a in range(model.n_x) if ca.depends_on(T, model.x[a])]
        return np.asarray(dep, dtype=np.int64)

    third_interval(model)   # builds the third-derivative Function
    return model.cached(("poly", "third_dependence"), build)


def unflatten_third(a: np.ndarray, n_x: int, n_z: int) -> np.ndarray:
    """Column-major flat ``(n_x n_z^2, n_z)`` of one box -> ``T[i, a, b, c]`` (n_x, n_z, n_z, n_z)."""
    return a.reshape(n_z, n_x, n_z, n_z).transpose(1, 2, 3, 0)


# ------------------------------------------------------------------------------------------------
# options
# ------------------------------------------------------------------------------------------------
@dataclass
class PolyOptions(ZonotopeOptions):
    """Options of ``poly``: those of ``taylor`` (:class:`ZonotopeOptions`) plus the sizes of the
    polynomial zonotopes; every value is checked before any work (``ocreach methods poly``)."""

    #: zonotope order of the linear part of a time-point set after each step (the linear
    #: monomials of factors that occur nowhere else, with the independent generators: order * n_x
    #: generators, reduced like a zonotope), >= 1
    order: float = 6.0
    #: monomials of degree >= 2 kept per state (poly_order * n_x; the smallest others are
    #: enclosed by the linear part), >= 0
    poly_order: float = 10.0
    #: zonotope order of the set the quadratic maps are evaluated on (its error_order * n_x
    #: largest monomials kept with their factors, the rest boxed; CORA's errorOrder), >= 1
    error_order: float = 10.0
    #: highest total degree of a monomial kept dependent (higher ones are enclosed by
    #: independent generators), 2..6
    max_degree: int = 3
    #: after each step the independent generators become dependent generators with fresh
    #: factors (restructuring), so later steps map their curvature and a split can halve them
    refactor: bool = True
    #: the remainder's interval derivatives are bounded as the maximum over remainder_splits^d
    #: sub-boxes of the tube's box, cut along the d <= 3 widest states the third derivatives
    #: depend on (less dependency in the interval evaluation), 1..4
    remainder_splits: int = 2
    #: zonotope order of the time-interval tubes, >= 1
    tube_order: float = 10.0
    #: the thrust's input solution of every step becomes new dependent factors (later steps map
    #: its curvature); False: independent generators
    input_factors: bool = True
    #: zonotope order of one step's input solution before it joins the set, >= 1
    input_order: float = 1.0
    #: the time-point sets as polynomial zonotopes ("pz") or as their zonotope enclosures
    #: ("zonotope", for consumers that need zonotopes, e.g. drift tubes)
    output: str = "pz"
    #: step-size control (as in :class:`ZonotopeOptions`), on by default for poly
    growth_tol: float | None = 0.1

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("tube_order", "input_order", "error_order"):
            v = check_real(name, getattr(self, name))
            if v < 1:
                raise ProblemError(f"{name} must be >= 1; got {getattr(self, name)!r}")
            setattr(self, name, v)
        self.poly_order = check_real("poly_order", self.poly_order)
        if self.poly_order < 0:
            raise ProblemError(f"poly_order must be >= 0; got {self.poly_order!r}")
        self.max_degree = check_count("max_degree", self.max_degree, 2)
        if self.max_degree > spz.MAX_DEGREE:
            raise ProblemError(f"max_degree must be an integer in 2..{spz.MAX_DEGREE}; got "
                               f"{self.max_degree!r}")
        for name in ("input_factors", "refactor"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ProblemError(f"{name} must be True or False; got {getattr(self, name)!r}")
        self.remainder_splits = check_count("remainder_splits", self.remainder_splits, 1)
        if self.remainder_splits > 4:
            raise ProblemError(f"remainder_splits must be an integer in 1..4; got "
                               f"{self.remainder_splits!r}")
        if self.output not in OUTPUTS:
            raise ProblemError(f"output must be one of {OUTPUTS}; got {self.output!r}")


# ------------------------------------------------------------------------------------------------
# one step
# ------------------------------------------------------------------------------------------------
@dataclass
class PolyStepOK:
    point: SoundPZ
    tube: Zonotope
    L: np.ndarray          # radius of the applied error box (warm start of the next step)
    err_mag: np.ndarray    # the same, reported per state
    iterations: int


class PolyContext(Context):
    """:class:`ocreach.reach.taylor_step.Context` plus the interval functions of the expansion, the
    factor numbering and the reduction sizes."""

    def __init__(self, problem: Problem, opts: PolyOptions, V: Zonotope, W: Zonotope | None):
        super().__init__(problem, opts, None, V, W)
        m = self.model
        self.n = m.n_x
        self.n_z = m.n_x + m.n_u + (1 if self.td else 0)
        self.point_iv = hessian_interval(m)
        self.third_iv = third_interval(m)
        #: states the third derivatives depend on (structurally): the candidates for sub-boxes
        self.split_dims = third_dependence(m)
        self.fid = FactorIds(opts.max_degree)
        self.bits = self.fid.bits
        self.d = opts.max_degree
        self.h_lin = max(int(np.floor(opts.order * self.n)), self.n)
        self.h_poly = int(np.floor(opts.poly_order * self.n))
        self.h_err = max(int(np.floor(opts.error_order * self.n)), self.n)
        #: per-state sensitivity of the last remainder bound to the set's extent (for splitting)
        self.weights: np.ndarray | None = None


def _magnitude_up(S: SoundPZ) -> np.ndarray:
    """:func:`ocreach.sets.pz_sound.magnitude` rounded up for its sum of generators."""
    return up(spz.magnitude(S), S.G.shape[1] + S.GI.shape[1] + 3)


def _lo_hi_pad(lo: np.ndarray, hi: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``[lo, hi]`` widened by the rounding of the sums that produced them (``k`` terms)."""
    r = rounding_radius(np.maximum(np.abs(lo), np.abs(hi)), k)
    return lo - r, hi + r


def chord_constants(j: np.ndarray) -> np.ndarray:
    """``|q_j| = max_{lambda in [0, 1]} lambda - lambda^j = j^(-1/(j-1)) - j^(-j/(j-1))`` for
    integers ``j >= 1`` (0 for ``j = 1``), rounded up (the float formula is within a few ulps)."""
    j = np.asarray(j, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(j > 1, j ** (-1.0 / (j - 1.0)) - j ** (-j / (j - 1.0)), 0.0)
    return q * (1.0 + 1e-12)


def gamma_matrices(et, k_max: int = 2) -> tuple[list[np.ndarray], np.ndarray, list[np.ndarray]]:
    """For ``k = 0..k_max``: ``Gamma_k = int_0^h e^{A (h - s)} (s / h)^k ds = h sum_i w_ik T_i``,
    ``w_ik = i! k! / (i + k + 1)!`` (the solution at ``h`` of the input ``(tau / h)^k g``;
    ``Gamma_0`` is ``linsys``' ``Gamma``), one elementwise radius valid for all of them (the series
    tail ``E h``, as every ``w_ik <= 1``, plus the rounding of the weighted sums), and the bounds
    ``C_k >= |y_k(tau) - (tau / h) y_k(h)|`` (elementwise, times ``|g|``) of the solution
    ``y_k(tau) = h sum_i w_ik (tau / h)^(i + k + 1) T_i g`` off its chord: ``lambda^j - lambda`` lies
    in ``[q_j, 0]`` on [0, 1] (the curvature constants of :mod:`ocreach.reach.linsys`), so
    ``C_k = h sum_i |q_(i+k+1)| w_ik |T_i| + E h``."""
    n = et.T.shape[1]
    i = np.arange(et.eta + 1)
    Tflat = et.T.reshape(et.eta + 1, n * n)
    absT = np.abs(Tflat)
    out, chord = [], []
    for k in range(k_max + 1):
        w = np.array([factorial(int(j)) * factorial(k) / factorial(int(j) + k + 1) for j in i])
        out.append(weighted_sum(et.h * w, Tflat, n))
        q = chord_constants(i + k + 1)
        chord.append(up(weighted_sum(et.h * w * q, absT, n) + et.E * et.h, et.eta + 4))
    rad = et.E * et.h + rounding_radius(et.h * et.M, et.eta + 4)
    return out, rad, chord


def derivative_bounds(ctx: PolyContext, xlo: np.ndarray, xhi: np.ndarray, t_lo: np.ndarray,
                      t_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interval bounds over the box ``[xlo, xhi] x U (x [t_lo, t_hi])`` of the third-derivative
    magnitudes ``|T_iabc|`` and of the Hessian ``[Hlo, Hhi]`` (n_x, n_z, n_z): the maximum (hull)
    over ``k^d`` sub-boxes, ``k = remainder_splits``, cut along the ``d <= 3`` widest states the
    derivatives depend on (``PolyContext.split_dims``).  The sub-boxes share their cut points
    exactly, so they cover the box, and the hull of sound bounds on a cover is a sound bound on
    the box; splitting only removes part of the interval evaluator's dependency overestimation."""
    n, nz, p = ctx.n, ctx.n_z, ctx.p
    k = ctx.opts.remainder_splits
    dims = ctx.split_dims
    if k > 1 and dims.size:
        dims = dims[np.argsort(-(xhi[dims] - xlo[dims]), kind="stable")[:3]]
        cuts = [np.linspace(xlo[j], xhi[j], k + 1) for j in dims]
        cuts = [np.concatenate([[xlo[j]], c[1:-1], [xhi[j]]]) for j, c in zip(dims, cuts)]
        grid = np.stack(np.meshgrid(*[np.arange(k)] * dims.size, indexing="ij"), -1).reshape(-1, dims.size)
        B = grid.shape[0]
        lo = np.repeat(xlo[:, None], B, axis=1)
        hi = np.repeat(xhi[:, None], B, axis=1)
        for a, j in enumerate(dims):
            lo[j] = cuts[a][grid[:, a]]
            hi[j] = cuts[a][grid[:, a] + 1]
    else:
        lo, hi, B = xlo[:, None], xhi[:, None], 1
    ulo, uhi = ctx.Ubox
    T = ctx.third_iv([lo, ulo, t_lo, p], [hi, uhi, t_hi, p], check=False)[0]
    H = ctx.point_iv([lo, ulo, t_lo, p], [hi, uhi, t_hi, p], check=False)[3]
    Tmag = np.maximum(np.abs(T[0]), np.abs(T[1])).max(axis=1)
    Hlo = unflatten_hessian(H[0], n, nz).min(axis=0)
    Hhi = unflatten_hessian(H[1], n, nz).max(axis=0)
    return unflatten_third(Tmag, n, nz), Hlo, Hhi


def poly_step(ctx: PolyContext, R: SoundPZ, t0: float, h: float,
              L_guess: np.ndarray | None) -> PolyStepOK | StepFail:
    """One step of conservative polynomialization (module docstring, items 1-6)."""
    n, nz, bits, d = ctx.n, ctx.n_z, ctx.bits, ctx.d
    nv = nz - n
    p = ctx.p
    uc = ctx.V.c
    c = spz.to_zonotope(R).c
    f_c = ctx.lin(c, uc, t0, p)[0].ravel()
    xs = c + 0.5 * h * f_c
    ts = t0 + 0.5 * h
    f0, A, Bv = ctx.lin(xs, uc, ts, p)
    f0 = f0.ravel()
    if not (np.all(np.isfinite(f0)) and np.all(np.isfinite(A)) and np.all(np.isfinite(Bv))):
        return StepFail(f"f or its Jacobian is not finite at the expansion point {xs}")
    vs = np.concatenate([uc, [ts]]) if ctx.td else uc
    # interval enclosures of f, A, B, H at the point z*: they bound the float values' rounding
    tp = np.array([ts])
    try:
        pt = ctx.point_iv([xs, uc, tp, p], [xs, uc, tp, p], check=False)
    except OcreachError as exc:
        return StepFail(f"the expansion at z* failed: {str(exc)[:300]}")
    Hlo = unflatten_hessian(pt[3][0], n, nz)[0]
    Hhi = unflatten_hessian(pt[3][1], n, nz)[0]
    Hs = 0.5 * (Hlo + Hhi)
    Hs = 0.5 * (Hs + Hs.transpose(0, 2, 1))          # exactly symmetric
    eH = up(np.maximum(Hhi - Hs, Hs - Hlo), 2)        # |H(z*) - Hs| elementwise
    Hmag = np.maximum(np.abs(Hlo), np.abs(Hhi))
    Hxx = Hs[:, :n, :n]
    absHxx = np.abs(Hxx)
    Hs0 = np.zeros_like(Hs)
    Hs0[:, :n, :n] = Hxx
    try:
        et = expm_terms(A, h)
    except SolverError as exc:
        return StepFail(str(exc))
    (G0, G1, G2), G_rad, (_, C1, C2) = gamma_matrices(et)
    # ---- the polynomial part (independent of the error box)
    D0 = spz.translate(R, -xs)
    D0m = spz.reduce_for_map(D0, ctx.h_err)
    Vstat = spz.translate(spz.quadratic(0.5 * Hxx, D0m, bits), f0)   # f0 + 1/2 d0^T H d0
    if ctx.W is not None:
        # the disturbance's centre is a constant input like f0: Gamma w_c enters P exactly and
        # F~ bounds it off the chord for tau < h (|Gamma(tau) w_c| can exceed |Gamma(h) w_c|)
        Vstat = spz.translate(Vstat, ctx.W.c)
    P = spz.add(spz.linear_map(et.Phi, D0, et.E), spz.linear_map(G0, Vstat, G_rad), bits)
    Dd = spz.add(P, spz.scale(-1.0, D0), bits)                  # P - D0 = D(alpha) + boxes
    # the quadratic term along the segment d0 + lambda D: 1/2 Q(d0) + lambda g1 + lambda^2 g2
    Dr = spz.reduce_for_map(Dd, ctx.h_err)
    g1 = spz.bilinear(Hxx, D0m, Dr, bits)                       # d0^T H D
    g2 = spz.quadratic(0.5 * Hxx, Dr, bits)                     # 1/2 D^T H D
    Pdyn = spz.add(spz.linear_map(G1, g1, G_rad), spz.linear_map(G2, g2, G_rad), bits)
    Pend = spz.add(P, Pdyn, bits)
    # the expansion's chord d0 + lambda D ends at P, the flow's near Pend: they differ by
    # lambda (Pend - P), which the deviation r_rho of the true d(tau) from the chord must hold
    mag_dyn = _magnitude_up(Pdyn)
    # the tube's polynomial part: CH(D0, P_end) with common factors
    lam = int(ctx.fid.new(1)[0])
    Dend = spz.add(Pend, spz.scale(-1.0, D0), bits)
    seg = spz.add(spz.add(spz.scale(0.5, D0), spz.scale(0.5, Pend), bits),
                  spz.times_new_factor(spz.scale(0.5, Dend), lam, bits), bits)
    seg_lo, seg_hi = spz.box(seg)
    magD0, magV = _magnitude_up(D0), _magnitude_up(Vstat)
    r_F = up((np.abs(et.F_mid) + et.F_rad) @ magD0 + (np.abs(et.Ft_mid) + et.Ft_rad) @ magV, n + 2)
    r_g = up(C1 @ _magnitude_up(g1) + C2 @ _magnitude_up(g2), n + 2)   # y_k off the chord
    # ---- the uncertain input B (V - v_c) [x (t - t*)] (+ W): its input solution R_W
    Gv = ctx.V.G
    if ctx.td:
        Gv = np.zeros((ctx.V.dim + 1, ctx.V.n_generators + 1))
        Gv[:-1, :-1] = ctx.V.G
        Gv[-1, -1] = up(max(ts - t0, t0 + h - ts), 2)   # |t - t*| on the step (ts is rounded)
    Gu = Bv @ Gv
    r_Gu = rounding_radius(np.abs(Bv) @ np.abs(Gv).sum(axis=1), Gv.shape[0])
    if ctx.W is not None:
        Gu = np.hstack([Gu, ctx.W.G])
    Gu = np.hstack([Gu, diag_columns(r_Gu)])
    RWG = input_generators(Gu, et)
    r_RW = rounding_radius(h * et.M @ np.abs(Gu).sum(axis=1), n + et.eta + 4)
    RWz = Zonotope.trusted(np.zeros(n), np.hstack([RWG, diag_columns(r_RW)]))
    r_RWz = up(np.abs(RWz.G).sum(axis=1), RWz.n_generators + 1)
    # box response of the error box [-L, L]: |R_W(box(L))| <= S_L L
    S_L = weighted_sum(h / np.arange(1, et.eta + 2), np.abs(et.T).reshape(et.eta + 1, n * n), n) + et.E * h
    S_L = up(S_L, et.eta + 3)
    # ---- boxes that do not depend on the error box: the tube's and the residual rho's
    r_rho0 = up(r_F + r_g + r_RWz, 3)
    base_lo, base_hi = _lo_hi_pad(xs + seg_lo - r_rho0, xs + seg_hi + r_rho0, 3)
    ulo, uhi = ctx.Ubox
    vlo = np.concatenate([ulo, [t0]]) if ctx.td else ulo
    vhi = np.concatenate([uhi, [t0 + h]]) if ctx.td else uhi
    dv = up(np.maximum(np.abs(vlo - vs), np.abs(vhi - vs)), 1)
    t_lo, t_hi = np.array([t0]), np.array([t0 + h if ctx.td else t0])
    # ---- the fixed-point loop on the error box
    Lbar = np.zeros(n) if L_guess is None else np.asarray(L_guess, dtype=float) * GROWTH
    need = None
    for it in range(1, ctx.opts.max_iter + 1):
        rL = up(S_L @ Lbar, n + 1)
        xlo, xhi = inflate_box(np.minimum(base_lo - rL, xs), np.maximum(base_hi + rL, xs))
        if not (np.all(np.isfinite(xlo)) and np.all(np.isfinite(xhi))):
            return StepFail("the tube is not finite", need)
        gx = up(np.maximum(np.abs(xlo - xs), np.abs(xhi - xs)), 1)
        r_rho = up((r_rho0 + mag_dyn + rL) * (1 + 1e-9) + 1e-300, 2)   # inflated like the box
        try:
            Tmag, Hblo, Hbhi = derivative_bounds(ctx, xlo, xhi, t_lo, t_hi)
        except OcreachError as exc:
            return bound_failed(exc, it, need)
        dz = np.concatenate([gx, dv])
        e3 = np.einsum("iabc,a,b,c->i", Tmag, dz, dz, dz) / 6.0
        emix = (np.einsum("a,iab,b->i", gx, Hmag[:, :n, n:], dv)
                + 0.5 * np.einsum("a,iab,b->i", dv, Hmag[:, n:, n:], dv)) if nv else 0.0
        eh = 0.5 * np.einsum("a,iab,b->i", dz, eH, dz)
        # the same terms from the Hessian's variation over the box (second-order Lagrange form)
        ealt = 0.5 * np.einsum("a,iab,b->i", dz, np.maximum(Hbhi - Hs0, Hs0 - Hblo), dz)
        # 1/2 |d - d'|^T |H| (|d| + |d'|), |d| <= gx on the tube's box, |d'| <= gx + mag_dyn
        eq = np.einsum("a,iab,b->i", r_rho, absHxx, up(gx + 0.5 * mag_dyn, 2))
        elin = eval_error(pt[:3], (f0, A, Bv), gx, dv)
        need = up(np.minimum(e3 + emix + eh, ealt) + eq + elin, nz * nz * nz + 8)
        if not np.all(np.isfinite(need)):
            return StepFail("the remainder bound is not finite", need)
        if np.all(need <= Lbar):
            break
        Lbar = np.maximum(Lbar, need) * GROWTH + 1e-300
    else:
        return loop_not_closed(ctx.opts.max_iter, need)
    ctx.last_terms = {"e3": e3, "ealt": ealt, "eq": eq, "emix": emix, "eh": eh, "elin": elin, "r_F": r_F, "r_g": r_g,
                      "r_RW": r_RWz, "gx": gx, "r_rho": r_rho}
    # sensitivity of the bound to the extent of the set in each state (for splitting)
    ctx.weights = (np.einsum("iabc,b,c->a", Tmag[:, :n], dz, dz) / 2.0
                   + np.einsum("iab,b->a", absHxx, r_rho))
    # ---- final sets with the bound found (every trajectory stays in the tube)
    rN = up(S_L @ need, n + 1)
    if ctx.opts.input_factors:
        Zin = RWz.reduce(ctx.opts.input_order, "girard")
        inp = spz.from_generators(np.asarray(Zin.G), ctx.fid, d)
    else:
        inp = SoundPZ(np.zeros(n), np.zeros((n, 0)), np.zeros((0, d), dtype=np.int64),
                      np.zeros(0, dtype=np.int64), np.asarray(RWz.G), np.zeros(n))
    point = spz.pad(spz.translate(spz.add(Pend, inp, bits), xs), rN)
    tube_r = up(r_F + r_g + rN, 3) + rounding_radius(np.abs(seg_lo) + np.abs(seg_hi) + np.abs(xs), 2)
    segz = spz.to_zonotope(seg)
    tube = Zonotope.trusted(segz.c + xs, np.hstack([segz.G, RWz.G, diag_columns(tube_r)]))
    if not all_finite(tube) or not (np.all(np.isfinite(point.c)) and np.all(np.isfinite(point.G))
                                    and np.all(np.isfinite(point.GI))):
        return StepFail("the step's sets are not finite", need)
    return PolyStepOK(point=point, tube=tube, L=need, err_mag=need, iterations=it)


# ------------------------------------------------------------------------------------------------
# the driver (taylor's, with polynomial zonotopes)
# ------------------------------------------------------------------------------------------------
class PolyReach(ZonotopeReach):
    """:class:`ZonotopeReach` with polynomial-zonotope parts and :func:`poly_step`."""

    def __init__(self, method: Method, problem: Problem, opts: PolyOptions):
        super().__init__(method, problem, opts, None, {"scheme": "conservative polynomialization "
                                                      "(Althoff 2013), third-order remainder"})
        self.ctx = PolyContext(self.problem, opts, self.ctx.V, self.ctx.W)

    def step(self, Z, t, h, L):
        return poly_step(self.ctx, Z, t, h, L)

    def set_radius(self, S: SoundPZ) -> np.ndarray:
        return spz.radius(S)

    def reduce_point(self, S: SoundPZ) -> SoundPZ:
        return spz.reduce(S, self.ctx.h_lin, self.ctx.h_poly, self.opts.reduction,
                          self.ctx.fid if self.opts.refactor else None)

    def reduce_tube(self, S: Zonotope) -> Zonotope:
        return S.reduce(self.opts.tube_order, self.opts.reduction)

    def initial_set(self) -> SoundPZ:
        return spz.from_zonotope(initial_zonotope(self.problem), self.ctx.fid, self.ctx.d)

    def can_split_set(self, S: SoundPZ) -> bool:
        return S.n_dependent > 0

    def split_part(self, part: Part) -> tuple[Part, Part]:
        """Split a failing part in two.  The set is first re-encoded with its linear part (the
        factors that occur only linearly, with the independent generators) reduced to its
        interval hull (Girard's box, ``n`` fresh factors): a thrust-dominated set is the sum of
        many comparable generators, so halving one of them barely shrinks it, while halving a box
        generator halves the set's extent in that state -- and the remainder is bounded on the
        box.  It is then split along the factor whose monomials weigh most in the last remainder
        bound (the weights of the failing bound, else the generator norms)."""
        ctx = self.ctx
        S = spz.reduce(part.Z, ctx.n, ctx.h_poly, "girard", ctx.fid)
        w = ctx.weights if ctx.weights is not None else np.ones(S.dim)
        col = w @ np.abs(S.G)
        f = S.factors()
        score = np.array([col[np.any(S.I == k, axis=1)].sum() for k in f])
        a, b = spz.split(S, int(f[int(np.argmax(score))]), ctx.bits)
        return Part(Z=a, L=None, level=part.level), Part(Z=b, L=None, level=part.level)

    def as_set(self, parts: list):
        if self.opts.output == "zonotope":
            zs = [spz.to_zonotope(p) for p in parts]
            return zs[0] if len(zs) == 1 else ZonotopeUnion(zs)
        pzs = [spz.to_polyzonotope(p, self.ctx.fid) for p in parts]
        return pzs[0] if len(pzs) == 1 else PZUnion(pzs)


class PolyReachMethod(Method):
    """Conservative polynomialization on sparse polynomial zonotopes (Althoff 2013)."""

    name = "poly"
    #: guaranteed enclosures with the default options (read by the soundness harness)
    guaranteed = True
    description = ("guaranteed polynomial-zonotope enclosure by conservative polynomialization: "
                   "quadratic static error kept as a polynomial zonotope, third-order remainder by "
                   "interval arithmetic (Althoff HSCC 2013; CORA 'poly')")

    Options = PolyOptions

    @classmethod
    def applicable(cls, problem: Problem) -> tuple[bool, str]:
        return TaylorZonotope.applicable(problem)

    def reacher(self, problem: Problem) -> PolyReach:
        """The propagator of ``problem`` (checked), run by :meth:`solve` and stepped grid step by
        grid step by the hybrid runner (:mod:`ocreach.reach.hybrid`)."""
        check_smooth(problem.model)
        initial_zonotope(problem)  # wrong dimension -> clear error before any work
        return PolyReach(self, problem, self.options)

    def solve(self, problem: Problem) -> ReachResult:
        return self.reacher(problem).run()
