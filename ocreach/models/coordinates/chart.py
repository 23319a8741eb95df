"""A coordinate chart of a model and the dynamics it induces, generated from the one CasADi model.

A :class:`Chart` holds a change of coordinates ``z = phi(x; p)`` with its inverse
``x = psi(z; p)`` (both symbolic CasADi expressions), and optionally a new independent variable
``s`` in place of the time ``t``.  The dynamics in the new coordinates are *derived* from the
model's ``f``, never typed a second time:

* same independent variable: ``dz/dt = (dphi/dx)(psi(z)) f(psi(z), u, t)`` (the chain rule, the
  Jacobian by CasADi);
* a time transformation ``dt = g ds`` (Sundman 1912; ``g = r^k``, or ``g = 1 / (dz_i/dt)`` when the
  coordinate ``z_i`` itself becomes the independent variable, e.g. the true longitude of the
  modified equinoctial elements): the state gains the time, ``w = (z, t)``, and
  ``dz/ds = g dz/dt``, ``dt/ds = g``; a coordinate that is the independent variable has
  ``dz_i/ds = 1`` exactly (not ``f_i / f_i``, which an interval bound would widen).

Simplified forms.  The chain rule applied to the model is exact, but its interval enclosure can
be useless: for the equinoctial elements the Keplerian drift of ``p, f, g, h, k`` is zero only
through cancellations (``h . (r x r)``, the conservation of the Laplace-Runge-Lenz vector) that
interval arithmetic cannot see, and the thrust terms pass through the Cartesian state and back
(norms, cross products, the derivative of ``atan2``).  Measured on earth-mars: the interval
Hessian of the generated drift on a set 0.2 rad wide in ``L`` is 1e4 times its true size (a
remainder bound of 500 against 0.05), and ``taylor`` with the generated thrust terms reaches 16 d
where the same terms in closed form reach 61 d.  A chart may therefore declare the algebraically
simplified forms of its own chain rule: ``drift`` (the unperturbed motion it is built around, for
the elements Keplerian motion, ``dL/dt = sqrt(mu p) (w / p)^2``) and ``input_matrix`` (the rates
per unit thrust acceleration in its control frame, for the elements Walker et al.'s perturbation
equations).  Then, for a model whose thrust is ``s u`` on the velocity rows,

    dz/dt = drift(z) + s input_matrix(z) u;

with a declared ``drift`` only, ``dz/dt = drift(z) + (dphi/dx)(psi(z)) G(psi(z), t) u``.  These are
not a second model: :meth:`Chart.check_forms` compares them with the chain rule of the model at
sample points (coasting and thrusting) before any work and refuses the chart if they differ
(a model with another drift, e.g. an oblate central body, or another thrust law); the setting
``form=generated`` uses the chain rule alone.

The control frame.  For a rotation-invariant control set (the thrust ball) a chart may also
express the control in a state-dependent orthonormal frame, ``u = R(x) u'`` (``control_frame``;
for the elements the radial / transverse / normal frame of the orbit): for every state ``R(x)``
maps the unit ball onto itself, and ``u(t) = R(x(t)) u'(t)`` is measurable exactly when ``u'`` is,
so the reachable sets are the same.  It matters for set methods: the thrust enters the elements
through ``(dphi/dx) G R``, which depends far less on the state than ``(dphi/dx) G`` (the inertial
thrust direction seen in the orbit's frame turns with the true longitude; measured on
earth-mars with ``taylor``: 17-21 d without the frame, 61 d with it).  Controls of samples are
then given in the frame, not in the model's axes.

Validity: ``valid_x`` (expressions of ``x``) and ``valid_z`` (expressions of ``z``) must be > 0
wherever the chart is used; the conversions check them with sound interval bounds, so a set that
reaches a singularity of the chart (a retrograde equatorial orbit for the equinoctial elements, a
collision for a Sundman transformation) is refused or reported, never converted wrongly.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError
from ocreach.model import Model


@dataclass(frozen=True, eq=False)
class Chart:
    """Coordinates ``z = phi(x; p)``, ``x = psi(z; p)`` of ``model`` (module docstring).

    Attributes
    ----------
    name : the coordinates' name as users type it (``"mee"``, ``"mee-longitude"``, ...).
    model : the Cartesian model.
    z : ``SX`` symbols of the new coordinates (as many as ``model.x``).
    phi : expression of ``z`` in ``model.x`` and ``model.p``.
    psi : expression of ``x`` in ``z`` and ``model.p``.
    names, units : per coordinate, for plots and tables.
    valid_x, valid_z : expressions that must be > 0 where the chart is used (``SX`` columns, may
        be empty); ``valid_why`` says in words what a failure means.
    time_scale : ``dt/ds`` as an expression of ``model.x`` (a Sundman transformation), or None.
    independent : index of the coordinate that becomes the independent variable, or None.
    control_frame : ``R(x)`` (``n_u x n_u`` orthonormal, an expression of ``model.x``): the control
        of the new dynamics is ``u'`` with ``u = R(x) u'`` (ball control sets only), or None.
    drift, input_matrix : simplified forms of the chain rule (module docstring): the unperturbed
        field ``dz/dt`` at ``u = 0`` and ``d(dz/dt)/d(a)`` for a unit thrust acceleration ``a``
        in the control frame (expressions of ``z`` and ``model.p``), verified against the chain
        rule by :meth:`check_forms`; None: the chain rule itself.
    s_name, s_unit : name and unit of the independent variable (``"t"`` when time is kept).
    description, citation : what the chart is and where it comes from.
    """

    name: str
    model: Model
    z: ca.SX
    phi: ca.SX
    psi: ca.SX
    names: tuple[str, ...]
    units: tuple[str, ...]
    valid_x: ca.SX
    valid_z: ca.SX
    valid_why: str = ""
    time_scale: ca.SX | None = None
    independent: int | None = None
    drift: ca.SX | None = None
    drift_name: str = ""
    control_frame: ca.SX | None = None
    input_matrix: ca.SX | None = None
    s_name: str = "t"
    s_unit: str = "TU"
    description: str = ""
    citation: str = ""
    cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        n = self.model.n_x
        for what, e in (("z", self.z), ("phi", self.phi), ("psi", self.psi)):
            if e.shape != (n, 1):
                raise ProblemError(f"chart {self.name!r}: {what} must be a column of length "
                                   f"n_x = {n}; got shape {e.shape}")
        if self.time_scale is not None and self.independent is not None:
            raise ProblemError(f"chart {self.name!r}: give time_scale or independent, not both")
        if self.independent is not None and not 0 <= self.independent < n:
            raise ProblemError(f"chart {self.name!r}: independent must be in 0..{n - 1}; "
                               f"got {self.independent}")

    # ------------------------------------------------------------------ properties
    @property
    def time_transformed(self) -> bool:
        """True if the independent variable is not the time (the state then gains ``t``)."""
        return self.time_scale is not None or self.independent is not None

    @property
    def n_w(self) -> int:
        """Size of the propagated state: ``n_x``, plus the time for a time transformation."""
        return self.model.n_x + (1 if self.time_transformed else 0)

    def cached(self, key: Any, builder):
        if key not in self.cache:
            self.cache[key] = builder()
        return self.cache[key]

    # ------------------------------------------------------------------ the induced dynamics
    @cached_property
    def generated_rates(self) -> ca.SX:
        """``dz/dt = (dphi/dx)(psi(z)) f(psi(z), R u, t)`` by the chain rule on the model (``R``
        the control frame, or the identity), an expression of ``z, u, t, p``."""
        m = self.model
        J = ca.jacobian(self.phi, m.x)
        f = m.f if self.control_frame is None else ca.substitute(
            m.f, m.u, ca.mtimes(self.control_frame, m.u))
        return ca.substitute(ca.mtimes(J, f), m.x, self.psi)

    def thrust_scale(self) -> ca.SX:
        """``s`` of a model whose input matrix is ``[0; s I]`` (the thrust acceleration on the
        velocity rows; ``s`` may depend on the state), as an expression of ``z`` and ``p``;
        :class:`ProblemError` otherwise (a declared ``input_matrix`` needs this structure)."""
        m = self.model
        if not m.control_affine:
            raise ProblemError(f"coordinates {self.name!r} need a control-affine model "
                               f"(f = f0 + G u); {m.name} is not")
        G = ca.jacobian(m.f, m.u)
        nu, n = m.n_u, m.n_x
        s = G[n - nu, 0]
        ok = n >= 2 * nu and all(G[i, j].is_zero() for i in range(n - nu) for j in range(nu))
        ok = ok and all(ca.is_equal(G[n - nu + i, j], s if i == j else ca.SX(0), 4)
                        for i in range(nu) for j in range(nu))
        if not ok:
            raise ProblemError(f"coordinates {self.name!r} (form=simplified) need the thrust as "
                               f"s u on the velocity rows of model {m.name!r}; use form=generated")
        return ca.substitute(s, m.x, self.psi)

    @cached_property
    def rates(self) -> ca.SX:
        """``dz/dt`` as an expression of ``z, u, t, p``: the chain rule on the model
        (:attr:`generated_rates`), or where the chart declares its simplified forms,
        ``drift(z) + s input_matrix(z) u`` (module docstring; :meth:`check_forms` verifies them
        against the chain rule)."""
        m = self.model
        if self.drift is None:
            return self.generated_rates
        if self.input_matrix is not None:
            return self.drift + self.thrust_scale() * ca.mtimes(self.input_matrix, m.u)
        if not m.control_affine:
            raise ProblemError(f"coordinates {self.name!r} need a control-affine model "
                               f"(f = f0 + G u); {m.name} is not")
        G = ca.jacobian(m.f, m.u)
        if self.control_frame is not None:
            G = ca.mtimes(G, self.control_frame)
        J = ca.jacobian(self.phi, m.x)
        return self.drift + ca.substitute(ca.mtimes(ca.mtimes(J, G), m.u), m.x, self.psi)

    def check_forms(self, Z: np.ndarray, p: np.ndarray, t: float = 0.0,
                    rtol: float = 1e-9) -> None:
        """Raise :class:`ProblemError` unless :attr:`rates` equal the chain rule of the model,
        :attr:`generated_rates`, at the points ``Z`` (N, n_x), coasting and with random unit
        controls, within ``rtol`` of their size (nothing to check without declared forms)."""
        if self.drift is None:
            return
        m = self.model
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        N = Z.shape[0]
        fun = ca.Function("forms_check", [self.z, m.u, m.t, m.p],
                          [self.generated_rates, self.rates])
        rng = np.random.default_rng(1)
        U = rng.standard_normal((N, m.n_u))
        U /= np.linalg.norm(U, axis=1, keepdims=True)
        for controls in (np.zeros((N, m.n_u)), U):
            a, b = (np.asarray(v) for v in fun.map(N)(Z.T, controls.T, t, p))
            scale = np.maximum(np.abs(a).max(axis=0), 1e-300)
            err = np.abs(a - b).max(axis=0) / scale
            if not np.all(err <= rtol):
                k = int(np.argmax(err))
                what = "drift" if not controls.any() else "thrust terms"
                raise ProblemError(
                    f"coordinates {self.name!r} are built around {self.drift_name}, but their "
                    f"{what} differ from the chain rule of model {m.name!r} at z = {Z[k].tolist()} "
                    f"(relative {err[k]:.3g} > {rtol:g}): the model has another drift or thrust; "
                    "use coordinates='cartesian' (or form=generated)")

    @cached_property
    def dynamics(self) -> Model:
        """The model in the new coordinates (and independent variable), derived from ``model.f``.

        Time kept: states ``z``, the same ``u``, ``t``, ``p``.  Time transformed: states
        ``(z, t)``, the independent variable a new symbol ``s`` (the dynamics do not depend on it:
        where ``f`` depends on the time, it depends on the state ``t``)."""
        m = self.model
        zdot = self.rates
        common = {"p": m.p, "p_default": m.p_default, "param_names": m.param_names,
                      "control_names": m.control_names, "control_set": m.control_set, "units": m.units,
                      "thrust_param": m.thrust_param}
        if not self.time_transformed:
            return Model.build(f"{m.name}@{self.name}", self.z, m.u, zdot, t=m.t,
                               state_names=self.names, state_units=self.units,
                               description=f"{m.description}; in {self.description}", **common)
        t_state = ca.SX.sym("t_state")
        s = ca.SX.sym(self.s_name)
        if self.independent is not None:
            g = 1.0 / zdot[self.independent]
        else:
            g = ca.substitute(self.time_scale, m.x, self.psi)
        rows = [ca.SX(1.0) if i == self.independent else zdot[i] * g for i in range(m.n_x)]
        f = ca.substitute(ca.vertcat(*rows, g), m.t, t_state)
        time_unit = m.units.time_label if m.units is not None else "TU"
        return Model.build(f"{m.name}@{self.name}", ca.vertcat(self.z, t_state), m.u, f, t=s,
                           state_names=(*self.names, "t"), state_units=(*self.units, time_unit),
                           description=(f"{m.description}; in {self.description}, independent "
                                        f"variable {self.s_name}"), **common)

    @cached_property
    def time_scale_z(self) -> ca.SX | None:
        """``dt/ds`` as an expression of ``(z, t)`` and ``p`` (None without a time transformation)."""
        if not self.time_transformed:
            return None
        return self.dynamics.f[-1]

    # ------------------------------------------------------------------ numeric maps
    def function(self, what: str) -> ca.Function:
        """``"phi"``: ``(x, p) -> z``; ``"psi"``: ``(z, p) -> x``; ``"valid_x"``, ``"valid_z"``;
        ``"scale"``: ``(w, u, p) -> dt/ds`` (time-transformed charts)."""
        m = self.model

        def build():
            if what == "phi":
                return ca.Function("phi", [m.x, m.p], [self.phi], ["x", "p"], ["z"])
            if what == "psi":
                return ca.Function("psi", [self.z, m.p], [self.psi], ["z", "p"], ["x"])
            if what == "valid_x":
                return ca.Function("valid_x", [m.x, m.p], [self.valid_x], ["x", "p"], ["g"])
            if what == "valid_z":
                return ca.Function("valid_z", [self.z, m.p], [self.valid_z], ["z", "p"], ["g"])
            if what == "scale":
                d = self.dynamics
                return ca.Function("scale", [d.x, d.u, d.p], [self.time_scale_z],
                                   ["w", "u", "p"], ["g"])
            raise ProblemError(f"Chart.function: unknown {what!r}")

        return self.cached(("function", what), build)
