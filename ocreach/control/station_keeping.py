"""Event-triggered station keeping on a reachable-set tube (Patel & Subbarao, "Station-keeping in
the near rectilinear halo orbit").

The thrust is off while the state stays in the drift tube ``R(t)`` (:mod:`ocreach.control.tube`,
refreshed at every apolune).  When the gauge of the state exceeds 1 the MPC of Eq. 27 is switched
on, its predicted states constrained to the ``beta``-shrunk tube (soft: a penalised slack keeps the
NLP feasible from outside the tube); it stays on until the gauge has been ``<= beta`` for ``m``
consecutive steps (hysteresis, :class:`EventTrigger`), then the thrust is off again.  The paper:
N = 15, initial deviation set ``G_pos = 1e-4 I``, ``G_vel = 5e-4 I``, disturbance ``W = 1e-7 I``
(non-dimensional), ``Delta V = 0.0061 m/s`` over 157 h.

:func:`run_station_keeping` runs this controller, a robust tube MPC (:mod:`ocreach.control.tube_mpc`),
the continuous MPC and the periodic LQR on the true CR3BP plant (or the DE421 ephemeris plant of
:mod:`ocreach.control.ephemeris_plant`, the CR3BP then only the prediction model) with the same seeded offset,
disturbance and (optional) navigation-error draws, over many revolutions, and computes the metrics of
:func:`station_keeping_metrics`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.control.common import control_scale
from ocreach.control.ephemeris_plant import DEFAULT_BODIES, DEFAULT_EPOCH, PLANTS, EphemerisPlant
from ocreach.control.ephemeris_reference import ephemeris_reference, reference_settings
from ocreach.control.lqr import LQR
from ocreach.control.mpc import MPC
from ocreach.control.reference import TrackingReference, reference_from_problem
from ocreach.control.simulate import SimOptions, SimResult, simulate
from ocreach.control.tube import (
    Tube,
    TubeSchedule,
    apolune_phase,
    linear_drift_tube,
    reach_drift_tube,
    sound_drift_partition,
)
from ocreach.control.tube_mpc import MPCWrapper
from ocreach.errors import ProblemError, SolverError, check_count

#: Patel & Subbarao's NRHO station-keeping settings (non-dimensional).
PAPER_N = 15
PAPER_G_POS, PAPER_G_VEL = 1e-4, 5e-4
PAPER_W = 1e-7
PAPER_DELTA_V_MPS = 0.0061
PAPER_TF_HOURS = 157.0
MEMBERSHIPS = ("zonotope", "box")
#: Sound-method options of the adaptive tubes (``tube_interval="adaptive"``), measured on nrho-9-2
#: with the paper's sets: 16 sub-steps per 1-h step keep the tube from perilune to the next
#: apolune within 1.32x of the linearised tube's box (4 sub-steps: 3.7x; 1: fails after 24
#: steps); the sub-step may be halved 10 times (at perilune ||A h||_inf of the unscaled CR3BP
#: exceeds what 40 Taylor terms of e^{Ah} bound at 6 halvings); no splitting (a union's zonotope
#: enclosure is looser than restarting the tube).
ADAPTIVE_TUBE_OPTIONS = {"substeps": 16, "max_halvings": 10, "split": False}
#: Tube sources: the linearised tube, a sound method, or a sound method with the linear tube
#: wherever it fails (each tube's source and guarantee are logged per refresh).
FALLBACK_SOURCES = ("taylor-or-linear", "sdc-or-linear")
TUBE_SOURCES = ("linear", "taylor", "sdc") + FALLBACK_SOURCES


# ------------------------------------------------------------------------------------------------
# trigger
# ------------------------------------------------------------------------------------------------
class EventTrigger:
    """Hysteresis on the tube gauge: off -> on when ``gamma > threshold`` (default 1: the state
    left the tube); on -> off when ``gamma <= beta`` for ``m`` consecutive steps (back inside the
    shrunk tube).  ``update`` returns the thrust flag for the current step."""

    def __init__(self, beta: float = 0.7, m: int = 3, threshold: float = 1.0) -> None:
        if isinstance(threshold, bool) or not np.isfinite(threshold) or threshold <= 0:
            raise ProblemError(f"threshold (trigger gauge) must be a finite number > 0; got {threshold!r}")
        if isinstance(beta, bool) or not np.isfinite(beta) or not 0 < beta < threshold:
            raise ProblemError(f"beta (release gauge, shrunk tube) must satisfy 0 < beta < threshold "
                               f"= {threshold:g}; got {beta!r}")
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1:
            raise ProblemError(f"m (steps inside the shrunk tube before release) must be an integer "
                               f">= 1; got {m!r}")
        self.beta, self.m, self.threshold = float(beta), int(m), float(threshold)
        self.reset()

    def reset(self) -> None:
        self.active = False
        self.inside = 0
        self.activations = 0

    def update(self, gamma: float) -> bool:
        if np.isnan(gamma):
            raise ProblemError(f"gauge must be a number; got {gamma!r}")
        if not self.active:
            if gamma > self.threshold:
                self.active = True
                self.activations += 1
                self.inside = 0
        else:
            self.inside = self.inside + 1 if gamma <= self.beta else 0
            if self.inside >= self.m:
                self.active = False
                self.inside = 0
        return self.active


def trigger_signal(gammas: Any, beta: float = 0.7, m: int = 3, threshold: float = 1.0) -> np.ndarray:
    """Thrust flags of :class:`EventTrigger` over a gauge sequence (for plots and tests)."""
    trig = EventTrigger(beta, m, threshold)
    return np.array([trig.update(float(g)) for g in np.asarray(gammas, float)], dtype=bool)


# ------------------------------------------------------------------------------------------------
# tubes for station keeping
# ------------------------------------------------------------------------------------------------
def paper_initial_set(problem, g_pos: float = PAPER_G_POS, g_vel: float = PAPER_G_VEL) -> np.ndarray:
    """Diagonal of the initial deviation set: ``g_pos`` on positions, ``g_vel`` on velocities."""
    d = np.zeros(problem.model.n_x)
    d[list(problem.position_dims)] = g_pos
    d[list(problem.velocity_dims)] = g_vel
    return d


def as_box(tube: Tube) -> Tube:
    """The tube's interval hulls as a tube (diagonal generators): the paper's Fig. 7 boxes."""
    hw = tube.half_widths()
    G = np.einsum("kn,nm->knm", hw, np.eye(tube.dim))
    return Tube(tube.centers, G, k0=tube.k0, guaranteed=tube.guaranteed,
                source=f"interval hull of {tube.source}", meta=tube.meta)


def drift_schedule(problem, reference: TrackingReference, *, initial: Any = "paper",
                   disturbance: Any = PAPER_W, membership: str = "box", phase: int | str = "apolune",
                   every: int = 1, lookahead: int = PAPER_N, source: str = "linear",
                   order: float = 5.0, tube_options: dict | None = None,
                   interval: int | str | None = None) -> TubeSchedule:
    """Drift tubes (zero thrust) about the reference, refreshed at ``phase`` every ``every``
    revolutions; each covers its interval plus ``lookahead`` steps.

    ``source``: ``"linear"`` (:func:`~ocreach.control.tube.linear_drift_tube`, not guaranteed),
    ``"taylor"`` / ``"sdc"`` (:func:`~ocreach.control.tube.reach_drift_tube`, guaranteed; with
    ``tube_options`` for the method, and ``interval`` for tubes shorter than a revolution; a
    method that cannot enclose the interval raises), or ``"taylor-or-linear"`` /
    ``"sdc-or-linear"`` (the sound tube where the method succeeds, else the linear one, its
    ``meta["fallback_reason"]`` the method's error).  :func:`tube_log` lists which was used.
    ``interval="adaptive"`` (with ``"taylor"`` / ``"sdc"``): guaranteed tubes over every whole
    revolution, each restarted from the initial set where the previous one stops
    (:func:`~ocreach.control.tube.sound_drift_partition`: on the NRHO a short tube across
    perilune); computed once for one period from ``phase`` and re-used, shifted, every period.
    ``membership``: ``"zonotope"`` (exact gauge of the set) or
    ``"box"`` (its interval hull).
    """
    if membership not in MEMBERSHIPS:
        raise ProblemError(f"membership must be one of {MEMBERSHIPS}; got {membership!r}")
    G0 = paper_initial_set(problem) if isinstance(initial, str) and initial == "paper" else initial
    if isinstance(G0, str):
        raise ProblemError(f"initial must be 'paper' or generators; got {initial!r}")
    if isinstance(interval, str):
        if interval != "adaptive" or source not in ("taylor", "sdc"):
            raise ProblemError(f"interval must be a number of steps, None (every revolution) or "
                               f"'adaptive' (with tube source 'taylor' or 'sdc'); got "
                               f"{interval!r} with source {source!r}")
        return _adaptive_schedule(problem, reference, G0, disturbance, source, membership, phase,
                                  tube_options or {})
    length = (every * reference.n_steps if interval is None else int(interval)) + lookahead + 1

    def linear(k: int) -> Tube:
        return linear_drift_tube(reference, k, length, G0, disturbance, problem.velocity_dims,
                                 order=order)

    def sound(k: int, method: str) -> Tube:
        return reach_drift_tube(problem, reference, k, length, G0, disturbance, method,
                                **(tube_options or {}))

    if source == "linear":
        build = linear
    elif source in ("taylor", "sdc"):
        def build(k: int) -> Tube:
            return sound(k, source)
    elif source in FALLBACK_SOURCES:
        method = source.split("-")[0]

        def build(k: int) -> Tube:
            try:
                return sound(k, method)
            except SolverError as err:  # e.g. taylor stops before perilune on the NRHO
                lin = linear(k)
                reason = " ".join(str(err).split())[:300]
                return Tube(lin.centers, lin.generators, k0=lin.k0, guaranteed=False,
                            source=f"{lin.source}; {method} failed", meta={
                                **lin.meta, "fallback_from": method, "fallback_reason": reason})
    else:
        raise ProblemError(f"tube source must be one of {list(TUBE_SOURCES)}; got {source!r}")
    wrap = as_box if membership == "box" else (lambda t: t)
    return TubeSchedule(lambda k: wrap(build(k)), reference, phase=phase, every=every,
                        lookahead=lookahead, reuse=True, interval=interval)


#: adaptive tube partitions of this process, by :func:`_partition_key` (they are deterministic:
#: several runs on the same reference, e.g. one per plant, compute them once)
_PARTITIONS: dict[str, list[Tube]] = {}


def _partition_key(problem, reference: TrackingReference, phase: int, G0: Any, disturbance: Any,
                   method: str, options: dict) -> str:
    """Everything :func:`~ocreach.control.tube.sound_drift_partition` depends on, hashed: the
    model, its parameters, the reference states and times, the sets, the method and options."""
    import hashlib

    h = hashlib.sha256()
    h.update(repr((problem.model.name, problem.model.n_x, problem.id, problem.control_set.kind,
                   phase, method,
                   sorted((k, repr(v)) for k, v in options.items()), repr(disturbance))).encode())
    for a in (reference.X, reference.time(np.arange(reference.n_steps + 1)), reference.params,
              problem.params, np.asarray(G0, float)):
        h.update(np.ascontiguousarray(np.asarray(a, float)).tobytes())
    return h.hexdigest()


def _adaptive_schedule(problem, reference: TrackingReference, G0: Any, disturbance: Any,
                       method: str, membership: str, phase: int | str,
                       options: dict) -> TubeSchedule:
    """Guaranteed tubes over one period from ``phase``, refreshed where the sound method stops
    (:func:`~ocreach.control.tube.sound_drift_partition`), re-used every period.  MPC windows that
    cross a refresh take the next tube's sets, so no tube needs a lookahead."""
    M = reference.n_steps
    p0 = apolune_phase(reference) if phase == "apolune" else phase
    if isinstance(p0, str) or isinstance(p0, bool) or int(p0) != p0 or not 0 <= int(p0) < M:
        raise ProblemError(f"phase must be 'apolune' or a reference step 0..{M - 1}; got {phase!r}")
    opts = {**ADAPTIVE_TUBE_OPTIONS, **options}
    key = _partition_key(problem, reference, int(p0), G0, disturbance, method, opts)
    tubes = _PARTITIONS.get(key)
    if tubes is None:
        tubes = sound_drift_partition(problem, reference, int(p0), int(p0) + M, G0, disturbance,
                                      method, **opts)
        if len(_PARTITIONS) >= 8:
            _PARTITIONS.pop(next(iter(_PARTITIONS)))
        _PARTITIONS[key] = tubes
    wrap = as_box if membership == "box" else (lambda t: t)
    by_phase = {t.k0 % M: wrap(t) for t in tubes}

    def build(k: int) -> Tube:
        return by_phase[k % M].shifted(k)

    return TubeSchedule(build, reference, phases=sorted(by_phase), reuse=True)


# ------------------------------------------------------------------------------------------------
# controllers
# ------------------------------------------------------------------------------------------------
class EventTriggeredMPC(MPCWrapper):
    """Thrust off inside the tube; the tube-constrained MPC (soft) when the trigger is on.

    ``schedule`` a :class:`TubeSchedule` on the same reference; ``mpc_options`` for
    :class:`MPC` (``tube`` and ``tube_slack`` are set here); ``trigger`` an :class:`EventTrigger`;
    ``target`` the tube scale the MPC's predicted states are constrained to (default: the
    trigger's ``beta``, so the MPC aims for the release region).  Logs per step: ``gauges``,
    ``active``, ``slacks`` (largest predicted slack, 0 when off), ``excursions`` (steps where the
    gauge exceeds 1, with the thrust flag).

    ``anticipate=True`` (not in the paper): the trigger sees ``max(gamma_now, gamma_next)``,
    ``gamma_next`` the gauge, in the next refresh's tube, of the state's drift predicted to the
    next refresh step by the reference's STMs (:meth:`predicted_gauge`).  A guaranteed tube that
    must restart from the initial set before perilune (``tube_interval="adaptive"``) is a gate the
    state has to pass; this fires while the correction is still cheap, not at the gate.  The
    prediction is linear (an estimate): it decides when to thrust, the tubes stay what they are.
    """

    name = "event-mpc"

    def __init__(self, Q, R, schedule: TubeSchedule, *, trigger: EventTrigger | None = None,
                 n_p: int = PAPER_N, n_c: int | None = None, tube_slack: float = 100.0,
                 target: float | None = None, fallback: LQR | None = None,
                 anticipate: bool = False, **mpc_options: Any) -> None:
        if not isinstance(anticipate, (bool, np.bool_)):
            raise ProblemError(f"anticipate must be True or False; got {anticipate!r}")
        self.anticipate = bool(anticipate)
        self._to_refresh: dict[tuple[int, int], np.ndarray] = {}
        self.schedule = schedule
        self.trigger = trigger or EventTrigger()
        self.target = self.trigger.beta if target is None else float(target)
        if not np.isfinite(self.target) or self.target <= 0:
            raise ProblemError(f"target (tube scale for the MPC) must be > 0; got {target!r}")
        q = schedule.n_generators
        self.mpc = MPC(Q, R, n_p=n_p, n_c=n_p if n_c is None else n_c, tube=q,
                       tube_slack=tube_slack, fallback=fallback, **mpc_options)
        self.n_p = n_p
        self.reset()

    def setup(self, reference: TrackingReference, control_set_kind: str) -> EventTriggeredMPC:
        if reference is not self.schedule.reference:
            raise ProblemError("EventTriggeredMPC: the tube schedule was built on another reference")
        self.mpc.setup(reference, control_set_kind)
        self.nu = reference.model.n_u
        self.reset()
        return self

    def reset(self) -> None:
        self.trigger.reset()
        if getattr(self.mpc, "reference", None) is not None:
            self.mpc.reset()
        self.gauges: list[float] = []
        self.predicted_gauges: list[float] = []  # anticipate: gauge at the next refresh
        self.active: list[bool] = []
        self.slacks: list[float] = []
        self.solve_times: list[float] = []

    def predicted_gauge(self, k: int, x: np.ndarray) -> float:
        """Gauge in the next refresh's tube of ``x_ref(r) + Phi(r, k) (x - x_ref(k))``, ``r`` the
        next refresh step after ``k`` and ``Phi`` the product of the reference's one-step STMs
        (along a non-periodic reference, after the last refresh: the tubes' last step)."""
        sched, ref = self.schedule, self.schedule.reference
        r = sched.next_refresh(sched.refresh_step(k))
        if sched.starts is not None:
            r = min(r, sched.end - 1)
        key = (k % ref.n_steps, r - k)  # Phi depends on the phase and the steps to go
        if key not in self._to_refresh:
            ref.linearize()
            idx = ref.gains_index(np.arange(k, r))
            Phi = np.eye(ref.model.n_x)
            for i in idx:
                Phi = ref.A[i] @ Phi
            self._to_refresh[key] = Phi
        d = self._to_refresh[key] @ (np.asarray(x, float) - ref.state(k))
        return sched.gauge(r, ref.state(r) + d)

    def control(self, k: int, x: np.ndarray) -> np.ndarray:
        g = self.schedule.gauge(k, x)
        g_next = self.predicted_gauge(k, x) if self.anticipate else 0.0
        on = self.trigger.update(max(g, g_next))
        self.gauges.append(g)
        self.predicted_gauges.append(g_next)
        self.active.append(on)
        if not on:
            self.slacks.append(0.0)
            return np.zeros(self.nu)
        c, G = self.schedule.window(k, self.n_p, beta=self.target)
        self.mpc.set_tube(c, G)
        t = time.perf_counter()
        u = self.mpc.control(k, x)
        self.solve_times.append(time.perf_counter() - t)
        self.slacks.append(self.mpc.last_tube_slack)
        return u


class NavigationError:
    """Wraps a controller so it sees ``x + e_k``, ``e_k`` uniform in ``diag(sigma) [-1, 1]^n``
    (seeded; the plant keeps the true state)."""

    def __init__(self, controller, sigma: Any, seed: int = 0) -> None:
        self.controller = controller
        self.sigma = np.asarray(sigma, float)
        if not np.all(np.isfinite(self.sigma)) or np.any(self.sigma < 0):
            raise ProblemError(f"navigation error half-widths must be finite and >= 0; got {sigma!r}")
        self.seed = seed
        self.name = getattr(controller, "name", "controller")

    def setup(self, reference, kind):
        self.controller.setup(reference, kind)
        self.sigma = np.broadcast_to(self.sigma, (reference.model.n_x,))
        return self

    def reset(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        if hasattr(self.controller, "reset"):
            self.controller.reset()

    def __getattr__(self, item):
        if item == "controller":
            raise AttributeError(item)
        return getattr(self.controller, item)

    def control(self, k: int, x: np.ndarray) -> np.ndarray:
        e = self.sigma * self.rng.uniform(-1.0, 1.0, self.sigma.size)
        return self.controller.control(k, np.asarray(x, float) + e)


def tube_log(schedule: TubeSchedule, n_steps: int) -> list[dict[str, Any]]:
    """Which tube was used when: one entry per refresh interval touching steps ``0..n_steps-1``
    (``refresh_step``, the steps ``[first, end)`` it was active for, the same in revolutions,
    ``source``, ``guaranteed``, and ``fallback_reason`` when a sound method failed and the
    linear tube stood in)."""
    M = schedule.reference.revolution_steps
    out = []
    for r in schedule.refresh_steps(n_steps):
        t = schedule.tube(r)
        a, b = max(r, 0), min(schedule.next_refresh(r), n_steps)
        out.append({"refresh_step": int(r), "steps": [int(a), int(b)],
                    "revolutions": [a / M, b / M], "source": t.source,
                    "guaranteed": bool(t.guaranteed),
                    "fallback_reason": (t.meta or {}).get("fallback_reason")})
    return out


def _ephemeris_schedule(problem, ref: TrackingReference, initial: Any, disturbance: Any,
                        membership: str, phase: Any, source: str, interval: Any,
                        options: dict | None, source_given: bool, n_p: int,
                        plant: EphemerisPlant) -> TubeSchedule:
    """Drift tubes along the ephemeris-corrected reference
    (:func:`~ocreach.control.ephemeris_tubes.along_reference_schedule`: refreshed at every
    apolune and where the sound method stops, nothing re-used).  A sound source taken from the
    problem's defaults (not given) becomes ``"<method>-or-linear"``: guaranteed where the method
    encloses, the linearised tube (labelled) where it cannot.  The sound method runs on the
    plant's frame model restricted to each interval (:meth:`EphemerisPlant.frame_model_on`: the
    same function there, without the ``if_else`` between DE421 fit pieces)."""
    from ocreach.control.ephemeris_tubes import along_reference_schedule

    if membership not in MEMBERSHIPS:
        raise ProblemError(f"membership must be one of {MEMBERSHIPS}; got {membership!r}")
    if phase != "apolune":
        raise ProblemError(f"phase along the ephemeris-corrected reference must be 'apolune' (the "
                           f"tubes restart at every apolune); got {phase!r}")
    if interval not in (None, "adaptive"):
        raise ProblemError(f"tube_interval along the ephemeris-corrected reference must be None "
                           f"or 'adaptive' (every apolune and where the sound method stops); "
                           f"got {interval!r}")
    if not source_given and source in ("taylor", "sdc"):
        source = f"{source}-or-linear"
    G0 = paper_initial_set(problem) if isinstance(initial, str) and initial == "paper" else initial
    if isinstance(G0, str):
        raise ProblemError(f"initial must be 'paper' or generators; got {initial!r}")
    # the run's steps and the last MPC window (n_p steps after the last solve)
    end = min(ref.n_steps, ref.n_default + n_p + 1)
    return along_reference_schedule(problem, ref, G0, disturbance, source,
                                    wrap=as_box if membership == "box" else (lambda t: t),
                                    options=options, end=end, model_on=plant.frame_model_on)


def _check_reference_kind(reference: str, plant: str, controllers) -> None:
    """``reference`` of :func:`run_station_keeping`: a name in ``REFERENCES`` that fits the plant
    and the controllers."""
    if reference not in REFERENCES:
        raise ProblemError(f"reference must be one of {list(REFERENCES)}; got {reference!r}")
    if reference == "ephemeris":
        if plant != "ephemeris":
            raise ProblemError(f"reference='ephemeris' (the DE421-corrected orbit) needs "
                               f"plant='ephemeris'; got plant={plant!r}")


# ------------------------------------------------------------------------------------------------
# metrics and runs
# ------------------------------------------------------------------------------------------------
def delta_v_si(U: np.ndarray, a_max: float, dt: float, units) -> np.ndarray:
    """Per-step Delta-V in m/s: ``||u_k|| a_max dt`` (model units) times ``l*/t*``."""
    return np.linalg.norm(np.asarray(U, float), axis=1) * a_max * dt * units.velocity


def _edges(on: np.ndarray) -> int:
    on = np.asarray(on, bool)
    return int(on[0]) + int(np.sum(on[1:] & ~on[:-1])) if on.size else 0


def station_keeping_metrics(res: SimResult, reference: TrackingReference,
                            schedule: TubeSchedule | None, problem,
                            controller=None) -> tuple[dict[str, Any], np.ndarray | None]:
    """Metrics of one closed-loop run (units: m/s, km, ms) and the gauge of every state (K+1,)
    (``schedule=None``: no tube, the gauge metrics and the gauges are ``None``).

    ``delta_v_mps`` = sum_k ||a_max u_k|| dt (applied thrust) in m/s, ``delta_v_per_rev_mps`` the
    same over the revolutions flown; ``activations`` off->on switches of the thrust (event-MPC:
    its trigger), ``duty_cycle`` the fraction of steps with thrust on, ``max_gauge`` / RMS of the
    tube gauge of the true state, ``max_gauge_off`` the largest gauge while the thrust is off (None
    if it never is), ``excursions`` the steps with gauge > 1 while the thrust is off, max / RMS
    position and velocity deviation from the reference, ``time_per_step_ms`` (mean controller time
    per step), ``time_per_solve_ms`` (mean over MPC solves), ``solver_failures`` (MPC fallbacks).
    """
    units = problem.units
    model = reference.model
    K = res.U.shape[0]
    a = control_scale(model, reference.params, "auto")
    dv = delta_v_si(res.U_applied, a, reference.dt, units)
    un = np.linalg.norm(res.U_applied, axis=1)
    if controller is not None and hasattr(controller, "active") and len(controller.active) == K:
        on = np.asarray(controller.active, bool)
        activations = int(controller.trigger.activations)
    else:
        on = un > 0
        activations = _edges(on)
    ks = np.arange(K + 1)
    if schedule is None:  # no tube (no tube controller on the corrected reference): no gauges
        return _deviation_metrics(res, reference, problem, controller, dv, on, activations,
                                  None, None), None
    refresh = np.array([schedule.refresh_step(int(k)) for k in ks])
    gam = np.empty(K + 1)
    for r in np.unique(refresh):  # one batched gauge call per tube
        sel = refresh == r
        gam[sel] = schedule.tube(int(r)).gauge(ks[sel], res.X[sel])
    return _deviation_metrics(res, reference, problem, controller, dv, on, activations, gam,
                              np.r_[~on, True]), gam  # the final state has no control: off


def _deviation_metrics(res: SimResult, reference: TrackingReference, problem, controller,
                       dv: np.ndarray, on: np.ndarray, activations: int, gam: np.ndarray | None,
                       off: np.ndarray | None) -> dict[str, Any]:
    """The metrics of :func:`station_keeping_metrics` from the per-step Delta-V ``dv``, thrust
    flags ``on`` and gauges ``gam`` (``None``: no tube, gauge metrics ``None``)."""
    units = problem.units
    K = res.U.shape[0]
    revs = K / reference.revolution_steps
    un = np.linalg.norm(res.U_applied, axis=1)
    pos, vel = list(problem.position_dims), list(problem.velocity_dims)
    d = res.X - res.X_ref
    dp = np.linalg.norm(d[:, pos], axis=1) * units.length / 1e3
    dvv = np.linalg.norm(d[:, vel], axis=1) * units.velocity
    exc = np.flatnonzero(off & (gam > 1.0)) if gam is not None else None
    solves = getattr(controller, "solve_times", None) or []
    return {
        "revolutions": float(revs),
        "n_steps": int(K),
        "delta_v_mps": float(dv.sum()),
        "delta_v_per_rev_mps": float(dv.sum() / revs),
        "activations": activations,
        "duty_cycle": float(on.mean()),
        "max_gauge": float(gam.max()) if gam is not None else None,
        "max_gauge_off": float(gam[off].max()) if gam is not None and off.any() else None,
        "excursions_off": int(exc.size) if exc is not None else None,
        "excursion_steps": exc.tolist()[:200] if exc is not None else [],
        "max_deviation_km": float(dp.max()),
        "rms_deviation_km": float(np.sqrt(np.mean(dp**2))),
        "max_deviation_mps": float(dvv.max()),
        "rms_deviation_mps": float(np.sqrt(np.mean(dvv**2))),
        "final_deviation_km": float(dp[-1]),
        "max_thrust_ratio": float(un.max()),
        "time_per_step_ms": float(1e3 * np.mean(res.step_times)),
        "time_per_solve_ms": float(1e3 * np.mean(solves)) if len(solves) else None,
        "solves": int(len(solves)),
        "solver_failures": int(res.fallbacks),
        "total_time_s": float(res.total_time),
    }


@dataclass
class StationKeepingRun:
    """Results of :func:`run_station_keeping`: per controller the :class:`SimResult`, metrics and
    gauge history; the reference and the tube schedule; the settings."""

    results: dict[str, SimResult]
    metrics: dict[str, dict]
    gauges: dict[str, np.ndarray | None]
    active: dict[str, np.ndarray]
    reference: TrackingReference
    schedule: TubeSchedule | None  # None: no tube (corrected reference, no tube controller)
    settings: dict = field(default_factory=dict)
    #: per controller with an anticipating trigger: the predicted gauge at the next refresh
    predicted_gauges: dict[str, np.ndarray] = field(default_factory=dict)


CONTROLLERS = ("event-mpc", "tube-mpc", "mpc", "lqr")
#: Controllers that need a tube schedule (a periodic reference).
TUBE_CONTROLLERS = ("event-mpc", "tube-mpc")
#: References of :func:`run_station_keeping`: the problem's periodic CR3BP orbit, or its
#: DE421-corrected multi-revolution orbit (:mod:`ocreach.control.ephemeris_reference`).
REFERENCES = ("cr3bp", "ephemeris")


def run_station_keeping(problem, *, controllers: tuple[str, ...] = CONTROLLERS,
                        revolutions: float = 10, dt: float | None = None, n_p: int = PAPER_N,
                        Q: Any = None, R: Any = None, beta: float = 0.7, m: int = 3,
                        membership: str = "box", tube_source: str | None = None,
                        tube_options: dict | None = None, tube_interval: int | str | None = None,
                        phase: int | str = "apolune",
                        initial: Any = "paper", offset: Any = "paper", disturbance: Any = PAPER_W,
                        navigation: Any = None, seed: int = 0, tube_slack: float = 100.0,
                        max_cpu_time: float = 2.0, n_sub: int | str = "auto",
                        prediction_substeps: int | None = 4, terminal_set: bool = True,
                        plant: str = "cr3bp", reference: str = "cr3bp",
                        epoch: Any = DEFAULT_EPOCH, ephemeris_bodies: Any = DEFAULT_BODIES,
                        anticipate: bool | None = None,
                        progress: bool = False) -> StationKeepingRun:
    """Closed loop of each controller over ``revolutions`` of the problem's periodic reference.

    Same seeded draws for every controller: the initial offset (``"paper"``: uniform in the
    paper's initial deviation set; or a vector; or ``None``), the disturbance ``W`` per step, and
    the navigation error (half-widths ``navigation`` on the measured state, or ``None``).
    Controllers: ``event-mpc`` (:class:`EventTriggeredMPC`), ``tube-mpc``
    (:class:`~ocreach.control.tube_mpc.TubeMPC`), ``mpc`` (continuous :class:`MPC`, no tube), ``lqr``
    (periodic LQR).  Weights default to Table 3 (``R`` on the thrust acceleration).  The
    reference, LQR and tubes use ``n_sub`` RK4 substeps (``"auto"``: one-step error <= 1e-6); the
    MPCs predict with ``prediction_substeps`` substeps and the reference's defect correction
    (``None``: ``n_sub``, no correction).  ``tube_source``: see :func:`drift_schedule`
    (``"taylor-or-linear"``: the sound tube where taylor encloses the interval, the linear one
    elsewhere); ``tube_interval="adaptive"`` with ``"taylor"``/``"sdc"``: guaranteed tubes over
    whole revolutions, refreshed where the sound method stops (:func:`drift_schedule`);
    ``settings["tubes"]`` (:func:`tube_log`) says which tube was used per refresh.
    ``tube_source=None`` (default): the problem's ``extra["station_keeping"]`` (source and
    interval; nrho-9-2: ``"taylor"``, ``"adaptive"``), else ``"linear"`` once per revolution.
    ``anticipate``: the event-triggered MPC also fires on the predicted gauge at the next refresh
    (:class:`EventTriggeredMPC`); ``None``: from the same ``extra`` entry, else False.

    ``terminal_set``: the tube MPC's LQR terminal set (:mod:`ocreach.control.tube_mpc`).
    ``plant``: ``"cr3bp"`` (the problem's model, default) or ``"ephemeris"``
    (:class:`~ocreach.control.ephemeris_plant.EphemerisPlant`: DE421 point masses
    ``ephemeris_bodies`` from ``epoch`` = reference time 0, the CR3BP rotating frame fixed at the
    epoch); with ``reference="cr3bp"`` (default) the controllers, tubes and reference stay CR3BP
    (the prediction model) either way.  ``reference="ephemeris"`` (with ``plant="ephemeris"``):
    the DE421-corrected orbit of :mod:`ocreach.control.ephemeris_reference` from ``epoch``, a
    natural orbit of the plant; the LQR (finite-horizon, the reference is not periodic), the MPCs
    and the tubes then linearise and predict with the plant's own dynamics in the CR3BP frame
    fixed at the epoch.  The tubes (only when ``event-mpc`` or ``tube-mpc`` runs) are computed
    along the reference per refresh interval, nothing re-used
    (:func:`~ocreach.control.ephemeris_tubes.along_reference_schedule`; ``tube_interval`` None
    or ``"adaptive"``, ``phase`` ``"apolune"``; the problem's default ``"taylor"`` becomes
    ``"taylor-or-linear"``), and the tube MPC's margins and terminal set are computed over the
    run's solve steps (:class:`~ocreach.control.tube_mpc.TubeMPC`).
    """
    from ocreach.control.report import PAPER_Q, paper_pattern
    from ocreach.control.tube_mpc import TubeMPC

    if problem.reference is None:
        raise ProblemError(f"station keeping needs a periodic reference orbit; problem "
                           f"{problem.id!r} has none (no period to refresh the tube on)")
    unknown = sorted(set(controllers) - set(CONTROLLERS))
    if unknown or not controllers:
        raise ProblemError(f"controllers must be a non-empty subset of {list(CONTROLLERS)}; got "
                           f"{list(controllers)!r}")
    if isinstance(revolutions, bool) or not np.isfinite(revolutions) or revolutions <= 0:
        raise ProblemError(f"revolutions must be a number > 0; got {revolutions!r}")
    EventTrigger(beta, m)  # beta and m checked before the tubes are built
    if plant not in PLANTS:
        raise ProblemError(f"plant must be one of {list(PLANTS)}; got {plant!r}")
    _check_reference_kind(reference, plant, controllers)
    if isinstance(ephemeris_bodies, str):
        ephemeris_bodies = tuple(b.strip() for b in ephemeris_bodies.split(",") if b.strip())
    n_p = check_count("n_p (prediction horizon)", n_p, 1)
    Q = paper_pattern(problem, PAPER_Q[0], PAPER_Q[3]) if Q is None else Q
    R = np.ones(problem.model.n_u) if R is None else R
    source_given = tube_source is not None
    if tube_source is None:
        default = problem.extra.get("station_keeping") or {}
        tube_source = default.get("tube_source", "linear")
        if tube_interval is None:
            tube_interval = default.get("tube_interval")
        if anticipate is None:
            anticipate = default.get("anticipate")
    anticipate = False if anticipate is None else anticipate
    if not isinstance(anticipate, (bool, np.bool_)):
        raise ProblemError(f"anticipate must be True, False or None (the problem's default); got "
                           f"{anticipate!r}")
    anticipate = bool(anticipate)
    if reference == "ephemeris":
        ref, orbit = ephemeris_reference(problem, revolutions, epoch=epoch,
                                         bodies=ephemeris_bodies, dt=dt, n_sub=n_sub)
        schedule = None
        if any(c in TUBE_CONTROLLERS for c in controllers):
            schedule = _ephemeris_schedule(problem, ref, initial, disturbance, membership, phase,
                                           tube_source, tube_interval, tube_options, source_given,
                                           n_p, orbit.plant)
    else:
        ref = reference_from_problem(problem, dt=dt, n_sub=n_sub)
        schedule = drift_schedule(problem, ref, initial=initial, disturbance=disturbance,
                                  membership=membership, phase=phase, lookahead=n_p,
                                  source=tube_source, tube_options=tube_options,
                                  interval=tube_interval)
    K = int(round(revolutions * ref.revolution_steps))
    lqr = LQR(Q, R).setup(ref, problem.control_set.kind)
    if isinstance(offset, str):
        if offset != "paper":
            raise ProblemError(f"offset must be 'paper', None or a state offset; got {offset!r}")
        box, x0_off = paper_initial_set(problem), None
    else:
        box, x0_off = None, offset
    # the offset is drawn at the refresh phase's reference state when the run starts there
    opt = SimOptions(n_steps=K, offset_box=box, x0_offset=x0_off, disturbance=disturbance,
                     seed=seed, n_sub=ref.n_sub, progress=progress)
    build = {
        "event-mpc": lambda: EventTriggeredMPC(Q, R, schedule, trigger=EventTrigger(beta, m),
                                               n_p=n_p, tube_slack=tube_slack, fallback=lqr,
                                               anticipate=anticipate, **mpc_kw),
        "tube-mpc": lambda: TubeMPC(Q, R, schedule, disturbance=disturbance,
                                    velocity_dims=problem.velocity_dims, n_p=n_p,
                                    tube_slack=tube_slack, terminal_set=terminal_set,
                                    fallback=lqr, **mpc_kw),
        "mpc": lambda: MPC(Q, R, n_p=n_p, n_c=n_p, fallback=lqr, **mpc_kw),
        "lqr": lambda: lqr,
    }
    kind = problem.control_set.kind
    if prediction_substeps is not None and prediction_substeps >= ref.n_sub:
        prediction_substeps = None  # the reference's model is already that cheap
    mpc_kw = {"max_cpu_time": max_cpu_time, "prediction_substeps": prediction_substeps,
              "defect_correction": prediction_substeps is not None}
    true_plant = None
    if reference == "ephemeris":
        true_plant = orbit.plant  # the plant the reference is an orbit of
    elif plant == "ephemeris":
        true_plant = EphemerisPlant(ref, kind, problem.velocity_dims,
                                    span_days=K * ref.dt * problem.units.time / 86400.0,
                                    epoch=epoch, bodies=ephemeris_bodies)
    results, metrics, gauges, active, predicted = {}, {}, {}, {}, {}
    for name in controllers:
        ctl = build[name]()
        if ctl is not lqr:
            ctl.setup(ref, kind)
        run_ctl = ctl if navigation is None else NavigationError(ctl, navigation, seed + 1).setup(ref, kind)
        res = simulate(ref, run_ctl, control_set_kind=kind, velocity_dims=problem.velocity_dims,
                       options=opt, name=name, plant=true_plant)
        met, gam = station_keeping_metrics(res, ref, schedule, problem, ctl)
        if getattr(ctl, "terminal_set", False):
            met["terminal_set"] = {"alpha": ctl.terminal_alpha,
                                   "contraction": ctl.terminal_contraction,
                                   "disturbance_term": ctl.terminal_disturbance,
                                   "robustly_invariant": ctl.terminal_robust}
        results[name], metrics[name], gauges[name] = res, met, gam
        if getattr(ctl, "anticipate", False):
            predicted[name] = np.asarray(ctl.predicted_gauges, float)
        active[name] = (np.asarray(ctl.active, bool) if hasattr(ctl, "active")
                        else np.linalg.norm(res.U_applied, axis=1) > 0)
    tube0 = schedule.tube(schedule.phase) if schedule is not None else None
    tubes = tube_log(schedule, K) if schedule is not None else []
    for met in metrics.values():  # the tubes are shared; repeated per controller for clarity
        met["tube_guaranteed"] = all(t["guaranteed"] for t in tubes) if tubes else None
        met["tube_sources"] = sorted({t["source"] for t in tubes})
    off0 = results[controllers[0]].X[0] - ref.state(0)
    settings = {
        "problem": problem.id, "revolutions": float(K / ref.revolution_steps), "n_steps": K,
        "steps_per_rev": ref.revolution_steps, "dt_TU": ref.dt,
        "dt_hours": ref.dt * problem.units.time / 3600.0, "period_hours": ref.revolution_steps
        * ref.dt * problem.units.time / 3600.0, "n_p": n_p, "beta": beta, "m": m,
        "membership": membership, "tube_source": tube0.source if tube0 is not None else None,
        "anticipate": anticipate,
        "tube_interval_steps": schedule.interval if schedule is not None else None,
        "refresh_steps_per_rev": ([schedule.phase + int(o) for o in schedule.offsets]
                                  if schedule is not None and schedule.offsets is not None
                                  else None),
        "tube_guaranteed": all(t["guaranteed"] for t in tubes) if tubes else None,
        "tubes": tubes, "tube_sources_used": sorted({t["source"] for t in tubes}),
        "refresh_phase_step": schedule.phase if schedule is not None else None,
        "initial_set": np.asarray(paper_initial_set(problem) if isinstance(initial, str)
                                  else initial, float).tolist(),
        "disturbance_W": disturbance, "navigation": navigation, "seed": seed,
        "offset": off0.tolist(),
        "offset_position_km": float(np.linalg.norm(off0[list(problem.position_dims)])
                                    * problem.units.length / 1e3),
        "offset_velocity_mps": float(np.linalg.norm(off0[list(problem.velocity_dims)])
                                     * problem.units.velocity),
        "Q": np.asarray(Q, float).tolist(), "R": np.asarray(R, float).tolist(),
        "tube_slack": tube_slack, "rk4_substeps": ref.n_sub,
        "prediction_substeps": prediction_substeps,
        "defect_correction": prediction_substeps is not None,
        "a_max": float(problem.param("a_max")), "thrust_N": problem.extra.get("thrust_N"),
        "mass_kg": problem.extra.get("mass_kg"),
        "plant": ({"plant": "cr3bp", "frame": "CR3BP rotating (the prediction model)"}
                  if true_plant is None else true_plant.describe()),
        "reference": (reference_settings(orbit, ref) if reference == "ephemeris" else
                      {"reference": "cr3bp", "periodic": True}),
        "paper": {"delta_v_mps": PAPER_DELTA_V_MPS, "t_f_hours": PAPER_TF_HOURS, "N": PAPER_N,
                  "G_pos": PAPER_G_POS, "G_vel": PAPER_G_VEL, "W": PAPER_W},
    }
    return StationKeepingRun(results, metrics, gauges, active, ref, schedule, settings, predicted)


__all__ = ["CONTROLLERS", "EventTrigger", "EventTriggeredMPC", "NavigationError",
           "StationKeepingRun", "as_box", "delta_v_si", "drift_schedule", "paper_initial_set",
           "run_station_keeping", "station_keeping_metrics", "trigger_signal", "tube_log"]
