"""Ctrl-C that is never lost: a SIGINT handler that records the request, and named stages.

Native code (CasADi integrators, IPOPT, compiled kernels) may see SIGINT and return an error or
even finish normally, so a plain ``KeyboardInterrupt`` can turn into another exception or vanish.
:func:`install` (done by the CLI) records every SIGINT in a flag before raising
``KeyboardInterrupt``; :func:`check_interrupt` (called by the guard after each step and by the CLI
after each piece of work) raises ``KeyboardInterrupt`` if one was recorded, and
:func:`interrupt_requested` lets an error handler tell an interrupted run from a failed one.

:func:`stage` marks named points of a command.  ``OCREACH_STAGE_LOG=1`` prints
``[ocreach-stage] NAME`` to stderr at each; ``OCREACH_PAUSE_AT=NAME`` makes the command wait
there (up to 120 s, interruptible) -- the hooks the SIGINT tests use.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import time
from collections.abc import Iterator

_STATE = {"requested": False}


def _handler(signum, frame) -> None:  # noqa: ARG001 (signal handler signature)
    _STATE["requested"] = True
    raise KeyboardInterrupt


def install():
    """Install the recording SIGINT handler (main thread only; a no-op elsewhere), reset the flag
    and return the previous handler (for :func:`restore`)."""
    _STATE["requested"] = False
    try:
        return signal.signal(signal.SIGINT, _handler)
    except ValueError:  # not the main thread
        return None


def restore(previous) -> None:
    """Put back the handler :func:`install` replaced and clear the flag (the command that
    installed it has handled the interruption), so later calls in the process are not affected."""
    _STATE["requested"] = False
    if previous is not None:
        try:
            signal.signal(signal.SIGINT, previous)
        except ValueError:
            pass


def interrupt_requested() -> bool:
    """Whether a SIGINT was received since :func:`install`."""
    return bool(_STATE["requested"])


def acknowledge() -> None:
    """Clear the flag: the caller has handled the interruption (e.g. compare keeps the finished
    methods and reports ``interrupted``), so later :func:`check_interrupt` calls pass."""
    _STATE["requested"] = False


def check_interrupt() -> None:
    """Raise ``KeyboardInterrupt`` if a SIGINT was received (and perhaps swallowed by native code)."""
    if _STATE["requested"]:
        raise KeyboardInterrupt


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold SIGINT back while the block runs (e.g. the renames that publish an output folder): a
    Ctrl-C during it is recorded and raised as ``KeyboardInterrupt`` when the block ends.  (A
    handler swap rather than a signal mask, so a signal delivered to another thread -- tqdm's
    monitor -- is held back too.)"""
    got: list[int] = []

    def hold(signum, frame) -> None:  # noqa: ARG001 (raised below, nothing can swallow it)
        got.append(signum)

    try:
        previous = signal.signal(signal.SIGINT, hold)
    except ValueError:  # not the main thread: nothing to hold back here
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if got:
            raise KeyboardInterrupt


def stage(name: str) -> None:
    """A named point of a command (see the module docstring)."""
    if os.environ.get("OCREACH_STAGE_LOG"):
        print(f"\n[ocreach-stage] {name}", file=sys.stderr, flush=True)
    if os.environ.get("OCREACH_PAUSE_AT") == name:
        t_end = time.monotonic() + 120.0
        while time.monotonic() < t_end:
            time.sleep(0.05)
    check_interrupt()
