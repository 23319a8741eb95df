"""Symbolic dynamics models and the compiled functions every method derives from them.

A :class:`Model` holds one symbolic CasADi expression ``f(x, u, t; p)``.  Everything numerical that
the methods need (Jacobians, derivative tensors of the augmented dynamics, SDC factors, the optimal
control of the Hamiltonian) is generated from that one expression and compiled once, on first use:
the derivative tensors of the augmented dynamics ``F(z) = [f; 0]``, ``z = [x; u]`` (Foss et al.
Eq. 11-12), the SDC factors ``A(x)`` (Patel & Subbarao Eq. 18-19) and the Hamiltonian-minimising
control (Foss et al. Eq. 4).  :meth:`Model.cached` is the one cache every derived Function goes
through, here and in the method modules.

Conventions
-----------
* States and controls are non-dimensional (see :class:`ocreach.units.Units`).
* Controls are *normalised*: the admissible set is the unit ball ``||u||_2 <= 1`` or the unit box
  ``[-1, 1]^m`` (``control_set``); thrust magnitude lives in a model parameter (e.g. ``a_max``).
* Tensors use NumPy's C order: ``F2[i, a, b] = d^2 F_i / dz_a dz_b``.
"""
from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError
from ocreach.units import Units

CONTROL_SETS = ("ball", "box", "free")


def _names(prefix: str, n: int, given: Sequence[str] | None, what: str) -> tuple[str, ...]:
    if given is None:
        return tuple(f"{prefix}{i}" for i in range(n))
    if len(given) != n:
        raise ProblemError(f"{what} must have {n} entries; got {len(given)}: {list(given)!r}")
    return tuple(given)


@dataclass(frozen=True, eq=False)
class Model:
    """Continuous-time dynamics ``dx/dt = f(x, u, t; p)`` as one symbolic CasADi expression.

    Parameters
    ----------
    name : short identifier, e.g. ``"cr3bp-planar"``.
    x, u, t, p : CasADi ``SX`` symbols (column vectors; ``t`` scalar; ``p`` may be empty).
    f : ``SX`` expression of the state derivative, same length as ``x``.
    p_default : default numeric parameter values (length of ``p``).
    control_set : ``"ball"`` (``||u||_2 <= 1``), ``"box"`` (``|u_i| <= 1``) or ``"free"``
        (unbounded physical controls, e.g. re-entry angles with a prescribed distribution).
    thrust_param : name of the parameter that scales the control's effect (``"a_max"``,
        ``"T_max"``, ``"gain"``), declared by the model builder; "" if none.  Methods that need
        the thrust level (ffoe, ole, bvp) and the problem's plausibility check read it from here.
    throttle : ``(sigma, f_sigma)`` or None.  For a model whose ``f`` depends on the control norm
        ``||u||`` (the mass flow ``dn/dt ~ ||u||`` of Patel & Scheeres Eq. 11), ``f_sigma`` is ``f``
        with ``||u||`` replaced by the scalar symbol ``sigma``.  ``||u||`` has no Taylor expansion
        at ``u = 0``, so expansion-based methods (stt) use :meth:`throttle_relaxed` instead.
    """

    name: str
    x: ca.SX
    u: ca.SX
    t: ca.SX
    p: ca.SX
    f: ca.SX
    p_default: np.ndarray
    state_names: tuple[str, ...]
    control_names: tuple[str, ...]
    param_names: tuple[str, ...]
    control_set: str = "ball"
    units: Units | None = None
    description: str = ""
    state_units: tuple[str, ...] = ()
    thrust_param: str = ""
    throttle: tuple[ca.SX, ca.SX] | None = field(default=None, repr=False)
    cache: dict = field(default_factory=dict, repr=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def build(
        cls,
        name: str,
        x: ca.SX,
        u: ca.SX,
        f: ca.SX,
        *,
        t: ca.SX | None = None,
        p: ca.SX | None = None,
        p_default: Sequence[float] | None = None,
        state_names: Sequence[str] | None = None,
        control_names: Sequence[str] | None = None,
        param_names: Sequence[str] | None = None,
        control_set: str = "ball",
        units: Units | None = None,
        description: str = "",
        state_units: Sequence[str] | None = None,
        thrust_param: str = "",
        throttle: tuple[ca.SX, ca.SX] | None = None,
    ) -> Model:
        """Validate shapes and build a model (the usual constructor).

        ``state_units``: optional unit label per state (e.g. ``"DU"``, ``"DU/TU"``) for plots.
        ``throttle``: ``(sigma, f_sigma)``, see the class docstring (``f`` must equal ``f_sigma``
        with ``sigma = ||u||``; the builder substitutes it, the check here is on shapes).
        """
        t = ca.SX.sym("t") if t is None else t
        p = ca.SX.sym("p", 0) if p is None else p
        f = ca.SX(f)
        if f.shape != (x.numel(), 1):
            raise ProblemError(f"f must be a column of length n_x = {x.numel()}; got shape {f.shape}")
        if control_set not in CONTROL_SETS:
            raise ProblemError(f"control_set must be one of {CONTROL_SETS}; got {control_set!r}")
        pd = np.zeros(p.numel()) if p_default is None else np.asarray(p_default, dtype=float).ravel()
        if pd.size != p.numel():
            raise ProblemError(f"p_default must have {p.numel()} entries; got {pd.size}")
        pnames = _names("p", p.numel(), param_names, "param_names")
        if throttle is not None:
            sigma, f_sigma = throttle
            if not (isinstance(sigma, ca.SX) and sigma.is_symbolic() and sigma.numel() == 1):
                raise ProblemError(f"throttle[0] must be one scalar SX symbol; got {sigma!r}")
            if ca.SX(f_sigma).shape != f.shape:
                raise ProblemError(f"throttle[1] must have the shape of f {f.shape}; "
                                   f"got {ca.SX(f_sigma).shape}")
            throttle = (sigma, ca.SX(f_sigma))
        if thrust_param and thrust_param not in pnames:
            raise ProblemError(f"thrust_param must be one of the parameters {list(pnames)}; "
                               f"got {thrust_param!r}")
        return cls(
            name=name, x=x, u=u, t=t, p=p, f=f, p_default=pd, thrust_param=thrust_param,
            state_names=_names("x", x.numel(), state_names, "state_names"),
            control_names=_names("u", u.numel(), control_names, "control_names"),
            param_names=pnames,
            control_set=control_set, units=units, description=description, throttle=throttle,
            state_units=_names("", x.numel(), state_units, "state_units") if state_units is not None
            else ("",) * x.numel(),
        )

    # ------------------------------------------------------------------ sizes
    @property
    def n_x(self) -> int:
        return self.x.numel()

    @property
    def n_u(self) -> int:
        return self.u.numel()

    @property
    def n_p(self) -> int:
        return self.p.numel()

    @property
    def n_z(self) -> int:
        """Size of the augmented state ``z = [x; u]`` (Foss et al. Eq. 12)."""
        return self.n_x + self.n_u

    def params(self, overrides: dict | None = None) -> np.ndarray:
        """Parameter vector with ``overrides`` ({name: value}) applied to the defaults."""
        p = self.p_default.copy()
        for key, value in (overrides or {}).items():
            if key not in self.param_names:
                raise ProblemError(f"unknown parameter {key!r} of model {self.name}; "
                                   f"allowed: {list(self.param_names)}")
            p[self.param_names.index(key)] = float(value)
        return p

    def param(self, name: str, p: np.ndarray | None = None) -> float:
        """Value of one named parameter in ``p`` (defaults if ``p`` is None)."""
        if name not in self.param_names:
            raise ProblemError(f"model {self.name} has no parameter {name!r}; "
                               f"allowed: {list(self.param_names)}")
        return float((self.p_default if p is None else p)[self.param_names.index(name)])

    # ------------------------------------------------------------------ compiled functions
    def cached(self, key: Hashable, builder: Callable[[], Any]) -> Any:
        """``builder()`` computed once per ``key`` and kept in :attr:`cache` (how every CasADi
        Function derived from this model, here and in the method modules, is built only once)."""
        if key not in self.cache:
            self.cache[key] = builder()
        return self.cache[key]

    @property
    def f_fun(self) -> ca.Function:
        """``f(x, u, t, p) -> xdot``."""
        return self.cached("f", lambda: ca.Function(
            "f", [self.x, self.u, self.t, self.p], [self.f], ["x", "u", "t", "p"], ["xdot"]))

    def costate_dynamics(self, lam: ca.SX, u: ca.SX) -> tuple[ca.SX, ca.SX]:
        """Symbolic state and costate rates ``dx/dt = f(x, u, t)``, ``dlam/dt = -(df/dx)^T lam``
        (Foss et al. Eq. 4) for a control expression ``u`` (usually ``u*(x, lam)``)."""
        f, A, _ = self.jac_fun(self.x, u, self.t, self.p)
        return f, -ca.mtimes(A.T, lam)

    @property
    def jac_fun(self) -> ca.Function:
        """``(x, u, t, p) -> (f, df/dx, df/du)``."""
        return self.cached("jac", lambda: ca.Function(
            "f_jac", [self.x, self.u, self.t, self.p],
            [self.f, ca.jacobian(self.f, self.x), ca.jacobian(self.f, self.u)],
            ["x", "u", "t", "p"], ["f", "A", "B"]))

    @cached_property
    def z(self) -> ca.SX:
        """Augmented state symbol ``z = [x; u]`` (Foss et al. Eq. 12)."""
        return ca.vertcat(self.x, self.u)

    def derivative_expressions(self, order: int) -> list[ca.SX]:
        """Symbolic derivatives of ``f`` w.r.t. ``z`` of orders 1..``order``.

        Entry ``j-1`` is an ``SX`` of shape ``(n_x * n_z**(j-1), n_z)``; reshaped in C order it is
        the tensor ``d^j f_i / dz_a dz_b ...`` (the ``f*_{i,alpha...}`` of Foss et al. Eq. 11).
        The augmented dynamics ``F = [f; 0]`` (Eq. 12) only add zero rows, which callers append.
        """
        if order not in (1, 2, 3):
            raise ProblemError(f"order must be 1, 2 or 3; got {order!r}")

        def build():
            out = [ca.jacobian(self.f, self.z)]
            for _ in range(1, 3):
                prev = out[-1]
                # row-major flatten of the previous tensor, then differentiate again
                flat = ca.reshape(prev.T, prev.numel(), 1)
                out.append(ca.jacobian(flat, self.z))
            return out

        return self.cached("dexpr", build)[:order]

    def tensor_fun(self, order: int) -> ca.Function:
        """``(x, u, t, p) -> (f, D1, ..., D_order)`` with ``D_j`` flat as in :meth:`derivative_expressions`."""
        if order not in (1, 2, 3):
            raise ProblemError(f"order must be 1, 2 or 3; got {order!r}")
        return self.cached(("tensor", order), lambda: ca.Function(
            f"f_tensors{order}", [self.x, self.u, self.t, self.p],
            [self.f, *self.derivative_expressions(order)]))

    def tensors(self, x, u, t: float = 0.0, p=None, order: int = 3) -> list[np.ndarray]:
        """Numeric derivative tensors of the *augmented* dynamics ``F(z) = [f; 0]`` (Foss Eq. 12).

        Returns ``[F (n_z,), F1 (n_z, n_z), F2 (n_z, n_z, n_z), F3 (n_z,)*4]`` up to ``order``.
        """
        out = self.tensor_fun(order)(x, u, t, self.p_default if p is None else p)
        out = out if isinstance(out, (list, tuple)) else [out]
        nx, nz = self.n_x, self.n_z
        res = [np.concatenate([np.asarray(out[0]).ravel(), np.zeros(self.n_u)])]
        for j in range(1, order + 1):
            d = np.asarray(out[j]).reshape((nx,) + (nz,) * j)
            full = np.zeros((nz,) + (nz,) * j)
            full[:nx] = d
            res.append(full)
        return res

    # ------------------------------------------------------------------ SDC factor
    def sdc_expression(self, n_quad: int = 8) -> tuple[ca.SX, ca.SX]:
        """SDC factor ``A(x; x0) = int_0^1 df/dx(x0 + lam (x - x0)) dlam`` (Patel & Subbarao Eq. 18).

        With base point ``x0 = 0`` this is Eq. 18 exactly; a non-zero base point gives the exact
        identity ``f(x) = f(x0) + A(x; x0) (x - x0)`` (the mean-value form), which is what a model
        with ``f(0) != 0`` (CR3BP) needs.  The integral is evaluated by ``n_quad``-point
        Gauss-Legendre quadrature; it is exact for polynomial ``f`` of degree <= 2 n_quad.
        Returns ``(x0_symbol, A_expression)``; ``u`` is held at its symbol.
        """
        def build():
            x0 = ca.SX.sym("x0", self.n_x)
            nodes, weights = np.polynomial.legendre.leggauss(n_quad)
            lam = 0.5 * (nodes + 1.0)
            w = 0.5 * weights
            jac = ca.Function("jx", [self.x, self.u, self.t, self.p], [ca.jacobian(self.f, self.x)])
            A = ca.SX.zeros(self.n_x, self.n_x)
            for lk, wk in zip(lam, w):
                A += wk * jac(x0 + lk * (self.x - x0), self.u, self.t, self.p)
            return x0, A

        return self.cached(("sdc_expr", n_quad), build)

    def sdc_fun(self, n_quad: int = 8) -> ca.Function:
        """``(x, x0, u, t, p) -> (A, dA/dx)``; ``dA/dx`` has shape ``(n_x*n_x, n_x)``.

        Reshape ``dA/dx`` in Fortran order to ``(n_x, n_x, n_x)`` to get ``dA[i, j] / dx_k``
        (CasADi flattens ``A`` column-major).  Patel & Subbarao Eq. 18-19.
        """
        def build():
            x0, A = self.sdc_expression(n_quad)
            dA = ca.jacobian(ca.reshape(A, -1, 1), self.x)
            return ca.Function("sdc", [self.x, x0, self.u, self.t, self.p], [A, dA],
                               ["x", "x0", "u", "t", "p"], ["A", "dA"])

        return self.cached(("sdc", n_quad), build)

    # ------------------------------------------------------------------ control structure
    def with_control_set(self, kind: str) -> Model:
        """The same dynamics with admissible set ``kind`` (``"ball"``/``"box"``) for the
        control laws (cached; its derived Functions are cached on the copy)."""
        import dataclasses

        if kind == self.control_set:
            return self
        if kind not in CONTROL_SETS:
            raise ProblemError(f"control set kind must be one of {CONTROL_SETS}; got {kind!r}")
        return self.cached(("with_control_set", kind), lambda: dataclasses.replace(
            self, name=f"{self.name}-{kind}", control_set=kind, cache={}))

    def throttle_relaxed(self, sigma_max: float = 1.0) -> Model:
        """The dynamics with ``||u||`` replaced by an extra control ``s in [-1, 1]``,
        ``sigma = sigma_max (1 + s) / 2 in [0, sigma_max]`` (cached per ``sigma_max``; the model
        itself if it declares no throttle).

        For ``||u|| <= sigma_max`` every control ``u`` of this model is the control
        ``(u, 2||u|| / sigma_max - 1)`` of the relaxed one, so the relaxed reachable set contains
        the true one; the relaxed ``f`` is smooth in the controls at ``u = 0``, where ``||u||``
        (regularised or not) has no Taylor expansion: its second derivative there is ``1/eps``
        (``1e15`` for the ``sqrt(|u|^2 + 1e-30)`` of the builders), which made the order-2 STT of
        the mass flow explode and the Lagrange remainder of ``taylor`` diverge on the first step.
        """
        import dataclasses

        if self.throttle is None:
            return self
        if not (np.isfinite(sigma_max) and sigma_max > 0):
            raise ProblemError(f"sigma_max must be finite and > 0; got {sigma_max!r}")
        sigma, f_sigma = self.throttle
        sigma_max = float(sigma_max)

        def build() -> Model:
            s = ca.SX.sym("s_throttle")
            u = ca.vertcat(self.u, s)
            f = ca.substitute(f_sigma, sigma, 0.5 * sigma_max * (1 + s))
            return dataclasses.replace(self, name=f"{self.name}-throttle", u=u, f=f, throttle=None,
                                       control_names=(*self.control_names, "throttle"), cache={})

        key = "throttle_relaxed" if sigma_max == 1.0 else ("throttle_relaxed", sigma_max)
        return self.cached(key, build)

    @cached_property
    def control_affine(self) -> bool:
        """True if ``f = f0(x, t) + G(x, t) u`` (``df/du`` does not depend on ``u``)."""
        return not ca.depends_on(ca.jacobian(self.f, self.u), self.u)

    def optimal_control_expression(self, lam: ca.SX, smooth: float = 0.0,
                                   kind: str | None = None) -> ca.SX:
        """``u* = argmin_{u in U} lam^T f(x, u, t)`` for control-affine models (Foss et al. Eq. 4).

        ``kind`` is the admissible set (default: the model's ``control_set``).  Ball:
        ``u* = -G^T lam / ||G^T lam||``; box: ``u* = -sign(G^T lam)``.  ``smooth > 0``
        regularises the switching (``sqrt(s^2 + smooth^2)`` / ``tanh(s/smooth)``) for Newton-type
        solvers; ``smooth = 0`` is the exact law.  A ``"free"`` (unbounded) set has no minimiser.
        """
        kind = self.control_set if kind is None else kind
        if kind not in ("ball", "box"):
            raise ProblemError(f"the optimal control needs a bounded control set 'ball' or 'box'; "
                               f"got {kind!r} (model {self.name})")
        if not self.control_affine:
            raise ProblemError(f"model {self.name} is not control-affine; the closed-form optimal "
                               "control needs f = f0(x, t) + G(x, t) u")
        G = ca.jacobian(self.f, self.u)
        s = ca.mtimes(G.T, lam)
        if kind == "ball":
            norm = ca.sqrt(ca.sumsqr(s) + smooth**2)
            return -s / ca.fmax(norm, 1e-300)
        if smooth > 0:
            return -ca.tanh(s / smooth)
        return -ca.sign(s)

    # ------------------------------------------------------------------ numeric helpers
    def __call__(self, x, u=None, t: float = 0.0, p=None) -> np.ndarray:
        """Evaluate ``f`` numerically at one point (defaults: ``u = 0``, default parameters)."""
        u = np.zeros(self.n_u) if u is None else u
        return np.asarray(self.f_fun(x, u, t, self.p_default if p is None else p)).ravel()

    def validate_state(self, x, name: str = "x0") -> np.ndarray:
        """Return ``x`` as a float array of length ``n_x`` or raise a clear :class:`ProblemError`."""
        arr = np.asarray(x, dtype=float)
        if arr.shape[-1:] != (self.n_x,):
            raise ProblemError(f"{name} must have length n_x = {self.n_x} for model {self.name} "
                               f"(states {list(self.state_names)}); got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ProblemError(f"{name} must be finite; got {arr!r}")
        return arr


#: Parameter names recognised as the thrust level when a model does not declare ``thrust_param``.
LEGACY_THRUST_PARAMS = ("a_max", "T_max")


def find_thrust_param(model: Model) -> str:
    """The model's declared ``thrust_param``, else ``a_max``/``T_max`` if it has one, else ""."""
    if model.thrust_param:
        return model.thrust_param
    return next((n for n in LEGACY_THRUST_PARAMS if n in model.param_names), "")

