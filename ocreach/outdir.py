"""Output folders written as a unit (``ocreach run|compare --out DIR``).

:class:`OutputDir` checks ``DIR`` before any work (it must be a folder or not exist, under a
writable folder) and creates a temporary folder ``.DIR.tmp-XXXX`` next to it; the command writes
everything there.  Then exactly one of:

* :meth:`OutputDir.commit` -- the run is complete: the temporary folder replaces ``DIR`` (old
  ``DIR`` renamed aside, new one renamed in, old one deleted; SIGINT is held back during the
  renames), so ``DIR`` is always either the old complete folder or the new complete one;
* :meth:`OutputDir.keep_partial` -- interrupted or failed: ``DIR`` is left as it was; the files
  finished so far (if any) become ``DIR.partial`` with a ``MANIFEST.json`` saying they are a
  partial run (``"complete": false``, the reason and the file list); with nothing finished the
  temporary folder is removed.

:class:`StagedFiles` is the same idea for files that join an existing folder (``ocreach sweep
collect`` writes its tables into the sweep's folder, ``ocreach bench --write`` the benchmark
sections into ``docs/benchmarks.md``): every file is finished in a temporary folder inside the
target folder first, and only then renamed into place, each rename atomic; a failure or Ctrl-C
before that leaves the target folder as it was.

:func:`write_as_unit` is the path every command that writes a folder takes (``run``, ``compare``,
``report``, ``custody``): it runs the command's work in the temporary folder and commits it, or
keeps the partial files on Ctrl-C or an error.  Inputs are checked before the folder exists
(:func:`check_output_dir` first); an error of the work itself leaves ``DIR`` untouched and no
temporary folder behind when nothing was finished.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from ocreach.errors import ProblemError
from ocreach.interrupt import deferred, interrupt_requested, stage


def check_output_dir(target: str | Path, option: str = "--out") -> Path:
    """``target`` as a Path if it can be written as a folder, else a :class:`ProblemError`
    naming ``option``: it exists and is not a folder, lies under a file, or is not writable."""
    target = Path(target)
    if target.exists() and not target.is_dir():
        raise ProblemError(f"{option} {str(target)!r} exists and is not a folder")
    anc = target.parent
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise ProblemError(f"{option} {str(target)!r}: {str(anc)!r} is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise ProblemError(f"{option} {str(target)!r}: folder {str(anc)!r} is not writable")
    return target


class OutputDir:
    """A temporary folder next to ``target`` that is published as a whole (module docstring)."""

    def __init__(self, target: str | Path, option: str = "--out") -> None:
        self.target = check_output_dir(target, option).absolute()
        try:
            self.target.parent.mkdir(parents=True, exist_ok=True)
            self.path = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.tmp-",
                                              dir=self.target.parent))
            mask = os.umask(0)
            os.umask(mask)
            os.chmod(self.path, 0o777 & ~mask)  # mkdtemp makes 0700; the folder gets normal permissions
        except OSError as exc:
            raise ProblemError(f"{option} {str(target)!r} cannot be written: {exc.strerror or exc}") from None
        self.done: str | None = None  # "committed", "partial", "discarded"

    @property
    def partial_path(self) -> Path:
        return self.target.with_name(self.target.name + ".partial")

    def files(self) -> list[str]:
        return sorted(str(p.relative_to(self.path)) for p in self.path.rglob("*") if p.is_file()) \
            if self.path.is_dir() else []

    def commit(self) -> Path:
        """Replace ``target`` by the finished folder (see the module docstring)."""
        old = None
        try:
            with deferred():  # a Ctrl-C here is delivered after the renames
                if self.target.exists():
                    old = self.target.with_name(f".{self.target.name}.old-{os.getpid()}-{time.time_ns()}")
                    os.rename(self.target, old)
                os.rename(self.path, self.target)
                self.done = "committed"
        finally:
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
            if self.done == "committed" and self.partial_path.is_dir():  # stale: an older run's
                shutil.rmtree(self.partial_path, ignore_errors=True)
        return self.target

    def keep_partial(self, reason: str) -> Path | None:
        """Publish the finished files as ``DIR.partial`` (None if there are none); ``DIR`` untouched."""
        with deferred():
            files = self.files()
            if not files:
                shutil.rmtree(self.path, ignore_errors=True)
                self.done = "discarded"
                return None
            manifest = {"complete": False, "reason": reason, "files": files,
                        "target": str(self.target)}
            (self.path / "MANIFEST.json").write_text(json.dumps(manifest, indent=2))
            if self.partial_path.exists():
                shutil.rmtree(self.partial_path)
            os.rename(self.path, self.partial_path)
            self.done = "partial"
        return self.partial_path

    def describe_partial(self, kept: Path | None) -> str:
        """The sentence the CLI prints after :meth:`keep_partial` (true by construction)."""
        state = ("left unchanged (the previous complete results)" if self.target.exists()
                 else "not created")
        if kept is None:
            return f"{self.target} {state}; nothing was finished, no files kept"
        files = [f for f in self.files_in(kept) if f != "MANIFEST.json"]
        return (f"{self.target} {state}; the finished files are kept in {kept} "
                f"({', '.join(files)}; MANIFEST.json marks them partial)")

    @staticmethod
    def files_in(folder: Path) -> list[str]:
        return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


class Stages:
    """Marks named stages (:func:`ocreach.interrupt.stage`) and remembers the last one reached."""

    def __init__(self) -> None:
        self.last = "start"

    def __call__(self, name: str) -> None:
        self.last = name
        stage(name)


def interrupted(out: OutputDir, mark: Stages) -> int:
    """Message and exit code 130 after Ctrl-C; the message says exactly what was kept."""
    if out.done == "committed":
        print(f"interrupted after the run was complete: {out.target} holds the new results",
              file=sys.stderr)
        return 130
    kept = out.keep_partial(f"interrupted (Ctrl-C) at stage {mark.last!r}")
    print(f"interrupted (Ctrl-C) at stage {mark.last!r}: {out.describe_partial(kept)}", file=sys.stderr)
    return 130


def write_as_unit(out: OutputDir, mark: Stages, work: Callable[[], int | None]) -> int | None:
    """Run ``work()`` (writes into ``out.path``; returns None when the run is complete, else an
    exit code after keeping its partial files) and publish the folder when complete.  Ctrl-C, or
    an error that a Ctrl-C turned into, ends in :func:`interrupted`; another error keeps the
    finished files as partial (none finished: the temporary folder is removed) and propagates."""
    try:
        rc = work()
        if rc is not None:
            return rc
        mark("commit")
        out.commit()
        mark("done")
    except KeyboardInterrupt:
        return interrupted(out, mark)
    except Exception:
        if interrupt_requested():  # a Ctrl-C that native code turned into another error
            return interrupted(out, mark)
        if out.done is None:
            out.keep_partial("failed")
        raise
    return None


class StagedFiles:
    """Files finished in a temporary folder inside ``folder`` and renamed into it on
    :meth:`commit` (module docstring); as a context manager the staging folder is removed on
    exit, committed or not."""

    def __init__(self, folder: str | Path, option: str = "folder") -> None:
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise ProblemError(f"{option} {str(self.folder)!r} is not a folder")
        if not os.access(self.folder, os.W_OK | os.X_OK):
            raise ProblemError(f"{option} {str(self.folder)!r} is not writable")
        self.stage = Path(tempfile.mkdtemp(prefix=".staged.tmp-", dir=self.folder))
        self.names: list[str] = []

    def path(self, name: str, seed: bool = False) -> Path:
        """The staged path of ``folder/name``; ``seed``: start from a copy of the current file."""
        if name not in self.names:
            self.names.append(name)
            if seed and (self.folder / name).is_file():
                shutil.copy2(self.folder / name, self.stage / name)
        return self.stage / name

    def commit(self) -> list[Path]:
        """Rename every staged file that exists into ``folder`` (Ctrl-C held back meanwhile)."""
        done = []
        with deferred():
            for name in self.names:
                if (self.stage / name).exists():
                    os.replace(self.stage / name, self.folder / name)
                    done.append(self.folder / name)
        return done

    def __enter__(self) -> StagedFiles:
        return self

    def __exit__(self, *exc) -> None:
        shutil.rmtree(self.stage, ignore_errors=True)


#: set by ``ocreach bench --write``: the staged copy of ``docs/benchmarks.md`` the scripts update
BENCH_DOC_ENV = "OCREACH_BENCH_DOC"


def benchmarks_doc(default: str | Path) -> Path:
    """Where a benchmark's ``--write`` goes: the staged copy that ``ocreach bench --write``
    publishes when every script succeeded (``$OCREACH_BENCH_DOC``), else ``default`` (a script
    run on its own updates its section of ``docs/benchmarks.md`` directly, atomically)."""
    staged = os.environ.get(BENCH_DOC_ENV)
    return Path(staged) if staged else Path(default)
