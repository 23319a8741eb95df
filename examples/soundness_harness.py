"""The soundness harness, long profile: every guaranteed method on hundreds of generated systems
and on every bundled problem with 10,000 truth samples; writes ``docs/validation/soundness.md``.

The CI profile of the same harness is ``tests/test_soundness_harness.py``; the harness itself is
``ocreach.testing`` (what is checked and how: its module docstrings).  Here:

* ``--systems`` (260) systems of the GENERAL population (seeds 0..N-1), ``--dominated`` (60)
  of the REMAINDER_DOMINATED population, ``--quadratic`` (60) of the QUADRATIC one and
  ``--disturbed`` (60) of the DISTURBED one (an additive disturbance set, the methods'
  ``disturbance`` option), each with ``--samples`` (90) truth trajectories, the
  tubes checked at a quarter, half and three quarters of every step and at both ends;
* every bundled problem on its first ``--bundled-steps`` (4) grid steps with
  ``--bundled-samples`` (10,000) trajectories at the grid times and ``--tube-samples`` (2,000 of
  them, evenly spread over every kind) in the tubes, where some guaranteed method returns sets
  (a problem that every method refuses is listed with the reasons, no truth is integrated);
* the harness's power: a copy of ``taylor`` with its remainder bound halved
  (``ocreach.testing.mutants``) on the same generated systems -- on how many it is caught.

    nice python examples/soundness_harness.py [--workers 2] [--quick]
        [--out docs/validation/soundness.md]

``--power``: only the power curve (copies of ``taylor`` with the remainder scaled by 0.5, 0.25,
0.1 and 0 on ``--power-systems`` (30) GENERAL systems, seeds 1000 on), which replaces its own
section of the page.

``--long PIDS``: only the whole-horizon check (comma-separated bundled problems, e.g.
``elliptic-earth,lunar-flyby``): each guaranteed method (``--methods``) is solved once on the
full problem to find how far it reaches, then checked by the harness over every step it reached
with ``--long-samples`` (2,000) trajectories, ``--tube-samples`` of them in the tubes; the table
replaces its own section of the page.

``--quick``: 12 + 6 + 6 systems, 2 bundled steps with 500 samples (a smoke run, about 5 minutes).
Progress (one line per finished system or problem) goes to stderr.
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import textwrap
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from ocreach.fileio import atomic_write_text, replace_markdown_section
from ocreach.testing import (
    DISTURBED,
    GENERAL,
    QUADRATIC,
    REMAINDER_DOMINATED,
    bundled_cases,
    generated_case,
    guaranteed_methods,
    run_method,
    seeded_system,
    summary,
)
from ocreach.testing.mutants import scaled_remainder_taylor

INNER = (0.25, 0.5, 0.75)
POPULATIONS = {"GENERAL": GENERAL, "REMAINDER_DOMINATED": REMAINDER_DOMINATED,
               "QUADRATIC": QUADRATIC, "DISTURBED": DISTURBED}
TRAILER = """## A new guaranteed method

Set the class attribute `guaranteed = True` on the method (`ocreach.reach.base.Method.guaranteed`:
read before anything is solved) and register it in `METHOD_PATHS`; the CI profile and this long
profile then run it on every generated system and bundled problem, with its default options,
and its results must say `meta["guaranteed"] = True`.  A hybrid automaton (a problem with an
`automaton`) is checked through its transitions (`ocreach.testing.truth.hybrid_truth`: each run
alone through SciPy's DOP853 with the guards and invariants as event functions; every state, and
the states just before and after each jump, against the flowpipe pieces of its location that
cover its time); a hybrid result without pieces is reported `no-truth` and a result without sets
on the time grid `no-sets` (failures).  A set type other than zonotopes, boxes, their unions and polynomial zonotopes is
checked by its support function only (weaker; the table would say so).
"""

INTRO = """# Validation: soundness of the guaranteed methods

Part of the [validation record](README.md).

## One harness for every guaranteed method

Every registered method whose class declares `guaranteed = True` (today: {methods}) is run, with
its default options, on generated systems and on every bundled problem, and checked against an
independent truth: SciPy's DOP853 at `rtol = 1e-12`, `atol = 1e-14` on a numpy coding of each
generated system (and on the model's `f` through a plain `casadi.Function` for a bundled
problem), from vertices, the centre and the inside of the initial set, under constant-vertex,
bang-bang, random and directed (extremal inputs of the linearised dynamics) piecewise-constant
inputs.  Every set at a grid time must contain every truth state at that time, and every
time-interval tube the states at both ends of its step and at a quarter, half and three quarters
of it; membership is the exact scaled gauge on zonotopes and their unions (sets enlarged by
`1e-9 (1 + |x|)`, gauge tolerance `1e-9`; a max gauge of 1 means every point was certified
inside).  A method that refuses a problem with `ProblemError` has refused it cleanly; one that
stops with `SolverError` has its partial sets checked; any other exception, or a result not
marked guaranteed, is a failure.  The harness is `ocreach.testing`; the CI profile is
`tests/test_soundness_harness.py`; this page is written by `examples/soundness_harness.py`
({run}).
"""


def system_task(args: tuple[str, int, int, tuple[str, ...], bool]):
    """The guaranteed ``methods`` (and, with ``mutant``, the halved-remainder copy of taylor) on
    system ``seed`` of ``population``."""
    population, seed, n_samples, methods, with_mutant = args
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    system = seeded_system(seed, POPULATIONS[population])
    case = generated_case(system)
    outs = [run_method(m, case, n_samples=n_samples, inner=INNER) for m in methods]
    mutant = (run_method(scaled_remainder_taylor(0.5), case, n_samples=n_samples, inner=INNER)
              if with_mutant else None)
    return population, seed, system.describe(), outs, mutant


POWER_FACTORS = (0.5, 0.25, 0.1, 0.0)
POWER_HEADING = "## Power of the harness on the GENERAL population"


def power_task(args: tuple[int, int]):
    """The scaled-remainder copies of :data:`POWER_FACTORS` on GENERAL system ``seed``."""
    seed, n_samples = args
    case = generated_case(seeded_system(seed, GENERAL))
    return seed, "", [run_method(scaled_remainder_taylor(f), case, n_samples=n_samples,
                                 inner=INNER) for f in POWER_FACTORS]


def power_section(rows, n_samples: int, workers: int, seconds: float) -> str:
    """The ``POWER_HEADING`` section from :func:`power_task` results."""
    seeds = [r[0] for r in rows]
    L = [POWER_HEADING, "",
         f"How small must the remainder bound be before the harness sees it on the GENERAL "
         f"population?  Copies of `taylor` with the remainder bound scaled by each factor, on "
         f"GENERAL seeds {min(seeds)}-{max(seeds)}, {n_samples} samples each (run "
         f"{datetime.date.today().isoformat()}, {platform.machine()}, {os.cpu_count()} cores "
         f"shared, {workers} worker(s), {seconds / 60:.1f} min).  Factor 0 drops the remainder: "
         "the plain linearisation.", "",
         "| remainder factor | systems run (>= 2 sets) | caught (>= 1 escape) |", "|---|---|---|"]
    for j, f in enumerate(POWER_FACTORS):
        ran = [r[2][j] for r in rows if r[2][j].sets_checked > 1]
        caught = sum(o.escapes > 0 for o in ran)
        L.append(f"| {f:g} | {len(ran)} | {caught} ({100 * caught / max(len(ran), 1):.0f} %) |")
    return "\n".join(L) + "\n"


def bundled_task(args: tuple[str, int, int, int, tuple[str, ...]]):
    pid, steps, n_samples, tube_samples, methods = args
    (case,) = bundled_cases(steps=steps, ids=[pid])
    outs = [run_method(m, case, n_samples=n_samples, inner=INNER, seed=1,
                       tube_samples=tube_samples) for m in methods]
    return pid, case.description, outs


LONG_HEADING = "## Bundled problems over the whole reached horizon"


def long_task(args: tuple[str, str, int, int]):
    """``method`` on bundled problem ``pid`` over every grid step it reaches on the full problem
    (one solve to find the reach, then the harness on the problem cut there)."""
    from ocreach.testing.harness import _solve

    pid, method, n_samples, tube_samples = args
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    (full,) = bundled_cases(steps=10**9, ids=[pid])
    result, status, reason = _solve(method, full.problem, dict(full.options))
    n_steps = full.problem.n_segments
    reached = 0 if result is None or not result.sets else len(result.sets) - 1
    if reached < 1:
        why = (f"{status}: {textwrap.shorten(reason.split(';')[0], 120, placeholder=' ...')}"
               if reason else status)
        return pid, f"{method}: no step reached ({why})", [], (reached, n_steps,
                                                              float(full.problem.grid[0]))
    (case,) = bundled_cases(steps=reached, ids=[pid])
    out = run_method(method, case, n_samples=n_samples, inner=INNER, seed=1,
                     tube_samples=tube_samples)
    return pid, f"{method}: {reached} of {n_steps} steps", [out], (
        reached, n_steps, float(case.problem.grid[-1]))


def long_section(rows, n_samples: int, tube_samples: int, workers: int, seconds: float) -> str:
    """The ``LONG_HEADING`` section from :func:`long_task` results."""
    L = [LONG_HEADING, "",
         f"Each method solved once on the full problem to find the steps it reaches with its "
         f"default options, then checked by the harness over all of them: {n_samples:,} truth "
         f"trajectories ({min(tube_samples, n_samples):,} of them in the tubes), every grid time "
         f"and the tubes at a quarter, half and three quarters of each step and at both ends (run "
         f"{datetime.date.today().isoformat()}, {platform.machine()}, {os.cpu_count()} cores "
         f"shared, {workers} worker(s), {seconds / 60:.1f} min).", "",
         "| problem | method | reached (steps) | t reached (model time units) | status | sets | "
         "tubes | points | escapes | max gauge | time [s] |", "|---" * 11 + "|"]
    for pid, desc, outs, (reached, n_steps, t_end) in rows:
        if not outs:
            method, why = desc.split(": no step reached (", 1)
            L.append(f"| `{pid}` | `{method}` | 0 / {n_steps} | - | {why[:-1].replace('|', '/')} "
                     "| | | | | | |")
        for o in outs:
            L.append(f"| `{pid}` | `{o.method}` | {reached} / {n_steps} | {t_end:.6g} | "
                     f"{o.status} | {o.sets_checked} | {o.tubes_checked} | "
                     f"{o.points_checked:,} | **{o.escapes}** | {o.max_gauge:.6g} | "
                     f"{o.seconds:.0f} |")
    bad = [o for r in rows for o in r[2] if not o.ok]
    L += ["", "Failures:", ""] + ([f"- {o.line()}" for o in bad] or ["- none"])
    return "\n".join(L) + "\n"


def _map(fn, tasks, workers: int):
    """``[fn(t) for t in tasks]`` on ``workers`` processes, a progress line per finished task."""
    t0 = time.perf_counter()

    def note(i: int, res) -> None:
        print(f"[{time.perf_counter() - t0:7.0f} s] {i + 1}/{len(tasks)} {res[0]} {res[1]}",
              file=sys.stderr, flush=True)

    if workers <= 1:
        out = []
        for i, t in enumerate(tasks):
            out.append(fn(t))
            note(i, out[-1])
        return out
    with ProcessPoolExecutor(workers) as pool:
        futures = {pool.submit(fn, t): i for i, t in enumerate(tasks)}
        out = [None] * len(tasks)
        for fut in as_completed(futures):
            out[futures[fut]] = fut.result()
            note(futures[fut], out[futures[fut]])
        return out


def _method_table(outcomes) -> list[str]:
    rows = ["| method | systems | complete | partial (SolverError, partial sets checked) | refused "
            "(ProblemError) | failures | sets checked | tubes checked | points checked | escapes "
            "| undecided (PZ) | support-only cases | max gauge | time [s] |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for m, r in summary(outcomes).items():
        rows.append(f"| `{m}` | {r['cases']} | {r['complete']} | {r['partial']} | {r['refused']} | "
                    f"{r['failed']} | {r['sets']:,} | {r['tubes']:,} | {r['points']:,} | "
                    f"**{r['escapes']}** | {r['undecided']} | {r['support_only']} | "
                    f"{r['max_gauge']:.6g} | {r['seconds']:.0f} |")
    return rows


def _failures(outcomes) -> list[str]:
    bad = [o for o in outcomes if not o.ok]
    return [f"- {o.line()}" for o in bad] or ["- none"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", type=int, default=260)
    ap.add_argument("--dominated", type=int, default=60)
    ap.add_argument("--quadratic", type=int, default=60)
    ap.add_argument("--disturbed", type=int, default=60)
    ap.add_argument("--samples", type=int, default=90)
    ap.add_argument("--bundled-steps", type=int, default=4)
    ap.add_argument("--bundled-samples", type=int, default=10_000)
    ap.add_argument("--tube-samples", type=int, default=2_000)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--power", action="store_true", help="only the power-curve section")
    ap.add_argument("--power-systems", type=int, default=30)
    ap.add_argument("--long", default="",
                    help="only the whole-horizon check of these comma-separated bundled problems")
    ap.add_argument("--long-samples", type=int, default=2_000)
    ap.add_argument("--methods", default="",
                    help="comma-separated guaranteed methods (default: every one; a subset skips "
                         "the halved-remainder copy)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "validation"
                                         / "soundness.md"))
    a = ap.parse_args()
    if a.quick:
        a.systems, a.dominated, a.quadratic, a.disturbed, a.bundled_steps = 12, 6, 6, 6, 2
        a.bundled_samples = a.tube_samples = 500
    t_start = time.perf_counter()
    if a.power:
        rows = _map(power_task, [(1000 + s, a.samples) for s in range(a.power_systems)], a.workers)
        text = power_section(rows, a.samples, a.workers, time.perf_counter() - t_start)
        print(text)
        print(f"written: {replace_markdown_section(a.out, text)}")
        return
    known = guaranteed_methods()
    methods = [m.strip() for m in a.methods.split(",") if m.strip()] or known
    unknown = sorted(set(methods) - set(known))
    if unknown:
        ap.error(f"--methods: {unknown} are not guaranteed methods; allowed: {known}")
    if a.long:
        from ocreach.registry import problem_factories

        pids = [p.strip() for p in a.long.split(",") if p.strip()]
        bad = sorted(set(pids) - set(problem_factories()))
        if bad:
            ap.error(f"--long: {bad} are not bundled problems; allowed: "
                     f"{sorted(problem_factories())}")
        rows = _map(long_task, [(pid, m, a.long_samples, a.tube_samples) for pid in pids
                                for m in methods], a.workers)
        text = long_section(rows, a.long_samples, a.tube_samples, a.workers,
                            time.perf_counter() - t_start)
        print(text)
        print(f"written: {replace_markdown_section(a.out, text)}")
        return
    with_mutant = set(methods) == set(known)
    from ocreach.registry import problem_factories

    tasks = ([("GENERAL", s, a.samples, tuple(methods), with_mutant) for s in range(a.systems)]
             + [("REMAINDER_DOMINATED", s, a.samples, tuple(methods), with_mutant)
                for s in range(a.dominated)]
             + [("QUADRATIC", s, a.samples, tuple(methods), with_mutant)
                for s in range(a.quadratic)]
             + [("DISTURBED", s, a.samples, tuple(methods), with_mutant)
                for s in range(a.disturbed)])
    done = _map(system_task, tasks, a.workers)
    t_gen = time.perf_counter() - t_start
    bundled = _map(bundled_task, [(pid, a.bundled_steps, a.bundled_samples, a.tube_samples,
                                   tuple(methods)) for pid in sorted(problem_factories())],
                   a.workers)
    t_all = time.perf_counter() - t_start

    run = (f"{'`--quick`, ' if a.quick else ''}{a.systems} + {a.dominated} + {a.quadratic} + "
           f"{a.disturbed} "
           f"systems, {a.samples} "
           f"samples each; bundled problems on {a.bundled_steps} grid steps with "
           f"{a.bundled_samples:,} samples, {min(a.tube_samples, a.bundled_samples):,} of them in "
           "the tubes")
    L = [INTRO.format(methods=", ".join(f"`{m}`" for m in methods), run=run),
         f"Run {datetime.date.today().isoformat()} on {platform.machine()} ({os.cpu_count()} "
         f"cores, shared), {a.workers} worker(s): {t_all / 60:.1f} min in total "
         f"({t_gen / 60:.1f} min for the generated systems).", ""]
    for pop in POPULATIONS:
        rows = [d for d in done if d[0] == pop]
        if not rows:
            continue
        outs = [o for d in rows for o in d[3]]
        L += [f"## Generated systems: {pop} (seeds 0-{len(rows) - 1})", ""]
        L += ["The population is `ocreach.testing.strategies." + pop + "` (its docstring gives the "
              "ranges); system `seed` is `seeded_system(seed, " + pop + ")`.", ""]
        L += _method_table(outs) + ["", "Failures:", ""] + _failures(outs) + [""]
    L += ["## Power of the harness: a halved remainder bound", "",
          "The same systems, run with a copy of `taylor` whose Lagrange remainder bound is "
          "multiplied by 0.5 (`ocreach.testing.mutants.scaled_remainder_taylor(0.5)`).  Where the "
          "interval bound of the remainder over the tube's box is loose by more than a factor 2 "
          "the halved copy can still contain every trajectory; the REMAINDER_DOMINATED "
          "population is built so that it is not, and the CI mutation check runs on its seeds "
          "0-7.", "",
          "| population | systems the copy ran on | caught (>= 1 escape) | median max gauge of the "
          "caught |", "|---|---|---|---|"]
    for pop in POPULATIONS:
        ms = [d[4] for d in done if d[0] == pop and d[4] is not None and d[4].sets_checked > 1]
        if not ms:
            continue
        caught = [m for m in ms if m.escapes]
        med = np.median([m.max_gauge for m in caught]) if caught else float("nan")
        L.append(f"| {pop} | {len(ms)} | {len(caught)} ({100 * len(caught) / len(ms):.0f} %) | "
                 f"{med:.4g} |")
    L += ["", f"## Bundled problems (first {a.bundled_steps} grid steps, "
          f"{a.bundled_samples:,} truth samples, {min(a.tube_samples, a.bundled_samples):,} in the "
          "tubes)", "",
          "| problem | method | status | sets | tubes | points | escapes | max gauge | note |",
          "|---|---|---|---|---|---|---|---|---|"]
    b_outs = []
    for pid, desc, outs in bundled:
        for o in outs:
            b_outs.append(o)
            note = o.reason.split(";")[0][:140].replace("|", "/") if o.reason else ""
            if o.truth_failure:
                note += f" truth: {o.truth_failure[:80]}"
            L.append(f"| `{pid}` | `{o.method}` | {o.status} | {o.sets_checked} | "
                     f"{o.tubes_checked} | {o.points_checked:,} | **{o.escapes}** | "
                     f"{o.max_gauge:.6g} | {note} |")
    L += ["", "Failures:", ""] + _failures(b_outs) + [""]
    all_outs = [o for d in done for o in d[3]] + b_outs
    total = sum(o.escapes for o in all_outs)
    L += ["## Summary", "",
          f"{total} escapes in {sum(o.points_checked for o in all_outs):,} checked truth points; "
          f"{sum(not o.ok for o in all_outs)} failed runs.", "", TRAILER]
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = "\n".join(L)
    for heading in (LONG_HEADING, POWER_HEADING):  # kept: the --long and --power runs' sections
        old = out.read_text() if out.is_file() else ""
        if heading in old:
            rest = old[old.index(heading):]
            nxt = rest.find("\n## ", 1)
            text = text.rstrip("\n") + "\n\n" + (rest if nxt < 0 else rest[:nxt + 1])
    atomic_write_text(out, text)
    print("\n".join(L))
    print(f"\nwritten: {out}")


if __name__ == "__main__":
    main()
