"""Reference trajectories for tracking: states, controls and their discrete linearisation on a grid.

A :class:`TrackingReference` is sampled on a uniform grid ``t_k = t_0 + k dt``.  A periodic
reference (one orbit period split into ``M`` steps) is indexed modulo ``M``, so a controller can
look any number of steps ahead (MPC windows, multi-revolution simulations) without integrating an
unstable orbit for long.  The states are propagated with SciPy's DOP853 at tight tolerance, not
with the prediction model, so the reference is the *true* nonlinear trajectory.  Its linearisation
``(A_k, B_k)`` is taken from the discrete prediction model of :mod:`ocreach.dynamics.discretize`
(Patel & Subbarao Eq. 26).
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

from ocreach.dynamics.discretize import Discretization
from ocreach.errors import ProblemError, SolverError, check_positive
from ocreach.model import Model

log = logging.getLogger("ocreach.control.reference")

#: Default bound on the prediction model's one-step error along the reference (max-norm, model
#: units) for ``n_sub="auto"``, and the largest number of RK4 substeps tried.
DEFECT_TOL = 1e-6
MAX_SUBSTEPS = 64


def propagate_natural(model: Model, x0: np.ndarray, times: np.ndarray, p: np.ndarray,
                      rtol: float = 1e-12, atol: float = 1e-13) -> np.ndarray:
    """States of the uncontrolled (``u = 0``) model at ``times`` (DOP853); shape ``(len, n_x)``."""
    u0 = np.zeros(model.n_u)
    f = model.f_fun

    def rhs(t, x):
        return np.asarray(f(x, u0, t, p)).ravel()

    sol = solve_ivp(rhs, (times[0], times[-1]), np.asarray(x0, float), method="DOP853",
                    t_eval=times, rtol=rtol, atol=atol)
    if not sol.success or sol.y.shape[1] != times.size:
        raise SolverError(f"reference propagation failed: {sol.message}")
    return sol.y.T


@dataclass(eq=False)
class TrackingReference:
    """Reference ``x_ref_k`` (and ``u_ref_k``, normalised) on ``t_k = t0 + k dt``.

    ``X`` has ``M + 1`` rows and ``U`` ``M`` rows.  If ``periodic``, step ``k`` is step ``k mod M``
    (``X[M]`` equals ``X[0]`` up to the orbit's correction accuracy); otherwise indices beyond ``M``
    are an error.  ``A``, ``B`` (``(M, n_x, n_x)``, ``(M, n_x, n_u)``) are the discrete
    linearisation of the prediction model about the reference, filled by :meth:`linearize`.
    ``steps_per_rev``: steps per revolution of a non-periodic multi-revolution orbit.
    """

    model: Model
    params: np.ndarray
    t0: float
    dt: float
    X: np.ndarray
    U: np.ndarray
    periodic: bool = False
    name: str = ""
    n_sub: int = 2
    A: np.ndarray | None = None
    B: np.ndarray | None = None
    n_track: int | None = None
    steps_per_rev: int | None = None
    cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.X = np.asarray(self.X, dtype=float)
        self.U = np.asarray(self.U, dtype=float)
        self.params = np.asarray(self.params, dtype=float)
        if self.X.ndim != 2 or self.X.shape[1] != self.model.n_x or self.X.shape[0] < 2:
            raise ProblemError(f"reference X must have shape (M + 1, {self.model.n_x}) with M >= 1; "
                               f"got {self.X.shape}")
        if self.U.shape != (self.X.shape[0] - 1, self.model.n_u):
            raise ProblemError(f"reference U must have shape ({self.X.shape[0] - 1}, "
                               f"{self.model.n_u}); got {self.U.shape}")

    @property
    def n_steps(self) -> int:
        """Number of grid steps ``M`` stored."""
        return self.U.shape[0]

    @property
    def n_default(self) -> int:
        """Steps a closed loop runs by default (the problem's horizon, without look-ahead padding)."""
        return self.n_steps if self.n_track is None else int(self.n_track)

    @property
    def revolution_steps(self) -> int:
        """Grid steps per revolution of the orbit: ``M`` for a periodic reference, else
        ``steps_per_rev`` (e.g. an ephemeris-corrected multi-revolution orbit) or ``M``."""
        if self.periodic or self.steps_per_rev is None:
            return self.n_steps
        return int(self.steps_per_rev)

    @property
    def discretization(self) -> Discretization:
        if "disc" not in self.cache:
            self.cache["disc"] = Discretization(self.model, self.dt, self.n_sub)
        return self.cache["disc"]

    def time(self, k) -> np.ndarray | float:
        return self.t0 + np.asarray(k) * self.dt

    def _index(self, k: np.ndarray, last: int) -> np.ndarray:
        k = np.asarray(k)
        if self.periodic:
            return k % self.n_steps
        if np.any(k > last) or np.any(k < 0):
            raise ProblemError(f"reference step index {int(np.max(k))} outside 0..{last} "
                               f"(non-periodic reference '{self.name}' of {self.n_steps} steps)")
        return k

    def state(self, k) -> np.ndarray:
        """``x_ref`` at step(s) ``k``."""
        return self.X[self._index(k, self.n_steps)]

    def control(self, k) -> np.ndarray:
        """``u_ref`` at step(s) ``k``."""
        return self.U[self._index(k, self.n_steps - 1)]

    def window(self, k: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(X_ref[k..k+n] (n+1, n_x), U_ref[k..k+n-1] (n, n_u))`` for a prediction horizon."""
        idx = np.arange(k, k + n + 1)
        return self.state(idx), self.control(idx[:-1])

    def linearize(self) -> TrackingReference:
        """Fill ``A_k = Phi(t_{k+1}, t_k)`` and ``B_k`` along the reference (one mapped call)."""
        if self.A is None:
            ks = np.arange(self.n_steps)
            _, self.A, self.B = self.discretization.linearize(
                self.X[:-1], self.U, self.time(ks), self.params)
        return self

    def defect(self) -> np.ndarray:
        """One-step error of the prediction model along the reference, per step (max-norm).

        ``|f_d(x_ref_k, u_ref_k, t_k) - x_ref_{k+1}|_inf`` for ``k = 0..M-1``: the reference is the
        DOP853 solution (rtol 1e-12), so this is the RK4 discretisation error of each step (plus
        the reference's own error, ~1e-12).  Cached.
        """
        if "defect" not in self.cache:
            ks = np.arange(self.n_steps)
            xn, _, _ = self.discretization.linearize(self.X[:-1], self.U, self.time(ks), self.params)
            self.cache["defect"] = np.max(np.abs(xn - self.X[1:]), axis=1)
        return self.cache["defect"]

    def defect_vectors(self) -> np.ndarray:
        """``x_ref_{k+1} - f_d(x_ref_k, u_ref_k, t_k)`` per step (M, n_x): the prediction model's
        one-step error along the reference (signed; :meth:`defect` is its max-norm).  Cached."""
        if "defect_vectors" not in self.cache:
            ks = np.arange(self.n_steps)
            xn, _, _ = self.discretization.linearize(self.X[:-1], self.U, self.time(ks), self.params)
            self.cache["defect_vectors"] = self.X[1:] - xn
        return self.cache["defect_vectors"]

    def with_substeps(self, n_sub: int) -> TrackingReference:
        """The same reference with a prediction model of ``n_sub`` RK4 substeps (fresh caches)."""
        return dataclasses.replace(self, n_sub=int(n_sub), A=None, B=None, cache={})

    def gains_index(self, k) -> np.ndarray:
        """Index into per-step arrays (``A``, ``B``, Riccati solutions) for step(s) ``k``."""
        return self._index(k, self.n_steps - 1)


def natural_reference(model: Model, x0, dt: float, n_steps: int, *, params=None, t0: float = 0.0,
                      periodic: bool = False, n_sub: int = 2, name: str = "") -> TrackingReference:
    """Reference along the uncontrolled trajectory from ``x0`` (``u_ref = 0``)."""
    check_positive("dt", dt)
    if int(n_steps) != n_steps or n_steps < 1:
        raise ProblemError(f"n_steps must be an integer >= 1; got {n_steps!r}")
    p = model.p_default if params is None else np.asarray(params, float)
    times = t0 + dt * np.arange(n_steps + 1)
    X = propagate_natural(model, model.validate_state(x0, "x0"), times, p)
    return TrackingReference(model, p, t0, dt, X, np.zeros((n_steps, model.n_u)),
                             periodic=periodic, n_sub=n_sub, name=name)


def periodic_reference(model: Model, x0, period: float, steps_per_period: int, *, params=None,
                       n_sub: int = 2, name: str = "") -> TrackingReference:
    """One period of a periodic orbit on ``steps_per_period`` equal steps, indexed modulo the period."""
    check_positive("period", period)
    if int(steps_per_period) != steps_per_period or steps_per_period < 2:
        raise ProblemError(f"steps_per_period must be an integer >= 2; got {steps_per_period!r}")
    return natural_reference(model, x0, period / steps_per_period, steps_per_period, params=params,
                             periodic=True, n_sub=n_sub, name=name)


def verified_substeps(ref: TrackingReference, tol: float = DEFECT_TOL,
                      max_sub: int = MAX_SUBSTEPS) -> TrackingReference:
    """Double ``ref.n_sub`` until the prediction model's one-step error along the reference
    (:meth:`TrackingReference.defect`) is at most ``tol``; warn if ``max_sub`` is not enough.

    Why: a fixed substep count that is accurate on one orbit can be far off on another (2 RK4
    substeps per 1 h step: 5e-12 DU on l2-halo, 5.6e-3 DU = 2150 km at the perilune of nrho-9-2),
    and an MPC predicting with a wrong model fights its own model error with thrust.
    """
    check_positive("defect_tol", tol)
    while float(ref.defect().max()) > tol and ref.n_sub < max_sub:
        ref = ref.with_substeps(min(2 * ref.n_sub, max_sub))
    worst = float(ref.defect().max())
    if worst > tol:
        log.warning("prediction model of %r: one-step error %.3g > defect_tol %.3g even with "
                    "%d RK4 substeps per step; use a smaller dt", ref.name, worst, tol, ref.n_sub)
    return ref


def reference_from_problem(problem, *, dt: float | None = None, n_steps: int | None = None,
                           n_sub: int | str = "auto", pad: int = 0,
                           defect_tol: float = DEFECT_TOL) -> TrackingReference:
    """Tracking reference of a :class:`ocreach.Problem`.

    With ``problem.reference`` (a corrected periodic orbit) the reference is one period on steps of
    about ``dt`` (rounded so the period is an integer number of steps; default: the problem's grid
    step), periodic; ``n_default`` covers the problem's grid span (or ``n_steps``).  Otherwise it
    is the natural trajectory from ``problem.x0`` on ``n_steps`` steps of ``dt`` (defaults: the
    problem's grid).

    ``n_sub`` is the number of RK4 substeps of the prediction model per step, or ``"auto"``
    (default): start at 2 and double until the one-step error along the reference is at most
    ``defect_tol`` (:func:`verified_substeps`).
    """
    if isinstance(n_sub, str):
        if n_sub != "auto":
            raise ProblemError(f"n_sub must be 'auto' or an integer >= 1; got {n_sub!r}")
        return verified_substeps(
            reference_from_problem(problem, dt=dt, n_steps=n_steps, n_sub=2, pad=pad), defect_tol)
    grid = problem.grid
    step = float(dt) if dt is not None else float(abs(grid[1] - grid[0]))
    check_positive("dt", step)
    ref = problem.reference
    if ref is not None:
        M = max(2, round(float(ref.period) / step))
        out = periodic_reference(problem.model, ref.x0, ref.period, M, params=problem.params,
                                 n_sub=n_sub, name=getattr(ref, "name", "") or problem.id)
        span = abs(grid[-1] - grid[0])
        out.n_track = int(n_steps) if n_steps is not None else max(1, round(float(span) / out.dt))
        return out
    if problem.backward:
        raise ProblemError(f"problem {problem.id!r} has a backward grid; tracking needs forward time")
    K = int(n_steps) if n_steps is not None else round(float(grid[-1] - grid[0]) / step)
    if int(pad) != pad or pad < 0:
        raise ProblemError(f"pad (look-ahead steps) must be an integer >= 0; got {pad!r}")
    ref = natural_reference(problem.model, problem.x0, step, K + int(pad), params=problem.params,
                            t0=float(grid[0]), n_sub=n_sub, name=problem.id)
    ref.n_track = K
    return ref
