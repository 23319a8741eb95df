"""Where tasks run: any :class:`concurrent.futures.Executor`.

* :class:`SerialExecutor` -- in the driver, one task at a time (debugging, tiny sweeps);
* a local process pool (the default): ``spawn``-started workers, ``workers`` of them (default the
  core count), each with one BLAS/OpenMP thread (the thread variables are set to 1 in the
  environment the workers start with, before they import numpy, and threadpoolctl limits them
  again when installed);
* Dask distributed: ``scheduler="tcp://HOST:PORT"`` connects a ``Client`` (short timeout, clear
  error when unreachable) and uses ``Client.get_executor()``; ``dask_local=N`` starts a
  ``LocalCluster`` of ``N`` single-threaded worker processes on 127.0.0.1 (Dask's nanny also
  sets the thread variables to 1 for its workers);
* any Executor object passed from Python.

:func:`make_executor` returns an :class:`ExecutorHandle` (a context manager that closes what it
started).
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from ocreach.sweep.errors import SweepError
from ocreach.sweep.worker import THREAD_ENV

CONNECT_TIMEOUT_S = 5.0


class SerialExecutor(Executor):
    """Runs each submitted call at once in the calling process (an Executor with no workers)."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            if isinstance(exc, KeyboardInterrupt):
                raise
            fut.set_exception(exc)
        return fut


@dataclass
class ExecutorHandle:
    """An executor, how many tasks it runs at once, a description, and what to close."""

    executor: Executor
    n_workers: int
    kind: str
    closers: list[Callable[[], Any]] = field(default_factory=list)
    #: set by the driver when it stops on an interrupt (Ctrl-C, SIGTERM): closers need not wait
    interrupted: bool = False

    def close(self) -> None:
        for fn in reversed(self.closers):
            with contextlib.suppress(Exception):
                fn()
        self.closers.clear()

    def __enter__(self) -> ExecutorHandle:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


@contextlib.contextmanager
def single_thread_env() -> Iterator[None]:
    """Temporarily set :data:`THREAD_ENV` to 1 (unless set) in ``os.environ``."""
    old = {k: os.environ.get(k) for k in THREAD_ENV}
    for k in THREAD_ENV:
        os.environ.setdefault(k, "1")
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


#: seconds between a pool worker's checks that its driver is still alive
ORPHAN_CHECK_S = 2.0


def _exit_when_orphaned(driver_pid: int) -> None:
    """Daemon thread of a pool worker: end the worker at once when its driver is gone (killed:
    the worker is re-parented, ``os.getppid()`` changes), instead of computing for nobody."""
    import time

    while os.getppid() == driver_pid:
        time.sleep(ORPHAN_CHECK_S)
    os._exit(1)


def _worker_init(driver_pid: int | None = None) -> None:
    """Pool worker start: one BLAS thread; ignore Ctrl-C (the driver handles it: it stops its
    workers, every finished record being on disk); exit when the driver dies."""
    import signal
    import threading

    from ocreach.sweep.worker import limit_threads

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    limit_threads()
    if driver_pid is not None:
        threading.Thread(target=_exit_when_orphaned, args=(driver_pid,), daemon=True,
                         name="ocreach-orphan-check").start()


def _stop_pool(pool: ProcessPoolExecutor, interrupted: Callable[[], bool]) -> None:
    """Shut ``pool`` down: wait for its workers after a normal end; after an interrupt terminate
    them (what they run is not recorded any more, so waiting for it only delays the exit)."""
    if interrupted():
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            with contextlib.suppress(Exception):
                proc.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        return
    pool.shutdown(wait=True, cancel_futures=True)


def process_pool(workers: int) -> ExecutorHandle:
    """A ``spawn`` process pool of ``workers`` processes, all started now (under one-thread env);
    closing it after an interrupt (``handle.interrupted``) terminates the workers."""
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init, initargs=(os.getpid(),))
    with single_thread_env():  # spawned children inherit this environment
        for f in [pool.submit(os.getpid) for _ in range(workers)]:
            f.result()
    handle = ExecutorHandle(pool, workers, f"process pool ({workers} workers)")
    handle.closers.append(lambda: _stop_pool(pool, lambda: handle.interrupted))
    return handle


def _dask():
    try:
        import distributed
    except ImportError:
        raise SweepError("the Dask executor needs dask[distributed]: pip install 'ocreach[dask]'") from None
    return distributed


def dask_client(address: str, timeout: float | None = None) -> ExecutorHandle:
    """Connect to the Dask scheduler at ``address`` (``tcp://HOST:PORT``) within ``timeout``
    seconds (default :data:`CONNECT_TIMEOUT_S`, read at call time)."""
    if timeout is None:
        timeout = CONNECT_TIMEOUT_S
    if not isinstance(address, str) or "://" not in address:
        raise SweepError(f"--scheduler must be an address like tcp://HOST:PORT; got {address!r}")
    distributed = _dask()
    try:
        client = distributed.Client(address, timeout=f"{timeout}s")
    except (OSError, TimeoutError) as exc:
        raise SweepError(f"cannot reach the Dask scheduler at {address!r} within {timeout:g} s "
                         f"({type(exc).__name__}: {exc}); is `dask scheduler` running there?") from None
    try:
        client.wait_for_workers(1, timeout=timeout)
    except (OSError, TimeoutError):
        client.close()
        raise SweepError(f"the Dask scheduler at {address!r} has no workers (waited {timeout:g} s); "
                         "start some with `dask worker ADDRESS --nthreads 1`") from None
    n = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values()))
    return ExecutorHandle(client.get_executor(pure=False), n, f"Dask scheduler {address} ({n} threads)",
                          [client.close])


def dask_local(workers: int, processes: bool = True) -> ExecutorHandle:
    """A Dask ``LocalCluster`` of ``workers`` single-threaded workers on 127.0.0.1
    (``processes=False``: threads in this process, for tests)."""
    distributed = _dask()
    with single_thread_env():
        where = {"host": "127.0.0.1"} if processes else {}  # threads talk in-process (inproc://)
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                           processes=processes, dashboard_address=None, **where)
    client = distributed.Client(cluster)
    kind = "processes" if processes else "threads"
    return ExecutorHandle(client.get_executor(pure=False), workers,
                          f"Dask LocalCluster ({workers} {kind})", [cluster.close, client.close])


def serial_executor() -> ExecutorHandle:
    """Tasks in the calling process with one BLAS/OpenMP thread, as each pool worker has (with
    OpenBLAS's default 2 threads a serial catalog ran 16% slower, docs/benchmarks.md "Sweep");
    the caller's thread limits are restored when the handle is closed."""
    from threadpoolctl import threadpool_limits

    limits = threadpool_limits(1)
    return ExecutorHandle(SerialExecutor(), 1, "serial", [limits.restore_original_limits])


def make_executor(workers: int | None = None, *, scheduler: str | None = None,
                  dask_local_workers: int | None = None, serial: bool = False,
                  executor: Executor | ExecutorHandle | None = None) -> ExecutorHandle:
    """The executor the options ask for (at most one of them; default: a local process pool);
    an :class:`ExecutorHandle` passed as ``executor`` is returned as it is."""
    chosen = [n for n, v in (("scheduler", scheduler), ("dask_local", dask_local_workers),
                             ("serial", serial or None), ("executor", executor)) if v is not None]
    if len(chosen) > 1:
        raise SweepError(f"choose one executor; got {chosen}")
    if isinstance(executor, ExecutorHandle):  # the caller's, already started (and closed by it)
        return executor
    if executor is not None:
        if not isinstance(executor, Executor):
            raise SweepError(f"executor must be a concurrent.futures.Executor; got "
                             f"{type(executor).__name__}")
        return ExecutorHandle(executor, workers or os.cpu_count() or 1, type(executor).__name__)
    if serial:
        return serial_executor()
    if scheduler is not None:
        return dask_client(scheduler)
    for name, n in (("workers", workers), ("dask_local", dask_local_workers)):
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
            raise SweepError(f"{name} must be an integer >= 1; got {n!r}")
    if dask_local_workers is not None:
        return dask_local(dask_local_workers)
    return process_pool(workers or os.cpu_count() or 1)
