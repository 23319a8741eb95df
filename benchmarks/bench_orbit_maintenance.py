"""Benchmark of the orbit-maintenance loop (ocreach.control.stationkeeping) on nrho-9-2.

1. **Plant propagation against SciPy.**  One revolution (157 control steps of 1.003 h) of the
   DE421 Moon/Earth/Sun + SRP plant from the reference's first state: the compiled DOP853 of
   ``ocreach.dynamics.flow.propagate`` (what the loop calls) against SciPy ``solve_ivp(DOP853)`` calling
   the same CasADi right-hand side (the peer the ephemeris plant of the station-keeping runs
   uses), same tolerances (rtol 1e-10, atol 1e-12), medians of 5; the end states agree to
   the printed km.  (heyoka is not compared: the DE421 Chebyshev fit is a CasADi expression,
   and rewriting it as a heyoka expression system is a different model.)
2. **Per-revolution cost of the loop** for each controller: CPU time of ``run_maintenance``
   over ``--years`` (default 0.25: 14 revolutions) for ``--runs`` runs (default 3), per
   revolution, after one warm-up run (the scenario, the STTs and the tubes are built once per
   process and excluded).
3. ``--monte-carlo``: the year-long Monte Carlo, ``--mc-runs`` runs (default 100) of each of
   ``--controllers`` on ``--workers`` processes (default 2), timed (wall and CPU); or
   ``--from-report DIR`` (with ``--report-when "DATE, MACHINE, LOAD"``): the timing and
   Delta-V of an ``ocreach report orbit-maintenance`` folder that ran it; what
   docs/validation/orbit-maintenance.md records.

Usage: ``python benchmarks/bench_orbit_maintenance.py [--write] [--monte-carlo]``; ``--write``
updates the ``## Orbit maintenance`` section of docs/benchmarks.md (date and load average
stamped).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from ocreach.control.stationkeeping import MaintenanceSettings, make_controller, run_maintenance
from ocreach.control.stationkeeping.scenario import ATOL, RTOL, scenario
from ocreach.fileio import replace_markdown_section
from ocreach.outdir import benchmarks_doc

DOCS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"


def bench_plant(years: float = 0.25, repeat: int = 5) -> dict:
    sc = scenario(MaintenanceSettings.from_options(years=years).scenario)
    k1 = sc.M
    x0 = sc.X[0]
    sc.propagate(x0, 0, k1, sc.params)  # compile / load once
    ours = []
    for _ in range(repeat):
        t = time.perf_counter()
        X = sc.propagate(x0, 0, k1, sc.params)
        ours.append(time.perf_counter() - t)
    f, u0, p = sc.model.f_fun, np.zeros(3), sc.params

    def rhs(t, y):
        return np.asarray(f(y, u0, t, p)).ravel()

    peer = []
    for _ in range(repeat):
        t = time.perf_counter()
        sol = solve_ivp(rhs, (sc.times[0], sc.times[k1]), x0, method="DOP853", rtol=RTOL,
                        atol=ATOL, t_eval=sc.times[:k1 + 1])
        peer.append(time.perf_counter() - t)
    diff_km = float(np.max(np.linalg.norm(sol.y.T[:, :3] - X[:, :3], axis=1))
                    * sc.units.length / 1e3)
    return {"ours_ms": 1e3 * statistics.median(ours), "scipy_ms": 1e3 * statistics.median(peer),
            "ratio": statistics.median(peer) / statistics.median(ours), "max_diff_km": diff_km,
            "steps": k1}


def bench_loop(controllers: list[str], years: float, runs: int) -> dict:
    settings = MaintenanceSettings.from_options(years=years)
    out = {}
    for name in controllers:
        ctl = make_controller(name)
        run_maintenance(settings, ctl, 10_000)  # warm-up: per-process preparation
        per_rev = []
        for i in range(runs):
            r = run_maintenance(settings, ctl, i)
            per_rev.append(1e3 * r["cpu_s"] / r["revolutions"])
        out[name] = {"cpu_ms_per_revolution": statistics.median(per_rev),
                     "revolutions": r["revolutions"]}
    return out


def bench_monte_carlo(controllers: list[str], runs: int, workers: int) -> dict:
    from ocreach.control.stationkeeping.maintenance_mc import run_monte_carlo

    settings = MaintenanceSettings.from_options(years=1.0)
    with tempfile.TemporaryDirectory(prefix="om-bench-") as tmp:
        c0 = time.process_time()
        mc = run_monte_carlo(settings, {c: {} for c in controllers}, runs, Path(tmp) / "store",
                             workers=workers, progress=False)
        driver_cpu = time.process_time() - c0
    return {"runs": runs, "workers": f"{workers} worker processes", "controllers": controllers,
            "timing": mc.timing, "driver_cpu_s": driver_cpu,
            "summary": {n: {"dv_mean": s["delta_v_per_year_mps"]["mean"],
                            "dv_p95": s["delta_v_per_year_mps"]["p95"], "lost": s["lost"],
                            "cpu_ms_per_revolution": s["cpu_ms_per_revolution"]}
                        for n, s in mc.summary.items()}}


def mc_from_report(folder: str | Path, when: str) -> dict:
    """The Monte Carlo record of an ``ocreach report orbit-maintenance`` folder (its
    ``metrics.json``) in the shape of :func:`bench_monte_carlo`, ``when`` the date and machine
    load it was measured at."""
    data = json.loads((Path(folder) / "metrics.json").read_text())
    return {"runs": data["runs"], "workers": data["timing"]["executor"],
            "controllers": list(data["summary"]), "timing": data["timing"], "when": when,
            "summary": {n: {"dv_mean": s["delta_v_per_year_mps"]["mean"],
                            "dv_p95": s["delta_v_per_year_mps"]["p95"], "lost": s["lost"],
                            "cpu_ms_per_revolution": s["cpu_ms_per_revolution"]}
                        for n, s in data["summary"].items()}}


def markdown(plant: dict, loop: dict, mcs: list[dict]) -> str:
    load = os.getloadavg()
    lines = ["## Orbit maintenance", "",
             f"`python benchmarks/bench_orbit_maintenance.py` ({datetime.date.today()}, 2 cores "
             f"shared, load average {load[0]:.1f}; OPENBLAS_NUM_THREADS="
             f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}).", "",
             "| case | ocreach | peer | ratio (peer / ocreach) |", "|---|---:|---:|---:|",
             f"| one revolution of the DE421 + SRP plant ({plant['steps']} steps) | "
             f"{plant['ours_ms']:.1f} ms (compiled DOP853) | {plant['scipy_ms']:.0f} ms (SciPy "
             f"DOP853 on the CasADi right-hand side) | {plant['ratio']:.0f} |", "",
             f"End states agree to {plant['max_diff_km']:.2g} km.  Loop cost per revolution "
             f"(CPU, median of the runs, preparation excluded):", "",
             "| controller | CPU per revolution (ms) |", "|---|---:|"]
    lines += [f"| {n} | {v['cpu_ms_per_revolution']:.0f} |" for n, v in loop.items()]
    for mc in mcs:
        t = mc["timing"]
        when = f" (measured {mc['when']})" if mc.get("when") else ""
        lines += ["", (f"Year-long Monte Carlo{when}: {mc['runs']} runs of each of "
                       f"{', '.join(mc['controllers'])} on {mc['workers']}: "
                       f"{t['total_wall_s'] / 60:.1f} min wall "
                       f"({t['driver_prepare_wall_s'] / 60:.1f} min preparing the reference and the tubes), "
                       f"{t['runs_cpu_s'] / 60:.1f} min CPU in the runs."), "",
                  "| controller | Delta-V per year, mean / p95 (m/s) | lost | CPU per revolution (ms) |",
                  "|---|---:|---:|---:|"]
        lines += [f"| {n} | {v['dv_mean']:.3g} / {v['dv_p95']:.3g} | {v['lost']} | "
                  f"{v['cpu_ms_per_revolution']:.0f} |" for n, v in mc["summary"].items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true")
    ap.add_argument("--years", type=float, default=0.25)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--controllers", default="xaxis,target-point,corridor,tube-mpc,lqr")
    ap.add_argument("--monte-carlo", action="store_true")
    ap.add_argument("--mc-runs", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--from-report", action="append", default=[], metavar="DIR",
                    help="add the Monte Carlo of an `ocreach report orbit-maintenance` folder "
                         "(instead of --monte-carlo; repeatable)")
    ap.add_argument("--report-when", action="append", default=[], metavar="TEXT",
                    help="date and machine load of each --from-report measurement")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
    plant = bench_plant(args.years)
    print(json.dumps(plant))
    loop = bench_loop(controllers, args.years, args.runs)
    print(json.dumps(loop))
    mcs = [bench_monte_carlo(controllers, args.mc_runs, args.workers)] if args.monte_carlo else []
    whens = args.report_when + [""] * len(args.from_report)
    mcs += [mc_from_report(d, w) for d, w in zip(args.from_report, whens, strict=False)]
    for mc in mcs:
        print(json.dumps(mc, default=str))
    text = markdown(plant, loop, mcs)
    print(text)
    if args.write:
        replace_markdown_section(benchmarks_doc(DOCS), text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
