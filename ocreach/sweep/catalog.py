"""A catalog of objects from a CSV file: one object per row, its initial state with units.

Format (``#`` lines are comments)::

    name,problem,family,x[km],y[km],z[km],vx[km/s],vy[km/s],vz[km/s]
    dro-0001,l2-halo,DRO,...

* ``name`` (required, unique): the object id, kept as tag ``object``;
* ``problem`` (optional): the problem id / file of that row (else the spec's base problem);
* state columns ``NAME[UNIT]``: ``NAME`` a state name of the model (checked by the driver against
  ``model.state_names``, :func:`ocreach.sweep.worker.state_vector`), ``UNIT`` one of :data:`UNITS` (``nd`` = the model's own units);
  every state column must carry a unit, so a km value is never read as a model unit;
* any other column is kept as a text tag (e.g. ``family``).

Each row becomes a partial task ``{"state": {...}, "tags": {...}[, "problem": ...]}``; the unit
conversion happens in the worker, where the problem's :class:`ocreach.units.Units` is known.
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import Any

from ocreach.sweep.errors import SweepError

#: unit -> (kind, SI factor); kind "nd" means the model's own units (no conversion)
UNITS: dict[str, tuple[str, float]] = {
    "nd": ("nd", 1.0), "DU": ("nd", 1.0), "DU/TU": ("nd", 1.0),
    "m": ("length", 1.0), "km": ("length", 1e3), "AU": ("length", 1.495978707e11),
    "m/s": ("velocity", 1.0), "km/s": ("velocity", 1e3),
    "kg": ("mass", 1.0),
}
_COLUMN = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*\[\s*([^\]]+?)\s*\]\s*$")
RESERVED = ("name", "problem")


def read_catalog(path: str | Path, limit: int | None = None) -> list[dict[str, Any]]:
    """Partial tasks, one per row of the CSV catalog at ``path`` (first ``limit`` rows if given)."""
    path = Path(path)
    if not path.is_file():
        raise SweepError(f"catalog file {str(path)!r} does not exist")
    with path.open(newline="", encoding="utf-8") as fh:
        lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    rows = list(csv.reader(lines))
    if not rows:
        raise SweepError(f"catalog {path} has no header line")
    header = [h.strip() for h in rows[0]]
    if "name" not in header:
        raise SweepError(f"catalog {path}: a 'name' column is required; got columns {header}")
    if len(set(header)) != len(header):
        raise SweepError(f"catalog {path}: repeated column names in {header}")
    state_cols: list[tuple[int, str, str]] = []
    tag_cols: list[tuple[int, str]] = []
    for j, h in enumerate(header):
        m = _COLUMN.match(h)
        if m:
            name, unit = m.group(1), m.group(2)
            if unit not in UNITS:
                raise SweepError(f"catalog {path}: column {h!r} has unit {unit!r}; allowed units: "
                                 f"{sorted(UNITS)}")
            state_cols.append((j, name, unit))
        elif h in RESERVED or re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", h):
            if h != "name" and h != "problem":
                tag_cols.append((j, h))
        else:
            raise SweepError(f"catalog {path}: column {h!r} is neither NAME[UNIT] (a state with "
                             f"its unit) nor a plain tag name")
    if not state_cols:
        raise SweepError(f"catalog {path}: no state columns NAME[UNIT] (e.g. 'x[km]') in {header}")
    i_name = header.index("name")
    i_prob = header.index("problem") if "problem" in header else None
    out: list[dict[str, Any]] = []
    seen: dict[str, int] = {}
    body = rows[1:] if limit is None else rows[1:1 + int(limit)]
    for r, row in enumerate(body, start=2):
        if len(row) != len(header):
            raise SweepError(f"catalog {path} data row {r - 1}: {len(row)} fields, header has "
                             f"{len(header)}")
        name = row[i_name].strip()
        if not name:
            raise SweepError(f"catalog {path} data row {r - 1}: empty name")
        if name in seen:
            raise SweepError(f"catalog {path}: object name {name!r} repeated (data rows "
                             f"{seen[name]} and {r - 1})")
        seen[name] = r - 1
        values = []
        for j, col, _unit in state_cols:
            try:
                v = float(row[j])
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise SweepError(f"catalog {path} object {name!r}: column {header[j]!r} must be a "
                                 f"finite number; got {row[j]!r}")
            values.append(v)
        task: dict[str, Any] = {
            "state": {"names": [c[1] for c in state_cols], "values": values,
                      "units": [c[2] for c in state_cols]},
            "tags": {"object": name, **{h: row[j].strip() for j, h in tag_cols}},
        }
        if i_prob is not None and row[i_prob].strip():
            task["problem"] = row[i_prob].strip()
        out.append(task)
    if not out:
        raise SweepError(f"catalog {path} has no data rows")
    return out
