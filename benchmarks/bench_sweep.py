"""Sweep engine: catalog speed-up on 2 local workers, per-task overhead of Dask vs the process pool,
and a paper estimate for a 64-core cluster.

    python benchmarks/bench_sweep.py [--write] [--objects 1000] [--tiny 400]

Rows: (1) the ``examples/sweep_catalog.json`` catalog (``--objects`` objects x 3 horizons of ffoe
with 50 directions) run serially in this process and on a 2-worker process pool, wall clock of
``run_sweep`` including worker start-up, kernel loading and the driver's fsynced log (target
>= 1.8x); (2) ``--tiny`` near-empty tasks (Monte Carlo with one sample on ``vdp``) on the process
pool and on a Dask LocalCluster, both with 2 workers: overhead per task = wall x workers / tasks -
mean task time; (3) the driver's cost per record (append + fsync); (4) an estimate for 10^4
objects x 3 thrust levels x 5 horizons on 64 cores from the measured per-task costs (task time
linear in the horizon, fitted on the catalog run).  With ``--write`` the ``## Sweep`` section of
docs/benchmarks.md is replaced.
"""
from __future__ import annotations

import argparse
import itertools
import json
import multiprocessing
import os
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ocreach.fileio import replace_markdown_section
from ocreach.outdir import benchmarks_doc
from ocreach.sweep import Spec, run_sweep, spec_from_dict
from ocreach.sweep.executors import ExecutorHandle, single_thread_env
from ocreach.sweep.store import LOG, Store

ROOT = Path(__file__).resolve().parents[1]
DOCS = benchmarks_doc(ROOT / "docs" / "benchmarks.md")


def _records(out: Path) -> list[dict]:
    return [json.loads(ln) for ln in (out / LOG).read_text().splitlines()]


def _run(spec, tmp: Path, name: str, **kw) -> tuple[float, list[dict]]:
    out = tmp / name
    t0 = time.perf_counter()
    s = run_sweep(spec, out, progress=False, **kw)
    wall = time.perf_counter() - t0
    if s.failed:
        raise RuntimeError(f"{name}: {s.failed} task(s) failed")
    return wall, _records(out)


def _own_session_init() -> None:
    """Pool worker start for the benchmark's second pool: its own session (Linux autogroup)."""
    from ocreach.sweep.executors import _worker_init

    os.setsid()
    _worker_init()


def own_session_pool(workers: int) -> ExecutorHandle:
    """A process pool whose workers each run in their own session.  With the kernel's
    ``sched_autogroup`` (on here) CPU time is shared between sessions, not processes, so a
    driver and its workers in one session get one session's share of a busy machine however
    many workers there are; in their own sessions the workers compete like separate jobs (what
    a dedicated machine or cluster gives anyway).  Passed to ``run_sweep(executor=...)``."""
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_own_session_init)
    with single_thread_env():
        for f in [pool.submit(os.getpid) for _ in range(workers)]:
            f.result()
    return ExecutorHandle(pool, workers, "own-session pool", [lambda: pool.shutdown(wait=True)])


def session_share(work: int = 4_000_000) -> dict:
    """CPU-bound pure-Python loops: throughput of 2 processes (same session / own sessions)
    relative to 1 process, on this machine now (what any 2-worker speed-up is capped by)."""
    code = f"x = 0\nfor i in range({work}): x += i\n"

    def thr(n: int, new_session: bool) -> float:
        t0 = time.perf_counter()
        procs = [subprocess.Popen([sys.executable, "-c", code], start_new_session=new_session)
                 for _ in range(n)]
        for p in procs:
            p.wait()
        return n / (time.perf_counter() - t0)

    one = thr(1, False)
    return {"same": thr(2, False) / one, "own": thr(2, True) / one}


def catalog_speedup(objects: int, tmp: Path, rounds: int = 4) -> dict:
    """Serial vs a 2-worker process pool (and a 2-worker pool in own sessions) on the catalog,
    alternating over ``rounds`` slices of the objects (so a change in the machine's load hits all
    alike); each pool is started once, its start-up timed and added to its total."""
    from ocreach.sweep.executors import process_pool

    raw = json.loads((ROOT / "examples" / "sweep_catalog.json").read_text())
    full = spec_from_dict(raw, base_dir=ROOT / "examples")
    n = min(objects, 1000) * 3
    spec = Spec(tasks=full.tasks[:n], raw=raw, base_dir=full.base_dir)  # the first objects
    bounds = np.linspace(0, n // 3, rounds + 1).astype(int) * 3
    wall = {"serial": 0.0, "pool": 0.0, "own": 0.0}
    recs: dict[str, list] = {k: [] for k in wall}
    start = {}
    t0 = time.perf_counter()
    pool = process_pool(2)
    start["pool"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    own = own_session_pool(2)
    start["own"] = time.perf_counter() - t0
    try:
        for r, (a, b) in enumerate(itertools.pairwise(bounds)):
            part = Spec(tasks=spec.tasks[a:b], raw={"slice": [int(a), int(b)]}, base_dir=spec.base_dir)
            for name, kw in (("serial", {"serial": True}), ("pool", {"executor": pool.executor}),
                             ("own", {"executor": own.executor})):
                # the serial run has one BLAS/OpenMP thread, as each worker does
                # (ocreach.sweep.executors.serial_executor)
                dt, rr = _run(part, tmp, f"{name}{r}", **kw)
                wall[name] += dt
                recs[name] += rr
    finally:
        pool.close()
        own.close()
    by_h: dict[float, list[float]] = {}
    for t, rec in zip(spec.tasks, recs_in_spec_order(spec, recs["serial"])):
        by_h.setdefault(t["horizon"]["value"], []).append(rec["runtime_s"])
    med = {h: statistics.median(v) for h, v in sorted(by_h.items())}
    slope, intercept = np.polyfit(list(med), list(med.values()), 1)
    busy = {k: sum(r["runtime_s"] for r in v) for k, v in recs.items()}
    out = {"tasks": n, "objects": n // 3, "rounds": rounds, "t_serial": wall["serial"],
           "median_by_horizon": med, "fit": (intercept, slope),
           "mean_task": float(np.mean([r["runtime_s"] for r in recs["serial"]])),
           "busy_serial": busy["serial"] / wall["serial"]}
    for k in ("pool", "own"):
        out[k] = {"t": wall[k] + start[k], "t_warm": wall[k], "t_start": start[k],
                  "speedup": wall["serial"] / (wall[k] + start[k]),
                  "speedup_warm": wall["serial"] / wall[k],
                  # task time summed over tasks, per wall second: how busy the workers were
                  "busy": busy[k] / wall[k], "inflation": busy[k] / busy["serial"]}
    return out


def recs_in_spec_order(spec, recs):
    by_key = {r["key"]: r for r in recs}
    return [by_key[k] for k in spec.keys]


def overhead(tiny: int, tmp: Path) -> dict:
    """Per-task overhead on started, warmed executors (start-up timed separately)."""
    from ocreach.sweep.executors import dask_local, process_pool

    def spec(seed0: int):
        return spec_from_dict({"base": {"problem": "vdp", "method": "mc", "options": {"samples": 1}},
                               "product": {"options.seed": list(range(seed0, seed0 + tiny))}})

    out: dict = {"n": tiny}
    for name, start in (("pool", lambda: process_pool(2)), ("dask", lambda: dask_local(2))):
        t0 = time.perf_counter()
        with start() as handle:
            t_start = time.perf_counter() - t0
            _run(spec(10**6), tmp, f"warm_{name}", executor=handle.executor, max_in_flight=4,
                 chunk=1)
            for chunk in (1, 16):
                wall, recs = _run(spec(chunk * tiny), tmp, f"tiny_{name}_{chunk}",
                                  executor=handle.executor, max_in_flight=4, chunk=chunk)
                mean_task = float(np.mean([r["runtime_s"] for r in recs]))
                out[(name, chunk)] = {"wall": wall, "per_task": wall * 2 / tiny - mean_task,
                                      "mean_task": mean_task}
        out[name] = {"start": t_start}
    return out


def driver_cost(n: int, tmp: Path, batch: int) -> float:
    """Driver seconds per record: JSON line + write, one fsync per ``batch`` records."""
    spec = spec_from_dict({"base": {"problem": "vdp", "method": "mc"},
                           "product": {"options.seed": list(range(n))}})
    rec = {"status": "ok", "outputs": {f"o{i}": 0.1 * i for i in range(12)}, "runtime_s": 0.01,
           "worker": "host:1"}
    with Store.open(tmp / f"driver{batch}", spec) as store:
        t0 = time.perf_counter()
        for i, k in enumerate(spec.keys):
            store.append({**rec, "key": k}, sync=(i + 1) % batch == 0)
        return (time.perf_counter() - t0) / n


def estimate(cat: dict, ov: dict, t_rec: float, cores: int = 64) -> dict:
    """10^4 objects x 3 thrusts x 5 horizons (1, 2, 3, 5, 7 d) on ``cores`` single-threaded workers."""
    horizons = [1.0, 2.0, 3.0, 5.0, 7.0]
    a, b = cat["fit"]
    t_task = float(np.mean([a + b * h for h in horizons]))  # ffoe task time, linear in the horizon
    n = 10_000 * 3 * len(horizons)
    per = t_task + max(ov[("dask", 16)]["per_task"], 0.0)
    # how well the engine kept the 2 local workers fed (sum of task times / wall / workers); the
    # longer task times under the shared machine's contention are not the engine's and a
    # dedicated cluster does not have them
    eff = min(1.0, cat["pool"]["busy"] / 2)
    wall_workers = n * per / (cores * eff)
    wall_driver = n * t_rec
    return {"tasks": n, "t_task": t_task, "per_task": per, "eff": eff, "cores": cores,
            "wall_workers": wall_workers, "wall_driver": wall_driver,
            "wall": max(wall_workers, wall_driver), "cpu_h": n * per / 3600}


def _threads() -> str:
    env = {k: os.environ.get(k, "unset") for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    return ", ".join(f"{k}={v} in the driver" for k, v in env.items()) + "; workers 1 thread each"


def _autogroup() -> str:
    try:
        return Path("/proc/sys/kernel/sched_autogroup_enabled").read_text().strip()
    except OSError:
        return "unknown"


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def markdown(cat, ov, t_recs, est, objects, share, load) -> str:
    t_rec1, t_rec = t_recs
    subset = ("the full catalog" if objects >= 1000 else
              f"the first {objects} objects of the catalog (a documented subset)")
    med = ", ".join(f"{h:g} d {1e3 * t:.0f} ms" for h, t in cat["median_by_horizon"].items())
    a, b = cat["fit"]
    lines = [
        "## Sweep",
        "",
        "`python benchmarks/bench_sweep.py` (one run; 1-minute load average "
        f"{load[0]:.1f} at the start and {load[1]:.1f} at the end on {os.cpu_count()} cores, "
        f"{_threads()}; the serial run limited to 1 BLAS thread like the workers).  Serial and pool runs alternate over slices of the catalog so that "
        "load changes hit both alike.",
        "",
        "| benchmark | ocreach | peer | ratio | target |",
        "|---|---|---|---|---|",
        f"| `examples/sweep_catalog.json`, {subset}: {cat['tasks']} ffoe tasks (50 directions, "
        f"1/3/5 d) | 2-worker process pool {cat['pool']['t']:.1f} s (incl. "
        f"{cat['pool']['t_start']:.1f} s start-up) | serial (1 BLAS thread) {cat['t_serial']:.1f} s | "
        f"{cat['pool']['speedup']:.2f}x faster ({cat['pool']['speedup_warm']:.2f}x without the "
        "start-up) | >= 1.8x |",
        f"| the same, pool workers in their own sessions (see below) | "
        f"{cat['own']['t']:.1f} s (incl. {cat['own']['t_start']:.1f} s start-up) | serial "
        f"{cat['t_serial']:.1f} s | {cat['own']['speedup']:.2f}x faster "
        f"({cat['own']['speedup_warm']:.2f}x without the start-up) | >= 1.8x |",
        f"| busy workers (sum of task times / wall) | pool {cat['pool']['busy']:.2f} of 2, own "
        f"sessions {cat['own']['busy']:.2f} of 2 | serial {cat['busy_serial']:.2f} of 1 | task "
        f"times {cat['pool']['inflation']:.2f}x / {cat['own']['inflation']:.2f}x the serial ones | - |",
        f"| CPU-bound loop, 2 processes vs 1 (what this machine gives now) | same session "
        f"{share['same']:.2f}x, own sessions {share['own']:.2f}x the throughput | 1 process | - | "
        "- |",
        *[f"| overhead per task, {ov['n']} tiny tasks (vdp mc, 1 sample), 2 warm workers, chunk "
          f"{c} | Dask LocalCluster {1e3 * ov[('dask', c)]['per_task']:.2f} ms (wall "
          f"{ov[('dask', c)]['wall']:.2f} s) | process pool {1e3 * ov[('pool', c)]['per_task']:.2f} ms "
          f"(wall {ov[('pool', c)]['wall']:.2f} s) | "
          f"{ov[('dask', c)]['per_task'] / max(ov[('pool', c)]['per_task'], 1e-9):.1f}x | - |"
          for c in (1, 16)],
        f"| executor start-up, 2 workers | Dask LocalCluster {ov['dask']['start']:.1f} s | process "
        f"pool {ov['pool']['start']:.1f} s | - | - |",
        f"| driver cost per record (JSON line, write, fsync) | {1e3 * t_rec:.2f} ms with one fsync per "
        f"16 records (a chunk) | {1e3 * t_rec1:.2f} ms with one fsync per record | "
        f"{t_rec1 / t_rec:.1f}x | - |",
        "",
        f"Wall clocks include starting the workers (spawned processes import ocreach and load the "
        f"compiled kernels from the disk cache once each) and the driver's fsynced log.  Median ffoe "
        f"task time by horizon: {med} (fit {1e3 * a:.1f} ms + {1e3 * b:.1f} ms/day).  Overhead per "
        "task = wall x workers / tasks - mean task time, on workers started and warmed (kernels loaded) beforehand; the "
        "driver fsyncs once per batch of records that finished together.  A 2-core machine "
        "running the driver (and for Dask the scheduler) beside 2 workers and other people's "
        "jobs inflates these overheads.",
        "",
        "**Why the speed-up depends on the session.**  The kernel here shares CPU time between "
        "sessions (`sched_autogroup_enabled = "
        f"{_autogroup()}`), not between processes: when other sessions keep the cores busy, a "
        "driver and its two workers in one session get one session's share, and each task runs "
        "longer than in the serial run (the task-time ratio above, here "
        f"{cat['pool']['inflation']:.2f}x).  The busy-workers row shows whether the engine keeps "
        "both workers fed; the CPU-bound loop row shows what the machine gives.  With the workers "
        "in their own sessions (a `ProcessPoolExecutor` whose initializer calls `os.setsid()`, "
        "passed as `run_sweep(executor=...)`) they compete like separate jobs.  `ocreach sweep` "
        "keeps its workers in the caller's session (Ctrl-C and job control reach them; no unfair "
        "share on a shared machine).  Expected speed-up on a dedicated machine: busy pool / busy "
        f"serial = {cat['pool']['busy'] / cat['busy_serial']:.2f}x less the start-up.  " + (
            f"The default pool met the >= 1.8x target in this run ({cat['pool']['speedup']:.2f}x)."
            if cat['pool']['speedup'] >= 1.8 else
            f"The default pool did not meet the >= 1.8x target in this run "
            f"({cat['pool']['speedup']:.2f}x"
            + (f"; own-session workers {cat['own']['speedup']:.2f}x" if cat['own']['speedup'] >= 1.8 else "")
            + "): the machine was shared, see the load average above."),
        "",
        "**Estimate, 10^4 objects x 3 thrust levels x 5 horizons (1, 2, 3, 5, 7 d) on a 64-core "
        "Dask cluster** (paper arithmetic from the numbers above, not a measurement; the task times come from "
        "this machine (see its load above)): "
        f"{est['tasks']:,} tasks x ({1e3 * est['t_task']:.0f} ms mean ffoe task + "
        f"{1e3 * max(ov[('dask', 16)]['per_task'], 0):.1f} ms Dask overhead at chunk 16) = {est['cpu_h']:.1f} core-hours; "
        f"at the measured worker utilisation {est['eff']:.2f} (busy pool workers above) that is {_duration(est['wall_workers'])} "
        f"on 64 single-threaded workers; the driver writes {est['tasks']:,} records x "
        f"{1e3 * t_rec:.2f} ms = {_duration(est['wall_driver'])}, so the run takes about "
        f"{_duration(est['wall'])} ({'worker' if est['wall_workers'] >= est['wall_driver'] else 'driver'}-bound), "
        "plus one kernel load per worker process.  The ffoe thrust sweep (`FFOE.sweep`, one STM pass "
        "for all levels) would cut the 3 thrust levels to about one task's cost if they were one task.",
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true")
    ap.add_argument("--objects", type=int, default=1000)
    ap.add_argument("--tiny", type=int, default=400)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_sweep_") as tmp:
        tmp = Path(tmp)
        load_start = os.getloadavg()[0]
        share = session_share()
        print(f"2 CPU-bound processes vs 1: {share}")
        cat = catalog_speedup(args.objects, tmp)
        print(f"catalog: {cat}")
        ov = overhead(args.tiny, tmp)
        print(f"overhead: {ov}")
        t_rec1 = driver_cost(400, tmp, 1)
        t_rec = driver_cost(800, tmp, 16)
        print(f"driver cost per record {1e3 * t_rec1:.3f} ms (fsync each), {1e3 * t_rec:.3f} ms "
              "(fsync per 16)")
        est = estimate(cat, ov, t_rec)
        print(f"estimate: {est}")
    text = markdown(cat, ov, (t_rec1, t_rec), est, args.objects, share,
                    (load_start, os.getloadavg()[0]))
    print(text)
    if args.write:
        replace_markdown_section(DOCS, text)
        print(f"updated {DOCS}")


if __name__ == "__main__":
    main()
