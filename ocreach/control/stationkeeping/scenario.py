"""The orbit-maintenance scenario: the DE421 plant with solar radiation pressure, its corrected
multi-revolution reference orbit, and what every controller and run shares about it.

* **Plant.**  Moon, Earth and Sun point masses from DE421
  (:class:`~ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant`, Patel & Scheeres Eq. 11 plus the
  Moon-centred frame's indirect term) plus cannonball SRP
  (:mod:`ocreach.control.stationkeeping.srp`), written in the CR3BP rotating frame fixed at the
  epoch; integrated with the compiled DOP853 of :mod:`ocreach.native` (rtol 1e-10, atol 1e-12).
  The model's third parameter ``srp_scale`` is the run's true ``C_r A / m`` over the nominal.
* **Reference.**  The problem's CR3BP orbit corrected by multiple shooting into an orbit of that
  plant *with the nominal SRP* (:func:`~ocreach.control.stationkeeping.ephemeris_reference.correct_orbit`:
  4 patch points per revolution, defects <= 1e-9, cached on disk), sampled on the problem's
  control grid (nrho-9-2: 157 steps of 1.003 h per revolution).  It covers the run plus
  ``lookahead`` revolutions (the controllers look that far ahead).
* **Shared data**, computed once per process and cached on the scenario: the exact one-step
  state-transition matrices ``A_k`` and thrust matrices ``B_k`` along the reference (variational
  equations, :func:`step_jacobians`), the reference's osculating Moon-centred true anomaly, its
  perilune passages through the rotating x-z plane (``y = 0``, the targets of x-axis crossing
  control) and the burn steps at a chosen true anomaly.

:func:`scenario` builds (or returns the cached) scenario of a :class:`ScenarioSpec` (plain data).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from ocreach.control.stationkeeping.ephemeris_plant import DEFAULT_BODIES, DEFAULT_EPOCH
from ocreach.control.stationkeeping.srp import SolarRadiationPressure
from ocreach.errors import ProblemError, SolverError, check_count, check_positive

#: Integrator tolerances of the plant and of the controllers' predictions.
RTOL, ATOL = 1e-10, 1e-12
DAYS_PER_YEAR = 365.25


@dataclass(frozen=True)
class ScenarioSpec:
    """What a scenario is built from (plain data): the problem id, the epoch (TDB), the years a
    run lasts, the SRP model, the ephemeris bodies and the revolutions of reference needed after
    the run (``lookahead``)."""

    problem: str = "nrho-9-2"
    epoch: str = DEFAULT_EPOCH
    years: float = 1.0
    srp: SolarRadiationPressure = field(default_factory=SolarRadiationPressure)
    bodies: tuple[str, ...] = DEFAULT_BODIES
    lookahead: int = 4

    def __post_init__(self) -> None:
        object.__setattr__(self, "years", check_positive("years (length of a run)", self.years))
        object.__setattr__(self, "lookahead", check_count("lookahead (revolutions)",
                                                          self.lookahead, 1))
        object.__setattr__(self, "bodies", tuple(self.bodies))

    def key(self) -> str:
        return repr((self.problem, self.epoch, self.years, sorted(self.srp.as_dict().items()),
                     self.bodies, self.lookahead))

    def as_dict(self) -> dict:
        out = asdict(self)
        out["srp"] = self.srp.as_dict()
        out["bodies"] = list(self.bodies)
        return out

    @classmethod
    def from_dict(cls, d: dict) -> ScenarioSpec:
        """The inverse of :meth:`as_dict` (the SRP's derived fields dropped)."""
        s = dict(d)
        srp = {k: v for k, v in s.pop("srp").items() if k != "p_1au_n_m2"}
        s["bodies"] = tuple(s["bodies"])
        return cls(srp=SolarRadiationPressure(**srp), **s)


class Scenario:
    """A built scenario (module doc).  ``steps``: control steps of a run; ``M``: steps per
    revolution; ``X`` (N + 1, 6) the reference on the grid, ``dt`` (TU) the step."""

    def __init__(self, spec: ScenarioSpec) -> None:
        from ocreach.control.stationkeeping.ephemeris_reference import correct_orbit
        from ocreach.registry import get_problem

        self.spec = spec
        self.problem = get_problem(spec.problem)
        if self.problem.reference is None or self.problem.units is None:
            raise ProblemError(f"orbit maintenance needs a periodic reference orbit with units; "
                               f"problem {spec.problem!r} has none")
        units = self.problem.units
        period_days = float(self.problem.reference.period) * units.time / 86400.0
        self.revolutions_run = spec.years * DAYS_PER_YEAR / period_days
        total = int(np.ceil(self.revolutions_run)) + spec.lookahead
        self.orbit = correct_orbit(self.problem, total, epoch=spec.epoch, bodies=spec.bodies,
                                   srp=spec.srp)
        self.plant = self.orbit.plant
        self.model = self.plant.frame_model()
        self.units = units
        self.params = np.asarray(self.model.p_default, float)
        self.dt = float(self.orbit.dt)
        self.M = int(self.orbit.steps[-1]) // total
        self.X = self.orbit.sample()
        self.times = self.dt * np.arange(self.X.shape[0])
        self.steps = int(round(spec.years * DAYS_PER_YEAR * 86400.0 / (self.dt * units.time)))
        if self.steps + spec.lookahead * self.M > self.X.shape[0] - 1:
            raise SolverError(f"the reference covers {self.X.shape[0] - 1} steps; the run needs "
                              f"{self.steps} plus {spec.lookahead} revolutions")
        self.cache: dict[str, Any] = {}

    # ------------------------------------------------------------------ units
    def km(self, d) -> np.ndarray:
        return np.asarray(d) * self.units.length / 1e3

    def mps(self, d) -> np.ndarray:
        return np.asarray(d) * self.units.velocity

    def params_with(self, srp_scale: float) -> np.ndarray:
        p = self.params.copy()
        p[list(self.model.param_names).index("srp_scale")] = srp_scale
        return p

    # ------------------------------------------------------------------ propagation
    def propagate(self, x: np.ndarray, k0: int, k1: int, p: np.ndarray,
                  u: np.ndarray | None = None) -> np.ndarray:
        """Plant states on the grid steps ``k0..k1`` (k1 - k0 + 1, 6) from ``x`` at step ``k0``
        (``u``: normalised thrust per step, (k1 - k0, 3); default none)."""
        from ocreach.dynamics.flow import propagate

        n = k1 - k0
        U = np.zeros((n, 3)) if u is None else u
        return propagate(self.model, x, U, self.times[k0:k1 + 1], p=p, rtol=RTOL, atol=ATOL)

    # ------------------------------------------------------------------ shared data
    @cached_property
    def jacobians(self) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)``: the exact one-step STMs (N, 6, 6) and thrust matrices (N, 6, 3) along the
        reference (:func:`step_jacobians`)."""
        return step_jacobians(self.model, self.X[:-1], self.times[:-1], self.times[1:],
                              self.params)

    @cached_property
    def reference(self):
        """The :class:`~ocreach.control.reference.TrackingReference` of the grid (non-periodic,
        ``A``/``B`` the exact :attr:`jacobians`), for the LQR and MPC."""
        from ocreach.control.reference import TrackingReference

        A, B = self.jacobians
        ref = TrackingReference(self.model, self.params, 0.0, self.dt, self.X,
                                np.zeros((self.X.shape[0] - 1, 3)), periodic=False,
                                name=f"{self.problem.id} (DE421 + SRP, epoch {self.spec.epoch})",
                                n_sub=8, A=A, B=B, n_track=self.steps, steps_per_rev=self.M)
        return ref

    @cached_property
    def true_anomaly_deg(self) -> np.ndarray:
        """Osculating Moon-centred true anomaly (deg, [0, 360)) of every reference grid state,
        from the inertial Moon-relative state (:meth:`EphemerisPlant.to_inertial`) and DE421's
        GM of the Moon."""
        units = self.units
        gm = self.plant.ephemeris.gm("moon") * 1e9 * units.time**2 / units.length**3
        Y = np.array([self.plant.to_inertial(t, x) for t, x in zip(self.times, self.X,
                                                                  strict=True)])
        r, v = Y[:, :3], Y[:, 3:6]
        rn = np.linalg.norm(r, axis=1)
        h = np.cross(r, v)
        e = np.cross(v, h) / gm - r / rn[:, None]
        cos_nu = np.einsum("ij,ij->i", e, r) / (np.linalg.norm(e, axis=1) * rn)
        nu = np.degrees(np.arccos(np.clip(cos_nu, -1.0, 1.0)))
        radial = np.einsum("ij,ij->i", r, v)
        return np.where(radial < 0, 360.0 - nu, nu) % 360.0

    def anomaly_steps(self, anomaly_deg: float, last: int | None = None) -> np.ndarray:
        """Grid steps (< ``last``, default the run's steps) nearest to where the reference's true
        anomaly passes ``anomaly_deg``: one per revolution (the anomaly increases through each
        revolution and wraps at perilune)."""
        nu = self.true_anomaly_deg
        last = self.steps if last is None else int(last)
        # unwrap across perilune passages, then find each crossing of anomaly + 360 n
        turns = np.cumsum(np.r_[0, (np.diff(nu) < -180.0).astype(int)])
        total = nu + 360.0 * turns
        first = total[0] - 0.5 * (total[1] - total[0])  # a crossing half a step before 0 counts
        out = []
        for n in range(int(turns[-1]) + 2):
            target = float(anomaly_deg) + 360.0 * n
            if not first <= target <= total[-1]:
                continue
            j = min(int(np.searchsorted(total, target)), total.size - 1)
            if 0 < j and target - total[j - 1] < total[j] - target:
                j -= 1
            if j < last:
                out.append(j)
        return np.unique(np.asarray(out, int))

    def synodic_map(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(T (6, 6), c (6,))`` with ``T x + c`` the Moon-centred state in the *true*
        Earth-Moon rotating frame at reference time ``t`` (x from the Earth to the Moon, z along
        their orbital angular momentum, DE421; velocities relative to that frame, DU and DU/TU)
        for a state ``x`` of the controllers' frame (the CR3BP frame fixed at the epoch,
        :class:`~ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant`).  With ``s = r - (1 - mu)
        e_x``, ``rho = C s`` and ``rho' = C (v + e_z x s)`` the inertial Moon-relative state,
        ``R`` the synodic axes and ``Omega`` their angular velocity (``|h| / r^2`` about z plus
        ``r (a . z) / |h|`` about x, from the Moon's ephemeris position, velocity and
        acceleration relative to the Earth): ``p = R^T rho``, ``p' = R^T (rho' - Omega x rho)``.
        The frame in which the NRHO is nearly symmetric about the x-z plane."""
        units = self.units
        r, v, a = np.split(np.asarray(self._earth_moon(float(t) * units.time), float).ravel(), 3)
        h = np.cross(r, v)
        x_hat = r / np.linalg.norm(r)
        z_hat = h / np.linalg.norm(h)
        R = np.column_stack([x_hat, np.cross(z_hat, x_hat), z_hat])
        w = (np.linalg.norm(h) / (r @ r) * z_hat
             + np.linalg.norm(r) * (a @ z_hat) / np.linalg.norm(h) * x_hat) * units.time
        W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
        C = self.plant.axes(t)
        E = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
        T = np.zeros((6, 6))
        T[:3, :3] = R.T @ C
        T[3:, :3] = R.T @ (C @ E - W @ C)
        T[3:, 3:] = R.T @ C
        c = -T[:, :3] @ np.array([1.0 - self.params[0], 0.0, 0.0])
        return T, c

    @cached_property
    def _earth_moon(self):
        """CasADi ``t (s after the epoch) -> [r, r', r'']`` of the Moon relative to the Earth (km,
        km/s, km/s^2) from the ephemeris fit's expression (one call per synodic map)."""
        import casadi as ca

        t = ca.SX.sym("t")
        r = self.plant.ephemeris.position_expr("moon", t, "earth")
        v = ca.jacobian(r, t)
        return ca.Function("earth_moon", [t], [ca.vertcat(r, v, ca.jacobian(v, t))])

    def synodic(self, t: float, x: np.ndarray) -> np.ndarray:
        """:meth:`synodic_map` applied to ``x`` (6,)."""
        T, c = self.synodic_map(t)
        return T @ np.asarray(x, float) + c

    def synodic_crossing(self, x0: np.ndarray, t0: float, t_guess: float,
                         p: np.ndarray | None = None) -> tuple[float, np.ndarray]:
        """Time and state (controllers' frame) where the trajectory from ``x0`` at ``t0``
        crosses the true synodic x-z plane (``y_syn = 0``) near ``t_guess``: the sign change
        nearest ``t_guess`` on a 15-minute grid over +-24 h, then Newton on ``y_syn(t)`` with
        ``dy_syn/dt = vy_syn`` (short propagations); :class:`SolverError` if there is none."""
        from ocreach.dynamics.flow import propagate

        p = self.params if p is None else p

        def flow(x, ta, tb):
            if tb == ta:
                return np.asarray(x, float)
            return propagate(self.model, x, np.zeros((1, 3)), [ta, tb], p=p, rtol=RTOL,
                             atol=ATOL)[-1]

        # bracket: the sign change of y_syn nearest t_guess on a 15-min grid within +-24 h
        # (after t0): Newton from a guess hours off (a drifted phase) can jump revolutions
        h = 900.0 / self.units.time
        grid = t_guess + h * np.arange(-96, 97)
        grid = grid[grid > t0]
        t, x = float(t_guess), None
        if grid.size >= 2:
            start = flow(x0, t0, grid[0])
            X = propagate(self.model, start, np.zeros((grid.size - 1, 3)), grid, p=p,
                          rtol=RTOL, atol=ATOL)
            y = np.array([self.synodic(tt, xx)[1] for tt, xx in zip(grid, X, strict=True)])
            s = np.flatnonzero(np.sign(y[:-1]) != np.sign(y[1:]))
            if s.size:
                j = int(s[np.argmin(np.abs(grid[s] - t_guess))])
                t, x = float(grid[j]), X[j]
        if x is None:
            x = flow(x0, t0, t)
        for _ in range(20):
            q = self.synodic(t, x)
            if abs(q[1]) < 1e-12:
                return t, x
            t_new = t - q[1] / q[4]
            if abs(t_new - t_guess) > 0.25 * self.M * self.dt:
                raise SolverError(f"no crossing of the Earth-Moon x-z plane within a quarter "
                                  f"revolution of t = {t_guess:.6g} TU (Newton left for "
                                  f"{t_new:.6g})")
            x = flow(x, t, t_new)
            t = t_new
        q = self.synodic(t, x)
        if abs(q[1]) > 1e-9:
            raise SolverError(f"no crossing of the Earth-Moon x-z plane near t = {t_guess:.6g} "
                              f"TU (|y| = {abs(q[1]) * self.units.length / 1e3:.3g} km after 20 "
                              f"Newton steps)")
        return t, x

    @cached_property
    def perilune_crossings(self) -> dict[str, np.ndarray]:
        """The reference's passages through the true Earth-Moon x-z plane (``y_syn = 0``,
        :meth:`synodic_map`) near each perilune: ``step`` (the grid step before the crossing),
        ``time`` (TU), ``state`` (6,, controllers' frame) and ``synodic`` (6,, synodic frame) at
        the crossing (Newton on ``y_syn(t) = 0`` from the grid state before it)."""
        d = np.linalg.norm(self.X[:, :3] - np.array([1.0 - self.params[0], 0.0, 0.0]), axis=1)
        peri = [k for k in range(1, d.size - 1) if d[k] <= d[k - 1] and d[k] <= d[k + 1]]
        steps, times, states, syn = [], [], [], []
        for k in peri:
            lo, hi = max(k - 3, 0), min(k + 4, d.size)
            y = np.array([self.synodic(self.times[j], self.X[j])[1] for j in range(lo, hi)])
            s = np.flatnonzero(np.sign(y[:-1]) != np.sign(y[1:]))
            if s.size == 0:
                continue
            j = lo + int(s[0])
            t, x = self.synodic_crossing(self.X[j], self.times[j], self.times[j])
            steps.append(j)
            times.append(t)
            states.append(x)
            syn.append(self.synodic(t, x))
        return {"step": np.asarray(steps, int), "time": np.asarray(times),
                "state": np.asarray(states), "synodic": np.asarray(syn)}


def step_jacobians(model, X: np.ndarray, t0: np.ndarray, t1: np.ndarray,
                   p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact ``A_k = d x(t1_k) / d x(t0_k)`` (N, n_x, n_x) and ``B_k = d x(t1_k) / d u`` (N, n_x,
    n_u) for a normalised thrust ``u`` held over each arc, from the model's variational equations
    (:func:`ocreach.dynamics.flow.stt_rhs` of order 1 on the augmented ``z = [x; u]``, Foss et al. Eq. 11-
    12), all arcs ``X[k]`` at ``t0[k]`` -> ``t1[k]`` integrated as one batch without thrust."""
    from ocreach.dynamics.flow import integrate_batch, stt_rhs

    nx, nz = model.n_x, model.n_z
    N = X.shape[0]
    Y0 = np.concatenate([X, np.tile(np.eye(nx, nz).ravel(), (N, 1))], axis=1)
    args = np.concatenate([np.zeros((N, model.n_u)), np.broadcast_to(p, (N, model.n_p))], axis=1)
    Y1 = integrate_batch(stt_rhs(model, 1), Y0, np.asarray(t0, float), np.asarray(t1, float),
                         args, rtol=RTOL, atol=ATOL)
    Phi = Y1[:, nx:nx + nx * nz].reshape(N, nx, nz)
    return Phi[:, :, :nx].copy(), Phi[:, :, nx:].copy()


#: scenarios built in this process, by :meth:`ScenarioSpec.key` (at most a few are kept)
_SCENARIOS: dict[str, Scenario] = {}


def scenario(spec: ScenarioSpec) -> Scenario:
    """The scenario of ``spec``, built once per process."""
    key = spec.key()
    if key not in _SCENARIOS:
        if len(_SCENARIOS) >= 4:
            _SCENARIOS.pop(next(iter(_SCENARIOS)))
        _SCENARIOS[key] = Scenario(spec)
    return _SCENARIOS[key]


__all__ = ["ATOL", "DAYS_PER_YEAR", "RTOL", "Scenario", "ScenarioSpec", "scenario",
           "step_jacobians"]
