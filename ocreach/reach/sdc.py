"""``sdc``: guaranteed zonotope reachability with the state-dependent-coefficient (SDC) form
(Patel & Subbarao Method 2, Eq. 17-25), in continuous time on the linear-system step of
:mod:`ocreach.reach.linsys`, the fixed-point loop of :mod:`ocreach.reach.taylor_step` and the
sub-step / splitting driver of :mod:`ocreach.reach.taylor`.

For control-affine dynamics with a constant input matrix, ``f(x, u) = f0(x) + B u``, the SDC factor
about the base point ``x*`` (the linearisation point of the step, the set centre moved by
``h/2 f``) is ``A(x; x*) = int_0^1 df0/dx(x* + lam (x - x*)) dlam`` (Eq. 18 with base ``x*``;
:meth:`ocreach.model.Model.sdc_fun`), so that exactly ``f0(x) = f0(x*) + A(x; x*) (x - x*)``.
Expanding the matrix about ``x*`` (Eq. 19-21):

    A(x; x*) = A(x*) + sum_k dA/dx_k (x - x*)_k + R_err(x),

with ``A(x*) = df0/dx(x*)`` and ``dA/dx_k = 1/2 d^2 f0/dx dx_k`` at ``x*`` (exact: the quadrature
of ``sdc_fun`` integrates the linear term in ``lam`` exactly), and, by Taylor's theorem inside the
integral, ``R_err,ij in 1/6 sum_kl T_ijkl (x - x*)_k (x - x*)_l`` with the third derivatives
``T = d^3 f0 / dx^3`` bounded by interval arithmetic over the tube's box (:mod:`ocreach.intervals`;
the paper leaves ``R_err`` undefined).  So on the tube, with ``d = x - x*`` in the zonotope
``D = tube - x*``:

* ``R_lin``: ``A(x*) d`` is the linear part of the step (Eq. 23);
* ``R_dev``: ``(sum_k dA/dx_k d_k) d`` lies in the matrix zonotope of Eq. 21 (generators
  ``G~_j = sum_k dA/dx_k g_kj``) times ``D`` (Eq. 24, :func:`matzonotope_times_zonotope`);
* ``R_err d`` is in the box ``1/6 sum_jkl |T_ijkl| gamma_j gamma_k gamma_l``, ``gamma = max |d|``;

and ``R_dev + R_err d`` is the error input of the step (Eq. 25).  As for ``taylor`` it is found by
the fixed-point loop on the tube and a part whose error cannot be enclosed is halved in time, then
bisected along the generator with the largest contribution (the paper's bisection on ``R_err``).

The paper's literal variant (``base="origin"``): base point 0, ``f(x) = A(x; 0) x``, and Eq. 21
taken as an enclosure (no ``R_err``).  It is NOT sound and is marked so in ``meta``: for the CR3BP
``f(0) != 0`` (so ``A(x; 0) x = f(x) - f(0)`` drops the constant term) and for the two-body
problem the segment from the origin passes through the singularity ``r = 0``.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError, check_count
from ocreach.fastcall import FastFunction
from ocreach.problem import Problem
from ocreach.reach.base import Method
from ocreach.reach.linsys import abs_extent, pad
from ocreach.reach.result import ReachResult
from ocreach.reach.taylor import (
    TaylorZonotope,
    ZonotopeOptions,
    ZonotopeReach,
    check_smooth,
    initial_zonotope,
)
from ocreach.reach.taylor_step import eval_error, time_dependent, tube_box, unflatten_hessian
from ocreach.sets.matzonotope import matzonotope_product
from ocreach.sets.rounding import rounding_radius, up
from ocreach.sets.zonotope import Zonotope

BASES = ("center", "origin")
UNSOUND_REASON = ("base point 0 with Eq. 21 taken as an enclosure: A(x; 0) x = f(x) - f(0) drops "
                  "f(0) != 0 (CR3BP), the segment from the origin crosses the two-body singularity, "
                  "and the matrix expansion has no remainder R_err")


def sdc_model_problem(model) -> str:
    """Why ``sdc`` cannot take ``model`` ("" if it can): the SDC form ``f = A(x) x + B u``
    (Patel & Subbarao Eq. 17) needs a constant input matrix ``B`` and no explicit time
    dependence.  The reason names the rows of ``f`` whose ``df/du`` depends on the state or the
    control and what it depends on (e.g. the thrust ``T_max n u`` and the mass flow
    ``T_max n^2 ||u|| / c`` of Patel & Scheeres Eq. 11)."""
    def build() -> str:
        Bsym = ca.jacobian(model.f, model.u)
        rows = []
        for i, name in enumerate(model.state_names):
            on = [nm for j, nm in enumerate(model.state_names) if ca.depends_on(Bsym[i, :], model.x[j])]
            on += [nm for j, nm in enumerate(model.control_names)
                   if ca.depends_on(Bsym[i, :], model.u[j])]
            if on:
                rows.append(f"{name} (on {', '.join(on)})")
        if rows:
            return (f"sdc needs control-affine dynamics f = f0(x) + B u with a constant B "
                    f"(Patel & Subbarao Eq. 17); df/du of model {model.name!r} depends on the state "
                    f"or control in the rows {'; '.join(rows)}"
                    + (" -- the thrust scaled by the inverse mass and the mass flow ||u||"
                       if model.throttle is not None else "")
                    + ". Use taylor or poly, which linearise in the control too")
        if time_dependent(model):
            return (f"sdc needs autonomous dynamics; model {model.name!r} depends on t "
                    "(use taylor or poly, which take t as an input)")
        return ""

    return model.cached(("sdc", "model_problem"), build)


def check_sdc_model(model) -> None:
    """Raise :class:`ProblemError` with :func:`sdc_model_problem`'s reason, if any."""
    why = sdc_model_problem(model)
    if why:
        raise ProblemError(why)


def third_interval(model):
    """Interval extension of ``(f, df/dx, df/du, H, T)``: ``H`` the Hessian in ``x`` (flat
    ``(n n, n)``) and ``T[l, i, j, k] = d^3 f_i / dx_j dx_k dx_l`` (flat).  One call on two boxes:
    the point ``x*`` (the rounding of the float ``f0``, ``A``, ``B``, ``dA``) and the tube's box
    (``R_err``)."""
    from ocreach.intervals import interval_function

    def build():
        x = model.x
        J = ca.jacobian(model.f, x)
        H = ca.jacobian(ca.reshape(J.T, -1, 1), x)
        T = ca.jacobian(ca.reshape(H.T, -1, 1), x)
        return ca.Function("sdc_third", [model.x, model.u, model.t, model.p],
                           [model.f, J, ca.jacobian(model.f, model.u), H, T])

    fun = model.cached(("sdc", "lin_third_fun"), build)
    return interval_function(fun, model=model, key=("sdc", "lin_third"), native=True)


class SDCError:
    """Error input ``R_dev + R_err d`` of the SDC expansion about the step's base point."""

    def __init__(self, model, p: np.ndarray, dev_order: float, base: str):
        self.model = model
        self.p = np.asarray(p, dtype=float)
        self.dev_order = dev_order
        self.base = base
        self.sdc = FastFunction(model.sdc_fun())  # one per run: not re-entrant
        self.T = third_interval(model) if base == "center" else None
        self.hmag: np.ndarray | None = None
        self.gamma: np.ndarray | None = None
        n = model.n_x
        self.B = np.asarray(ca.Function("B", [model.x, model.u, model.t, model.p],
                                        [ca.jacobian(model.f, model.u)])(np.zeros(n), np.zeros(model.n_u),
                                                                         0.0, self.p))

    def _dA(self, x: np.ndarray, x0: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = self.model.n_x
        A, dA = self.sdc(x, x0, u, 0.0, self.p)
        return np.asarray(A), np.asarray(dA).reshape(n, n, n, order="F")

    def linearize(self, xs: np.ndarray, uc: np.ndarray, ts: float):
        """``(f(x*), A, B)`` of the step: the Jacobian for ``base="center"``; ``A(x*; 0)`` and
        ``A(x*; 0) x* + B u`` for the literal ``base="origin"``."""
        if self.base == "center":
            return None
        A0, _ = self._dA(xs, np.zeros_like(xs), uc)
        return A0 @ xs + self.B @ uc, A0, self.B

    def bound(self, tube: Zonotope, xs: np.ndarray, vs: np.ndarray, Vbox: tuple, t_box: tuple,
              lin: tuple) -> Zonotope:
        """Error set ``R_dev + R_err d`` on the tube, plus (``base="center"``) the rounding of the
        float ``f0``, ``A``, ``B`` (:func:`~ocreach.reach.taylor_step.eval_error`) and ``dA`` against
        their interval enclosures at ``x*``, and the rounding of the matrix-zonotope product."""
        n = self.model.n_x
        nu = self.model.n_u
        # D must contain tube - x* exactly: the centre's subtraction is rounded
        D0 = Zonotope.trusted(tube.c - xs, tube.G)
        D0 = pad(D0, rounding_radius(np.abs(tube.c) + np.abs(xs), 1))
        D = D0.reduce(self.dev_order, "girard")
        base = xs if self.base == "center" else np.zeros(n)
        u = vs[:nu]
        _, dA = self._dA(xs, base, u)
        # matrix zonotope of Eq. 21 about x*: centre sum_k dA_k c_k, generators sum_k dA_k g_kj
        C = np.tensordot(dA, D.c, axes=([2], [0]))
        Gs = np.einsum("ijk,kh->hij", dA, D.G)
        Dx_c = D.c if self.base == "center" else D.c + xs
        # literal: (sum dA_k d_k) x, x = x* + d (matzonotope_times_zonotope on the arrays)
        dev = Zonotope.trusted(*matzonotope_product(C, Gs, Dx_c, D.G))
        # rounding of C, Gs and the product: absolute value (sum_k |dA_k| a_D,k) a_Dx
        aD = abs_extent(D)
        aDx = aD if self.base == "center" else aD + np.abs(xs)
        dev_abs = np.einsum("ijk,k->ij", np.abs(dA), aD) @ aDx
        dev = pad(dev, rounding_radius(dev_abs, 2 * n + 4))
        dev = dev.reduce(max(self.dev_order, 2.0), "girard")
        self.hmag = 2.0 * np.abs(dA).sum(axis=0)
        xlo, xhi = tube_box(tube, xs)
        gamma = np.maximum(np.abs(xlo - xs), np.abs(xhi - xs))
        self.gamma = gamma
        if self.T is None:
            return dev
        gamma = up(gamma, 1)
        ulo, uhi = Vbox
        out = self.T([np.stack([xs, xlo], axis=1), np.stack([u, ulo], axis=1),
                      np.array([t_box[0], t_box[0]]), self.p],
                     [np.stack([xs, xhi], axis=1), np.stack([u, uhi], axis=1),
                      np.array([t_box[0], t_box[1]]), self.p], check=False)
        Tlo, Thi = out[4]
        Tmag = np.maximum(np.abs(Tlo[:, 1]), np.abs(Thi[:, 1])).reshape(n, n, n, n)  # (l, i, j, k)
        r = np.einsum("lijk,j,k,l->i", Tmag, gamma, gamma, gamma) / 6.0
        r = r * (1 + 1e-12) + 1e-300
        # float dA against the interval Hessian at x*: dA_ijk = 1/2 d^2 f_i / dx_j dx_k
        Hlo, Hhi = out[3]
        Hlo = unflatten_hessian(Hlo[:, :1], n, n)[0]
        Hhi = unflatten_hessian(Hhi[:, :1], n, n)[0]
        rdA = up(np.maximum(dA - 0.5 * Hlo, 0.5 * Hhi - dA), 2)
        r = r + np.einsum("ijk,j,k->i", rdA, gamma, gamma)
        gv = up(np.maximum(np.abs(ulo - u), np.abs(uhi - u)), 1)
        r = up(r + eval_error(out[:3], lin, gamma, gv), n * n + 4)
        return pad(dev, r)

    def split_scores(self, Z: Zonotope) -> np.ndarray:
        if self.hmag is None:
            return np.linalg.norm(Z.G, axis=0)
        return np.abs(Z.G).T @ (self.hmag @ self.gamma)


class SDCZonotope(Method):
    """Patel & Subbarao Method 2: zonotopes with the SDC matrix expansion (Eq. 17-25)."""

    name = "sdc"
    guaranteed = True
    description = ("guaranteed zonotope enclosure with the state-dependent-coefficient matrix "
                   "expansion and an interval R_err (Patel & Subbarao Method 2)")

    @dataclass
    class Options(ZonotopeOptions):
        """:class:`~ocreach.reach.taylor.ZonotopeOptions` plus the SDC factorisation's."""

        #: base point of the factorisation: "center" (sound) or "origin" (the paper's literal
        #: base point 0, NOT sound: see the module docstring)
        base: str = "center"
        #: zonotope order of the tube in the matrix-zonotope product of Eq. 24 (its generators
        #: multiply pairwise), >= 1
        dev_order: float = 2.0

        def __post_init__(self) -> None:
            super().__post_init__()
            if self.base not in BASES:
                raise ProblemError(f"base must be one of {BASES}; got {self.base!r}")
            self.dev_order = float(check_count("dev_order", self.dev_order, 1))

    @classmethod
    def applicable(cls, problem: Problem) -> tuple[bool, str]:
        """:meth:`TaylorZonotope.applicable` and the SDC form (:func:`sdc_model_problem`)."""
        ok, why = TaylorZonotope.applicable(problem)
        if not ok:
            return ok, why
        why = sdc_model_problem(problem.model)
        return not why, why

    def solve(self, problem: Problem) -> ReachResult:
        return self.reacher(problem).run()

    def reacher(self, problem: Problem) -> ZonotopeReach:
        """The propagator of ``problem`` (checked), run by :meth:`solve` and stepped by the
        hybrid runner (:mod:`ocreach.reach.hybrid`)."""
        check_smooth(problem.model)
        check_sdc_model(problem.model)
        initial_zonotope(problem)
        o = self.options
        meta = {"alg": "ct", "base": o.base}
        if o.base == "origin":
            meta.update({"guaranteed": False, "unsound_reason": UNSOUND_REASON})
        return ZonotopeReach(self, problem, o,
                             lambda prob: SDCError(prob.model, prob.params, o.dev_order, o.base), meta)
