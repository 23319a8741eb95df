"""One ARCH-COMP instance: warm-up, timed guaranteed reachability, spec checks on the tubes,
measures on the final sets, and the sampled-truth check (:mod:`ocreach.arch.truth`); the suite of
instances, one after the other or on a process pool.

Each instance's guaranteed method and its options are part of the suite definition
(``problems/arch.py``: ``extra["arch"]["method"]`` and the problem's ``method_options``), the same
for every run.  A run that stops early keeps its partial sets, which are checked against the
sampled truth up to where they got (``computed_to``).

The reported ``time`` is, as in the ARCH-COMP reports, the wall time of computing the reachable set
and checking the specifications, after a warm-up run over the first grid steps that builds and
compiles the model functions (the one-off cost a tool's start-up or JIT pays; it is reported apart
as ``warmup_s``).  The truth check is not timed into it.  ``cpu_s`` holds the CPU seconds of each
phase, which the machine's load does not inflate.
"""
from __future__ import annotations

import dataclasses
import platform
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.errors import OcreachError, ProblemError
from ocreach.specs import check, overall

#: the guaranteed method of an instance whose suite definition names none
METHOD = "taylor"


def arch_ids(only: str | None = None) -> list[str]:
    """Ids of the bundled ARCH problems, in the order of ``problems/arch.py``; ``only`` keeps those
    whose id, ARCH-COMP benchmark name or ``BENCHMARK-INSTANCE`` matches one of its
    comma-separated names (case-insensitive)."""
    from ocreach.registry import problem_factories

    ids = [pid for pid in problem_factories() if pid.startswith("arch-")]
    import ocreach.problems.arch as arch

    order = list(arch.PROBLEMS)
    ids.sort(key=lambda p: order.index(p) if p in order else len(order))
    if not only:
        return ids
    wanted = [w.strip().lower() for w in only.split(",") if w.strip()]
    out = []
    for pid in ids:
        bench = pid.split("-")[1]
        keys = {pid, pid.removeprefix("arch-"), bench}
        if any(w in keys for w in wanted):
            out.append(pid)
    if not out:
        benches = sorted({p.split("-")[1].upper() for p in ids})
        raise ProblemError(f"--only {only!r} matches no ARCH instance; benchmarks: {benches}; "
                           f"instances: {[p.removeprefix('arch-') for p in ids]}")
    return out


@dataclass
class InstanceRun:
    """The row of one instance (ARCH-COMP format plus what the suite adds)."""

    problem_id: str
    benchmark: str
    instance: str
    method: str
    result: str = "unknown"
    time: float = float("nan")
    reach_s: float = float("nan")
    check_s: float = float("nan")
    warmup_s: float = float("nan")
    accuracy: float | None = None
    accuracy_label: str = ""
    measures: dict[str, float] = field(default_factory=dict)
    timesteps: int = 0
    specs: list[dict[str, Any]] = field(default_factory=list)
    paths: dict[str, Any] = field(default_factory=dict)
    error: str = ""
    truth: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    #: the guaranteed sets enclose every run up to this time (the horizon, or where the method
    #: stopped)
    computed_to: float = float("nan")
    #: CPU seconds of this process per phase (warm-up, reach with the spec checks, truth): the
    #: cost apart from the machine's load
    cpu_s: dict[str, float] = field(default_factory=dict)
    #: the guaranteed method stopped before the horizon (its partial sets are what was computed)
    stopped: bool = False

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def machine() -> str:
    """A one-line description of this machine (CPU model and count)."""
    import os

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{cpu}, {n} cores available, Python {platform.python_version()}"


def _short(problem):
    """The problem over its first grid steps, same model objects (for the warm-up)."""
    g = problem.grid
    return dataclasses.replace(problem, grid=g[: min(3, g.size)])


def _reach(problem, method: str):
    from ocreach.reach.base import reach

    return reach(problem, method)


def _steps(problem, result) -> int:
    if hasattr(result, "pieces"):
        return int(result.meta.get("steps", 0))
    return int(sum(result.meta.get("steps", {}).get("substeps", [])))


def suite_method(problem) -> str:
    """The guaranteed method the suite definition gives an instance (``extra["arch"]["method"]``
    of its problem, :data:`METHOD` if it names none)."""
    return str(problem.extra["arch"].get("method", METHOD))


def _computed_to(problem, result) -> float:
    """How far a (possibly partial) guaranteed result encloses every run."""
    if hasattr(result, "pieces"):
        return float(result.meta.get("valid_until", problem.t_final))
    return float(result.times[len(result.sets) - 1])


def run_instance(pid: str, *, method: str | None = None, samples: int = 2000, seed: int = 0,
                 truth_stride: int = 1, warmup: bool = True) -> tuple[InstanceRun, Any, Any]:
    """Run one instance with ``method`` (default: the suite definition's, :func:`suite_method`);
    returns the row, the problem and the guaranteed result (None if it failed before any set).

    A method failure (e.g. the remainder cannot be enclosed) is the row's ``error`` and makes the
    result ``unknown``, with the reason; the part computed before it (the method's partial
    result) is still measured against the sampled truth up to where it stopped
    (``computed_to``), and drawn."""
    from ocreach.registry import get_problem

    problem = get_problem(pid)
    info = problem.extra["arch"]
    method = method or suite_method(problem)
    run = InstanceRun(pid, info["benchmark"], info["instance"], method,
                      options={**problem.options_for(method), "hybrid": problem.options_for("hybrid")})
    if warmup:
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            _reach(_short(problem), method)
        except OcreachError:
            pass
        run.warmup_s = time.perf_counter() - t0
        run.cpu_s["warm-up"] = time.process_time() - c0
    ver = problem.extra["verification"]
    names = problem.model.state_names
    c0 = time.process_time()
    t0 = time.perf_counter()
    try:
        res = _reach(problem, method)
        partial = False
    except OcreachError as exc:
        run.reach_s = time.perf_counter() - t0
        run.error = f"{type(exc).__name__}: {exc}"
        run.result = "unknown"
        res, partial = getattr(exc, "partial", None), True
        run.stopped = True
        if res is None:
            return run, problem, None
    if not partial:
        run.reach_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        spec_results = [check(s, res, names) for s in ver.specs]
        run.check_s = time.perf_counter() - t1
        run.time = run.reach_s + run.check_s
        run.specs = [r.as_dict() for r in spec_results]
        run.result = _verdict(problem, res, spec_results, run)
        finals = res.final_sets if hasattr(res, "pieces") else [res.sets[-1]]
        fnames = res.names if hasattr(res, "pieces") else names
        for m in ver.measures:
            run.measures[m.label] = float(m.of_sets(finals, fnames))
        if ver.measures:
            run.accuracy_label = ver.measures[0].label
            run.accuracy = run.measures[run.accuracy_label]
    run.cpu_s["reachable set and specs"] = time.process_time() - c0
    run.computed_to = _computed_to(problem, res)
    run.timesteps = _steps(problem, res)
    if samples:
        from ocreach.arch.truth import continuous_truth, hybrid_truth

        fn = hybrid_truth if hasattr(res, "pieces") else continuous_truth
        c0 = time.process_time()
        run.truth = fn(problem, res, samples=samples, seed=seed, stride=truth_stride).as_dict()
        run.cpu_s["sampled truth"] = time.process_time() - c0
        _contradictions(run)
    return run, problem, res


def _contradictions(run: InstanceRun) -> None:
    """A verified instance whose sampled truth breaks a spec, or leaves the guaranteed sets (which
    then prove nothing), is a soundness defect: the row says so and is not reported verified."""
    tr = run.truth
    why = []
    if tr.get("escapes"):
        why.append(f"{tr['escapes']} sampled state(s) outside the guaranteed sets (e.g. "
                   f"{tr['escape_example']})")
    if run.result == "verified" and tr.get("violations"):
        why.append("sampled truth contradicts the verification: "
                   + "; ".join(f"{k}: {v['detail']}" for k, v in tr["violations"].items()))
    if why:
        run.result = "unknown"
        run.error = "; ".join(why + ([run.error] if run.error else []))


def _verdict(problem, res, spec_results, run: InstanceRun) -> str:
    """``overall`` of the specs; a hybrid instance with jump-count requirements (LOVO21) also
    needs final sets with each of those jump counts; a result cut short (``truncated``, or fewer
    sets than grid times) is ``unknown``; an instance without specs or requirements is
    ``verified`` when the reachable set was computed (the report's convention for ROBE21)."""
    need = problem.extra["verification"].extra.get("final_jump_counts")
    if hasattr(res, "pieces"):
        counts = sorted({len(p) for p in res.final_paths()})
        run.paths = {"final_paths": [" -> ".join(p) for p in res.final_paths()],
                     "final_jump_counts": counts, "branches": len(res.branches)}
        if need is not None and not set(need) <= set(counts):
            return "unknown"
    if res.meta.get("truncated") or (not hasattr(res, "pieces")
                                     and len(res.sets) < problem.grid.size):
        return "unknown"  # the sets stop short of the horizon: nothing is proven after that
    if not spec_results:
        return "verified"
    return overall(spec_results)


def instance_task(pid: str, method: str | None, samples: int, seed: int,
                  truth_stride: int) -> tuple[InstanceRun, Any]:
    """:func:`run_instance` as a task of a process pool: plain data in, the row and the
    guaranteed result (arrays and set objects, no CasADi objects) out."""
    run, _problem, res = run_instance(pid, method=method, samples=samples, seed=seed,
                                      truth_stride=truth_stride)
    return run, res


def run_suite(ids: list[str], *, method: str | None = None, samples: int = 2000, seed: int = 0,
              truth_stride: int = 1, workers: int = 1, progress=None,
              on_done=None) -> list[InstanceRun]:
    """Run ``ids`` (each with ``method`` or the suite definition's); ``progress(text)`` is told
    each step, ``on_done(run, problem, result)`` gets each finished instance (the report writes
    its files as they finish).  ``workers > 1`` runs the instances on a process pool of that
    many workers (:func:`ocreach.sweep.executors.process_pool`, one BLAS thread each), the
    longest first; the rows come back in the order of ``ids``."""
    from ocreach.errors import check_count

    workers = check_count("workers", workers, 1)
    rows: dict[str, InstanceRun] = {}

    def finished(run: InstanceRun, problem, res) -> None:
        rows[run.problem_id] = run
        if progress:
            tr = run.truth
            extra = (f", truth: {tr['escapes']} escapes / {tr['points_checked']} points up to "
                     f"t = {tr['checked_to']:.4g}, {len(tr['violations'])} violated spec(s)"
                     ) if tr else ""
            acc = f", {run.accuracy_label} = {run.accuracy:.4g}" if run.accuracy is not None else ""
            why = f" -- {run.error[:200]}" if run.error else ""
            if np.isfinite(run.time):
                took = f"in {run.time:.2f} s"
            elif np.isfinite(run.computed_to):
                took = f"(sets to t = {run.computed_to:.4g}) after {run.reach_s:.2f} s"
            else:
                took = f"(no sets) after {run.reach_s:.2f} s"
            progress(f"[{len(rows)}/{len(ids)}] {run.problem_id} ({run.method}): {run.result} "
                     f"{took}{acc}{extra}{why}")
        if on_done:
            on_done(run, problem, res)

    if workers == 1 or len(ids) == 1:
        for i, pid in enumerate(ids):
            if progress:
                progress(f"[{i + 1}/{len(ids)}] {pid} ...")
            run, problem, res = run_instance(pid, method=method, samples=samples, seed=seed,
                                             truth_stride=truth_stride)
            finished(run, problem, res)
    else:
        from concurrent.futures import as_completed

        from ocreach.registry import get_problem
        from ocreach.sweep.executors import process_pool

        order = sorted(ids, key=lambda p: -COST.get(p, 0.0))
        with process_pool(min(workers, len(ids))) as pool:
            futs = {pool.executor.submit(instance_task, pid, method, samples, seed,
                                         truth_stride): pid for pid in order}
            if progress:
                progress(f"{len(ids)} instances on {pool.kind}")
            for fut in as_completed(futs):
                run, res = fut.result()
                finished(run, get_problem(futs[fut]), res)
    return [rows[pid] for pid in ids]


#: relative cost of the instances (wall seconds of reachable set and sampled truth with the suite
#: definition, 2,000 samples, truth stride 10, 2026-12-03 on 2 shared cores under a load of
#: about 6): the pool starts the longest first so that its workers finish close together
COST: dict[str, float] = {
    "arch-cvdp20-mu1": 430, "arch-prde20-ip": 350, "arch-prde20-p": 270, "arch-cvdp20-mu2": 256,
    "arch-robe21-1": 180, "arch-spre22": 160, "arch-robe21-3": 122, "arch-lalo20-w001": 113,
    "arch-robe21-2": 91, "arch-quad20-d04": 85, "arch-quad20-d08": 82, "arch-lalo20-w005": 78,
    "arch-quad20-d01": 75, "arch-cvdp23": 66, "arch-prde20-i": 61, "arch-lalo20-w01": 59,
    "arch-lovo21": 58}


def summary_line(rows: list[InstanceRun]) -> str:
    n = len(rows)
    v = sum(r.result == "verified" for r in rows)
    esc = sum(r.truth.get("escapes", 0) for r in rows if r.truth)
    t = float(np.nansum([r.time for r in rows]))
    return f"{v}/{n} verified, total time {t:.1f} s, {esc} truth escapes"
