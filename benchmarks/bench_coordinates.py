"""Regularised coordinates against the model's own: ``taylor`` in Cartesian, in modified equinoctial
elements (``mee``, ``mee-longitude``) on earth-mars and with a Sundman time transformation
(``sundman``) on nrho-9-2, in the same process.

Per row: the guaranteed horizon reached of the one asked (the run keeps its sets up to the step
where the remainder can no longer be enclosed), the warm wall time (median of ``--reps`` runs
after one warm-up run, caches and compiled kernels in place), its ratio to the paper's Table 1
time for earth-mars (Patel & Subbarao: 3.443 s for 200 d, 5.103 s for 300 d, MATLAB + CORA), and
on the first problem of each case, per row: the truth check (``--samples`` trajectories from
SciPy DOP853 at rtol 1e-12 on the numpy right-hand sides of ``tests/_reach_truth.py``, constant /
bang-bang / random thrust, every grid time the row reached, the first ``--tube-samples`` also at
the step midpoints in the step's tube; verified three-way membership of the sets enlarged by
``1e-9 (1 + |x|)``, :func:`ocreach.sets.pz_witness.classify_zonotope`: escapes / undecided /
points) and the width ratio set / samples in 50 random position directions at its last time.
Every timing row and every truth row is written to ``--out``/rows.json as it finishes (an
interrupted run keeps them) and printed.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_coordinates.py [--reps 3] [--samples 10000]
        [--tube-samples 2000] [--only earth-mars|nrho] [--out out/bench_coordinates] [--write]

``--write`` updates the ``## Regularised coordinates`` section of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import time
from pathlib import Path

import numpy as np

import ocreach
from ocreach.errors import SolverError
from ocreach.fileio import atomic_write_text, json_text, replace_markdown_section
from ocreach.registry import get_problem
from ocreach.sets.zonotope import Zonotope

DOCS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"
PAPER = {200: 3.443, 300: 5.103}
HOUR = 3600.0 / 375200.0
#: parts of taylor's splitting in every row (the setting of docs/validation's earth-mars rows)
MAX_PARTS = 8
#: the sets are enlarged by ABS_TOL (1 + |x|_inf) for the truth check (the truth's own error is far below)
ABS_TOL = 1e-9
CASES = {
    "earth-mars": [("cartesian", {}), ("mee", {}), ("mee", {"order": 30}), ("mee-longitude", {})],
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


def _truth_module():
    """``tests/_reach_truth.py``: SciPy DOP853 (rtol 1e-12) on numpy right-hand sides, the same
    independent truth as the tests."""
    path = Path(__file__).resolve().parents[1] / "tests" / "_reach_truth.py"
    spec = importlib.util.spec_from_file_location("_reach_truth", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def check(problem, results: dict, samples: int, tube_samples: int, save) -> dict:
    """Per row: escapes / undecided / points of ``samples`` trajectories (a third each constant,
    bang-bang and random thrust, the same for every row) at every grid time the row reached, and of
    the first ``tube_samples`` at the step midpoints in the step's tube
    (:func:`ocreach.sets.pz_witness.classify_zonotope`: a verified witness is inside, a verified
    separating direction outside, the rest undecided; the sets enlarged by ``1e-9 (1 + |x|)``), and
    the width ratio set / samples in 50 random position directions at its last time.  ``save(name,
    entry)`` is called after each row."""
    from ocreach.sets.pz_witness import classify_zonotope

    truth = _truth_module()
    K = max(r.times.size for r in results.values()) - 1
    sub = dataclasses.replace(problem, grid=problem.grid[: K + 1])
    rng = np.random.default_rng(11)
    n = samples // 3
    U = np.concatenate([truth.ball_controls(rng, m, K, law) for m, law in
                        ((n, "constant"), (n, "bang"), (samples - 2 * n, "random"))])
    X0 = truth.initial_samples(rng, problem.initial_set or Zonotope(problem.x0), samples)
    t0 = time.perf_counter()
    ends, mids = truth.simulate(sub, X0, U, inner=1)
    print(f"{problem.id}: {samples} trajectories over {K} steps in {time.perf_counter() - t0:.0f} s",
          flush=True)
    pos = list(problem.position_dims)
    D = np.random.default_rng(7).standard_normal((50, len(pos)))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    base = next(iter(results.values()))      # the first row: taylor in Cartesian coordinates

    def ratio_at(res, k):
        P = ends[:, k][:, pos]
        w_mc = (P @ D.T).max(axis=0) + (-P @ D.T).max(axis=0)
        S = res.sets[k].project(pos)
        return (S.support(D) + S.support(-D)) / w_mc

    def verdicts(S, P):
        v = classify_zonotope(S, P, ABS_TOL * (1.0 + float(np.abs(P).max())))
        return int(v.outside.sum()), int(v.undecided.sum())

    out = {}
    for name, res in results.items():
        t0 = time.perf_counter()
        k = res.times.size - 1
        e = {"checked_to_k": k, "samples": samples, "tube_samples": min(samples, tube_samples),
             "set_escapes": 0, "set_undecided": 0, "set_points": 0, "tube_escapes": 0,
             "tube_undecided": 0, "tube_points": 0}
        for j in range(k + 1):
            esc, und = verdicts(res.sets[j], ends[:, j])
            e["set_escapes"] += esc
            e["set_undecided"] += und
            e["set_points"] += samples
            if esc:
                print(f"  ESCAPE: {name}: {esc} of {samples} points outside the set at grid index {j}",
                      flush=True)
        for j in range(k):
            P = mids[:tube_samples, j, 0]
            esc, und = verdicts(res.tubes[j], P)
            e["tube_escapes"] += esc
            e["tube_undecided"] += und
            e["tube_points"] += P.shape[0]
            if esc:
                print(f"  ESCAPE: {name}: {esc} step midpoints outside the tube of step {j}", flush=True)
        ratio = ratio_at(res, k)
        k_b = min(k, base.times.size - 1)
        ratio_b = ratio_at(base, k_b)
        e.update({"width_ratio": [float(ratio.mean()), float(ratio.min()), float(ratio.max())],
                  "cartesian_width_ratio": float(ratio_b.mean()) if k_b == k else None,
                  "check_s": time.perf_counter() - t0})
        out[name] = e
        print(f"{problem.id} {name}: {e['set_escapes']} escapes / {e['set_undecided']} undecided of "
              f"{e['set_points']} set points, {e['tube_escapes']} / {e['tube_undecided']} of "
              f"{e['tube_points']} tube points ({e['check_s']:.0f} s)", flush=True)
        save(name, e)
    return out


def bench(case: str, reps: int, samples: int, tube_samples: int, save) -> list[str]:
    if case == "earth-mars":
        problems = [(get_problem("earth-mars", t_days=float(d)), f"{d} d", d) for d in (200, 300)]
        unit, scale = "d", None
    else:
        problems = [(get_problem("nrho-9-2"), "76 h", None)]
        unit, scale = "h", HOUR
    rows = ["| problem | coordinates | reached (of) | warm wall [s] | vs paper | stopped because |",
            "|---|---|---|---|---|---|"]
    first = {}
    for p, label, days in problems:
        step = p.extra["day_TU"] if scale is None else scale
        reached = {}
        for coords, extra in CASES[case]:
            opts = {"max_parts": MAX_PARTS, **extra}
            label_c = coords + "".join(f", {k}={v}" for k, v in extra.items())
            run(p, coords, **opts)   # warm-up: compiled kernels, CasADi and interval caches
            runs = [run(p, coords, **opts) for _ in range(reps)]
            wall = float(np.median([r[0] for r in runs]))
            _, res, stopped = runs[-1]
            reached[label_c] = res
            t_end = res.times[-1] / step
            paper = f"{PAPER[days] / wall:.2f}x" if days in PAPER and not stopped else "-"
            why = res.meta.get("failure", "") if stopped else ""
            why = (why[:90] + "...") if len(why) > 90 else why
            rows.append(f"| {p.id} {label} | {label_c} | {t_end:.0f} {unit} ({label}) | {wall:.2f} | "
                        f"{paper} | {why or '-'} |")
            print(rows[-1], flush=True)
            save(f"{p.id} {label} {label_c}", {"reached": float(t_end), "unit": unit,
                                               "warm_wall_s": wall, "stopped": stopped})
        if not first:
            first = reached
    p0 = problems[0][0]
    if samples:
        w = check(p0, first, samples, tube_samples,
                  lambda name, e: save(f"truth {p0.id} {problems[0][1]} {name}", e))
        rows += ["", (f"Truth on {p0.id} {problems[0][1]}: {samples} trajectories (SciPy DOP853, "
                 "rtol 1e-12, constant / bang-bang / random thrust) at every grid time each row "
                 f"reached, the first {min(samples, tube_samples)} also at the step midpoints; "
                 "verified three-way membership (escapes / undecided / points); width ratio set / "
                 "samples in 50 random position directions at the row's last time:"), "",
                 ("| coordinates | checked to | sets: escapes / undecided / points | "
                 "tubes: escapes / undecided / points | width ratio mean (min..max) | "
                 "Cartesian taylor's at that time |"),
                 "|---|---|---|---|---|---|"]
        for name, e in w.items():
            t_k = p0.grid[e["checked_to_k"]] / (p0.extra["day_TU"] if scale is None else scale)
            mean, lo, hi = e["width_ratio"]
            base = e["cartesian_width_ratio"]
            rows.append(f"| {name} | {t_k:.0f} {unit} | {e['set_escapes']} / {e['set_undecided']} / "
                        f"{e['set_points']} | {e['tube_escapes']} / {e['tube_undecided']} / "
                        f"{e['tube_points']} | {mean:.2f} ({lo:.2f}..{hi:.2f}) | "
                        f"{'-' if base is None else f'{base:.2f}'} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--samples", type=int, default=10000)
    ap.add_argument("--tube-samples", type=int, default=2000)
    ap.add_argument("--only", choices=sorted(CASES))
    ap.add_argument("--out", default="out/bench_coordinates",
                    help="folder of rows.json, written after every row")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "rows.json"
    saved = json.loads(path.read_text()) if path.exists() else {}

    def save(key: str, entry: dict) -> None:
        saved[key] = {**entry, "date": time.strftime("%Y-%m-%d %H:%M"),
                      "load_average_1min": os.getloadavg()[0]}
        atomic_write_text(path, json_text(saved, indent=1))

    load = os.getloadavg()[0]
    lines = ["## Regularised coordinates", "", (f"Measured {time.strftime('%Y-%m-%d')}, 2-core shared machine (load {load:.1f}), "
             f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, taylor "
             f"with max_parts {MAX_PARTS}, medians of {args.reps} warm runs."), ""]
    for case in ([args.only] if args.only else list(CASES)):
        lines += bench(case, args.reps, args.samples, args.tube_samples, save) + [""]
    text = "\n".join(lines)
    print(text, flush=True)
    if args.write:
        replace_markdown_section(DOCS, text)


if __name__ == "__main__":
    main()
