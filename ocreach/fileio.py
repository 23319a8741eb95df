"""Files written whole: atomic writes (temporary file, then rename), strict JSON, Markdown sections.

Every file a user reads is written through :func:`atomic_write_bytes` (a reader sees the old or
the new file, never half of one), and every JSON file through :func:`json_text` (NaN and
infinities become ``null``: they are not JSON); :func:`replace_markdown_section` rewrites one
section of a Markdown file (the benchmark and validation tables each script keeps).  Folders
written as a unit: :mod:`ocreach.outdir`.
"""
from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ocreach.errors import ProblemError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file normal permissions
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically, as :func:`atomic_write_bytes`."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def jsonable(obj: Any) -> Any:
    """``obj`` made JSON-serialisable: dict keys as strings, tuples as lists, numpy arrays and scalars
    as Python values, anything else as its ``repr`` (used for ``meta`` and summaries)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    return repr(obj)


def _finite_or_none(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite_or_none(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def json_text(obj: Any, indent: int | None = 2) -> str:
    """``obj`` as strict JSON text for the output files users read (summary.json, metrics.json,
    custody.json): :func:`jsonable`, then every NaN or infinity as ``null`` (they are not JSON,
    and strict parsers refuse them), dumped with ``allow_nan=False``."""
    return json.dumps(_finite_or_none(jsonable(obj)), indent=indent, allow_nan=False)


def replace_markdown_section(path: str | Path, text: str) -> Path:
    """Replace the ``## Heading`` section of a markdown file by ``text`` (or append it).

    ``text`` starts with its ``## `` heading line; the old section runs to the next ``## ``
    heading.  The rest of the file is left alone and the file is written atomically, so several
    scripts can each keep their own section of ``docs/benchmarks.md`` or of a file of
    ``docs/validation/``.
    """
    path = Path(path)
    heading = text.lstrip().splitlines()[0].strip() if text.strip() else ""
    if not heading.startswith("## "):
        raise ProblemError(f"text must start with a '## ' heading line; got {heading[:40]!r}")
    old = path.read_text() if path.exists() else ""
    lines = old.splitlines()
    start = next((i for i, ln in enumerate(lines) if ln.strip() == heading), None)
    body = text.strip().splitlines()
    if start is None:
        new = (old.rstrip() + "\n\n" if old.strip() else "") + "\n".join(body) + "\n"
    else:
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")),
                   len(lines))
        tail = [""] + lines[end:] if end < len(lines) else []
        new = "\n".join(lines[:start] + body + tail) + "\n"
    return atomic_write_text(path, new)
