"""Regularised coordinates against the model's own: ``taylor`` in Cartesian, in modified equinoctial
elements (``mee``, ``mee-longitude``) on earth-mars and with a Sundman time transformation
(``sundman``) on nrho-9-2, in the same process.

Per row: the guaranteed horizon reached of the one asked (the run keeps its sets up to the step
where the remainder can no longer be enclosed), the warm wall time (median of ``--reps`` runs
after one warm-up run, caches and compiled kernels in place), its ratio to the paper's Table 1
time for earth-mars (Patel & Subbarao: 3.443 s for 200 d, 5.103 s for 300 d, MATLAB + CORA), and
on the horizon every row reaches: the Monte Carlo check (``--samples`` trajectories of ``mc``,
random / constant / bang-bang controls, every grid time, scaled gauge <= 1 + 1e-9) and the width
ratio set / samples in 50 random position directions at the last common time.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_coordinates.py [--reps 3] [--samples 10000]
        [--only earth-mars|nrho] [--write]

``--write`` updates the ``## Regularised coordinates`` section of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import ocreach
from ocreach.errors import SolverError
from ocreach.registry import get_problem
from ocreach.fileio import replace_markdown_section
from ocreach.sets.union import union_gauge

DOCS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"
PAPER = {200: 3.443, 300: 5.103}
HOUR = 3600.0 / 375200.0
CASES = {
    "earth-mars": [("cartesian", {}), ("mee", {}), ("mee-longitude", {})],
    "nrho": [("cartesian", {}), ("sundman", {}), ("sundman:k=1.5", {})],
}


def run(problem, coords: str, **opts):
    """(wall, result, stopped) of one ``taylor`` run in ``coords``."""
    t = time.perf_counter()
    try:
        res, stopped = ocreach.reach(problem, "taylor", coordinates=coords, **opts), False
    except SolverError as exc:
        res, stopped = exc.partial, True
    return time.perf_counter() - t, res, stopped


def widths(problem, results: dict, k: int, samples: int) -> dict:
    """Escapes of ``samples`` mc trajectories at grid times 0..k and width ratios at time k."""
    sub = get_problem(problem.id, **({"t_days": float(k)} if problem.id == "earth-mars"
                                     else {"t_final": k * HOUR}))   # daily / hourly grids
    mc = ocreach.reach(sub, "mc", samples=samples, seed=11)
    pos = list(problem.position_dims)
    D = np.random.default_rng(7).standard_normal((50, len(pos)))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    P = mc.points[k][:, pos]
    w_mc = (P @ D.T).max(axis=0) + (-P @ D.T).max(axis=0)
    out = {}
    for name, res in results.items():
        esc = sum(int(np.sum(union_gauge(res.sets[j], mc.points[j]) > 1 + 1e-9)) for j in range(k + 1))
        S = res.sets[k].project(pos)
        ratio = (S.support(D) + S.support(-D)) / w_mc
        out[name] = (esc, float(ratio.mean()), float(ratio.min()), float(ratio.max()))
    return out


def bench(case: str, reps: int, samples: int) -> list[str]:
    if case == "earth-mars":
        problems = [(get_problem("earth-mars", t_days=float(d)), f"{d} d", d) for d in (200, 300)]
        unit, scale = "d", None
    else:
        problems = [(get_problem("nrho-9-2"), "76 h", None)]
        unit, scale = "h", HOUR
    rows = ["| problem | coordinates | reached (of) | warm wall [s] | vs paper | stopped because |",
            "|---|---|---|---|---|---|"]
    common = {}
    for p, label, days in problems:
        step = p.extra["day_TU"] if scale is None else scale
        reached = {}
        for coords, opts in CASES[case]:
            run(p, coords, **opts)   # warm-up: compiled kernels, CasADi and interval caches
            runs = [run(p, coords, **opts) for _ in range(reps)]
            wall = float(np.median([r[0] for r in runs]))
            _, res, stopped = runs[-1]
            reached[coords] = res
            t_end = res.times[-1] / step
            paper = f"{PAPER[days] / wall:.2f}x" if days in PAPER and not stopped else "-"
            why = res.meta.get("failure", "") if stopped else ""
            why = (why[:90] + "...") if len(why) > 90 else why
            rows.append(f"| {p.id} {label} | {coords} | {t_end:.0f} {unit} ({label}) | {wall:.2f} | "
                        f"{paper} | {why or '-'} |")
        if not common:
            common = reached
    k = min(r.times.size for r in common.values()) - 1
    p0 = problems[0][0]
    if k >= 1 and samples:
        w = widths(p0, common, k, samples)
        t_k = p0.grid[k] / (p0.extra["day_TU"] if scale is None else scale)
        rows += ["", f"On the horizon every row reaches ({t_k:.0f} {unit}), {samples} mc samples:", "",
                 "| coordinates | escapes / samples x times | width ratio mean (min..max) |",
                 "|---|---|---|"]
        for name, (esc, mean, lo, hi) in w.items():
            rows.append(f"| {name} | {esc} / {samples} x {k + 1} | {mean:.2f} ({lo:.2f}..{hi:.2f}) |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--samples", type=int, default=10000)
    ap.add_argument("--only", choices=sorted(CASES))
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    load = os.getloadavg()[0]
    lines = ["## Regularised coordinates", "", (f"Measured {time.strftime('%Y-%m-%d')}, 2-core shared machine (load {load:.1f}), "
             f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, taylor "
             f"defaults (max_parts 64), medians of {args.reps} warm runs."), ""]
    for case in ([args.only] if args.only else list(CASES)):
        lines += bench(case, args.reps, args.samples) + [""]
    text = "\n".join(lines)
    print(text)
    if args.write:
        replace_markdown_section(DOCS, text)


if __name__ == "__main__":
    main()
