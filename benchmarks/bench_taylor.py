"""Benchmarks of the sound zonotope methods ``taylor`` and ``sdc`` (Patel & Subbarao Methods 1-2).

1. earth-mars (Table 1): wall time of ``taylor`` and ``sdc`` on the 200 d and 300 d daily grids
   against the paper's 3.443 s / 5.103 s (MATLAB + CORA, Intel i7 2.1 GHz).  The sound enclosure
   stops where the Lagrange remainder can no longer be enclosed (see docs/validation/sound-zonotope.md), so the time to that point and the time per daily step are reported;
   the ratio is paper time per step / our time per step (target >= 10x).
2. nrho-9-2: runtime per 1 h step of ``taylor`` and ``sdc`` over the first 24 h.
3. The compiled remainder bounds (:mod:`ocreach.intervals.kernel`) against the numpy
   interval evaluator on earth-mars 200 d, runs interleaved in this process (same sets).

Medians of ``--reps`` runs with the min..max spread of the CPU time per step.  Run it with
``OPENBLAS_NUM_THREADS=1`` (the text states the thread settings and the load average it saw).
``--write`` updates the ``## Taylor / SDC zonotopes`` section of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import ocreach
from ocreach.errors import SolverError
from ocreach.fileio import replace_markdown_section
from ocreach.outdir import benchmarks_doc
from ocreach.registry import get_problem

DOCS = benchmarks_doc(Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md")
PAPER = {200: 3.443, 300: 5.103}
HOUR = 3600.0 / 375200.0


def timed(problem, method, **opts):
    """(wall, CPU, result, stopped) of one run; CPU = process time (less sensitive to the other
    jobs on a shared machine than the wall time)."""
    t, c = time.perf_counter(), time.process_time()
    try:
        res = ocreach.reach(problem, method, **opts)
        stopped = False
    except SolverError as exc:
        res = exc.partial
        stopped = True
    return time.perf_counter() - t, time.process_time() - c, res, stopped


def median_run(problem, method, reps, **opts):
    """(median wall, median CPU, (min CPU, max CPU), last result, stopped)."""
    runs = [timed(problem, method, **opts) for _ in range(reps)]
    wall = float(np.median([r[0] for r in runs]))
    cpus = [r[1] for r in runs]
    return wall, float(np.median(cpus)), (min(cpus), max(cpus)), runs[-1][2], runs[-1][3]


def kernel_vs_numpy(reps: int) -> tuple[list[float], list[float], int]:
    """CPU per earth-mars 200 d ``taylor`` run with the compiled interval Hessian and with the
    numpy evaluator (the kernel switched off on the cached IntervalFunction), interleaved."""
    from ocreach.reach.taylor_step import hessian_interval

    p = get_problem("earth-mars", t_days=200.0)
    fun = hessian_interval(p.model)
    timed(p, "taylor", max_parts=1, max_halvings=2)
    kernel = fun._native
    nat, ref, steps = [], [], 1
    for _ in range(reps):
        fun._native = kernel
        _, cpu, res, _ = timed(p, "taylor", max_parts=1, max_halvings=2)
        nat.append(cpu)
        steps = res.times.size - 1
        fun._native = False
        ref.append(timed(p, "taylor", max_parts=1, max_halvings=2)[1])
    fun._native = kernel
    return nat, ref, steps


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--write", action="store_true")
    ap.add_argument("--reps", type=int, default=5, help="runs per case (medians are reported)")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    header = ("| case | method | reached | wall [s] | CPU [s] | CPU per step [ms] (min..max) "
              "| paper per step [ms] | ratio (CPU) |")
    rows = [header, "|---|---|---|---|---|---|---|---|"]
    for days in (200, 300):
        p = get_problem("earth-mars", t_days=float(days))
        for method in ("taylor", "sdc"):
            timed(get_problem("earth-mars", t_days=2.0), method)  # warm the CasADi/interval caches
            wall, cpu, (c_lo, c_hi), res, stopped = median_run(p, method, args.reps, max_parts=1,
                                                                max_halvings=2)
            steps = max(res.times.size - 1, 1)
            per = cpu / steps
            paper_per = PAPER[days] / days
            reached = f"{steps} of {days} d" + (" (stopped)" if stopped else "")
            rows.append(f"| earth-mars {days} d | {method} | {reached} | {wall:.2f} | {cpu:.3f} | "
                        f"{1e3 * per:.2f} ({1e3 * c_lo / steps:.2f}..{1e3 * c_hi / steps:.2f}) | "
                        f"{1e3 * paper_per:.1f} | {paper_per / per:.1f}x "
                        f"({paper_per * steps / c_hi:.1f}..{paper_per * steps / c_lo:.1f}) |")
            print(rows[-1], flush=True)
    p = get_problem("nrho-9-2", t_final=24 * HOUR)
    for method in ("taylor", "sdc"):
        timed(p, method)
        wall, cpu, (c_lo, c_hi), res, _ = median_run(p, method, args.reps)
        per = cpu / p.n_segments
        rows.append(f"| nrho-9-2 first 24 h | {method} | 24 h | {wall:.2f} | {cpu:.3f} | "
                    f"{1e3 * per:.2f} ({1e3 * c_lo / p.n_segments:.2f}..{1e3 * c_hi / p.n_segments:.2f})"
                    f" | - | - |")
        print(rows[-1], flush=True)
    nat, ref, steps = kernel_vs_numpy(args.reps)
    ratio = float(np.median(np.asarray(ref) / np.asarray(nat)))
    kernel_text = (f"Compiled remainder bounds against the numpy interval evaluator (earth-mars 200 d "
                   f"`taylor`, {args.reps} interleaved pairs, the same sets): CPU per step "
                   f"{1e3 * np.median(nat) / steps:.2f} ms against {1e3 * np.median(ref) / steps:.2f} "
                   f"ms, the numpy evaluator takes {ratio:.2f}x the time (median of the pairs' ratios).")
    print(kernel_text, flush=True)
    load1 = os.getloadavg()[0]
    threads = ", ".join(f"{k}={os.environ.get(k, 'unset')}"
                        for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"))
    text = ("## Taylor / SDC zonotopes\n\n"
            f"`benchmarks/bench_taylor.py` (median of {args.reps} runs per case, min..max in "
            "brackets, after a warm-up that builds the cached CasADi and interval functions and "
            f"compiles the interval kernels; {threads}; 1-minute load average {load0:.1f} at the "
            f"start and {load1:.1f} at the end, on 2 cores).  The paper's "
            "Table 1 times are MATLAB + CORA on an Intel i7 at 2.1 GHz for the whole horizon; the sound "
            "enclosure stops before 200 d (docs/validation/sound-zonotope.md), so the "
            "comparison is per daily step (ratio = paper ms per step / our CPU ms per step; the "
            "bracket is the ratio at the slowest and fastest run).  CPU is the process time, "
            "reported because the machine is shared (the wall time is then up to ~2x the CPU "
            "time).\n\n" + "\n".join(rows) + "\n\n" + kernel_text + "\n")
    print(text)
    if args.write:
        replace_markdown_section(DOCS, text)


if __name__ == "__main__":
    main()
