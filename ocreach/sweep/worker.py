"""What runs on a worker: build the task's problem (cached per process), solve, post-process.

Tasks arrive as plain data (:func:`ocreach.sweep.spec.normalize_task` plus the key); nothing
CasADi- or ctypes-backed crosses a process boundary.  Each worker process keeps its problems in
:data:`_PROBLEMS` (keyed by the canonical problem reference and overrides) so the models, their
cached CasADi Functions and the loaded compiled kernels are built once per process; the state
and horizon overrides are applied to a copy.  A task that raises becomes an ``"error"`` record
(type, message, traceback tail): the sweep goes on.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import socket
import tempfile
import threading
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.registry import split_file_id
from ocreach.sweep.catalog import UNITS
from ocreach.sweep.errors import SweepError
from ocreach.sweep.keys import canonical_json

if TYPE_CHECKING:
    from ocreach.problem import Problem

#: problems built in this process, oldest first (at most MAX_PROBLEMS are kept)
_PROBLEMS: dict[str, Any] = {}
MAX_PROBLEMS = 128
_THREADS_LIMITED = False
#: tasks in one process run one at a time (a threaded executor, e.g. a Dask worker with several
#: threads, would otherwise share the problem cache and CasADi objects between threads)
_TASK_LOCK = threading.Lock()
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
              "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


#: Units of a task's horizon: factor to seconds ("TU": the problem's own time unit).
HORIZON_UNITS = {"TU": None, "s": 1.0, "h": 3600.0, "d": 86400.0}


def split_problem_ref(ref: str) -> tuple[str, str | None]:
    """``"FILE.py:ID"`` -> ``("FILE.py", "ID")``; ``"FILE.py"`` -> ``("FILE.py", None)`` (the
    problem registry's own rule, :func:`ocreach.registry.split_file_id`)."""
    file_spec = split_file_id(ref)
    if file_spec is None:
        return ref, None
    return str(file_spec[0]), file_spec[1]


def limit_threads() -> None:
    """One BLAS/OpenMP thread in this process (threadpoolctl when installed; once per process).

    The process pool also starts its workers with :data:`THREAD_ENV` set to 1
    (:mod:`ocreach.sweep.executors`), which covers libraries loaded after this call.
    """
    global _THREADS_LIMITED
    if _THREADS_LIMITED:
        return
    _THREADS_LIMITED = True
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    threadpool_limits(1)


def base_problem(task: dict[str, Any], base_dir: str) -> Problem:
    """The task's problem before state/horizon overrides, cached per process."""
    from ocreach.registry import get_problem, load_problem_file

    ref = task["problem"]
    cache_key = canonical_json([ref, task["problem_sha256"], task["overrides"], base_dir])
    if cache_key in _PROBLEMS:
        return _PROBLEMS[cache_key]
    if task["problem_sha256"] is not None:
        path, pid = split_problem_ref(ref)
        full = Path(base_dir) / path
        if hashlib.sha256(full.read_bytes()).hexdigest() != task["problem_sha256"]:
            raise SweepError(f"problem file {str(full)!r} changed after the spec was read "
                             "(its SHA-256 differs); re-run to make new tasks")
        prob = load_problem_file(full, pid, **task["overrides"])
    else:
        prob = get_problem(ref, **task["overrides"])
    _PROBLEMS[cache_key] = prob
    while len(_PROBLEMS) > MAX_PROBLEMS:
        del _PROBLEMS[next(iter(_PROBLEMS))]
    return prob


#: state names that take a mass unit (kg); other states take length units when they are position
#: dims of the problem, velocity units when velocity dims, and model units (nd) always
MASS_STATES = ("m", "mass")


def _unit_kind_allowed(problem: Problem, index: int, name: str) -> str | None:
    if index in problem.position_dims:
        return "length"
    if index in problem.velocity_dims:
        return "velocity"
    return "mass" if name in MASS_STATES else None


def state_vector(problem: Problem, state: dict[str, Any]) -> np.ndarray:
    """The initial state in model units from a task's ``state`` (see :mod:`ocreach.sweep.catalog`).

    Raises :class:`SweepError` naming the entry ``NAME[UNIT]`` (a catalog column), the problem's
    states and the units allowed: the names must be exactly ``model.state_names``, a length unit
    goes on a position state, a velocity unit on a velocity state, ``kg`` on a mass state, and a
    problem without units takes model units (``nd``) only.  Called by the driver for every task
    (:func:`ocreach.sweep.spec.spec_from_dict`) and again by the worker for the conversion.
    """
    names = list(problem.model.state_names)
    values = np.asarray(state["values"], dtype=float)
    units = state["units"] or ["nd"] * values.size
    if state["names"] is None:
        if values.size != len(names):
            raise SweepError(f"state has {values.size} values; problem {problem.id!r} has "
                             f"{len(names)} states {names}")
        given = names
    else:
        given = list(state["names"])

    def label(j: int) -> str:
        return f"{given[j]}[{units[j]}]" if state["names"] is not None else f"state[{j}] ({given[j]})"

    unknown = [label(j) for j, n in enumerate(given) if n not in names]
    repeated = sorted({label(j) for j, n in enumerate(given) if given.count(n) > 1})
    missing = [n for n in names if n not in given]
    if unknown or repeated or missing:
        parts = ([f"unknown state column(s) {unknown}"] if unknown else []) + \
                ([f"repeated state column(s) {repeated}"] if repeated else []) + \
                ([f"missing state(s) {missing}"] if missing else [])
        raise SweepError(f"state of problem {problem.id!r}: {'; '.join(parts)}; the state columns "
                         f"must be exactly the problem's states {names}, each as NAME[UNIT]")
    u = problem.units
    scale = {"nd": 1.0} if u is None else {"nd": 1.0, "length": 1.0 / u.length,
                                            "velocity": 1.0 / u.velocity, "mass": 1.0 / u.mass}
    x0 = np.empty(len(names))
    for j, n in enumerate(given):
        i = names.index(n)
        kind, factor = UNITS[units[j]]
        want = _unit_kind_allowed(problem, i, n)
        if kind != "nd" and (kind != want or kind not in scale):
            ok = sorted(k for k, (kd, _) in UNITS.items() if kd == "nd" or (kd == want and kd in scale))
            why = (f"problem {problem.id!r} has no units" if kind not in scale else
                   f"{units[j]!r} is a {kind} unit and {n!r} is "
                   + {"length": "a position state", "velocity": "a velocity state",
                      "mass": "a mass state", None: "neither a position, velocity nor mass state"}[want])
            raise SweepError(f"state {label(j)} of problem {problem.id!r}: {why}; allowed units "
                             f"for {n!r}: {ok}")
        x0[i] = values[j] * factor * scale[kind]
    return x0


def _grid(problem: Problem, horizon: dict[str, Any]) -> np.ndarray:

    factor = HORIZON_UNITS[horizon["unit"]]
    if factor is not None and problem.units is None:
        raise SweepError(f"horizon in {horizon['unit']!r} needs units; problem {problem.id!r} has "
                         "none (give the horizon in 'TU', the model's time unit)")
    H = horizon["value"] if factor is None else horizon["value"] * factor / problem.units.time
    g = problem.grid
    step = g[1] - g[0]
    n = max(1, int(round(H / abs(step))))
    return g[0] + np.sign(step) * np.linspace(0.0, H, n + 1)


def build_problem(task: dict[str, Any], base_dir: str) -> Problem:
    """The task's :class:`~ocreach.problem.Problem` with its state and horizon overrides."""
    prob = base_problem(task, base_dir)
    changes: dict[str, Any] = {}
    if task["state"] is not None:
        if prob.initial_set is not None or prob.stochastic is not None:
            raise SweepError(f"problem {prob.id!r} has an initial set / stochastic spec centred on "
                             "its own x0; a 'state' override would leave it there")
        changes["x0"] = state_vector(prob, task["state"])
    if task["horizon"] is not None:
        changes["grid"] = _grid(prob, task["horizon"])
    return dataclasses.replace(prob, **changes) if changes else prob


def _result_bytes(result) -> bytes:
    with tempfile.TemporaryDirectory(prefix="ocreach-sweep-") as tmp:
        path = Path(tmp) / "result.npz"
        result.save(path)
        return path.read_bytes()


def run_tasks(payloads: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """:func:`run_task` for each payload of a chunk (one round trip for several small tasks)."""
    return [run_task(p) for p in payloads]


def run_task(payload: dict[str, Any]) -> dict[str, Any]:
    """Run one task ``{"key", "task", "base_dir"}``; return its record (never raises for a task
    failure: the error is in the record)."""
    with _TASK_LOCK:
        return _run_task(payload)


def _run_task(payload: dict[str, Any]) -> dict[str, Any]:
    from ocreach.reach.base import reach
    from ocreach.sweep.outputs import compute_outputs

    limit_threads()
    t0 = time.perf_counter()
    task = payload["task"]
    rec: dict[str, Any] = {"key": payload["key"], "worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        problem = build_problem(task, payload["base_dir"])
        result = reach(problem, task["method"], **task["options"])
        rec["outputs"] = compute_outputs(result, problem, task["keep"])
        if task["keep"]["result"]:
            rec["result_npz"] = _result_bytes(result)
        rec["status"] = "ok"
    except Exception as exc:  # noqa: BLE001 - a failing task is recorded, the sweep goes on
        rec["status"] = "error"
        rec["error"] = {"type": type(exc).__name__, "message": str(exc),
                        "traceback": "".join(traceback.format_exc(limit=-4))[-4000:]}
    rec["runtime_s"] = time.perf_counter() - t0
    return rec
