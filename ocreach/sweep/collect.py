"""Reading a sweep folder: ``status`` (counts, failures) and the table of all tasks (CSV, Parquet).

The table has one row per task of the spec, in spec order: ``index``, ``key``, ``status``
(``ok``, ``error`` or ``pending``), the task fields flattened (``problem``, ``method``,
``label``, ``tags.*``, ``overrides.*``, ``options.*``, ``horizon``, ``state``; lists and objects
as compact JSON), the recorded outputs (``out.*``), ``error``, ``result_file``, ``runtime_s``
and ``worker``.  The deterministic columns (all but ``runtime_s``, ``worker``, ``finished``) are
the same whatever executor ran the sweep.
"""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from ocreach.fileio import atomic_write_bytes
from ocreach.sweep.errors import SweepError
from ocreach.sweep.store import LOG, read_log, read_meta

#: columns that depend on where/when a task ran
RUN_COLUMNS = ("runtime_s", "worker", "finished")
FORMATS = ("csv", "parquet")


def status(out: str | Path) -> dict[str, Any]:
    """Counts of ok / failed / pending tasks, total task time and the first errors."""
    meta = read_meta(out)
    log = read_log(Path(out) / LOG)
    keys = [t["key"] for t in meta["tasks"]]
    recs = [log.records.get(k) for k in keys]
    ok = [r for r in recs if r and r["status"] == "ok"]
    failed = [r for r in recs if r and r["status"] == "error"]
    times = [r["runtime_s"] for r in ok + failed if r.get("runtime_s") is not None]
    return {"name": meta.get("name", ""), "total": len(keys), "ok": len(ok), "failed": len(failed),
            "pending": len(keys) - len(ok) - len(failed), "task_seconds": sum(times),
            "versions": meta.get("versions"), "notes": log.notes,
            "errors": [{"key": r["key"], **{k: r["error"].get(k) for k in ("type", "message")}}
                       for r in failed[:10]]}


def format_status(st: dict[str, Any]) -> str:
    lines = [f"sweep {st['name']!r}: {st['total']} tasks: {st['ok']} ok, {st['failed']} failed, "
             f"{st['pending']} pending; {st['task_seconds']:.1f} s of task time"]
    lines += [f"note: {n}" for n in st["notes"]]
    lines += [f"failed {e['key']}: {e['type']}: {e['message']}" for e in st["errors"]]
    if st["failed"] > len(st["errors"]):
        lines.append(f"... and {st['failed'] - len(st['errors'])} more failed (see collect)")
    return "\n".join(lines)


def _flat(prefix: str, value: Any) -> dict[str, Any]:
    if isinstance(value, dict):
        return {f"{prefix}.{k}": (json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else v)
                for k, v in value.items()}
    return {prefix: json.dumps(value, sort_keys=True) if isinstance(value, (dict, list)) else value}


def collect_table(out: str | Path) -> tuple[list[str], list[dict[str, Any]]]:
    """``(columns, rows)`` of the sweep folder ``out`` (see the module docstring)."""
    meta = read_meta(out)
    log = read_log(Path(out) / LOG)
    rows = []
    for i, t in enumerate(meta["tasks"]):
        rec = log.records.get(t["key"])
        row: dict[str, Any] = {"index": i, "key": t["key"],
                               "status": rec["status"] if rec else "pending",
                               "problem": t["problem"], "method": t["method"], "label": t["label"]}
        for name in ("tags", "overrides", "options"):
            row.update(_flat(name, t[name]))
        row["horizon"] = (None if t["horizon"] is None
                          else f"{t['horizon']['value']:g} {t['horizon']['unit']}")
        row["state"] = None if t["state"] is None else json.dumps(t["state"]["values"])
        if rec:
            row.update({f"out.{k}": v for k, v in (rec.get("outputs") or {}).items()})
            err = rec.get("error")
            row["error"] = f"{err['type']}: {err['message']}" if err else None
            row["result_file"] = rec.get("result_file")
            for k in RUN_COLUMNS:
                row[k] = rec.get(k)
        rows.append(row)
    columns: list[str] = []
    for row in rows:
        columns += [c for c in row if c not in columns]
    return columns, rows


def write_table(out: str | Path, formats: str | list[str] = "csv") -> list[Path]:
    """Write ``DIR/table.csv`` (and ``table.parquet`` when asked and pyarrow is installed).

    Every table is built in memory and written into a staging folder inside ``DIR`` before any of
    them replaces the old one (:class:`ocreach.outdir.StagedFiles`): a failure leaves the old
    tables, never a new ``table.csv`` beside an old ``table.parquet``."""
    from ocreach.outdir import StagedFiles

    fmts = [f.strip() for f in (formats.split(",") if isinstance(formats, str) else formats) if f.strip()]
    bad = [f for f in fmts if f not in FORMATS]
    if bad or not fmts:
        raise SweepError(f"--format must be a comma-separated list of {list(FORMATS)}; got {formats!r}")
    if "parquet" in fmts:
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise SweepError("--format parquet needs pyarrow, which is not installed: "
                             "pip install 'ocreach[parquet]' (csv needs nothing extra)") from None
    columns, rows = collect_table(out)
    data: dict[str, bytes] = {}
    if "csv" in fmts:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
        w.writeheader()
        for row in rows:
            w.writerow({c: ("" if row.get(c) is None else row.get(c)) for c in columns})
        data["table.csv"] = buf.getvalue().encode()
    if "parquet" in fmts:
        import pyarrow as pa
        import pyarrow.parquet as pq

        cols = {}
        for c in columns:
            vals = [row.get(c) for row in rows]
            kinds = {type(v) for v in vals if v is not None}
            if len(kinds) > 1 and not kinds <= {int, float}:
                vals = [None if v is None else str(v) for v in vals]
            cols[c] = vals
        sink = pa.BufferOutputStream()
        pq.write_table(pa.table(cols), sink)
        data["table.parquet"] = sink.getvalue().to_pybytes()
    with StagedFiles(out, "sweep folder") as staged:
        for name, blob in data.items():
            atomic_write_bytes(staged.path(name), blob)
        return staged.commit()
