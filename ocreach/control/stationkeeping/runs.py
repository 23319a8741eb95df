"""Station keeping on the NRHO: the closed-loop runs (Patel & Subbarao, "Station-keeping in the
near rectilinear halo orbit").

:func:`run_station_keeping` runs the event-triggered MPC (:mod:`ocreach.control.stationkeeping.event_mpc`, on the
drift tubes of :mod:`ocreach.control.stationkeeping.drift_tubes`), a robust tube MPC
(:mod:`ocreach.control.stationkeeping.tube_mpc`), the continuous MPC and the periodic LQR on the true CR3BP plant
(or the DE421 ephemeris plant of :mod:`ocreach.control.stationkeeping.ephemeris_plant`, the CR3BP then only the
prediction model) with the same seeded offset, disturbance and (optional) navigation-error draws
(:class:`NavigationError`), over many revolutions, and computes the metrics of
:func:`~ocreach.control.stationkeeping.metrics.station_keeping_metrics`.  The paper's settings:
:mod:`ocreach.control.stationkeeping.paper`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.control.lqr import LQR
from ocreach.control.mpc import MPC
from ocreach.control.reference import TrackingReference, reference_from_problem
from ocreach.control.simulate import SimOptions, SimResult, simulate
from ocreach.control.stationkeeping.drift_tubes import (
    drift_schedule,
    ephemeris_drift_schedule,
    tube_log,
)
from ocreach.control.stationkeeping.ephemeris_plant import (
    DEFAULT_BODIES,
    DEFAULT_EPOCH,
    PLANTS,
    EphemerisPlant,
)
from ocreach.control.stationkeeping.ephemeris_reference import (
    ephemeris_reference,
    reference_settings,
)
from ocreach.control.stationkeeping.event_mpc import (
    EventTrigger,
    EventTriggeredMPC,
    check_anticipate,
)
from ocreach.control.stationkeeping.metrics import station_keeping_metrics
from ocreach.control.stationkeeping.paper import (
    PAPER_DELTA_V_MPS,
    PAPER_G_POS,
    PAPER_G_VEL,
    PAPER_N,
    PAPER_TF_HOURS,
    PAPER_W,
    paper_initial_set,
)
from ocreach.control.stationkeeping.tubes import TubeSchedule
from ocreach.errors import ProblemError, check_count


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


def run_tube_logs(schedule, n_steps: int, n_p: int) -> tuple[list[dict], list[dict]]:
    """The tube log of a run (:func:`~ocreach.control.stationkeeping.drift_tubes.tube_log` over its ``n_steps``
    steps) and the tubes refreshed after its last step that the MPC predictions still reach (the
    plan made at step ``n_steps - 1`` constrains steps up to ``n_steps - 1 + n_p``): both count
    for whether the tubes used were guaranteed."""
    if schedule is None:
        return [], []
    tubes = tube_log(schedule, n_steps)
    beyond = [e for e in tube_log(schedule, n_steps + n_p) if e["refresh_step"] >= n_steps]
    return tubes, beyond


def tubes_enclose_plant(tubes: list[dict], plant: str, reference: str) -> bool | None:
    """Whether every tube of the run (:func:`~ocreach.control.stationkeeping.drift_tubes.tube_log`) is a
    guaranteed enclosure of the drift of the plant the run simulates: the tubes are sound for the
    reference's model, so with the DE421 plant and the CR3BP reference (tubes of the CR3BP drift)
    none is, whatever method built them.  ``None`` without tubes."""
    if not tubes:
        return None
    if plant == "ephemeris" and reference == "cr3bp":
        return False
    return all(t["guaranteed"] for t in tubes)


def _check_reference_kind(reference: str, plant: str, controllers) -> None:
    """``reference`` of :func:`run_station_keeping`: a name in ``REFERENCES`` that fits the plant
    and the controllers."""
    if reference not in REFERENCES:
        raise ProblemError(f"reference must be one of {list(REFERENCES)}; got {reference!r}")
    if reference == "ephemeris":
        if plant != "ephemeris":
            raise ProblemError(f"reference='ephemeris' (the DE421-corrected orbit) needs "
                               f"plant='ephemeris'; got plant={plant!r}")


def _check_initial(problem, initial: Any, reference: str, controllers) -> None:
    """``initial`` of :func:`run_station_keeping`: ``"paper"`` or finite generators of the tubes'
    initial deviation set (a scalar, the diagonal or an ``n_x x q`` matrix).  With
    ``reference="ephemeris"`` and no tube controller no tube is computed, so a value other than
    the default ``"paper"`` would have no effect: refused."""
    n = problem.model.n_x
    if isinstance(initial, str):
        if initial != "paper":
            raise ProblemError(f"initial must be 'paper' or generators (a scalar, {n} diagonal "
                               f"entries or an n_x x q matrix, n_x = {n}); got {initial!r}")
    else:
        try:
            G = np.asarray(initial, dtype=float)
        except (TypeError, ValueError):
            G = None
        if G is None or not (G.ndim == 0 or (G.ndim == 1 and G.size == n)
                             or (G.ndim == 2 and G.shape[0] == n)) or not np.all(np.isfinite(G)):
            raise ProblemError(f"initial must be 'paper' or finite generators (a scalar, {n} "
                               f"diagonal entries or an n_x x q matrix, n_x = {n}); "
                               f"got {initial!r}")
    tubes = [c for c in controllers if c in TUBE_CONTROLLERS]
    if reference == "ephemeris" and not tubes and not isinstance(initial, str):
        raise ProblemError(f"initial (the tubes' initial deviation set) has no effect with "
                           f"reference='ephemeris' and controllers {list(controllers)}: no tube is "
                           f"computed (only {list(TUBE_CONTROLLERS)} use one); leave initial "
                           f"'paper' or add a tube controller; got initial={initial!r}")


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
#: DE421-corrected multi-revolution orbit (:mod:`ocreach.control.stationkeeping.ephemeris_reference`).
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
    Controllers: ``event-mpc`` (:class:`~ocreach.control.stationkeeping.event_mpc.EventTriggeredMPC`), ``tube-mpc``
    (:class:`~ocreach.control.stationkeeping.tube_mpc.TubeMPC`), ``mpc`` (continuous :class:`MPC`, no tube), ``lqr``
    (periodic LQR).  Weights default to Table 3 (``R`` on the thrust acceleration).  The
    reference, LQR and tubes use ``n_sub`` RK4 substeps (``"auto"``: one-step error <= 1e-6); the
    MPCs predict with ``prediction_substeps`` substeps and the reference's defect correction
    (``None``: ``n_sub``, no correction).  ``tube_source``: see :func:`~ocreach.control.stationkeeping.drift_tubes.drift_schedule`
    (``"taylor-or-linear"``: the sound tube where taylor encloses the interval, the linear one
    elsewhere); ``tube_interval="adaptive"`` with ``"taylor"``/``"sdc"``: guaranteed tubes over
    whole revolutions, refreshed where the sound method stops (:func:`~ocreach.control.stationkeeping.drift_tubes.drift_schedule`);
    ``settings["tubes"]`` (:func:`~ocreach.control.stationkeeping.drift_tubes.tube_log`) says which tube was used per refresh.
    ``tube_source=None`` (default): the problem's ``extra["station_keeping"]`` (source and
    interval; nrho-9-2: ``"taylor"``, ``"adaptive"``), else ``"linear"`` once per revolution.
    ``anticipate``: the event-triggered MPC also fires on the predicted gauge at the next refresh
    (:class:`~ocreach.control.stationkeeping.event_mpc.EventTriggeredMPC`); ``None``: from the same ``extra`` entry, else False.

    ``terminal_set``: the tube MPC's LQR terminal set (:mod:`ocreach.control.stationkeeping.tube_mpc`).
    ``plant``: ``"cr3bp"`` (the problem's model, default) or ``"ephemeris"``
    (:class:`~ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant`: DE421 point masses
    ``ephemeris_bodies`` from ``epoch`` = reference time 0, the CR3BP rotating frame fixed at the
    epoch); with ``reference="cr3bp"`` (default) the controllers, tubes and reference stay CR3BP
    (the prediction model) either way.  ``reference="ephemeris"`` (with ``plant="ephemeris"``):
    the DE421-corrected orbit of :mod:`ocreach.control.stationkeeping.ephemeris_reference` from ``epoch``, a
    natural orbit of the plant; the LQR (finite-horizon, the reference is not periodic), the MPCs
    and the tubes then linearise and predict with the plant's own dynamics in the CR3BP frame
    fixed at the epoch.  The tubes (only when ``event-mpc`` or ``tube-mpc`` runs) are computed
    along the reference per refresh interval, nothing re-used
    (:func:`~ocreach.control.stationkeeping.ephemeris_tubes.along_reference_schedule`; ``tube_interval`` None
    or ``"adaptive"``, ``phase`` ``"apolune"``; the problem's default ``"taylor"`` becomes
    ``"taylor-or-linear"``), and the tube MPC's margins and terminal set are computed over the
    run's solve steps (:class:`~ocreach.control.stationkeeping.tube_mpc.TubeMPC`).
    """
    from ocreach.control.report import PAPER_Q, paper_pattern
    from ocreach.control.stationkeeping.tube_mpc import TubeMPC

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
    _check_initial(problem, initial, reference, controllers)
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
    anticipate = check_anticipate(False if anticipate is None else anticipate)
    if reference == "ephemeris":
        ref, orbit = ephemeris_reference(problem, revolutions, epoch=epoch,
                                         bodies=ephemeris_bodies, dt=dt, n_sub=n_sub)
        schedule = None
        if any(c in TUBE_CONTROLLERS for c in controllers):
            schedule = ephemeris_drift_schedule(problem, ref, initial, disturbance, membership,
                                                phase, tube_source, tube_interval, tube_options,
                                                source_given, n_p, orbit.plant)
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
    tubes, tubes_beyond = run_tube_logs(schedule, K, n_p)
    guaranteed = tubes_enclose_plant(tubes + tubes_beyond, plant, reference)
    sources = sorted({t["source"] for t in tubes})
    for met in metrics.values():  # the tubes are shared; repeated per controller for clarity
        met["tube_guaranteed"] = guaranteed
        met["tube_sources"] = list(sources)
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
        "tube_guaranteed": guaranteed,
        # the model whose drift the tubes enclose: "plant" or "cr3bp" (DE421 plant, CR3BP tubes)
        "tube_model": (None if not tubes else
                       "cr3bp" if plant == "ephemeris" and reference == "cr3bp" else "plant"),
        "tubes": tubes, "tube_sources_used": sources,
        # refreshed after the last step, reached only by the last MPC predictions (counted in
        # tube_guaranteed)
        "tubes_in_last_predictions": tubes_beyond,
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


__all__ = ["CONTROLLERS", "NavigationError", "REFERENCES", "StationKeepingRun", "TUBE_CONTROLLERS",
           "run_station_keeping", "tubes_enclose_plant"]
