"""The sweep output folder; the driver is its only writer.

::

    DIR/sweep.json        the spec, its expanded tasks with keys, the spec hash and versions
    DIR/tasks.jsonl       one JSON record per finished task (ok or error), flushed and fsynced
    DIR/results/KEY.npz   the full result of a task that keeps it (written before its record)
    DIR/.sweep.lock       held (flock) while a driver writes

Opening a folder for a run checks it belongs to the same spec (same hash of the expanded tasks)
and the same package versions, takes the lock, and reads the log: the latest record of a key
wins; a half-written or corrupt last line (a driver killed mid-write) is cut off so its task runs
again; a corrupt line elsewhere is skipped (reported) and its task runs again.
"""
from __future__ import annotations

import datetime
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ocreach.fileio import atomic_write_bytes, atomic_write_text
from ocreach.sweep.errors import SweepError
from ocreach.sweep.keys import versions as current_versions

META, LOG, RESULTS, LOCK = "sweep.json", "tasks.jsonl", "results", ".sweep.lock"
FORMAT = 1


def now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


@dataclass
class LogContents:
    """The records of a log (latest per key) and what was wrong with it."""

    records: dict[str, dict[str, Any]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    good_bytes: int = 0  # length of the log up to the end of its last good line
    torn_tail: bool = False


def read_log(path: Path) -> LogContents:
    """Parse ``tasks.jsonl`` without changing it."""
    out = LogContents()
    if not path.exists():
        return out
    data = path.read_bytes()
    lines = data.split(b"\n")
    tail = lines.pop()  # the bytes after the last newline: empty unless a write was cut short
    offset = 0
    for n, raw in enumerate(lines, start=1):
        end = offset + len(raw) + 1
        try:
            rec = json.loads(raw)
            if not isinstance(rec, dict) or "key" not in rec or rec.get("status") not in ("ok", "error"):
                raise ValueError("not a task record")
        except ValueError:
            if n == len(lines) and not tail:
                out.torn_tail = True
                out.notes.append(f"{path.name} line {n} (the last) is corrupt; its task will run again")
                break
            out.notes.append(f"{path.name} line {n} is corrupt and was skipped; its task will run again")
            offset = end
            out.good_bytes = end
            continue
        out.records[rec["key"]] = rec
        offset = end
        out.good_bytes = end
    if tail:
        out.torn_tail = True
        out.notes.append(f"{path.name} ends in a half-written line ({len(tail)} bytes, a killed "
                         "driver?); its task will run again")
    return out


def finished_keys(records: dict[str, dict[str, Any]], retry_failed: bool = False) -> set[str]:
    """Keys not to run again: ok tasks, and failed ones unless ``retry_failed``."""
    return {k for k, r in records.items() if r["status"] == "ok" or not retry_failed}


def read_meta(out: str | Path) -> dict[str, Any]:
    path = Path(out) / META
    if not path.is_file():
        raise SweepError(f"{str(out)!r} is not a sweep folder (no {META})")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except ValueError as exc:
        raise SweepError(f"{path} is not valid JSON ({exc})") from None


class Store:
    """An output folder opened for writing by one driver (see the module docstring)."""

    def __init__(self, out: Path, meta: dict[str, Any], log: LogContents, lock_fd: int) -> None:
        self.out, self.meta, self.log = out, meta, log
        self._lock_fd = lock_fd
        self._fd = os.open(out / LOG, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)

    # ------------------------------------------------------------------ opening
    @staticmethod
    def check(out: str | Path, spec) -> dict[str, Any] | None:
        """Refuse ``out`` if it is not new, empty, or a folder of this spec and these versions
        (writes nothing); return its ``sweep.json`` contents if it has one."""
        out = Path(out)
        vers = spec.package_versions or current_versions()
        if (out / META).is_file():
            meta = read_meta(out)
            if meta.get("spec_hash") != spec.spec_hash:
                raise SweepError(f"{str(out)!r} belongs to a different spec (its sweep.json was "
                                 f"written for {meta.get('spec_path') or meta.get('name')!r}, "
                                 f"{len(meta.get('tasks', []))} tasks); use another --out")
            if meta.get("versions") != vers:
                raise SweepError(f"{str(out)!r} was written with versions {meta.get('versions')}; "
                                 f"this run has {vers}; results would not be comparable "
                                 "(use another --out)")
            return meta
        if out.exists() and (not out.is_dir() or any(p.name != LOCK for p in out.iterdir())):
            raise SweepError(f"{str(out)!r} exists and is not a sweep folder (no {META}); "
                             "give a new or empty --out")
        return None

    @classmethod
    def open(cls, out: str | Path, spec) -> Store:
        """Create ``out`` for ``spec`` or reopen it (same spec and versions), locked, log repaired."""
        out = Path(out)
        cls.check(out, spec)  # refuse a foreign folder before creating anything
        out.mkdir(parents=True, exist_ok=True)
        lock_fd = _lock(out)
        try:  # under the lock: check again (another driver may have written sweep.json meanwhile)
            meta = cls.check(out, spec)
            if meta is None:
                meta = {"format": FORMAT, "name": spec.name, "spec_path": spec.path,
                        "base_dir": spec.base_dir, "spec_hash": spec.spec_hash,
                        "versions": spec.package_versions or current_versions(),
                        "created": now(), "spec": spec.raw,
                        "tasks": [{"key": k, **t} for k, t in zip(spec.keys, spec.tasks)]}
                atomic_write_text(out / META, json.dumps(meta, indent=1, allow_nan=False))
            log = read_log(out / LOG)
            if log.torn_tail:
                with open(out / LOG, "r+b") as fh:
                    fh.truncate(log.good_bytes)
                    fh.flush()
                    os.fsync(fh.fileno())
            return cls(out, meta, log, lock_fd)
        except BaseException:
            os.close(lock_fd)
            raise

    # ------------------------------------------------------------------ queries
    def finished(self, retry_failed: bool = False) -> set[str]:
        """Keys not to run again (:func:`finished_keys` of the log)."""
        return finished_keys(self.log.records, retry_failed)

    # ------------------------------------------------------------------ writing
    def append(self, rec: dict[str, Any], sync: bool = True) -> dict[str, Any]:
        """Write a task record (and first its result file, if it carries one); fsync unless
        ``sync=False`` (the driver then calls :meth:`sync` once for the records that finished
        together: a crash can only tear lines written after the last sync, and those tasks
        run again)."""
        rec = dict(rec)
        blob = rec.pop("result_npz", None)
        if blob is not None:
            rel = f"{RESULTS}/{rec['key']}.npz"
            _fsync_file(atomic_write_bytes(self.out / rel, blob))  # on disk before its record
            rec["result_file"] = rel
        rec["finished"] = now()
        try:
            line = json.dumps(rec, sort_keys=True, allow_nan=False) + "\n"
        except (TypeError, ValueError) as exc:  # a non-JSON output: record that instead
            rec = {"key": rec["key"], "status": "error", "worker": rec.get("worker"),
                   "runtime_s": rec.get("runtime_s"), "finished": rec["finished"],
                   "error": {"type": "SweepError", "message": f"task outputs are not JSON: {exc}"}}
            line = json.dumps(rec, sort_keys=True) + "\n"
        data = line.encode("utf-8")
        while data:
            n = os.write(self._fd, data)
            data = data[n:]
        if sync:
            self.sync()
        self.log.records[rec["key"]] = rec
        return rec

    def sync(self) -> None:
        """fsync the log."""
        os.fsync(self._fd)

    def close(self) -> None:
        for fd in (self._fd, self._lock_fd):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _lock(out: Path) -> int:
    import fcntl

    fd = os.open(out / LOCK, os.O_WRONLY | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise SweepError(f"another sweep driver is writing {str(out)!r} (its lock is held)") from None
    return fd
