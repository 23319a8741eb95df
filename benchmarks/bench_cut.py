"""Benchmark ``cut`` (Jain et al.) against the stochastic Monte Carlo, in one process.

1. Speed: CUT8 moment propagation (default: rule over the 5 states the step depends on; and the
   paper's full 6-D rule) vs the paper's 10,000-sample Monte Carlo (same Euler step map, both as
   fused C kernels, same horizon) on shuttle-reentry (2000 steps) and glider-reentry (1200 steps),
   warm; the one-off setup (rule solves, kernel compiles on an empty cache) is timed separately.
2. Accuracy at equal cost: UT / CUT4 / CUT6 / CUT8 vs a large Monte Carlo (glider, 100,000
   samples): max over states and report times of |mean error| / sigma and |std error| / sigma,
   next to a Monte Carlo with as many samples as the rule has state points (equal cost).

``python benchmarks/bench_cut.py [--truth 100000] [--write]``; ``--write`` updates the
``## CUT`` section of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import ocreach
from ocreach.dynamics.stochastic_mc import stochastic_monte_carlo
from ocreach.fileio import replace_markdown_section
from ocreach.outdir import benchmarks_doc
from ocreach.reach.cut import standard_rule
from ocreach.registry import get_problem

ROOT = Path(__file__).resolve().parents[1]


def _best(fn, repeat=2):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def cold_setup(pid: str) -> dict:
    """One-off costs on an empty cache (a fresh OCREACH_CACHE_DIR, in-process caches cleared):
    CUT rule solves, C generation + compilation of the cut kernel and of the MC kernel."""
    import os
    import tempfile

    from ocreach.dynamics import quadrature as q

    old = os.environ.get("OCREACH_CACHE_DIR")
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["OCREACH_CACHE_DIR"] = str(Path(tmp) / "jit")
        try:
            q._solve_cut.cache_clear()
            q._cut_arrays.cache_clear()
            p = get_problem(pid)
            t0 = time.perf_counter()
            standard_rule("cut", 5, 8), standard_rule("cut", 6, 8), standard_rule("cut", 2, 8)
            rules = time.perf_counter() - t0
            from ocreach.dynamics.stochastic_mc import step_map_for
            from ocreach.native.cut_kernel import cut_kernel
            from ocreach.native.mc_kernel import mc_kernel

            sm = step_map_for(p)
            t0 = time.perf_counter()
            cut_kernel(sm)
            cc_cut = time.perf_counter() - t0
            t0 = time.perf_counter()
            mc_kernel(sm)
            cc_mc = time.perf_counter() - t0
        finally:
            if old is None:
                os.environ.pop("OCREACH_CACHE_DIR", None)
            else:
                os.environ["OCREACH_CACHE_DIR"] = old
    return {"rules": rules, "cc_cut": cc_cut, "cc_mc": cc_mc}


def speed(pid: str) -> dict:
    """Warm timings (rules solved, kernels compiled), best of 3 (cut) / 2 (MC), same process."""
    p = get_problem(pid)
    ocreach.reach(p, "cut"), ocreach.reach(p, "cut", reduce=False)  # warm-up: rules, kernels
    stochastic_monte_carlo(p, samples=100, seed=0, times=[p.grid[-1]])
    t_cut, r = _best(lambda: ocreach.reach(p, "cut"), 3)
    t_full, rf = _best(lambda: ocreach.reach(p, "cut", reduce=False), 3)
    t_mc, _ = _best(lambda: stochastic_monte_carlo(p, samples=10000, seed=0, times=[p.grid[-1]]), 2)
    return {"problem": pid, "steps": p.n_segments, "cut": t_cut, "full": t_full, "mc": t_mc,
            "points": r.meta["points_x"], "points_full": rf.meta["points_x"],
            "points_u": r.meta["points_u"], **cold_setup(pid)}


def errors(p, mean, std, ref) -> tuple[float, float]:
    idx = ref["index"]
    s = ref["std"]
    live = s > 0
    em = np.abs(mean[idx] - ref["mean"])[live] / s[live]
    es = np.abs(std[idx] - s)[live] / s[live]
    return float(em.max()), float(es.max())


def accuracy(truth_samples: int) -> tuple[list[dict], dict]:
    p = get_problem("glider-reentry")
    T = p.extra["report_times"]
    t0 = time.perf_counter()
    ref = stochastic_monte_carlo(p, samples=truth_samples, seed=12345, times=T)
    t_ref = time.perf_counter() - t0
    rows = []
    for rule, order, label, red in (("ut", 4, "UT", True), ("cut", 4, "CUT4", True),
                                    ("cut", 6, "CUT6", True), ("cut", 8, "CUT8", True),
                                    ("cut", 8, "CUT8 6-D", False)):
        ocreach.reach(p, "cut", rule=rule, order=order, reduce=red)  # setup outside the timing
        t_cut, r = _best(lambda: ocreach.reach(p, "cut", rule=rule, order=order, reduce=red), 3)
        em, es = errors(p, r.meta["mean"], r.meta["std"], ref)
        M = r.meta["points_x"]
        # Monte Carlo at equal cost: as many samples as state points (median over 5 seeds)
        e_mc = []
        t_mc = 0.0
        for seed in range(5):
            t1 = time.perf_counter()
            mc = stochastic_monte_carlo(p, samples=max(M, 2), seed=100 + seed, times=T)
            t_mc += (time.perf_counter() - t1) / 5
            e_mc.append(errors(p, mc["grid_mean"], mc["grid_std"], ref))
        e_mc = np.median(np.array(e_mc), axis=0)
        rows.append({"rule": label, "points": M, "points_u": r.meta["points_u"], "time": t_cut,
                     "err_mean": em, "err_std": es, "mc_time": t_mc,
                     "mc_err_mean": float(e_mc[0]), "mc_err_std": float(e_mc[1])})
    return rows, {"samples": truth_samples, "time": t_ref,
                  "se_mean": 1 / np.sqrt(truth_samples), "se_std": 1 / np.sqrt(2 * truth_samples)}


def report(sp: list[dict], rows: list[dict], ref: dict) -> str:
    out = ["Generated by `python benchmarks/bench_cut.py --write` (one process; 2 shared cores, warm",
           "timings are best of 3 (cut) and 2 (MC)).  Both sides run fused C kernels built from the",
           "same CasADi model: `cut` the whole-horizon moment recursion (ocreach/native/cut_kernel.py),",
           "the MC its steps and per-step mean/std in blocks of <= 64 steps (NumPy draws the normals).",
           "", "**Speed: CUT8 vs the paper's 10,000-sample Monte Carlo** (equal horizon, same Euler map)", "",
           "| problem | steps | cut [s] (355 + 21 pts) | cut full 6-D [s] (745 + 21 pts) | MC 10k [s] "
           "| MC / cut | MC / cut full 6-D |",
           "|---|---|---|---|---|---|---|"]
    for s in sp:
        out.append(f"| {s['problem']} | {s['steps']} | {s['cut']:.3f} | {s['full']:.3f} | {s['mc']:.2f} "
                   f"| **{s['mc'] / s['cut']:.0f}x** | {s['mc'] / s['full']:.0f}x |")
    out += ["", "One-off setup on an empty cache (then cached on disk under ~/.cache/ocreach): solving "
            "the CUT8 rules (n = 5, 6 and 2), generating + compiling the cut kernel and the MC kernel.", "",
            "| problem | CUT8 rule solves [s] | compile cut kernel [s] | compile MC kernel [s] "
            "| MC / cut incl. cut's one-off setup | same, MC incl. its compile |",
            "|---|---|---|---|---|---|"]
    for s in sp:
        cold_cut = s["cut"] + s["rules"] + s["cc_cut"]
        out.append(f"| {s['problem']} | {s['rules']:.2f} | {s['cc_cut']:.2f} | {s['cc_mc']:.2f} "
                   f"| {s['mc'] / cold_cut:.1f}x | {(s['mc'] + s['cc_mc']) / cold_cut:.1f}x |")
    out += ["", f"**Accuracy at equal cost** (glider-reentry, truth: MC with {ref['samples']} samples, "
            f"{ref['time']:.1f} s; its own standard errors are {ref['se_mean']:.4f} sigma (mean) and "
            f"{ref['se_std']:.4f} sigma (std)).  Errors are the max over the 6 states and t = 1, 30, "
            "60, 120 s, in units of the truth's sigma; `MC@M` is a Monte Carlo with as many samples "
            "as the rule has state points (median of 5 seeds).  Rules are over the 5 states the step "
            "depends on (default `reduce=True`) unless marked 6-D.", "",
            "| rule | x points | u points | time [s] | mean err | std err | MC@M time [s] | MC@M mean err | MC@M std err |",
            "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['rule']} | {r['points']} | {r['points_u']} | {r['time']:.3f} | {r['err_mean']:.4f} | "
                   f"{r['err_std']:.4f} | {r['mc_time']:.3f} | {r['mc_err_mean']:.4f} | {r['mc_err_std']:.4f} |")
    out += ["", NOTES.strip()]
    return "\n".join(out)


NOTES = """
Reading: the 20x target is **met** by the default `cut` (CUT8 over the 5 states the Euler step
depends on): about 30-35x warm on both problems; the paper's full 6-D CUT8 (745 points) is about
15x, close to its evaluation-count bound 10,000 / (745 + 21) = 13 times the cost ratio of one MC
step (drift, gain and control map, 9 transcendentals) to one CUT point (drift and gain, 7).  What
closed the earlier gap (4x): (1) one fused C kernel for the whole horizon (semidefinite Cholesky,
points, model, weighted sums; no Python per step; the previous ~20 NumPy calls per step cost more
than the model), (2) `G_d C_h G_d^T` generated symbolically so the structural zeros of G cost
nothing (halved the kernel time), (3) ellipsoids built on access instead of 2001 per run,
(4) the longitude enters the step only through the identity, so integrating over the other 5 states
and adding the longitude's conditional covariance is exact under the Gaussian closure and halves
the points (option `reduce`, default on).  The MC peer got the same treatment (one C call per block
of steps, including the per-step mean/std; 7.5-10 s before, same random stream, bit-identical
results), so the ratio is not bought by a slow peer; its remaining Python cost is NumPy's normal
draws.  One-off setup: on an empty cache the CUT8 rule solves (n = 5, 6, 2) take a few seconds and
each kernel compile about 0.5 s, so a first-ever call can be *slower* than the MC (0.4-1.2x measured); both are
then cached on disk (rules re-verified on load), and every later process sees the warm ratio.
At equal cost (an MC with as many samples as the rule has points) every rule is 7-80x more
accurate than the MC; CUT4-CUT8 sit at the truth's own noise floor on the glider.
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--truth", type=int, default=100000)
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args(argv)
    sp = [speed("shuttle-reentry"), speed("glider-reentry")]
    for s in sp:
        print(f"{s['problem']}: cut {s['cut']:.3f} s (full 6-D {s['full']:.3f} s), MC 10k {s['mc']:.2f} s, "
              f"MC/cut = {s['mc'] / s['cut']:.1f}x ({s['mc'] / s['full']:.1f}x); one-off: rules "
              f"{s['rules']:.2f} s, compile {s['cc_cut']:.2f} s")
    rows, ref = accuracy(args.truth)
    text = report(sp, rows, ref)
    print(text)
    if args.write:
        doc = benchmarks_doc(ROOT / "docs" / "benchmarks.md")
        replace_markdown_section(doc, "## CUT\n\n" + text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
