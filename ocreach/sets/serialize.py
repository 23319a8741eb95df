"""Sets as plain arrays + JSON (the result file format; no pickle, a file is data, not code).

Every set type is written as its defining arrays under a schema name; unions as lists of parts.
:func:`to_arrays` turns a set into ``(descriptor, arrays)``: a JSON-able descriptor
``{"type": NAME, "arrays": {field: key}}`` (or ``{"type": NAME, "parts": [...]}`` for a union) and
a dict ``{key: ndarray}`` to store beside it; :func:`from_arrays` rebuilds the set.

Only registered types are ever constructed on load, and their classes are resolved from this
module's table (never from a name read from the file), so a crafted file cannot make ``load``
import or run anything.  A new set type registers itself with :func:`register_set_type`::

    register_set_type("ZonotopeUnion", "ocreach.sets.union:ZonotopeUnion", union=True)
    register_set_type("Zonotope", "ocreach.sets.zonotope:Zonotope", fields=("c", "G"))

``fields`` are attribute names that are also the constructor's keyword arguments (write
``"attr=kwarg"`` where they differ); a union type has a ``parts`` attribute and a constructor taking
the list of parts.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from ocreach.errors import ProblemError

#: Version of the set schema (bumped when a type's fields change meaning).
SET_SCHEMA_VERSION = 1


@dataclass(frozen=True)
class SetCodec:
    """How one set type is stored: class path ``"module:Class"``, array fields, or a union."""

    name: str
    cls_path: str
    fields: tuple[str, ...] = ()
    union: bool = False

    @property
    def attrs(self) -> list[str]:
        return [f.partition("=")[0] for f in self.fields]

    def kwargs(self) -> list[str]:
        return [f.partition("=")[2] or f.partition("=")[0] for f in self.fields]

    def cls(self) -> type:
        mod, _, qual = self.cls_path.partition(":")
        return getattr(importlib.import_module(mod), qual)


_CODECS: dict[str, SetCodec] = {}


def register_set_type(name: str, cls_path: str, fields: tuple[str, ...] = (),
                      union: bool = False) -> None:
    """Register a set type for the result format (see the module docstring)."""
    if not union and not fields:
        raise ProblemError(f"set type {name!r}: give its array fields or union=True")
    _CODECS[name] = SetCodec(name, cls_path, tuple(fields), union)


for _args in (
    ("Interval", "ocreach.sets.interval:Interval", ("lo", "hi")),
    ("Zonotope", "ocreach.sets.zonotope:Zonotope", ("c", "G")),
    ("PolyZonotope", "ocreach.sets.polyzonotope:PolyZonotope", ("c", "G", "GI", "E", "id")),
    ("Ellipsoid", "ocreach.sets.ellipsoid:Ellipsoid", ("q", "Q")),
    ("MatrixZonotope", "ocreach.sets.matzonotope:MatrixZonotope", ("C", "G=gens")),
):
    register_set_type(*_args)
register_set_type("PZUnion", "ocreach.sets.pz_union:PZUnion", union=True)
register_set_type("ZonotopeUnion", "ocreach.sets.union:ZonotopeUnion", union=True)


def registered_types() -> list[str]:
    """Names of the set types the result format can hold."""
    return sorted(_CODECS)


def _codec_of(obj: Any) -> SetCodec:
    path = f"{type(obj).__module__}:{type(obj).__qualname__}"
    for codec in _CODECS.values():
        if codec.cls_path == path:
            return codec
    raise ProblemError(f"cannot save a set of type {type(obj).__name__} ({path}); the result "
                       f"format holds {registered_types()} (register others with "
                       "ocreach.sets.serialize.register_set_type)")


def to_arrays(obj: Any, prefix: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """``(descriptor, arrays)`` of set ``obj``; array keys start with ``prefix``."""
    codec = _codec_of(obj)
    if codec.union:
        descs, arrays = [], {}
        for i, part in enumerate(obj.parts):
            d, a = to_arrays(part, f"{prefix}.{i}")
            descs.append(d)
            arrays.update(a)
        return {"type": codec.name, "parts": descs}, arrays
    arrays = {f"{prefix}.{f}": np.asarray(getattr(obj, f)) for f in codec.attrs}
    return {"type": codec.name, "arrays": {f: f"{prefix}.{f}" for f in codec.attrs}}, arrays


def from_arrays(desc: Any, arrays: Any) -> Any:
    """The set described by ``desc`` (from :func:`to_arrays`) with its arrays looked up in
    ``arrays`` (a mapping such as an open ``np.load`` file).  Raises :class:`ProblemError` for an
    unknown type or a malformed descriptor."""
    if not isinstance(desc, dict) or desc.get("type") not in _CODECS:
        got = desc.get("type") if isinstance(desc, dict) else desc
        raise ProblemError(f"unknown set type {got!r} in the set descriptor; known: {registered_types()}")
    codec = _CODECS[desc["type"]]
    if codec.union:
        parts = desc.get("parts")
        if not isinstance(parts, list):
            raise ProblemError(f"set descriptor of {codec.name} needs a list 'parts'")
        return codec.cls()([from_arrays(p, arrays) for p in parts])
    keys = desc.get("arrays")
    if not isinstance(keys, dict) or set(keys) != set(codec.attrs):
        raise ProblemError(f"set descriptor of {codec.name} needs arrays {codec.attrs}; "
                           f"got {keys!r}")
    return codec.cls()(**{kw: arrays[str(keys[a])] for a, kw in zip(codec.attrs, codec.kwargs())})
