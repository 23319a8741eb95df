"""Reachability / control problems: model + initial state or set + control set + time grid.

A scenario is a function returning a :class:`Problem`; the bundled ones and users' files are found
by :mod:`ocreach.registry` (``get_problem("dro")``, ``get_problem("path/to/file.py")``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.dynamics.flow import check_grid
from ocreach.errors import ProblemError, check_real
from ocreach.model import CONTROL_SETS, Model, find_thrust_param
from ocreach.units import Units

#: Largest plausible initial thrust acceleration (m/s^2): 1 g0 (see ``Problem._check_thrust``).
MAX_THRUST_ACCEL = 9.80665

#: Relative tolerance of "t_final is a multiple of dt" in :func:`time_grid`.
GRID_RTOL = 1e-6


def time_grid(t_final: Any, dt: Any, *, fit: bool = False, unit: str = "TU",
              names: tuple[str, str] = ("t_final", "dt")) -> np.ndarray:
    """The forward grid ``0, dt, 2 dt, ..., t_final`` shared by the problem factories.

    Rule: ``t_final`` and ``dt`` finite and > 0, and ``t_final / dt`` an integer within
    :data:`GRID_RTOL` (relative) -- otherwise a :class:`ProblemError` stating the rule and the
    nearest valid ``t_final`` values (no silent rounding of the horizon).  With ``fit=True``
    (a horizon fixed by physics, e.g. one orbit period) the grid instead has
    ``n = max(1, round(t_final / dt))`` equal segments ending exactly at ``t_final`` (the step is
    ``t_final / n``, within a factor 1.5 of ``dt``).
    """
    tn, dn = names
    T, h = check_real(tn, t_final), check_real(dn, dt)
    if T <= 0:
        raise ProblemError(f"{tn} must be > 0 {unit}; got {t_final!r}")
    if h <= 0:
        raise ProblemError(f"{dn} must be > 0 {unit}; got {dt!r}")
    ratio = T / h
    if fit:
        if ratio < 0.5:
            raise ProblemError(f"{dn} must be <= 2 {tn} = {2 * T:g} {unit}; got {dt!r}")
        n = max(1, int(round(ratio)))
        return np.linspace(0.0, T, n + 1)
    n = int(round(ratio))
    if n < 1 or abs(ratio - n) > GRID_RTOL * max(1.0, ratio):
        lo, hi = max(1, int(np.floor(ratio))), max(1, int(np.ceil(ratio)))
        near = sorted({lo * h, hi * h})
        raise ProblemError(f"{tn} = {T:g} {unit} must be a whole multiple of {dn} = {h:g} {unit} "
                           f"(relative tolerance {GRID_RTOL:g}); nearest valid {tn}: "
                           + " or ".join(f"{v:.10g}" for v in near))
    if n > 10_000_000:
        raise ProblemError(f"{tn} / {dn} = {n} segments exceeds 1e7; use a larger {dn}")
    return np.linspace(0.0, n * h, n + 1)


@dataclass(frozen=True)
class ControlSet:
    """Admissible normalised controls: the unit ``"ball"`` (``||u||_2 <= 1``) or ``"box"`` ``[-1, 1]^m``."""

    kind: str
    dim: int

    def __post_init__(self) -> None:
        if self.kind not in CONTROL_SETS:
            raise ProblemError(f"control set kind must be one of {CONTROL_SETS}; got {self.kind!r}")
        if self.dim < 1:
            raise ProblemError(f"control dimension must be >= 1; got {self.dim}")

    def _bounded(self, what: str) -> None:
        if self.kind == "free":
            raise ProblemError(f"ControlSet.{what} needs a bounded control set ('ball' or 'box'); "
                               "this problem's controls are 'free' (prescribed distribution)")

    def contains(self, u: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """Boolean mask with one entry per control vector of ``u`` (shape ``(..., dim)``)."""
        u = np.asarray(u, dtype=float)
        if self.kind == "free":
            return np.all(np.isfinite(u), axis=-1)
        if self.kind == "ball":
            return np.linalg.norm(u, axis=-1) <= 1 + tol
        return np.all(np.abs(u) <= 1 + tol, axis=-1)

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Uniform samples of shape ``shape + (dim,)``."""
        self._bounded("sample")
        if self.kind == "box":
            return rng.uniform(-1.0, 1.0, size=shape + (self.dim,))
        g = rng.standard_normal(shape + (self.dim,))
        g /= np.linalg.norm(g, axis=-1, keepdims=True)
        r = rng.uniform(size=shape + (1,)) ** (1.0 / self.dim)
        return g * r

    def max_norm(self) -> float:
        """The largest ``||u||_2`` of the set: 1 on the ball, ``sqrt(dim)`` at a corner of the box."""
        self._bounded("max_norm")
        return 1.0 if self.kind == "ball" else float(np.sqrt(self.dim))

    def sample_boundary(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Samples on the boundary (unit sphere, or the box's vertices for ``"box"``)."""
        self._bounded("sample_boundary")
        if self.kind == "box":
            return rng.choice([-1.0, 1.0], size=shape + (self.dim,))
        g = rng.standard_normal(shape + (self.dim,))
        return g / np.linalg.norm(g, axis=-1, keepdims=True)

    def argmin(self, s: np.ndarray) -> np.ndarray:
        """``argmin_{u in U} s^T u`` row-wise (the Hamiltonian-minimising control, Foss Eq. 4)."""
        self._bounded("argmin")
        s = np.asarray(s, dtype=float)
        if self.kind == "box":
            return -np.sign(s)
        n = np.linalg.norm(s, axis=-1, keepdims=True)
        return -s / np.where(n > 0, n, 1.0)


@dataclass(frozen=True)
class Reference:
    """A corrected periodic orbit used as reference (``x0``, ``period``, monodromy, stability)."""

    x0: np.ndarray
    period: float
    monodromy: np.ndarray | None = None
    stability: tuple[float, ...] | None = None
    name: str = ""


@dataclass(frozen=True)
class StochasticSpec:
    """Gaussian initial state and Gaussian controls about a nominal profile (Jain et al. Eq. 24-27).

    ``u_nominal`` has shape ``(K, n_u)`` (one control per grid segment); ``u_cov`` is the control
    covariance (``(n_u, n_u)``), sampled afresh at every step.
    """

    x0_mean: np.ndarray
    x0_cov: np.ndarray
    u_nominal: np.ndarray
    u_cov: np.ndarray


@dataclass
class Problem:
    """A reachability or control problem.

    Attributes
    ----------
    id : stable identifier (e.g. ``"dro"``).
    model : the dynamics.
    x0 : nominal initial state (model units).
    grid : time grid ``t_0 < t_1 < ... < t_K`` (or strictly decreasing for backward problems);
        controls are piecewise constant on its segments.
    params : parameter vector of the model (defaults to ``model.p_default``).
    control_set : admissible normalised controls.
    initial_set : optional set of initial states (an ``ocreach.sets`` object) for uncertain cases.
    stochastic : optional Gaussian initial state and control distribution (stochastic problems).
    reference : optional corrected periodic orbit.
    units : conversion to SI.
    method_options : per-method default options, e.g. ``{"stt": {"order": 2, "h_max": 400}}``.
    position_dims, velocity_dims : state indices used for plots and position-space directions.
    coordinates : the coordinates the methods propagate in (:mod:`ocreach.models.coordinates`:
        ``"cartesian"``, the model's own state, or e.g. ``"mee"``); results are always given in the
        model's coordinates.
    """

    id: str
    model: Model
    x0: np.ndarray
    grid: np.ndarray
    params: np.ndarray | None = None
    control_set: ControlSet | None = None
    initial_set: Any = None
    stochastic: StochasticSpec | None = None
    reference: Reference | None = None
    units: Units | None = None
    description: str = ""
    citation: str = ""
    method_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    position_dims: tuple[int, ...] | None = None
    velocity_dims: tuple[int, ...] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    coordinates: str = "cartesian"

    def __post_init__(self) -> None:
        if self.params is None:
            self.params = self.model.p_default.copy()
        if self.control_set is None:
            self.control_set = ControlSet(self.model.control_set, self.model.n_u)
        if self.units is None:
            self.units = self.model.units
        self.x0 = np.asarray(self.x0, dtype=float)
        self.grid = np.asarray(self.grid, dtype=float)
        self.params = np.asarray(self.params, dtype=float)
        if self.position_dims is None:
            half = self.model.n_x // 2
            self.position_dims = tuple(range(min(half, 3)))
        if self.velocity_dims is None:
            half = self.model.n_x // 2
            self.velocity_dims = tuple(range(half, half + min(half, 3)))
        self.validate()

    # ---------------------------------------------------------------- validation
    def validate(self) -> Problem:
        """Check every field; raise :class:`ProblemError` naming the field, value and what is allowed."""
        self.model.validate_state(self.x0, "x0")
        if self.x0.ndim != 1:
            raise ProblemError(f"x0 must be one state vector of length {self.model.n_x}; "
                               f"got shape {self.x0.shape}")
        check_grid(self.grid)
        if self.params.shape != (self.model.n_p,):
            raise ProblemError(f"params must have {self.model.n_p} entries "
                               f"{list(self.model.param_names)}; got shape {self.params.shape}")
        if not np.all(np.isfinite(self.params)):
            raise ProblemError(f"params must be finite; got {self.params!r}")
        self._check_thrust()
        if self.control_set.dim != self.model.n_u:
            raise ProblemError(f"control_set.dim must equal n_u = {self.model.n_u}; "
                               f"got {self.control_set.dim}")
        for d in (*self.position_dims, *self.velocity_dims):
            if not 0 <= d < self.model.n_x:
                raise ProblemError(f"position/velocity dims must be in [0, {self.model.n_x}); got {d}")
        from ocreach.models.coordinates import parse

        self.coordinates = str(parse(self.coordinates))
        return self

    def thrust_acceleration_si(self) -> float | None:
        """Initial thrust acceleration in m/s^2 (``a_max``, or ``T_max`` times the inverse-mass
        state ``n``, converted with ``units``), or None if the model has no physical thrust."""
        name = find_thrust_param(self.model)
        if name not in ("a_max", "T_max") or self.units is None:
            return None
        a = self.model.param(name, self.params)
        if "n" in self.model.state_names:
            a *= float(self.x0[self.model.state_names.index("n")])
        return float(a * self.units.length / self.units.time**2)

    def _check_thrust(self) -> None:
        """Thrust level > 0 and physically plausible.

        Rule: ocreach models continuous low thrust, so the initial thrust acceleration must not
        exceed :data:`MAX_THRUST_ACCEL` = 1 g0 = 9.80665 m/s^2 (electric propulsion gives
        1e-5..1e-2 m/s^2; even a chemical stage rarely exceeds 1 g).  A deliberate high-thrust
        study sets ``extra={"allow_high_thrust": True}``.
        """
        name = find_thrust_param(self.model)
        if not name:
            return
        val = self.model.param(name, self.params)
        if not val > 0:
            raise ProblemError(f"{name} (thrust) must be > 0; got {val!r}")
        a = self.thrust_acceleration_si()
        if a is not None and a > MAX_THRUST_ACCEL and not self.extra.get("allow_high_thrust"):
            thrust_n = self.extra.get("thrust_N")
            raise ProblemError(
                f"thrust is implausible for a low-thrust model: {name} = {val:g} gives a thrust "
                f"acceleration of {a:.4g} m/s^2" + (f" (thrust {thrust_n:g} N)" if thrust_n else "")
                + f", above the limit {MAX_THRUST_ACCEL:g} m/s^2 (1 g0); lower the thrust or raise "
                "the mass, or set extra={'allow_high_thrust': True} on the Problem")

    # ---------------------------------------------------------------- convenience
    @property
    def n_segments(self) -> int:
        return self.grid.size - 1

    @property
    def backward(self) -> bool:
        return bool(self.grid[-1] < self.grid[0])

    def param(self, name: str) -> float:
        return self.model.param(name, self.params)

    def planes(self) -> dict[str, tuple[int, int]]:
        """Named 2-D projection planes used by metrics and figures.

        ``"pos"``: the first two position dims, ``"vel"``: the first two velocity dims; a plane
        equal to an earlier one is dropped (e.g. Van der Pol, whose position and velocity dims are
        both ``(0, 1)``), and ``{"x": (0, 1)}`` is used when neither has two dims (e.g. a user
        problem with a 2-state model and default dims).
        """
        out: dict[str, tuple[int, int]] = {}
        for tag, dims in (("pos", self.position_dims), ("vel", self.velocity_dims)):
            d = tuple(int(i) for i in dims[:2])
            if len(d) == 2 and d not in out.values():
                out[tag] = d  # type: ignore[assignment]
        if not out and self.model.n_x >= 2:
            out["x"] = (0, 1)
        return out

    def options_for(self, method: str) -> dict[str, Any]:
        return dict(self.method_options.get(method, {}))

    def summary(self) -> str:
        g = self.grid
        return (f"{self.id}: {self.description}\n  model {self.model.name} (n_x={self.model.n_x}, "
                f"n_u={self.model.n_u}), control set {self.control_set.kind}, "
                f"t = {g[0]:g} .. {g[-1]:g} in {g.size - 1} segments\n  x0 = {np.array2string(self.x0, precision=6)}"
                + (f"\n  source: {self.citation}" if self.citation else ""))
