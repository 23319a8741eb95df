"""``ocreach report orbit-maintenance``: the orbit-maintenance Monte Carlo and its record.

::

    ocreach report orbit-maintenance --problem nrho-9-2 [--runs 100] [--years 1]
        [--controllers xaxis,target-point,corridor,tube-mpc,lqr] [--workers N | --dask-local N]
        [--out DIR] [--set KEY=VALUE ...]

runs :func:`~ocreach.control.stationkeeping.maintenance_mc.run_monte_carlo` (its store, the
resumable sweep folder, is ``DIR.runs`` next to the report unless ``--set store=PATH``; an
interrupted run is continued by the same command) and writes ``DIR`` as a unit
(:func:`ocreach.outdir.write_as_unit`): ``metrics.json`` (settings, sources, per controller the
summary and every run's metrics), ``report.md`` (the table and the comparison with the
published budgets) and the figures ``delta_v_histogram.png``, ``deviation_envelope.png`` and
``burns_on_orbit.png``.  ``--set`` takes the options of
:meth:`~ocreach.control.stationkeeping.orbit_maintenance.MaintenanceSettings.from_options`
(``area_to_mass``, ``nav_position_sigma_km``, ``min_burn_mps``, ``burn_anomaly_deg``, ...) and
controller options as ``CONTROLLER.NAME`` (``xaxis.target_revolutions=3``).  Every input is
checked before any work.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from ocreach.control.stationkeeping.maintenance_mc import run_monte_carlo
from ocreach.control.stationkeeping.orbit_maintenance import (
    CONTROLLERS,
    MaintenanceSettings,
    make_controller,
)
from ocreach.control.stationkeeping.published import (
    CAPSTONE_DV_PER_REV_MPS,
    CAPSTONE_DV_PER_YEAR_MPS,
    SOURCES,
    ZHANG2022_DV_PER_YEAR_MPS,
)
from ocreach.errors import ProblemError, check_count

DEFAULT_CONTROLLERS = ("xaxis", "target-point", "corridor", "tube-mpc", "lqr")
FIGURES = ("delta_v_histogram.png", "deviation_envelope.png", "burns_on_orbit.png")


def parse_controllers(controllers: Any, options: dict[str, Any]) -> dict[str, dict]:
    """``controllers`` (comma-separated, a sequence, or a dict of name -> options) with the
    ``CONTROLLER.NAME`` entries of ``options`` (removed from it) as their options, every one
    checked by constructing it."""
    names = ([c.strip() for c in controllers.split(",") if c.strip()]
             if isinstance(controllers, str) else list(controllers))
    if not names or len(set(names)) != len(names):
        raise ProblemError(f"controllers must name distinct controllers from {list(CONTROLLERS)}; "
                           f"got {controllers!r}")
    given = controllers if isinstance(controllers, dict) else {}
    out: dict[str, dict] = {n: dict(given.get(n) or {}) for n in names}
    for key in [k for k in options if "." in k]:
        name, _, opt = key.partition(".")
        if name not in out:
            raise ProblemError(f"option {key!r}: {name!r} is not one of the controllers run "
                               f"({names})")
        out[name][opt] = options.pop(key)
    for name, opts in out.items():
        make_controller(name, opts)
    return out


def check_report_arguments(problem, out_dir: str | Path, *, runs: int = 100,
                           years: float = 1.0, controllers: Any = DEFAULT_CONTROLLERS,
                           workers: int | None = None, dask_local: int | None = None,
                           scheduler: str | None = None, store: str | None = None,
                           serial: bool = False, progress: bool = True,
                           **options: Any) -> dict[str, Any]:
    """Every argument of :func:`orbit_maintenance_report` checked, nothing created or run:
    the counts, the executor choice, the controllers and their options, the settings, the
    problem (no overrides), ``out_dir`` and the store (new, empty or this Monte Carlo's own;
    default ``out_dir.runs``).  Returns the keyword arguments with ``store`` filled in (what
    ``ocreach report`` passes on after it has made the folder's temporary twin)."""
    from ocreach.control.stationkeeping.maintenance_mc import task_spec
    from ocreach.outdir import check_output_dir
    from ocreach.registry import get_problem
    from ocreach.sweep.store import Store

    runs = check_count("runs (Monte Carlo runs per controller)", runs, 1)
    for nm, v in (("workers", workers), ("dask_local", dask_local)):
        if v is not None:
            check_count(nm, v, 1)
    if sum(v is not None for v in (workers, dask_local, scheduler)) + bool(serial) > 1:
        raise ProblemError("choose one of workers, dask_local, scheduler and serial")
    options = dict(options)
    ctl = parse_controllers(controllers, options)
    settings = MaintenanceSettings.from_options(problem=problem.id, years=years, **options)
    default = get_problem(problem.id)
    if not (np.array_equal(default.params, problem.params)
            and np.array_equal(default.grid, problem.grid)):
        raise ProblemError(f"orbit-maintenance builds its scenario from the problem id "
                           f"{problem.id!r}; problem overrides (--set problem.KEY=...) are not "
                           f"supported")
    target = check_output_dir(out_dir)
    store = Path(store) if store is not None else target.with_name(target.name + ".runs")
    check_output_dir(store, "store")
    Store.check(store, task_spec(settings, ctl, runs))  # a foreign folder: refused here
    return {"runs": runs, "years": years, "controllers": ctl, "workers": workers,
            "dask_local": dask_local, "scheduler": scheduler, "store": str(store),
            "serial": serial, "progress": progress, **{k: v for k, v in options.items()}}


def orbit_maintenance_report(problem, out_dir: str | Path, *, runs: int = 100,
                             years: float = 1.0, controllers: Any = DEFAULT_CONTROLLERS,
                             workers: int | None = None, dask_local: int | None = None,
                             scheduler: str | None = None, store: str | None = None,
                             serial: bool = False, progress: bool = True,
                             as_unit: bool = True, **options: Any) -> dict:
    """Run the Monte Carlo for ``problem`` and write the report folder ``out_dir`` (module
    doc): ``runs`` per controller of ``years`` each; ``workers`` (a local process pool, default
    the core count), ``dask_local`` (a Dask LocalCluster of that many workers), ``scheduler``
    (a Dask address) or ``serial``; ``store`` the resumable Monte Carlo folder (default
    ``out_dir.runs``).  Every argument is checked first (:func:`check_report_arguments`).
    ``as_unit``: write ``out_dir`` as a unit (:func:`ocreach.outdir.write_as_unit`); False
    when the caller does (``ocreach report`` writes into the folder's temporary twin).
    Returns the summary (per controller) and where everything went."""
    from ocreach.outdir import OutputDir, Stages, write_as_unit

    kw = check_report_arguments(problem, out_dir, runs=runs, years=years,
                                controllers=controllers, workers=workers,
                                dask_local=dask_local, scheduler=scheduler, store=store,
                                serial=serial, progress=progress, **options)
    if not as_unit:
        return _write_report(problem, Path(out_dir), **kw)
    out, mark, done = OutputDir(out_dir), Stages(), {}

    def work() -> None:
        mark("orbit-maintenance")
        done["result"] = _write_report(problem, out.path, **kw)

    if write_as_unit(out, mark, work) is not None:  # Ctrl-C: the partial files are kept
        raise KeyboardInterrupt
    return {**done["result"], "out": str(out.target)}


#: ``ocreach report`` checks every argument before it creates the folder's temporary twin
orbit_maintenance_report.check_arguments = check_report_arguments  # type: ignore[attr-defined]


def _write_report(problem, folder: Path, *, runs: int, years: float, controllers: dict,
                  workers, dask_local, scheduler, store: str, serial: bool, progress: bool,
                  **options: Any) -> dict:
    """The Monte Carlo (resumed from ``store``) and the report's files written into ``folder``
    (arguments as :func:`check_report_arguments` returns them)."""
    from ocreach.fileio import atomic_write_text, json_text

    settings = MaintenanceSettings.from_options(problem=problem.id, years=years, **options)
    try:
        mc = run_monte_carlo(settings, controllers, runs, store, workers=workers,
                             dask_local=dask_local, scheduler=scheduler, serial=serial,
                             progress=progress)
    except KeyboardInterrupt:
        print(f"interrupted: the finished runs are kept in {store}; the same command continues "
              f"from there", file=sys.stderr)
        raise
    data = {"problem": problem.id, "runs": runs, "years": settings.scenario.years,
            "settings": settings.to_dict(), "controllers": {
                n: make_controller(n, o).describe() for n, o in controllers.items()},
            "summary": mc.summary, "failures": mc.failures, "timing": mc.timing,
            "store": str(store), "sources": SOURCES,
            "published_budgets": {"capstone_dv_per_year_mps": CAPSTONE_DV_PER_YEAR_MPS,
                                  "capstone_dv_per_rev_mps": CAPSTONE_DV_PER_REV_MPS,
                                  "zhang2022_dv_per_year_mps": ZHANG2022_DV_PER_YEAR_MPS},
            "runs_metrics": {n: [_compact(r) for r in rs] for n, rs in mc.records.items()}}
    _add_tube_log(data, settings, controllers)
    atomic_write_text(folder / "metrics.json", json_text(data))
    atomic_write_text(folder / "report.md", markdown(data))
    figures(mc.records, settings, folder)
    return {"summary": mc.summary, "out": str(folder), "store": str(store),
            "files": ["metrics.json", "report.md", *FIGURES], "timing": mc.timing}


def _compact(r: dict) -> dict:
    """A run's metrics without its series (those stay in the store)."""
    return {k: v for k, v in r.items() if k not in ("deviation_km", "deviation_mps", "burns")}


def _add_tube_log(data: dict, settings: MaintenanceSettings, ctl: dict[str, dict]) -> None:
    """Which drift tube was used per refresh interval (guaranteed or linearised), for the
    tube controller (the tubes were built in :func:`maintenance_mc.prepare`)."""
    if "tube-mpc" not in ctl:
        return
    from ocreach.control.stationkeeping.scenario import scenario

    c = make_controller("tube-mpc", ctl["tube-mpc"])
    c.prepare(scenario(settings.scenario), settings)
    log = c._tubes["log"]
    data["controllers"]["tube-mpc"]["tubes"] = log
    data["controllers"]["tube-mpc"]["tube_intervals"] = {
        "total": len(log), "guaranteed": sum(r["guaranteed"] for r in log)}


# ------------------------------------------------------------------------------------------------
# text
# ------------------------------------------------------------------------------------------------
def _f(v, fmt: str = ".3g") -> str:
    return "-" if v is None else format(v, fmt)


ROWS = [
    ("runs", lambda s: str(s["runs"])),
    ("lost orbits", lambda s: f"{s['lost']} ({100 * s['lost_share']:.0f} %)"),
    ("Delta-V per year, mean (m/s)", lambda s: _f(s["delta_v_per_year_mps"]["mean"], ".4g")),
    ("Delta-V per year, 95th percentile (m/s)",
     lambda s: _f(s["delta_v_per_year_mps"]["p95"], ".4g")),
    ("Delta-V per year, max (m/s)", lambda s: _f(s["delta_v_per_year_mps"]["max"], ".4g")),
    ("burns per revolution (executed, mean)",
     lambda s: "continuous" if s["burns_per_rev"] is None else _f(s["burns_per_rev"]["mean"])),
    ("burns below the minimum / skipped", lambda s: f"{s['burns_below_minimum']} / "
                                                    f"{s['burns_skipped']}"),
    ("max deviation (km), mean over runs", lambda s: _f(s["max_deviation_km"]["mean"])),
    ("max deviation (km), 95th percentile", lambda s: _f(s["max_deviation_km"]["p95"])),
    ("max deviation (km), worst run", lambda s: _f(s["max_deviation_km"]["max"])),
    ("max velocity deviation (m/s), worst run", lambda s: _f(s["max_deviation_mps"]["max"])),
    ("max phase offset at apolune (min), worst run",
     lambda s: _f(s["max_phase_offset_min"]["max"])),
    ("max deviation from the orbit's path at apolune (km), worst run",
     lambda s: _f(s["max_path_deviation_km"]["max"])),
    ("burn opportunities taken", lambda s: "-" if s.get("opportunities") is None else
     f"{s['burns_planned']} of {s['opportunities']}"),
    ("corridor: worst ratio of the true deviation / steps outside",
     lambda s: "-" if "corridor_max_ratio" not in s else
     f"{_f(s['corridor_max_ratio']['max'])} / {s['corridor_exit_steps']}"),
    ("CPU per revolution (ms)", lambda s: _f(s["cpu_ms_per_revolution"])),
]


def markdown(data: dict) -> str:
    """``report.md``: settings, the table, the comparison with the published budgets; every
    number from ``data``."""
    s = data["settings"]
    names = list(data["summary"])
    nav, exe, srp = s["navigation"], s["execution"], s["scenario"]["srp"]
    lines = [f"# Orbit maintenance: {data['problem']}, {data['runs']} runs x "
             f"{data['years']:g} year(s)", "",
             f"Plant: DE421 Moon, Earth, Sun point masses plus cannonball SRP (C_r = {srp['cr']:g}, "
             f"A/m = {srp['area_to_mass']:g} m^2/kg, true value within +-"
             f"{100 * srp['uncertainty']:g} % of the nominal per run), epoch "
             f"{s['scenario']['epoch']} TDB; reference: the CR3BP orbit corrected into an orbit "
             f"of the plant with the nominal SRP.",
             f"Navigation: Gaussian OD error per fix, 1-sigma {nav['position_sigma_km']:.3g} km "
             f"and {1e2 * nav['velocity_sigma_mps']:.3g} cm/s per axis; a fix at every "
             f"scheduled burn, every {nav['od_interval_h']:g} h for the event-triggered and "
             f"continuous controllers.",
             f"Execution: 1-sigma magnitude {100 * exe['magnitude_sigma']:.3g} %, pointing "
             f"{exe['pointing_sigma_deg']:.3g} deg; burns below {100 * exe['min_burn_mps']:.3g} "
             f"cm/s not executed; skipped burns {exe['skipped_burns'] or 'none'}, skip "
             f"probability {exe['skip_probability']:g}.",
             f"Scheduled burns at true anomaly {s['burn_anomaly_deg']:g} deg; a run is lost "
             f"when its distance from the Moon leaves the reference's range widened by a factor "
             f"{s['loss_ratio']:g}.", "",
             "| metric | " + " | ".join(names) + " |",
             "| --- |" + " ---: |" * len(names)]
    for label, fn in ROWS:
        lines.append(f"| {label} | " + " | ".join(fn(data["summary"][n]) for n in names) + " |")
    pb = data["published_budgets"]
    lines += ["", "Published budgets (docs/validation/orbit-maintenance.md has the sources): "
              f"CAPSTONE flight {pb['capstone_dv_per_rev_mps']:.3f} m/s per revolution "
              f"({pb['capstone_dv_per_year_mps']:.2f} m/s per year); Zhang et al. 2022 (discrete "
              f"LQR every 2 days, the default error levels here) "
              f"{pb['zhang2022_dv_per_year_mps']:.2f} m/s per year.  The Gateway papers' own "
              "budgets (Davis et al. 2017, Guzzetti et al. 2017, Newman et al. 2018) were not "
              "available, only their abstracts."]
    for n in names:
        m = data["summary"][n]["delta_v_per_year_mps"]["mean"]
        if m is not None:
            lines.append(f"- {n}: {m / pb['capstone_dv_per_year_mps']:.3g} x CAPSTONE's rate, "
                         f"{m / pb['zhang2022_dv_per_year_mps']:.3g} x Zhang et al.'s.")
    if "tube-mpc" in data["controllers"] and "tube_intervals" in data["controllers"]["tube-mpc"]:
        ti = data["controllers"]["tube-mpc"]["tube_intervals"]
        rest = ("" if ti["guaranteed"] == ti["total"] else
                ", the others linearised (labelled in metrics.json)")
        lines.append(f"- tube-mpc drift tubes: {ti['guaranteed']} of {ti['total']} refresh "
                     f"intervals guaranteed (taylor){rest}.")
    if data["failures"]:
        lines.append(f"- {len(data['failures'])} run(s) failed (metrics.json `failures`).")
    t = data["timing"]
    lines += ["", f"Time: {t['total_wall_s']:.0f} s wall ({t['driver_prepare_wall_s']:.0f} s "
              f"preparing the reference and the tubes, {t['monte_carlo_wall_s']:.0f} s "
              f"of runs on {t['executor']}); {t['runs_cpu_s']:.0f} s of CPU in the runs "
              f"({t['ran_now']} run now, {t['already_finished']} from the store {data['store']}).",
              "", "Figures: " + ", ".join(f"`{f}`" for f in FIGURES) + "."]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------
# figures
# ------------------------------------------------------------------------------------------------
def figures(records: dict[str, list[dict]], settings: MaintenanceSettings, folder: Path) -> None:
    """The three figures of the report (module doc), written atomically into ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ocreach.control.stationkeeping.scenario import scenario
    from ocreach.reach.plot import save_figure

    sc = scenario(settings.scenario)
    names = list(records)
    colors = dict(zip(names, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))

    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 3.2), squeeze=False)
    for ax, n in zip(axes[0], names, strict=True):
        dv = [r["dv_per_year_mps"] for r in records[n] if not r["lost"]]
        if dv:
            ax.hist(dv, bins=min(30, max(5, len(dv) // 3)), color=colors[n])
            ax.axvline(np.mean(dv), color="k", lw=1, label=f"mean {np.mean(dv):.3g}")
            ax.axvline(np.percentile(dv, 95), color="k", ls="--", lw=1,
                       label=f"95 % {np.percentile(dv, 95):.3g}")
            ax.legend(fontsize=7)
        lost = sum(r["lost"] for r in records[n])
        ax.set_title(f"{n} ({len(records[n])} runs, {lost} lost)", fontsize=9)
        ax.set_xlabel("Delta-V per year (m/s)")
    axes[0][0].set_ylabel("runs")
    fig.tight_layout()
    save_figure(fig, folder / FIGURES[0])

    fig, ax = plt.subplots(figsize=(8, 4))
    for n in names:
        rs = records[n]
        L = max(len(r["deviation_km"]) for r in rs)
        D = np.full((len(rs), L), np.nan)
        for i, r in enumerate(rs):
            D[i, :len(r["deviation_km"])] = r["deviation_km"]
        w = rs[0]["deviation_window_steps"]
        days = (np.arange(L) + 0.5) * w * sc.dt * sc.units.time / 86400.0
        with np.errstate(all="ignore"):
            lo, med, hi = (np.nanpercentile(D, q, axis=0) for q in (5, 50, 95))
        ax.fill_between(days, lo, hi, color=colors[n], alpha=0.25)
        ax.plot(days, med, color=colors[n], lw=1, label=f"{n}: median, 5-95 % band")
        ax.plot(days, np.nanmax(D, axis=0), color=colors[n], lw=0.5, ls=":")
    ax.set_yscale("log")
    ax.set_xlabel("days from the epoch")
    ax.set_ylabel("position deviation from the reference (km)")
    ax.set_title("deviation envelope (dotted: worst run)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, folder / FIGURES[1])

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.2))
    rev = slice(0, sc.M + 1)
    km = sc.units.length / 1e3
    for a, (i, j), lab in ((a1, (0, 2), ("x", "z")), (a2, (1, 2), ("y", "z"))):
        a.plot(sc.X[rev, i] * km, sc.X[rev, j] * km, color="0.6", lw=1,
               label="reference, first revolution")
        for n in names:
            steps = [b["step"] for r in records[n] for b in r["burns"]
                     if b["status"] == "executed"]
            if steps:
                P = sc.X[np.asarray(steps)]
                a.scatter(P[:, i] * km, P[:, j] * km, s=6, color=colors[n], alpha=0.5,
                          label=f"{n}: {len(steps)} burns")
        a.set_xlabel(f"{lab[0]} (km, rotating frame)")
        a.set_ylabel(f"{lab[1]} (km)")
        a.set_aspect("equal", adjustable="datalim")
    a1.legend(fontsize=7)
    fig.suptitle("executed burns on the orbit (all runs; reference state at the burn step)",
                 fontsize=9)
    fig.tight_layout()
    save_figure(fig, folder / FIGURES[2])


__all__ = ["DEFAULT_CONTROLLERS", "FIGURES", "check_report_arguments", "markdown",
           "orbit_maintenance_report", "parse_controllers"]
