"""A reachable-set controller on the orbit-maintenance loop: event-triggered tube MPC (Patel &
Subbarao, "Station-keeping in the near rectilinear halo orbit", the controller of
:mod:`ocreach.control.stationkeeping.event_mpc`) with impulsive execution, its trigger fed the OD estimate and
its tubes enclosing the navigation error.

**Tubes.**  Zero-thrust drift tubes along the DE421 + SRP reference
(:func:`~ocreach.control.stationkeeping.ephemeris_tubes.along_reference_schedule`): restarted at step 0, at every
apolune and wherever the sound method stops, each from the initial box ``G = gate (+)
nav``: the ``k``-sigma box of the navigation ellipsoid plus an optional gate (default none: the
tube of the navigation error alone; ``None`` gives Patel & Subbarao's initial deviation set,
``G_pos = 1e-4`` DU = 38 km, ``G_vel = 5e-4`` DU/TU = 0.51 m/s per axis, the tubes of the
existing event-triggered MPC, which measured an order of magnitude dearer here:
docs/validation/orbit-maintenance.md; the navigation box is
:meth:`~ocreach.control.stationkeeping.navigation.NavigationErrors.box`), under the disturbance
box ``W`` = the largest SRP dispersion (:meth:`~ocreach.control.stationkeeping.srp.
SolarRadiationPressure.dispersion_bound`, the part of SRP no controller knows).  Source
``"taylor-or-linear"``: guaranteed ``taylor`` tubes on the plant's windowed frame model (with the
window error added to ``W``; a window across a blend of two DE421 fit pieces included), the
linearised tube (labelled, not guaranteed) where ``taylor`` cannot enclose an interval (it
fails, or the window's error bound cannot be computed there).  Membership by the interval
hull (the paper's Fig. 7 boxes).  Computed once per scenario and cached on disk
(``$OCREACH_CACHE_DIR/orbit_maintenance``), shared by every run.

**Trigger** (at every OD fix, ``od_interval_h``): with ``h_k`` the tube's half-widths at step
``k`` and ``n`` the navigation box, the estimate's gauge

    gamma_k = max_i |xhat_i - x_ref,i(k)| / (h_k,i + n_i)

(``gamma > 1`` means the *true* state has left the drift tube, whatever the OD error in its
box), and, as the existing controller's anticipating trigger, the predicted gauge at the next
refresh ``r``: ``max_i |(Phi(r, k) dxhat)_i| / (g_i + (|Phi(r, k)| n)_i)``, ``g`` the fresh tube's
first box.  A burn when either exceeds 1.

**Burn** (impulsive MPC, Eq. 27 with one impulse and a fuel objective): ``dv`` minimising
``|dv| + rho sum_j s_j`` subject to the predicted deviations over ``horizon_revolutions``
staying in the ``beta``-shrunk tubes, robustly over the navigation error:

    |(Phi(j, k) (dxhat + [0; dv]))_i| <= beta h_j,i - (|Phi(j, k)| n)_i + s_j h_j,i,   s_j >= 0,

at every ``check_every``-th step ``j`` and at every refresh within the horizon (the slacks keep
it feasible from outside; ``Phi`` the exact reference STMs).  A second-order cone program
(cvxpy, Clarabel), parameterised once per process.
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import shutil
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ocreach.control.stationkeeping.scenario import Scenario
from ocreach.control.stationkeeping.srp import check_nonnegative
from ocreach.errors import ProblemError, SolverError, check_count, check_positive

log = logging.getLogger("ocreach.control.stationkeeping.impulsive_tube")

#: Patel & Subbarao's initial deviation set (DU, DU/TU per axis): the default gate.
PAPER_GATE = (1e-4, 5e-4)
TUBE_SOURCES = ("taylor-or-linear", "linear")
_CACHE_VERSION = 2  # 2: tubes across DE421 fit-piece blends are guaranteed (one window polynomial)


@dataclass
class ImpulsiveTubeMPC:
    """Event-triggered impulsive tube MPC (module doc).  ``gate_position_km`` /
    ``gate_velocity_mps``: the gate box per axis added to the navigation box (default 0: the
    tubes start from the navigation box alone; None: the paper's 38.44 km / 0.513 m/s);
    ``beta`` the shrunk tube the plan aims for; ``horizon_revolutions``; ``check_every`` steps;
    ``slack_penalty`` rho; ``tube_source``; ``anticipate`` (the predicted-gauge trigger)."""

    gate_position_km: float | None = 0.0
    gate_velocity_mps: float | None = 0.0
    beta: float = 0.7
    horizon_revolutions: float = 2.0
    check_every: int = 2
    slack_penalty: float = 100.0
    tube_source: str = "taylor-or-linear"
    anticipate: bool = True
    name = "tube-mpc"
    placement = "gauge"

    def __post_init__(self) -> None:
        if not (isinstance(self.beta, (int, float)) and 0 < self.beta <= 1):
            raise ProblemError(f"beta (shrunk tube of the plan) must be in (0, 1]; got "
                               f"{self.beta!r}")
        self.horizon_revolutions = check_positive("horizon_revolutions", self.horizon_revolutions)
        self.check_every = check_count("check_every", self.check_every, 1)
        self.slack_penalty = check_positive("slack_penalty", self.slack_penalty)
        for nm in ("gate_position_km", "gate_velocity_mps"):
            if getattr(self, nm) is not None:
                setattr(self, nm, check_nonnegative(nm, getattr(self, nm)))
        if self.tube_source not in TUBE_SOURCES:
            raise ProblemError(f"tube_source must be one of {list(TUBE_SOURCES)}; got "
                               f"{self.tube_source!r}")
        if not isinstance(self.anticipate, (bool, np.bool_)):
            raise ProblemError(f"anticipate must be True or False; got {self.anticipate!r}")

    def lookahead(self) -> int:
        return int(np.ceil(self.horizon_revolutions)) + 1

    # ------------------------------------------------------------------ setup
    def build_tubes(self, sc: Scenario, settings, executor: Executor | None = None,
                    progress: bool = False) -> dict:
        """The drift tubes of this controller on ``sc`` (:func:`drift_tubes`: from the disk
        cache, or computed, their refresh intervals on ``executor`` when given); kept on the
        scenario for :meth:`prepare`."""
        nav = settings.navigation.box(sc.units)
        gp = (PAPER_GATE[0] if self.gate_position_km is None
              else self.gate_position_km * 1e3 / sc.units.length)
        gv = (PAPER_GATE[1] if self.gate_velocity_mps is None
              else self.gate_velocity_mps / sc.units.velocity)
        gate = np.r_[np.full(3, gp), np.full(3, gv)]
        # the tubes cover the whole reference (the run and its look-ahead): one set of tubes
        # (and one disk-cache entry) for every horizon
        return drift_tubes(sc, gate + nav, settings, self.tube_source, sc.X.shape[0] - 1,
                           executor=executor, progress=progress)

    def prepare(self, sc: Scenario, settings) -> None:
        self._nav = settings.navigation.box(sc.units)
        self._N = int(round(self.horizon_revolutions * sc.M))
        self._tubes = self.build_tubes(sc, settings)
        self._A = sc.jacobians[0]
        self._solver = None

    # ------------------------------------------------------------------ trigger
    def _phi(self, k: int, j: int) -> np.ndarray:
        P = np.eye(6)
        for i in range(k, j):
            P = self._A[i] @ P
        return P

    def gauges(self, sc: Scenario, k: int, xhat: np.ndarray) -> tuple[float, float]:
        """The estimate's gauge at step ``k`` and the predicted gauge at the next refresh."""
        h, starts = self._tubes["half_widths"], self._tubes["starts"]
        d = np.asarray(xhat, float) - sc.X[k]
        g_now = float(np.max(np.abs(d) / (h[k] + self._nav)))
        if not self.anticipate:
            return g_now, 0.0
        later = starts[starts > k]
        if later.size == 0:
            return g_now, 0.0
        r = int(later[0])
        P = self._phi(k, r)
        g_next = float(np.max(np.abs(P @ d) / (h[r] + np.abs(P) @ self._nav)))
        return g_now, g_next

    def triggered(self, sc: Scenario, k: int, xhat: np.ndarray) -> bool:
        return max(self.gauges(sc, k, xhat)) > 1.0

    # ------------------------------------------------------------------ burn
    def _checks(self, k: int) -> np.ndarray:
        starts = self._tubes["starts"]
        end = self._tubes["half_widths"].shape[0] - 1
        last = min(k + self._N, end)
        js = set(range(k + self.check_every, last + 1, self.check_every))
        js |= {int(s) for s in starts if k < s <= last}
        js.add(last)
        return np.array(sorted(js), int)

    def _problem(self, n_checks: int):
        import cvxpy as cp

        # every row divided by its tube half-width h_j,i: the entries are O(1) (the raw rows
        # span 1e-9 .. 1 in model units and Clarabel stalled at its iteration limit)
        dv = cp.Variable(3)
        s = cp.Variable(n_checks, nonneg=True)
        M = cp.Parameter((6 * n_checks, 3))   # Phi(j, k) [0; I] / h, stacked
        b = cp.Parameter(6 * n_checks)        # Phi(j, k) dxhat / h
        c = cp.Parameter(6 * n_checks)        # (beta h_j - |Phi| n) / h
        E = np.kron(np.eye(n_checks), np.ones((6, 1)))
        cons = [cp.abs(M @ dv + b) <= c + E @ s]
        prob = cp.Problem(cp.Minimize(cp.norm(dv, 2) + self.slack_penalty * cp.sum(s)), cons)
        return prob, dv, s, M, b, c

    def burn(self, sc: Scenario, k: int, xhat: np.ndarray) -> np.ndarray:
        """Commanded burn (model units, (3,)) from the estimate at step ``k``."""
        js = self._checks(k)
        n = js.size
        if self._solver is None or self._solver[0] != n:
            self._solver = (n, self._problem(n))
        prob, dv, _, M, b, c = self._solver[1]
        h = self._tubes["half_widths"][js]
        d = np.asarray(xhat, float) - sc.X[k]
        P = np.empty((n, 6, 6))
        Pk = np.eye(6)
        i = k
        for m, j in enumerate(js):  # cumulative STM products Phi(j, k)
            for q in range(i, j):
                Pk = self._A[q] @ Pk
            i = j
            P[m] = Pk
        # the velocity scale: dv in units of 1 cm/s keeps the SOCP well conditioned
        scale = 0.01 / sc.units.velocity
        M.value = (P[:, :, 3:] * scale / h[:, :, None]).reshape(-1, 3)
        b.value = (P @ d / h).ravel()
        c.value = ((self.beta * h - np.abs(P) @ self._nav) / h).ravel()
        try:
            prob.solve(solver="CLARABEL", max_iter=400)
        except Exception as exc:  # noqa: BLE001 - cvxpy raises SolverError subclasses
            raise SolverError(f"impulsive tube MPC at step {k}: the SOCP failed: {exc}") from exc
        self.last_status = prob.status
        # an iteration limit with a finite iterate is burnt (recorded); nothing to burn is an error
        if dv.value is None or not np.all(np.isfinite(dv.value)) or prob.status not in (
                "optimal", "optimal_inaccurate", "user_limit"):
            raise SolverError(f"impulsive tube MPC at step {k}: the SOCP returned {prob.status}")
        self.last_converged = prob.status == "optimal"
        return np.asarray(dv.value, float) * scale

    def describe(self) -> dict:
        return {"controller": self.name, "placement": self.placement, "beta": self.beta,
                "gate_position_km": self.gate_position_km,
                "gate_velocity_mps": self.gate_velocity_mps,
                "horizon_revolutions": self.horizon_revolutions, "check_every": self.check_every,
                "slack_penalty": self.slack_penalty, "tube_source": self.tube_source,
                "anticipate": self.anticipate,
                "tubes": getattr(self, "_tubes", {}).get("log"),
                "method": "event-triggered tube MPC (Patel & Subbarao) with impulsive execution: "
                          "trigger on the estimate's gauge in the drift tube + navigation box, "
                          "SOCP for one impulse keeping the robust predictions in the beta tube"}


# ------------------------------------------------------------------------------------------------
# tubes
# ------------------------------------------------------------------------------------------------
def srp_disturbance(sc: Scenario) -> float:
    """The SRP dispersion bound in model units (a box on the velocity rates): ``uncertainty``
    times the SRP acceleration at the smallest Sun distance over the reference (sampled daily,
    less 1e6 km: the spacecraft is within 1e5 km of the Moon and the Sun distance changes by
    less than 3e5 km a day)."""
    srp = sc.spec.srp
    if srp.uncertainty == 0 or srp.area_to_mass == 0:
        return 0.0
    days = np.arange(0.0, sc.times[-1] * sc.units.time / 86400.0 + 1.0)
    r = sc.plant.ephemeris.position("sun", days * 86400.0, "moon")
    d_min = float(np.min(np.linalg.norm(r, axis=1))) - 1e6
    return srp.dispersion_bound(d_min) / sc.units.acceleration


def _tube_key(sc: Scenario, G: np.ndarray, W: float, source: str, end: int) -> str:
    payload = json.dumps({"v": _CACHE_VERSION, "scenario": sc.spec.key(),
                          "G": np.asarray(G).tolist(), "W": W, "source": source, "end": end,
                          "defect": float(sc.orbit.max_defect)}, sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()[:24]


def drift_tubes(sc: Scenario, G: np.ndarray, settings, source: str, end: int,
                executor: Executor | None = None, progress: bool = False) -> dict:
    """Box drift tubes along the scenario's reference from the initial box ``G`` (half-widths,
    model units) for steps ``0 .. end - 1`` (module doc): ``{"half_widths" (end, 6), "starts"
    (refresh steps), "log" (per interval: steps, source, guaranteed, fallback reason)}``, from
    the disk cache when it has them.  Otherwise the refresh intervals (independent of each
    other) are computed on ``executor`` (workers rebuild the scenario from
    ``settings.scenario``, its reference from the disk cache), or here one after the other when
    it is None; ``progress`` shows a bar over the intervals.  Each finished interval is kept
    beside the cache file until the whole is written, so an interrupted first run resumes where
    it stopped."""
    from ocreach.native.compile import cache_dir

    key = ("drift_tubes", tuple(np.round(G, 18)), source, end)
    if key in sc.cache:
        return sc.cache[key]
    W = srp_disturbance(sc)
    path = cache_dir("orbit_maintenance") / f"tubes_{_tube_key(sc, G, W, source, end)}.npz"
    out = None
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {"half_widths": np.asarray(z["half_widths"]), "starts": np.asarray(z["starts"]),
                   "log": json.loads(str(z["log"]))}
        if out["half_widths"].shape != (end, 6):
            out = None
    except (OSError, ValueError, KeyError):
        out = None
    if out is None:
        parts_dir = path.with_suffix(".parts")
        out = _compute_tubes(sc, G, W, source, end, settings, executor, progress, parts_dir)
        from ocreach.fileio import atomic_write_bytes

        buf = io.BytesIO()
        np.savez(buf, half_widths=out["half_widths"], starts=out["starts"],
                 log=json.dumps(out["log"]))
        try:
            atomic_write_bytes(path, buf.getvalue())
            shutil.rmtree(parts_dir, ignore_errors=True)  # kept in the whole file now
        except OSError as exc:
            log.warning("could not cache the drift tubes in %s: %s", path.parent, exc)
    sc.cache[key] = out
    return out


def interval_rows(sc: Scenario, G: np.ndarray, W: float, source: str, a: int,
                  b: int) -> list[dict]:
    """The box tubes covering the refresh interval ``a .. b - 1`` (restarted where the sound
    method stops, :func:`~ocreach.control.stationkeeping.ephemeris_tubes.interval_tubes`), as
    rows ``{"steps": [k0, k1], "half_widths" (k1 - k0, 6), "source", "guaranteed",
    "fallback_reason"}`` in step order."""
    from ocreach.control.stationkeeping.drift_tubes import ADAPTIVE_TUBE_OPTIONS, as_box
    from ocreach.control.stationkeeping.ephemeris_tubes import interval_tubes

    tubes = sorted((as_box(t) for t in interval_tubes(
        sc.problem, sc.reference, a, b, np.diag(G), W, source, dict(ADAPTIVE_TUBE_OPTIONS),
        sc.plant.frame_model_on)), key=lambda t: t.k0)
    ends = [t.k0 for t in tubes[1:]] + [b]
    return [{"steps": [int(t.k0), int(k1)], "half_widths": t.half_widths()[: k1 - t.k0],
             "source": t.source, "guaranteed": bool(t.guaranteed),
             "fallback_reason": (t.meta or {}).get("fallback_reason")}
            for t, k1 in zip(tubes, ends, strict=True)]


def interval_rows_task(spec: dict, G: np.ndarray, W: float, source: str, a: int,
                       b: int) -> list[dict]:
    """Worker entry point of :func:`interval_rows`: the scenario of the plain ``spec``
    (:meth:`~ocreach.control.stationkeeping.scenario.ScenarioSpec.as_dict`), built once per
    process."""
    from ocreach.control.stationkeeping.scenario import ScenarioSpec, scenario
    from ocreach.sweep.worker import _TASK_LOCK, limit_threads

    limit_threads()
    with _TASK_LOCK:
        sc = scenario(ScenarioSpec.from_dict(spec))
        return interval_rows(sc, G, W, source, a, b)


def _compute_tubes(sc: Scenario, G: np.ndarray, W: float, source: str, end: int, settings,
                   executor: Executor | None, progress: bool,
                   parts_dir: Path | None = None) -> dict:
    """The refresh intervals' rows (:func:`drift_tubes`), each kept in ``parts_dir`` as soon as
    it is computed and read from there on the next call, so an interrupted first run keeps the
    intervals it finished."""
    from concurrent.futures import as_completed

    from tqdm import tqdm

    from ocreach.control.stationkeeping.ephemeris_tubes import refresh_starts

    starts = refresh_starts(sc.reference, end)
    intervals = list(zip(starts, starts[1:] + [end], strict=True))
    parts = {ab: _read_interval(parts_dir, ab) for ab in intervals}
    todo = [ab for ab in intervals if parts[ab] is None]
    bar = tqdm(total=len(intervals), initial=len(intervals) - len(todo), unit="interval",
               desc="drift tubes", disable=not progress, dynamic_ncols=True)

    def done(ab: tuple[int, int], rows: list[dict]) -> None:
        parts[ab] = rows
        _write_interval(parts_dir, ab, rows)
        bar.update()

    try:
        if executor is None:
            for a, b in todo:
                done((a, b), interval_rows(sc, G, W, source, a, b))
        else:
            plain = settings.scenario.as_dict()
            futures = {executor.submit(interval_rows_task, plain, G, W, source, a, b): (a, b)
                       for a, b in todo}
            for f in as_completed(futures):  # the first error raises; the finished are kept
                done(futures[f], f.result())
    finally:
        bar.close()
    parts = [parts[ab] for ab in intervals]
    h = np.full((end, 6), np.nan)
    log_rows = []
    for row in (r for part in parts for r in part):
        k0, k1 = row["steps"]
        h[k0:k1] = row.pop("half_widths")
        log_rows.append(row)
    if not np.all(np.isfinite(h)):
        raise SolverError(f"the drift tubes leave steps {np.flatnonzero(~np.isfinite(h[:, 0]))[:5]}"
                          f"... uncovered or not finite")
    return {"half_widths": h, "starts": np.asarray([r["steps"][0] for r in log_rows], int),
            "log": log_rows}


def _interval_file(parts_dir: Path, ab: tuple[int, int]) -> Path:
    return parts_dir / f"interval_{ab[0]}_{ab[1]}.json"


def _read_interval(parts_dir: Path | None, ab: tuple[int, int]) -> list[dict] | None:
    """The rows of interval ``ab`` kept by an earlier call, or None (none kept, or unreadable)."""
    if parts_dir is None:
        return None
    try:
        rows = json.loads(_interval_file(parts_dir, ab).read_text())
        for r in rows:
            r["half_widths"] = np.asarray(r["half_widths"], dtype=float).reshape(-1, 6)
            k0, k1 = r["steps"]
            if r["half_widths"].shape[0] != k1 - k0:
                return None
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return rows


def _write_interval(parts_dir: Path | None, ab: tuple[int, int], rows: list[dict]) -> None:
    """Keep the rows of interval ``ab`` (plain JSON; the floats round-trip exactly)."""
    if parts_dir is None:
        return
    from ocreach.fileio import atomic_write_text

    plain = [{**r, "half_widths": np.asarray(r["half_widths"]).tolist()} for r in rows]
    try:
        parts_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(_interval_file(parts_dir, ab), json.dumps(plain))
    except OSError as exc:
        log.warning("could not keep the drift tubes of steps %s in %s: %s", ab, parts_dir, exc)


__all__ = ["ImpulsiveTubeMPC", "PAPER_GATE", "TUBE_SOURCES", "drift_tubes", "srp_disturbance"]
