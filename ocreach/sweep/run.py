"""The driver loop: submit pending tasks (a bounded number in flight), record each as it finishes.

Only the driver writes (:class:`ocreach.sweep.store.Store`); workers return plain records.  The
records of the futures that finished together are appended in submission order and fsynced
once (group commit: at a high completion rate one fsync covers several records).  A
progress bar (tqdm) shows counts of ok / failed tasks, the rate and the ETA.  Ctrl-C or SIGTERM
(or any exception in the driver) cancels what has not started and stops the local workers (the
tasks they were running are not recorded and run again next time); every finished record is
already on disk and the next run with the same spec and ``--out`` continues from there.
"""
from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, Executor, Future, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ocreach.sweep.errors import SweepError
from ocreach.sweep.executors import ExecutorHandle, make_executor
from ocreach.sweep.spec import Spec, load_spec
from ocreach.sweep.store import LOG, Store, finished_keys, read_log
from ocreach.sweep.worker import run_tasks


@dataclass
class RunSummary:
    """What one run did: tasks in the spec, skipped as finished, run now (ok / failed)."""

    total: int
    skipped: int
    ran: int = 0
    ok: int = 0
    failed: int = 0
    notes: list[str] = field(default_factory=list)
    executor: str = ""
    out: str = ""

    def line(self) -> str:
        if not self.ran:
            return f"nothing to run: all {self.total} task(s) already finished in {self.out}"
        return (f"{self.ran} task(s) run on {self.executor}: {self.ok} ok, {self.failed} failed; "
                f"{self.skipped} already finished; {self.total} in the spec -> {self.out}")


#: auto chunk size: about 20 chunks per worker, at most this many tasks in one chunk
MAX_AUTO_CHUNK = 16


def _failures(keys: list[str], fut: Future) -> list[dict[str, Any]]:
    exc = fut.exception()
    return [{"key": key, "status": "error", "worker": None, "runtime_s": None,
             "error": {"type": type(exc).__name__,
                       "message": f"the executor lost the task: {exc} (when a worker dies, every "
                                  "task in flight is recorded so; --retry-failed runs them again)"}}
            for key in keys]


def auto_chunk(n_tasks: int, n_workers: int) -> int:
    """Tasks per submitted chunk: ``n_tasks / (20 n_workers)`` clipped to ``[1, MAX_AUTO_CHUNK]``."""
    return max(1, min(MAX_AUTO_CHUNK, n_tasks // (20 * max(1, n_workers))))


def run_sweep(spec: Spec | str | Path, out: str | Path, *,
              executor: Executor | ExecutorHandle | None = None,
              workers: int | None = None, scheduler: str | None = None,
              dask_local: int | None = None, serial: bool = False, retry_failed: bool = False,
              max_in_flight: int | None = None, limit: int | None = None, chunk: int | None = None,
              progress: bool = True,
              on_record: Callable[[dict[str, Any]], None] | None = None,
              runner: Callable[[list[dict[str, Any]]], list[dict[str, Any]]] = run_tasks,
              desc: str = "sweep") -> RunSummary:
    """Run the pending tasks of ``spec`` into the folder ``out`` (created when new).

    Executor choice: ``executor`` (any Executor, or a started
    :class:`~ocreach.sweep.executors.ExecutorHandle`, which the caller closes), ``serial``,
    ``scheduler`` (Dask address), ``dask_local`` (LocalCluster size) or, by default, a process
    pool of ``workers`` (default the core count).  Tasks go out in chunks of ``chunk``
    (default :func:`auto_chunk`; 1 for small sweeps) and at most ``max_in_flight`` chunks are
    submitted and unfinished (default twice the worker count); ``limit`` stops after that many new tasks; ``retry_failed`` reruns
    failed ones; ``on_record`` is called with every record written; ``runner`` is the
    module-level function a worker calls on a chunk of payloads ``{"key", "task", "base_dir"}``
    (default :func:`~ocreach.sweep.worker.run_tasks`, ``reach`` tasks; another kind of task
    brings its own, e.g. the orbit-maintenance Monte Carlo), ``desc`` the progress bar's
    label.  Spec, folder and executor
    are all checked before the first task is submitted (the folder first: a foreign folder or
    an unreachable scheduler leaves nothing behind).
    """
    if not isinstance(spec, Spec):
        spec = load_spec(spec)
    for name, v in (("max_in_flight", max_in_flight), ("limit", limit), ("chunk", chunk)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise SweepError(f"{name} must be an integer >= 1; got {v!r}")
    Store.check(out, spec)  # a foreign folder fails before an executor is started
    previous = read_log(Path(out) / LOG)
    if all(k in finished_keys(previous.records, retry_failed) for k in spec.keys):
        for note in previous.notes:
            print(f"note: {note}", file=sys.stderr)
        return RunSummary(total=len(spec), skipped=len(spec), notes=previous.notes,
                          executor="nothing to run", out=str(out))
    handle = make_executor(workers, scheduler=scheduler, dask_local_workers=dask_local,
                           serial=serial, executor=executor)
    try:
        with Store.open(out, spec) as store, sigterm_as_interrupt():
            summary = RunSummary(total=len(spec), skipped=0, notes=list(store.log.notes),
                                 out=str(out), executor=handle.kind)
            done = store.finished(retry_failed)
            todo = [(k, t) for k, t in zip(spec.keys, spec.tasks) if k not in done]
            summary.skipped = len(spec) - len(todo)
            if limit is not None:
                todo = todo[:limit]
            for note in summary.notes:
                print(f"note: {note}", file=sys.stderr)
            size = chunk or auto_chunk(len(todo), handle.n_workers)
            chunks = [todo[i:i + size] for i in range(0, len(todo), size)]
            _drive(spec, chunks, len(todo), store, handle, summary,
                   max_in_flight or 2 * handle.n_workers, progress, on_record, runner, desc)
            return summary
    except KeyboardInterrupt:
        handle.interrupted = True
        raise
    finally:
        if executor is None:
            handle.close()


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM handled like Ctrl-C while the driver runs (in the main thread): the driver stops,
    every finished record is on disk, its workers are stopped (not left computing for nobody)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum} (SIGTERM)")

    old = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _drive(spec: Spec, chunks: list[list[tuple[str, dict[str, Any]]]], n_tasks: int, store: Store,
           handle: ExecutorHandle, summary: RunSummary, bound: int, progress: bool,
           on_record: Callable[[dict[str, Any]], None] | None,
           runner: Callable[[list[dict[str, Any]]], list[dict[str, Any]]] = run_tasks,
           desc: str = "sweep") -> None:
    from tqdm import tqdm

    pending = iter(chunks)
    in_flight: dict[Future, list[str]] = {}
    bar = tqdm(total=n_tasks, unit="task", disable=not progress, dynamic_ncols=True,
               desc=desc, file=sys.stderr)

    def submit_more() -> None:
        while len(in_flight) < bound:
            nxt = next(pending, None)
            if nxt is None:
                return
            payloads = [{"key": key, "task": task, "base_dir": spec.base_dir} for key, task in nxt]
            try:
                fut = handle.executor.submit(runner, payloads)
            except BrokenExecutor as exc:
                raise SweepError(f"the executor ({handle.kind}) broke, e.g. a worker process died "
                                 f"({exc}); the finished records are kept, re-run to continue") from None
            in_flight[fut] = [key for key, _ in nxt]

    try:
        submit_more()
        while in_flight:
            finished, _ = wait(list(in_flight), return_when=FIRST_COMPLETED)
            batch = []
            for fut in [f for f in in_flight if f in finished]:  # in submission order
                keys = in_flight.pop(fut)
                recs = fut.result() if fut.exception() is None else _failures(keys, fut)
                for rec in recs:
                    rec = store.append(rec, sync=False)
                    summary.ran += 1
                    if rec["status"] == "ok":
                        summary.ok += 1
                    else:
                        summary.failed += 1
                    batch.append(rec)
                bar.set_postfix(ok=summary.ok, failed=summary.failed, refresh=False)
                bar.update(len(recs))
            store.sync()  # one fsync per batch of records that finished together
            if on_record is not None:
                for rec in batch:
                    on_record(rec)
            submit_more()
    finally:
        for fut in in_flight:
            fut.cancel()
        bar.close()
