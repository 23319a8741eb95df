"""Benchmark of the sound ``poly`` method (conservative polynomialization, Althoff 2013) against
``taylor`` (conservative linearisation) on the horizons both reach, in the same process.

Per case: the CPU time of each method (median of ``--reps`` warm runs, min..max in brackets), the
ratio ``taylor / poly`` of the CPU times, and the tightness at the case's last time against the
Monte Carlo peer (``mc``, the same 2,000 samples for both): the mean (min..max) over 50 random
position directions of the set's width over the samples' width (for a polynomial zonotope the
rigorous upper support bound of :func:`ocreach.sets.pz_exact.support_bounds`).  Run with
``OPENBLAS_NUM_THREADS=1``; ``--write`` updates the ``## poly (conservative polynomialization)``
section of docs/benchmarks.md.
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
from ocreach.registry import get_problem

DOCS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"
HOUR = 3600.0 / 375200.0
#: (label, problem id, overrides, options of both methods)
CASES = [
    ("vdp 3 TU", "vdp", {}, {}),
    ("dro 2 TU (8 sub-steps)", "dro", {"t_final": 2.0}, {"substeps": 8}),
    ("nrho-9-2 24 h", "nrho-9-2", {"t_final": 24 * HOUR}, {}),
    ("nrho-9-2 76 h", "nrho-9-2", {}, {"max_parts": 1}),
    ("nrho-9-2 76 h, sundman:k=1.5", "nrho-9-2", {}, {"max_parts": 1, "coordinates": "sundman:k=1.5"}),
    ("l2-halo 80 h", "l2-halo", {"t_final": 80 * HOUR}, {"max_parts": 1}),
    ("earth-mars 200 d", "earth-mars", {"t_days": 200.0}, {"max_parts": 1}),
    ("earth-mars 200 d, mee", "earth-mars", {"t_days": 200.0}, {"max_parts": 1, "coordinates": "mee"}),
]


def timed(problem, method, **opts):
    """(CPU seconds, result, stopped) of one run (CPU = process time: the machine is shared)."""
    c = time.process_time()
    try:
        res, stopped = ocreach.reach(problem, method, **opts), False
    except SolverError as exc:
        res, stopped = exc.partial, True
    return time.process_time() - c, res, stopped


def widths(S, D: np.ndarray, dims: list[int]) -> np.ndarray:
    from ocreach.sets.polyzonotope import PolyZonotope
    from ocreach.sets.pz_exact import support_bounds

    parts = getattr(S, "parts", [S])
    DD = np.vstack([D, -D])
    vals = [support_bounds(p.project(dims), DD, tol=1e-3).upper if isinstance(p, PolyZonotope)
            else p.project(dims).support(DD) for p in parts]
    u = np.max(vals, axis=0)
    return u[: len(D)] + u[len(D):]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--write", action="store_true")
    ap.add_argument("--reps", type=int, default=3, help="runs per case (medians are reported)")
    ap.add_argument("--only", default=None, help="comma-separated case labels' first words")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    rows = [("| case | taylor reached | taylor CPU [s] | poly reached | poly CPU [s] | CPU taylor / poly "
            "| width / MC taylor | width / MC poly |"), "|---|---|---|---|---|---|---|---|"]
    for label, pid, over, opts in CASES:
        if args.only and label.split()[0] not in args.only.split(","):
            continue
        p = get_problem(pid, **over)
        out = {}
        for method in ("taylor", "poly"):
            timed(p, method, **opts)                       # warm the caches and kernels
            runs = [timed(p, method, **opts) for _ in range(args.reps)]
            cpus = [r[0] for r in runs]
            out[method] = (float(np.median(cpus)), min(cpus), max(cpus), runs[-1][1], runs[-1][2])
        K = min(out[m][3].times.size for m in out) - 1
        mc = ocreach.reach(p, "mc", samples=2000, seed=1)
        pos = list(p.position_dims) or list(range(p.model.n_x))
        D = np.random.default_rng(7).standard_normal((50, len(pos)))
        D /= np.linalg.norm(D, axis=1, keepdims=True)
        P = mc.points_at(K)[:, pos]
        wmc = (P @ D.T).max(axis=0) + (-P @ D.T).max(axis=0)
        cells = []
        for method in ("taylor", "poly"):
            med, lo, hi, res, stopped = out[method]
            steps = res.times.size - 1
            reached = f"{steps} of {p.grid.size - 1} steps" + (" (stopped)" if stopped else "")
            cells.append(f"{reached} | {med:.2f} ({lo:.2f}..{hi:.2f})")
        wr = {m: widths(out[m][3].sets[K], D, pos) / wmc for m in out}
        rows.append(f"| {label} (at step {K}) | {cells[0]} | {cells[1]} | "
                    f"{out['taylor'][0] / out['poly'][0]:.2f} | "
                    f"{wr['taylor'].mean():.2f} ({wr['taylor'].min():.2f}..{wr['taylor'].max():.2f}) | "
                    f"{wr['poly'].mean():.2f} ({wr['poly'].min():.2f}..{wr['poly'].max():.2f}) |")
        print(rows[-1], flush=True)
    load1 = os.getloadavg()[0]
    threads = ", ".join(f"{k}={os.environ.get(k, 'unset')}" for k in ("OPENBLAS_NUM_THREADS",))
    text = ("## poly (conservative polynomialization)\n\n"
            f"`benchmarks/bench_poly.py` ({time.strftime('%Y-%m-%d')}, this machine: 2 cores, shared; "
            f"{threads}; 1-minute load average {load0:.1f} at the start and {load1:.1f} at the end).  "
            f"`poly` against `taylor` with the same options, CPU (process time) median of "
            f"{args.reps} warm runs (min..max); widths at the last step both reached over the widths "
            "of 2,000 `mc` samples in 50 random position directions (mean, min..max; the samples are "
            "an inner approximation, so the ratios overstate the conservatism).\n\n"
            + "\n".join(rows) + "\n")
    print(text)
    if args.write:
        replace_markdown_section(DOCS, text)


if __name__ == "__main__":
    main()
