"""Thread settings: how many threads the native kernels split a batch over, and the BLAS limit.

Two knobs, both without any change of results:

* **Kernel threads** (:func:`threads`): the compiled batch integrator
  (:func:`ocreach.native.integrator.integrate_batch`, ``propagate_segments``) runs a batch in
  that many threads (its C loop runs without the GIL), which take samples from one shared
  counter, so a thread whose core is busy with other work takes fewer.  Each sample's arithmetic
  does not depend on the thread, so results are bit-identical for any thread count.
  Default: ``$OCREACH_THREADS``, else the number of cores this process may run on.
* **BLAS threads** (:func:`blas_limit`): OpenBLAS/MKL start one thread per core.  For the
  medium-sized products of the set library and the STT engine that is a loss as soon as another
  process holds a core (2-5x slower on 2 cores in an earlier measurement; see
  docs/benchmarks.md, "Speed and memory") and hardly a gain on a quiet machine, so ``reach()`` and the CLI run methods under a limit of ``$OCREACH_BLAS_THREADS``
  (default 1) through threadpoolctl.  With the default limit every run computes its products
  single-threaded whatever the environment, so results no longer depend on how many BLAS threads
  the environment would have started.

``with parallel.settings(threads=2, blas_threads=1): ...`` sets both for a block of code.

The limit alone does not give back all of single-threaded BLAS: a process whose OpenBLAS started
with 2 threads spent 1.1-1.3x the CPU time of one started with ``OPENBLAS_NUM_THREADS=1`` on
``stt``/``dro`` even under the 1-thread limit (docs/benchmarks.md, "Speed and memory").  So
``import ocreach`` before numpy starts OpenBLAS with :func:`blas_default` threads
(:func:`preset_blas_env`), unless the environment already says how many.
"""
from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator

from ocreach.errors import ProblemError, check_count

__all__ = ["blas_default", "blas_info", "blas_limit", "default_threads", "env_count", "preset_blas_env",
           "set_threads", "settings", "threads"]

_state = threading.local()


def env_count(name: str) -> int | None:
    """The integer >= 1 in environment variable ``name``, None if unset (ProblemError if bad)."""
    raw = os.environ.get(name)
    if raw is None or raw == "":
        return None
    try:
        value = int(raw)
    except ValueError:
        raise ProblemError(f"environment {name} must be an integer >= 1; got {raw!r}") from None
    if value < 1:
        raise ProblemError(f"environment {name} must be an integer >= 1; got {raw!r}")
    return value


def _check(name: str, value) -> int:
    return int(check_count(name, value, 1))


def default_threads() -> int:
    """``$OCREACH_THREADS`` or the number of cores available to this process."""
    env = env_count("OCREACH_THREADS")
    if env is not None:
        return env
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def threads() -> int:
    """Threads the native kernels use now (:func:`settings` / :func:`set_threads`, else the
    default)."""
    value = getattr(_state, "threads", None)
    return default_threads() if value is None else value


def set_threads(value: int | None) -> None:
    """Set the kernel thread count of this thread (``None``: back to the default)."""
    _state.threads = None if value is None else _check("threads", value)


def blas_default() -> int:
    """``$OCREACH_BLAS_THREADS`` or 1 (see the module docstring)."""
    env = env_count("OCREACH_BLAS_THREADS")
    return 1 if env is None else env


_controller: tuple[int, object] | None = None   # (len(sys.modules) when built, controller)


def _thread_pools():
    """threadpoolctl's controller of the loaded thread pools.  Building one scans the loaded
    shared libraries (~4 ms, about 1 % of a 0.5 s ``reach``), so it is kept and built again only
    when modules have been imported since (a new extension module can bring its own BLAS)."""
    global _controller
    from threadpoolctl import ThreadpoolController

    n_modules = len(sys.modules)
    cached = _controller
    if cached is None or cached[0] != n_modules:
        cached = _controller = (n_modules, ThreadpoolController())
    return cached[1]


#: environment variables through which OpenBLAS takes its thread count at start (in this order)
OPENBLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def preset_blas_env() -> bool:
    """Set ``OPENBLAS_NUM_THREADS`` to :func:`blas_default` if numpy (and so OpenBLAS) is not
    loaded yet and none of :data:`OPENBLAS_THREAD_VARS` is set; returns whether it did.  Called
    first thing by ``import ocreach``.  The variable is inherited by child processes; with numpy
    already imported it is too late and nothing changes (the limit inside ``reach()`` still
    holds).  A bad ``OCREACH_BLAS_THREADS`` is left to be reported where the limit is used."""
    if "numpy" in sys.modules or any(os.environ.get(v) for v in OPENBLAS_THREAD_VARS):
        return False
    try:
        os.environ["OPENBLAS_NUM_THREADS"] = str(blas_default())
    except ProblemError:
        return False
    return True


@contextlib.contextmanager
def blas_limit(limit: int | None = None) -> Iterator[None]:
    """Limit the BLAS thread pools (OpenBLAS, MKL, BLIS) to ``limit`` threads (default
    :func:`blas_default`) inside the block; restores them afterwards."""
    limit = blas_default() if limit is None else _check("blas_threads", limit)
    with _thread_pools().limit(limits=limit, user_api="blas"):
        yield


def blas_info() -> list[dict]:
    """threadpoolctl's description of the loaded BLAS libraries (for benchmark records)."""
    from threadpoolctl import threadpool_info

    return [{k: d.get(k) for k in ("internal_api", "version", "num_threads", "threading_layer",
                                   "architecture")} for d in threadpool_info()
            if d.get("user_api") == "blas"]


@contextlib.contextmanager
def settings(threads: int | None = None, blas_threads: int | None = None) -> Iterator[None]:
    """Kernel threads (``None``: keep the current setting) and the BLAS limit (``None``:
    :func:`blas_default`) for a block of code."""
    old = getattr(_state, "threads", None)
    if threads is not None:
        set_threads(threads)
    try:
        with blas_limit(blas_threads):
            yield
    finally:
        _state.threads = old
