"""Monte Carlo of the orbit-maintenance loop on the sweep executors (a process pool by default,
Dask for clusters; :mod:`ocreach.sweep.executors`), resumable from its store.

Each task is one run of one controller: plain data (the settings' :meth:`~ocreach.control.
stationkeeping.orbit_maintenance.MaintenanceSettings.to_dict`, the controller name and options,
the run index), keyed by :func:`ocreach.sweep.keys.task_key`.  Workers build the scenario once
per process (:func:`~ocreach.control.stationkeeping.scenario.scenario`: the corrected reference
and the drift tubes come from the disk cache the driver filled, :func:`prepare`; on a first
run the tubes' refresh intervals are computed on the same executor, one task each), run the task
(:func:`~ocreach.control.stationkeeping.orbit_maintenance.run_maintenance`) and return its record;
the driver alone writes the store (:class:`ocreach.sweep.store.Store`: ``sweep.json`` and one
line per finished run in ``tasks.jsonl``).  An interrupted Monte Carlo (Ctrl-C, a killed driver)
keeps every finished run; the same call with the same store runs only the rest.

:func:`summarize` gives per controller: Delta-V per year (mean, 95th percentile, max), burns per
revolution, the maximum deviation from the reference, and the lost orbits.
"""
from __future__ import annotations

import os
import socket
import time
import traceback
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ocreach.control.stationkeeping.orbit_maintenance import (
    MaintenanceSettings,
    make_controller,
    run_maintenance,
)
from ocreach.control.stationkeeping.scenario import scenario
from ocreach.errors import ProblemError, check_count
from ocreach.sweep.executors import make_executor
from ocreach.sweep.run import sigterm_as_interrupt

TASK_KIND = "orbit-maintenance"


def task_spec(settings: MaintenanceSettings, controllers: dict[str, dict], runs: int):
    """The sweep :class:`~ocreach.sweep.spec.Spec` of ``runs`` runs of every controller."""
    from ocreach.sweep.spec import Spec

    runs = check_count("runs (Monte Carlo runs per controller)", runs, 1)
    if not controllers:
        raise ProblemError("controllers must name at least one controller")
    plain = settings.to_dict()
    # run by run (every controller's run i before run i + 1): an interrupted Monte Carlo keeps
    # comparable runs of every controller, on the same draws
    tasks = [{"kind": TASK_KIND, "settings": plain, "controller": name,
              "options": dict(opts), "run": i}
             for i in range(runs) for name, opts in controllers.items()]
    raw = {"name": f"orbit maintenance {settings.scenario.problem}",
           "description": f"{runs} runs x {list(controllers)}", "settings": plain,
           "controllers": controllers, "runs": runs}
    return Spec(tasks=tasks, raw=raw, base_dir=str(Path.cwd()), name=raw["name"])


#: controllers of this process, by (name, options): their per-process preparation is kept
_CONTROLLERS: dict[str, Any] = {}


def _controller(name: str, options: dict):
    key = repr((name, sorted(options.items())))
    if key not in _CONTROLLERS:
        _CONTROLLERS[key] = make_controller(name, options)
    return _CONTROLLERS[key]


def run_tasks(payloads: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Worker entry point (:func:`ocreach.sweep.run.run_sweep` ``runner``): one record per
    payload; a failing task becomes an ``"error"`` record, the Monte Carlo goes on."""
    from ocreach.sweep.worker import _TASK_LOCK, limit_threads

    limit_threads()
    out = []
    for payload in payloads:
        with _TASK_LOCK:
            t0 = time.perf_counter()
            task = payload["task"]
            rec: dict[str, Any] = {"key": payload["key"],
                                   "worker": f"{socket.gethostname()}:{os.getpid()}"}
            try:
                settings = MaintenanceSettings.from_dict(task["settings"])
                ctl = _controller(task["controller"], task["options"])
                rec["outputs"] = run_maintenance(settings, ctl, task["run"])
                rec["status"] = "ok"
            except Exception as exc:  # noqa: BLE001 - recorded, the Monte Carlo goes on
                rec["status"] = "error"
                rec["error"] = {"type": type(exc).__name__, "message": str(exc),
                                "traceback": "".join(traceback.format_exc(limit=-4))[-4000:]}
            rec["runtime_s"] = time.perf_counter() - t0
            out.append(rec)
    return out


def prepare(settings: MaintenanceSettings, controllers: dict[str, dict],
            executor: Executor | None = None, progress: bool = False) -> dict[str, float]:
    """Build, in the driver, what the workers then read from the disk caches (the corrected
    reference, the drift tubes: their refresh intervals on ``executor`` when given) and check
    every controller's options and look-ahead; returns the seconds (wall) each part took."""
    t = time.perf_counter()
    sc = scenario(settings.scenario)
    out = {"scenario_s": time.perf_counter() - t}
    for name, opts in controllers.items():
        ctl = make_controller(name, opts)
        if ctl.lookahead() > settings.scenario.lookahead:
            raise ProblemError(f"controller {name!r} looks {ctl.lookahead()} revolutions ahead; "
                               f"lookahead = {settings.scenario.lookahead} (raise it)")
        t = time.perf_counter()
        if hasattr(ctl, "build_tubes"):  # the long part of a first run: on the workers
            ctl.build_tubes(sc, settings, executor=executor, progress=progress)
        ctl.prepare(sc, settings)
        out[f"prepare_{name}_s"] = time.perf_counter() - t
    return out


@dataclass
class MonteCarlo:
    """Records of a Monte Carlo (per controller, by run index), its summary and timing."""

    records: dict[str, list[dict]]
    failures: list[dict]
    summary: dict[str, dict]
    timing: dict[str, Any] = field(default_factory=dict)
    store: str = ""


def run_monte_carlo(settings: MaintenanceSettings, controllers: dict[str, dict], runs: int,
                    store: str | Path, *, workers: int | None = None,
                    dask_local: int | None = None, scheduler: str | None = None,
                    serial: bool = False, progress: bool = True,
                    on_record=None) -> MonteCarlo:
    """``runs`` runs of every controller (module doc) into the sweep folder ``store`` (created,
    or resumed: finished runs are not run again).  Executor options as
    :func:`ocreach.sweep.run.run_sweep`."""
    from ocreach.sweep.run import run_sweep
    from ocreach.sweep.store import LOG, Store, read_log

    spec = task_spec(settings, controllers, runs)
    Store.check(store, spec)  # a foreign folder fails before any work
    t0, c0 = time.perf_counter(), time.process_time()
    # one executor for the tubes of a first run and for the runs
    handle = make_executor(workers, scheduler=scheduler, dask_local_workers=dask_local,
                           serial=serial)
    try:
        with sigterm_as_interrupt():
            timing: dict[str, Any] = {"prepare": prepare(
                settings, controllers, executor=None if serial else handle.executor,
                progress=progress)}
        t1 = time.perf_counter()
        summary = run_sweep(spec, store, executor=handle, progress=progress,
                            on_record=on_record, runner=run_tasks, desc="orbit maintenance")
    except KeyboardInterrupt:
        handle.interrupted = True
        raise
    finally:
        handle.close()
    t2 = time.perf_counter()
    log = read_log(Path(store) / LOG)
    by_key = dict(zip(spec.keys, spec.tasks, strict=True))
    records: dict[str, list[dict]] = {name: [] for name in controllers}
    failures = []
    for key, rec in log.records.items():
        task = by_key.get(key)
        if task is None:
            continue
        if rec["status"] == "ok":
            records[task["controller"]].append(rec["outputs"])
        else:
            failures.append({"controller": task["controller"], "run": task["run"],
                             "error": rec.get("error")})
    for rs in records.values():
        rs.sort(key=lambda r: r["run"])
    cpu_runs = sum(r["cpu_s"] + r.get("prepare_cpu_s", 0.0) for rs in records.values()
                   for r in rs)
    timing.update({"driver_prepare_wall_s": t1 - t0, "monte_carlo_wall_s": t2 - t1,
                   "total_wall_s": t2 - t0, "driver_cpu_s": time.process_time() - c0,
                   "runs_cpu_s": cpu_runs, "executor": summary.executor,
                   "ran_now": summary.ran, "already_finished": summary.skipped})
    return MonteCarlo(records, failures, summarize(records), timing, str(store))


def _stats(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"mean": None, "p95": None, "max": None, "min": None}
    a = np.asarray(values, float)
    return {"mean": float(a.mean()), "p95": float(np.percentile(a, 95)),
            "max": float(a.max()), "min": float(a.min())}


def summarize(records: dict[str, list[dict]]) -> dict[str, dict]:
    """Per controller: runs, lost orbits (count and share), Delta-V per year over the runs that
    kept the orbit (mean / p95 / max / min, m/s), burns per revolution (executed; planned,
    below the minimum, skipped and not converged in total), the maximum position deviation
    (km; per-run max: mean / p95 / max), the phase offset and the deviation from the orbit's
    path at apolune, the CPU time per run and per revolution (the per-process preparation,
    the reference's STMs, tensors or tubes, excluded; it is in ``runs_cpu_s`` of the timing),
    the burn opportunities, and for a controller with a corridor the largest ratio of the true
    deviation to it (per run: mean / p95 / max), the steps outside it and the burns whose plan
    could not keep the sets in it."""
    out = {}
    for name, rs in records.items():
        kept = [r for r in rs if not r["lost"]]
        bpr = [r["burns_per_rev"] for r in kept if r["burns_per_rev"] is not None]
        revs = sum(r["revolutions"] for r in rs)
        out[name] = {
            "runs": len(rs), "lost": sum(r["lost"] for r in rs),
            "lost_share": (sum(r["lost"] for r in rs) / len(rs)) if rs else None,
            "delta_v_per_year_mps": _stats([r["dv_per_year_mps"] for r in kept]),
            "burns_per_rev": _stats(bpr) if bpr else None,
            "burns_planned": sum(r["burns_planned"] for r in rs),
            "burns_executed": sum(r["burns_executed"] for r in rs),
            "burns_below_minimum": sum(r["burns_below_minimum"] for r in rs),
            "burns_skipped": sum(r["burns_skipped"] for r in rs),
            "burns_not_converged": sum(r["burns_not_converged"] for r in rs),
            "max_phase_offset_min": _stats([r["max_phase_offset_min"] for r in rs
                                            if r["max_phase_offset_min"] is not None]),
            "max_path_deviation_km": _stats([r["max_path_deviation_km"] for r in rs
                                             if r["max_path_deviation_km"] is not None]),
            "max_deviation_km": _stats([r["max_position_deviation_km"] for r in rs]),
            "max_deviation_mps": _stats([r["max_velocity_deviation_mps"] for r in rs]),
            "revolutions_per_run": _stats([r["revolutions"] for r in rs]),
            "cpu_s_per_run": _stats([r["cpu_s"] for r in rs]),
            "cpu_ms_per_revolution": (1e3 * sum(r["cpu_s"] for r in rs) / revs) if revs else None,
            "loss_reasons": sorted({r["loss"]["reason"] for r in rs if r["lost"]}),
            "opportunities": (sum(r["opportunities"] for r in rs)
                              if all(r.get("opportunities") is not None for r in rs) else None),
        }
        if rs and all("corridor_max_ratio" in r for r in rs):  # a controller with a corridor
            out[name]["corridor_max_ratio"] = _stats([r["corridor_max_ratio"] for r in rs
                                                      if r["corridor_max_ratio"] is not None])
            out[name]["corridor_exit_steps"] = sum(r["corridor_exit_steps"] for r in rs)
            out[name]["burns_corridor_not_met"] = sum(
                not b.get("corridor_met", True) for r in rs for b in r["burns"])
    return out


__all__ = ["MonteCarlo", "TASK_KIND", "prepare", "run_monte_carlo", "run_tasks", "summarize",
           "task_spec"]
