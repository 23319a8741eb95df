"""Benchmarks of the sound zonotope methods ``taylor`` and ``sdc`` (Patel & Subbarao Methods 1-2).

1. earth-mars (Table 1): wall time of ``taylor`` and ``sdc`` on the 200 d and 300 d daily grids
   against the paper's 3.443 s / 5.103 s (MATLAB + CORA, Intel i7 2.1 GHz).  The sound enclosure
   stops where the Lagrange remainder can no longer be enclosed (see docs/validation.md, "Sound
   zonotope reachability"), so the time to that point and the time per daily step are reported;
   the ratio is paper time per step / our time per step (target >= 10x).
2. nrho-9-2: runtime per 1 h step of ``taylor`` and ``sdc`` over the first 24 h (median of 3).

``--write`` updates the ``## Taylor / SDC zonotopes`` section of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import ocreach
from ocreach.errors import SolverError
from ocreach.problem import get_problem
from ocreach.report import replace_markdown_section

DOCS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"
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
    runs = [timed(problem, method, **opts) for _ in range(reps)]
    wall = float(np.median([r[0] for r in runs]))
    cpu = float(np.median([r[1] for r in runs]))
    return wall, cpu, runs[-1][2], runs[-1][3]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--write", action="store_true")
    ap.add_argument("--reps", type=int, default=3, help="runs per case (medians are reported)")
    args = ap.parse_args()
    header = ("| case | method | reached | wall [s] | CPU [s] | CPU per step [ms] "
              "| paper per step [ms] | ratio (CPU) |")
    rows = [header, "|---|---|---|---|---|---|---|---|"]
    for days in (200, 300):
        p = get_problem("earth-mars", t_days=float(days))
        for method in ("taylor", "sdc"):
            timed(get_problem("earth-mars", t_days=2.0), method)  # warm the CasADi/interval caches
            wall, cpu, res, stopped = median_run(p, method, args.reps, max_parts=1, max_halvings=2)
            steps = res.times.size - 1
            per = cpu / max(steps, 1)
            paper_per = PAPER[days] / days
            reached = f"{steps} of {days} d" + (" (stopped)" if stopped else "")
            rows.append(f"| earth-mars {days} d | {method} | {reached} | {wall:.2f} | {cpu:.2f} | "
                        f"{1e3 * per:.2f} | {1e3 * paper_per:.1f} | {paper_per / per:.1f}x |")
            print(rows[-1], flush=True)
    p = get_problem("nrho-9-2", t_final=24 * HOUR)
    for method in ("taylor", "sdc"):
        timed(p, method)
        wall, cpu, res, _ = median_run(p, method, args.reps)
        per = cpu / p.n_segments
        rows.append(f"| nrho-9-2 first 24 h | {method} | 24 h | {wall:.2f} | {cpu:.2f} | "
                    f"{1e3 * per:.2f} | - | - |")
        print(rows[-1], flush=True)
    text = ("## Taylor / SDC zonotopes\n\n"
            f"`benchmarks/bench_taylor.py` (median of {args.reps} runs per case after a warm-up that "
            "builds the cached CasADi and interval functions; OPENBLAS_NUM_THREADS=1).  The paper's "
            "Table 1 times are MATLAB + CORA on an Intel i7 at 2.1 GHz for the whole horizon; the sound "
            "enclosure stops before 200 d (docs/validation.md, 'Sound zonotope reachability'), so the "
            "comparison is per daily step (ratio = paper ms per step / our CPU ms per step).  CPU is "
            "the process time, reported because the shared 2-core machine runs other developers' "
            "jobs (the wall time is then up to ~2x the CPU time).\n\n" + "\n".join(rows) + "\n")
    print(text)
    if args.write:
        replace_markdown_section(DOCS, text)


if __name__ == "__main__":
    main()
