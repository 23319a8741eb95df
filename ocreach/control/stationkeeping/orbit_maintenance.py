"""The orbit-maintenance loop as flown: a controller acting on an estimate, impulsive burns with
execution errors (or continuous thrust), the DE421 + SRP plant, over a year.

One run (:func:`run_maintenance`):

1. the plant starts at the reference plus one navigation-error draw (the orbit as known at the
   start of maintenance); its true ``C_r A / m`` is the nominal one times ``1 + delta``, ``delta``
   uniform in ``+-srp uncertainty`` (:mod:`ocreach.control.stationkeeping.srp`);
2. at every decision step the controller gets the estimate ``xhat = x + e``
   (:mod:`ocreach.control.stationkeeping.navigation`: a fresh Gaussian OD error at each fix):
   * ``placement="anomaly"`` (x-axis control, target point, corridor control): one burn
     opportunity per revolution where the reference passes the true anomaly
     ``burn_anomaly_deg`` (180: apolune), with a fix there; a burn at every opportunity, or
     only where the controller's ``triggered`` says so (corridor control);
   * ``placement="gauge"`` (the event-triggered tube MPC): a fix every ``od_interval_h``; a burn
     only when the controller's trigger fires on the estimate;
   * ``placement="continuous"`` (LQR, MPC): a thrust command every control step, on the estimate
     dead-reckoned from the last fix (``e_{k+1} = A_k e_k + B_k (u_cmd - u_executed)``);
3. a burn is executed with magnitude and pointing errors, not at all below the minimum burn or
   when skipped (:mod:`ocreach.control.stationkeeping.execution`), and applied to the plant;
   the burn record keeps what the controller says about it (its ``last_info``);
4. the plant is propagated on the control grid; the run stops as **lost** when it leaves the
   NRHO: its distance from the Moon outside ``[d_min / loss_ratio, d_max * loss_ratio]``, ``d_min``
   and ``d_max`` the reference's closest and farthest grid distances (default ratio 1.25: below
   about 2350 km or beyond 90,000 km for the 9:2 NRHO), or the controller or the integrator
   fails (the reason is recorded).  The deviation from the reference *at the same time* is
   recorded, not a loss criterion: x-axis control leaves the phase along the orbit free, and a
   minute of phase is 100 km at perilune.  At every apolune the deviation is split into the
   phase offset ``dt = d . v_ref / |v_ref|^2`` and the rest ``|d - v_ref dt|`` (the deviation
   from the orbit's path, valid while ``dt`` is small beside a revolution).  For a controller
   with a corridor (``corridor_half_widths``, per step) the true state's largest ratio to it
   and the steps outside it are recorded.

Random draws are keyed by (seed, run, stream, step): every controller of the same run index sees
the same OD errors at the same fixes, the same execution-error draws at the same steps and the
same SRP scale (common random numbers), so differences between controllers are not sampling
noise.  :func:`run_maintenance` returns plain data (the Monte Carlo record, :mod:`ocreach.
control.stationkeeping.maintenance_mc`).
"""
from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from ocreach.control.stationkeeping.execution import ExecutionErrors
from ocreach.control.stationkeeping.navigation import NavigationErrors
from ocreach.control.stationkeeping.scenario import Scenario, ScenarioSpec, scenario
from ocreach.control.stationkeeping.srp import SolarRadiationPressure, check_nonnegative
from ocreach.errors import OcreachError, ProblemError, check_count

#: Steps per window of the deviation series kept per run (the envelope figure).
DEVIATION_WINDOW = 6
DEFAULT_LOSS_RATIO = 1.25
PLACEMENTS = ("anomaly", "gauge", "continuous")


def check_anomaly(value: Any) -> float:
    """A burn true anomaly in degrees, ``0 <= value < 360``; :class:`ProblemError` otherwise."""
    v = check_nonnegative("burn_anomaly_deg (true anomaly of the burns, deg)", value,
                          "a number in [0, 360) (180 = apolune)")
    if v >= 360.0:
        raise ProblemError(f"burn_anomaly_deg (true anomaly of the burns, deg) must be a number "
                           f"in [0, 360) (180 = apolune); got {value!r}")
    return v


@dataclass(frozen=True)
class MaintenanceSettings:
    """Everything a run depends on besides the controller: the scenario (problem, epoch, years,
    SRP), the navigation and execution errors, the burn true anomaly, the loss ratio and the
    seed.  Plain data: :meth:`to_dict` / :meth:`from_dict`, :meth:`from_options` (the flat
    option names of the report and the CLI)."""

    scenario: ScenarioSpec = field(default_factory=ScenarioSpec)
    navigation: NavigationErrors = field(default_factory=NavigationErrors)
    execution: ExecutionErrors = field(default_factory=ExecutionErrors)
    burn_anomaly_deg: float = 180.0
    loss_ratio: float = DEFAULT_LOSS_RATIO
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "burn_anomaly_deg", check_anomaly(self.burn_anomaly_deg))
        ratio = check_nonnegative("loss_ratio (Moon-distance band of a kept orbit)",
                                  self.loss_ratio, "a finite number > 1")
        if ratio <= 1:
            raise ProblemError(f"loss_ratio (Moon-distance band of a kept orbit) must be a "
                               f"finite number > 1; got {self.loss_ratio!r}")
        object.__setattr__(self, "loss_ratio", ratio)
        object.__setattr__(self, "seed", check_count("seed", self.seed, 0))

    #: flat option name -> (part, field)
    OPTIONS = {
        "problem": ("scenario", "problem"), "epoch": ("scenario", "epoch"),
        "years": ("scenario", "years"), "lookahead": ("scenario", "lookahead"),
        "area_to_mass": ("srp", "area_to_mass"), "cr": ("srp", "cr"),
        "srp_uncertainty": ("srp", "uncertainty"),
        "nav_position_sigma_km": ("navigation", "position_sigma_km"),
        "nav_velocity_sigma_mps": ("navigation", "velocity_sigma_mps"),
        "od_interval_h": ("navigation", "od_interval_h"),
        "magnitude_sigma": ("execution", "magnitude_sigma"),
        "pointing_sigma_deg": ("execution", "pointing_sigma_deg"),
        "min_burn_mps": ("execution", "min_burn_mps"),
        "skip_probability": ("execution", "skip_probability"),
        "skipped_burns": ("execution", "skipped_burns"),
        "burn_anomaly_deg": ("self", "burn_anomaly_deg"), "loss_ratio": ("self", "loss_ratio"),
        "seed": ("self", "seed"),
    }

    @classmethod
    def from_options(cls, **options: Any) -> MaintenanceSettings:
        """Settings from flat options (:data:`OPTIONS`); unknown names are an error."""
        unknown = sorted(set(options) - set(cls.OPTIONS))
        if unknown:
            raise ProblemError(f"unknown orbit-maintenance option(s) {unknown}; allowed: "
                               f"{sorted(cls.OPTIONS)}")
        parts: dict[str, dict] = {"scenario": {}, "srp": {}, "navigation": {}, "execution": {},
                                  "self": {}}
        for name, value in options.items():
            part, fld = cls.OPTIONS[name]
            parts[part][fld] = value
        srp = SolarRadiationPressure(**parts["srp"])
        return cls(scenario=ScenarioSpec(srp=srp, **parts["scenario"]),
                   navigation=NavigationErrors(**parts["navigation"]),
                   execution=ExecutionErrors(**parts["execution"]), **parts["self"])

    def to_dict(self) -> dict:
        return {"scenario": self.scenario.as_dict(), "navigation": self.navigation.as_dict(),
                "execution": self.execution.as_dict(), "burn_anomaly_deg": self.burn_anomaly_deg,
                "loss_ratio": self.loss_ratio, "seed": self.seed}

    @classmethod
    def from_dict(cls, d: dict) -> MaintenanceSettings:
        nav = {k: v for k, v in d["navigation"].items() if k != "enclosure_sigma"}
        exe = dict(d["execution"])
        exe["skipped_burns"] = tuple(exe["skipped_burns"])
        return cls(scenario=ScenarioSpec.from_dict(d["scenario"]),
                   navigation=NavigationErrors(**nav), execution=ExecutionErrors(**exe),
                   burn_anomaly_deg=d["burn_anomaly_deg"], loss_ratio=d["loss_ratio"],
                   seed=d["seed"])


def _controllers() -> dict[str, type]:
    from ocreach.control.stationkeeping.continuous import ContinuousLQR, ContinuousMPC
    from ocreach.control.stationkeeping.corridor import CorridorControl
    from ocreach.control.stationkeeping.impulsive_tube import ImpulsiveTubeMPC
    from ocreach.control.stationkeeping.target_point import TargetPointControl
    from ocreach.control.stationkeeping.xaxis import XAxisControl

    return {"xaxis": XAxisControl, "target-point": TargetPointControl,
            "tube-mpc": ImpulsiveTubeMPC, "corridor": CorridorControl, "lqr": ContinuousLQR,
            "mpc": ContinuousMPC}


#: controller names (:func:`make_controller`)
CONTROLLERS = ("xaxis", "target-point", "corridor", "tube-mpc", "lqr", "mpc")


def make_controller(name: str, options: dict | None = None):
    """The controller ``name`` (:data:`CONTROLLERS`) with its ``options`` (checked)."""
    table = _controllers()
    if name not in table:
        raise ProblemError(f"controller must be one of {list(CONTROLLERS)}; got {name!r}")
    cls = table[name]
    options = dict(options or {})
    allowed = [f.name for f in fields(cls)]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ProblemError(f"controller {name!r} has no option(s) {unknown}; allowed: {allowed}")
    return cls(**options)


# ------------------------------------------------------------------------------------------------
# one run
# ------------------------------------------------------------------------------------------------
def _rng(settings: MaintenanceSettings, run: int, stream: int, step: int) -> np.random.Generator:
    return np.random.default_rng([settings.seed, run, stream, step + 1])


def execute_thrust(u: np.ndarray, execution: ExecutionErrors,
                   rng: np.random.Generator) -> np.ndarray:
    """A continuous-thrust command ``u`` executed with the burn magnitude and pointing errors (no
    minimum and no skips), keeping ``|u| <= 1``."""
    n = float(np.linalg.norm(u))
    if n == 0.0:
        return np.zeros(3)
    free = replace(execution, min_burn_mps=0.0, skip_probability=0.0, skipped_burns=())
    out, _ = free.execute(u, -1, rng)
    m = float(np.linalg.norm(out))
    return out / m if m > 1.0 else out


def decision_steps(sc: Scenario, placement: str, settings: MaintenanceSettings) -> np.ndarray:
    """Steps at which the controller decides (and an OD fix is taken, except for continuous
    thrust, which decides every step): burn steps at the true anomaly, or every
    ``od_interval_h``."""
    if placement == "anomaly":
        return sc.anomaly_steps(settings.burn_anomaly_deg)
    n = max(1, int(round(settings.navigation.od_interval_h * 3600.0 / (sc.dt * sc.units.time))))
    return np.arange(0, sc.steps, n)


class _Track:
    """Per-step deviations and Moon distances of one run, and the loss test."""

    def __init__(self, sc: Scenario, ratio: float, corridor: np.ndarray | None = None) -> None:
        self.sc = sc
        K = sc.steps
        self.corridor = corridor
        self.corridor_ratio = np.full(K + 1, np.nan)
        self.pos = np.full(K + 1, np.nan)
        self.vel = np.full(K + 1, np.nan)
        self.dist = np.full(K + 1, np.nan)
        ref = np.linalg.norm(sc.X[:, :3] - self._moon(), axis=1)
        self.band = (float(ref.min()) / ratio, float(ref.max()) * ratio)

    def _moon(self) -> np.ndarray:
        return np.array([1.0 - self.sc.params[0], 0.0, 0.0])

    def record(self, k0: int, states: np.ndarray) -> dict | None:
        """Store the states of steps ``k0 ..``; the loss (step, reason) if one left the band."""
        sc, n = self.sc, states.shape[0]
        d = states - sc.X[k0:k0 + n]
        self.pos[k0:k0 + n] = sc.km(np.linalg.norm(d[:, :3], axis=1))
        self.vel[k0:k0 + n] = sc.mps(np.linalg.norm(d[:, 3:], axis=1))
        if self.corridor is not None and n > 1:  # the last state is the next segment's first
            h = self.corridor[k0:k0 + n - 1]
            self.corridor_ratio[k0:k0 + n - 1] = np.max(np.abs(d[:-1]) / h, axis=1)
        r = np.linalg.norm(states[:, :3] - self._moon(), axis=1)
        self.dist[k0:k0 + n] = r
        out = np.flatnonzero((r < self.band[0]) | (r > self.band[1]))
        if out.size == 0:
            return None
        k = k0 + int(out[0])
        return {"step": k, "reason": (
            f"left the NRHO: {sc.km(r[out[0]]):.0f} km from the Moon, outside "
            f"{sc.km(self.band[0]):.0f}..{sc.km(self.band[1]):.0f} km")}


def run_maintenance(settings: MaintenanceSettings, controller, run: int) -> dict[str, Any]:
    """One run of ``controller`` (module doc); returns its metrics and series (plain data)."""
    t_prep = time.process_time()
    sc = scenario(settings.scenario)
    if controller.lookahead() > settings.scenario.lookahead:
        raise ProblemError(f"controller {controller.name!r} looks {controller.lookahead()} "
                           f"revolutions ahead; the scenario's reference covers "
                           f"{settings.scenario.lookahead} after the run (raise lookahead)")
    controller.prepare(sc, settings)  # per process: shared by the runs, timed apart
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    units = sc.units
    srp_scale = 1.0 + settings.scenario.srp.uncertainty * (
        2.0 * _rng(settings, run, 2, -1).random() - 1.0)
    p = sc.params_with(srp_scale)
    x = sc.X[0] + settings.navigation.draw(_rng(settings, run, 0, -1), units)
    track = _Track(sc, settings.loss_ratio, getattr(controller, "corridor_half_widths", None))
    track.record(0, x[None])
    burns: list[dict] = []
    states_at: dict[int, np.ndarray] = {}
    loop = _run_continuous if controller.placement == "continuous" else _run_impulsive
    try:
        dv_total, dv_cmd_total, loss, k_end = loop(sc, controller, settings, run, x, p, track,
                                                   burns, states_at)
    except OcreachError as err:  # the controller or the integrator failed: a lost orbit, reported
        dv_total = sum(b["dv_mps"] for b in burns)
        dv_cmd_total = sum(b["dv_cmd_mps"] for b in burns)
        k_end = int(np.max(np.flatnonzero(np.isfinite(track.pos))))
        loss = {"step": k_end, "reason": f"{type(err).__name__}: {' '.join(str(err).split())}"}
    flown = max(k_end, 1)
    days = flown * sc.dt * units.time / 86400.0
    revs = flown / sc.M
    pos, vel = track.pos[:k_end + 1], track.vel[:k_end + 1]
    ok = np.isfinite(pos)
    executed = [b for b in burns if b["status"] == "executed"]
    n_win = int(np.ceil((k_end + 1) / DEVIATION_WINDOW))
    windows = [slice(i * DEVIATION_WINDOW, (i + 1) * DEVIATION_WINDOW) for i in range(n_win)]
    phase = _phase_at_apolunes(sc, states_at)
    if loss is not None:
        loss["days"] = loss["step"] * sc.dt * units.time / 86400.0
    return {
        "controller": controller.name, "run": int(run), "seed": settings.seed,
        "srp_scale": srp_scale, "steps": int(k_end), "days": days, "revolutions": revs,
        "dv_total_mps": dv_total, "dv_commanded_mps": dv_cmd_total,
        "dv_per_year_mps": dv_total * 365.25 / days,
        "opportunities": (None if controller.placement == "continuous" else int(np.sum(
            decision_steps(sc, controller.placement, settings) < max(k_end, 1)))),
        "burns_planned": len(burns), "burns_executed": len(executed),
        "burns_below_minimum": sum(b["status"] == "below_minimum" for b in burns),
        "burns_skipped": sum(b["status"] == "skipped" for b in burns),
        "burns_not_converged": sum(not b["targeting_converged"] for b in burns),
        "burns_per_rev": len(executed) / revs if controller.placement != "continuous" else None,
        "max_position_deviation_km": float(np.max(pos[ok])),
        "rms_position_deviation_km": float(np.sqrt(np.mean(pos[ok] ** 2))),
        "max_velocity_deviation_mps": float(np.max(vel[ok])),
        "final_position_deviation_km": float(pos[-1]) if np.isfinite(pos[-1]) else None,
        "max_phase_offset_min": phase["max_phase_offset_min"],
        "final_phase_offset_min": phase["final_phase_offset_min"],
        "max_path_deviation_km": phase["max_path_deviation_km"],
        "lost": loss is not None, "loss": loss,
        **_corridor_metrics(track, k_end),
        "deviation_window_steps": DEVIATION_WINDOW,
        "deviation_km": [float(np.nanmax(pos[w])) for w in windows],
        "deviation_mps": [float(np.nanmax(vel[w])) for w in windows],
        "apolune_phase_offset_min": phase["offsets_min"], "burns": burns,
        "cpu_s": time.process_time() - t_cpu, "wall_s": time.perf_counter() - t_wall,
        "prepare_cpu_s": t_cpu - t_prep,
    }


def _corridor_metrics(track: _Track, k_end: int) -> dict[str, Any]:
    """For a controller with a corridor (``corridor_half_widths``): the largest ratio of the
    true deviation to the corridor over the run and the steps outside it (ratio > 1)."""
    if track.corridor is None:
        return {}
    r = track.corridor_ratio[:k_end]
    r = r[np.isfinite(r)]
    return {"corridor_max_ratio": float(r.max()) if r.size else None,
            "corridor_exit_steps": int(np.sum(r > 1.0))}


def _phase_at_apolunes(sc: Scenario, states_at: dict[int, np.ndarray]) -> dict[str, Any]:
    """Phase offset (minutes, ``d . v_ref / |v_ref|^2``) and the deviation from the orbit's path
    (km, ``|d - v_ref dt|``) at the apolune steps the run passed (module doc)."""
    offsets, path = [], []
    for k in sorted(states_at):
        d = states_at[k] - sc.X[k]
        v = np.asarray(sc.model.f_fun(sc.X[k], np.zeros(3), sc.times[k], sc.params)).ravel()[:3]
        dt = float(d[:3] @ v / (v @ v))
        offsets.append(dt * sc.units.time / 60.0)
        path.append(float(sc.km(np.linalg.norm(d[:3] - v * dt))))
    return {"offsets_min": offsets,
            "max_phase_offset_min": float(np.max(np.abs(offsets))) if offsets else None,
            "final_phase_offset_min": offsets[-1] if offsets else None,
            "max_path_deviation_km": float(np.max(path)) if path else None}


def _run_impulsive(sc: Scenario, ctl, settings: MaintenanceSettings, run: int, x: np.ndarray,
                   p: np.ndarray, track: _Track, burns: list,
                   states_at: dict) -> tuple[float, float, dict | None, int]:
    nav, exe, units = settings.navigation, settings.execution, sc.units
    K = sc.steps
    decisions = decision_steps(sc, ctl.placement, settings)
    apolunes = sc.anomaly_steps(180.0)
    bounds = sorted(set(decisions) | set(apolunes) | {0, K})
    decisions = set(int(k) for k in decisions)
    apolunes = set(int(k) for k in apolunes)
    dv_total = dv_cmd_total = 0.0
    nu = sc.true_anomaly_deg
    for k, k_next in itertools.pairwise(bounds):
        if k in apolunes:
            states_at[k] = x.copy()
        if k in decisions:
            xhat = x + nav.draw(_rng(settings, run, 0, k), units)
            trigger = getattr(ctl, "triggered", None)
            if trigger is None or trigger(sc, k, xhat):
                dv_cmd = sc.mps(ctl.burn(sc, k, xhat))
                dv, status = exe.execute(dv_cmd, len(burns), _rng(settings, run, 1, k))
                x = x.copy()
                x[3:] += dv / units.velocity
                dv_total += float(np.linalg.norm(dv))
                dv_cmd_total += float(np.linalg.norm(dv_cmd))
                burns.append({"step": int(k), "days": k * sc.dt * units.time / 86400.0,
                              "anomaly_deg": float(nu[k]),
                              "dv_cmd_mps": float(np.linalg.norm(dv_cmd)),
                              "dv_mps": float(np.linalg.norm(dv)), "status": status,
                              "targeting_converged": getattr(ctl, "last_converged", True),
                              **getattr(ctl, "last_info", {})})
        X = sc.propagate(x, k, k_next, p)
        loss = track.record(k, X)
        if loss is not None:
            return dv_total, dv_cmd_total, loss, loss["step"]
        x = X[-1]
    return dv_total, dv_cmd_total, None, K


def _run_continuous(sc: Scenario, ctl, settings: MaintenanceSettings, run: int, x: np.ndarray,
                    p: np.ndarray, track: _Track, burns: list,
                    states_at: dict) -> tuple[float, float, dict | None, int]:
    nav, exe, units = settings.navigation, settings.execution, sc.units
    K = sc.steps
    A, B = sc.jacobians
    fixes = set(int(k) for k in decision_steps(sc, "continuous", settings))
    apolunes = set(int(k) for k in sc.anomaly_steps(180.0))
    a_max = float(sc.params[list(sc.model.param_names).index("a_max")])
    dv_step = a_max * sc.dt * units.velocity  # m/s of one step at full thrust
    e = np.zeros(6)
    dv_total = dv_cmd_total = 0.0
    for k in range(K):
        if k in apolunes:
            states_at[k] = x.copy()
        if k in fixes:
            e = nav.draw(_rng(settings, run, 0, k), units)
        u_cmd = np.asarray(ctl.control(sc, k, x + e), float)
        u = execute_thrust(u_cmd, exe, _rng(settings, run, 1, k))
        X = sc.propagate(x, k, k + 1, p, u[None])
        e = A[k] @ e + B[k] @ (u_cmd - u)
        dv_total += float(np.linalg.norm(u)) * dv_step
        dv_cmd_total += float(np.linalg.norm(u_cmd)) * dv_step
        loss = track.record(k, X)
        if loss is not None:
            return dv_total, dv_cmd_total, loss, loss["step"]
        x = X[-1]
    return dv_total, dv_cmd_total, None, K


__all__ = ["CONTROLLERS", "DEFAULT_LOSS_RATIO", "MaintenanceSettings", "PLACEMENTS",
           "check_anomaly", "decision_steps", "execute_thrust", "make_controller",
           "run_maintenance"]
