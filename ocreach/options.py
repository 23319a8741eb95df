"""Option values by declared type: strict booleans, CLI strings, and option descriptions.

A method's options are the fields of its ``Options`` dataclass; a problem's overrides are the
keyword arguments of its factory.  Both declare types (``lift_independent: bool = False``), and
values typed on the command line are converted by that declared type, not by guessing:
``bool`` accepts only true/false/1/0/yes/no/on/off (any case), everything else is parsed as a
Python literal (``400``, ``1e-3``, ``(4, 0.01)``, ``None``) or kept as a string.

:func:`describe_fields` lists a dataclass's (or a factory's) options with default, type and
description (``ocreach methods NAME`` and ``ocreach problem ID`` print it).  A dataclass field is
described by the ``#:`` comment lines right above it (or a ``#:`` comment on its line), searched
through the class's bases, as Sphinx reads attribute comments::

    #: zonotope order (generators / n) after each step, >= 1
    order: float = 10.0

A field without one, and a factory's parameter, get the sentence of the docstring that names it
in double backquotes.
"""
from __future__ import annotations

import ast
import dataclasses
import inspect
import re
import textwrap
from typing import Any

import numpy as np

from ocreach.errors import ProblemError

TRUE_WORDS = ("true", "1", "yes", "on")
FALSE_WORDS = ("false", "0", "no", "off")


def parse_bool(name: str, raw: Any) -> bool:
    """``raw`` as a boolean: a bool, the ints 0/1, or one of true/false/1/0/yes/no/on/off."""
    if isinstance(raw, (bool, np.bool_)):
        return bool(raw)
    if isinstance(raw, (int, np.integer)) and raw in (0, 1):
        return bool(raw)
    if isinstance(raw, str) and raw.strip().lower() in TRUE_WORDS + FALSE_WORDS:
        return raw.strip().lower() in TRUE_WORDS
    raise ProblemError(f"{name} must be a boolean ({'/'.join(TRUE_WORDS)} or "
                       f"{'/'.join(FALSE_WORDS)}); got {raw!r}")


def _type_text(annotation: Any) -> str:
    if annotation is inspect.Parameter.empty or annotation is dataclasses.MISSING:
        return ""
    return annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))


def is_bool_type(annotation: Any) -> bool:
    """Whether a declared type is ``bool`` (or ``bool | None``)."""
    parts = {p.strip() for p in re.split(r"[|,\[\]]", _type_text(annotation)) if p.strip()}
    return "bool" in parts and parts <= {"bool", "None", "Optional"}


def _number_kind(annotation: Any) -> tuple[str, bool] | None:
    """``("float" | "int", none_allowed)`` for a declared ``float``/``int`` (optionally ``| None``)."""
    parts = {p.strip() for p in re.split(r"[|,\[\]]", _type_text(annotation)) if p.strip()}
    nums = parts & {"float", "int"}
    if len(nums) != 1 or not parts <= {"float", "int", "None", "Optional"}:
        return None
    return nums.pop(), "None" in parts


def typed_number(name: str, value: Any, annotation: Any) -> Any:
    """``value`` checked against a declared ``float``/``int`` (finite number; integral for int);
    other declared types pass unchanged.  Raises :class:`ProblemError` naming ``name``."""
    from ocreach.errors import check_real

    kind = _number_kind(annotation)
    if kind is None or (value is None and kind[1]):
        return value
    if isinstance(value, str):
        value = parse_literal(value)
    v = check_real(name, value)
    if kind[0] == "int":
        if v != int(v):
            raise ProblemError(f"{name} must be an integer; got {value!r}")
        return int(v)
    return v


def parse_literal(raw: str) -> Any:
    """A CLI string as a Python literal if it is one (``400``, ``1e-3``, ``None``), else the string."""
    try:
        return ast.literal_eval(raw)
    except (ValueError, SyntaxError, MemoryError, RecursionError, TypeError):
        return raw


def declared_types(target: Any) -> dict[str, Any]:
    """``{name: declared type}`` of a dataclass's fields or a callable's keyword parameters."""
    if dataclasses.is_dataclass(target):
        return {f.name: f.type for f in dataclasses.fields(target)}
    params = inspect.signature(target).parameters.values()
    return {p.name: p.annotation for p in params if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}


def coerce(values: dict[str, str], target: Any, where: str = "") -> dict[str, Any]:
    """CLI strings converted by the declared types of ``target`` (dataclass or callable).

    Unknown names are parsed as literals and left for ``target`` to refuse by name.
    """
    types = declared_types(target)
    out = {}
    for key, raw in values.items():
        label = f"{where}{key}"
        if not isinstance(raw, str):
            out[key] = raw
        elif key in types and is_bool_type(types[key]):
            out[key] = None if raw.strip() == "None" and "None" in _type_text(types[key]) else parse_bool(label, raw)
        elif key in types and not dataclasses.is_dataclass(target) and _number_kind(types[key]):
            out[key] = typed_number(label, raw, types[key])  # problem factories: float/int args
        else:
            out[key] = parse_literal(raw)
    return out


def strict_bools(target: Any, values: dict[str, Any], where: str = "") -> dict[str, Any]:
    """``values`` with every field declared ``bool`` parsed strictly by :func:`parse_bool` (so the
    string ``"false"`` is False, not truthy; ``"maybe"`` or 2 raise naming the option)."""
    types = declared_types(target)
    out = dict(values)
    for key, val in values.items():
        if key in types and is_bool_type(types[key]) and not (val is None and "None" in _type_text(types[key])):
            out[key] = parse_bool(f"{where}{key}", val)
    return out


def _doc_for(doc: str, name: str) -> str:
    """The sentence(s) of ``doc`` that document ``name``: from its ````name```` mention (in an
    ``Options:`` paragraph if there is one; the first mention followed by ``(`` or ``:``, else the
    first) to the next option's mention or the end of the paragraph."""
    if not doc:
        return ""
    text = " ".join(doc.split())
    at = text.find("Options:")
    m = None
    for start in ((at, 0) if at >= 0 else (0,)):
        m = (re.compile(rf"``{re.escape(name)}``\s*[(:]").search(text, start)
             or re.compile(rf"``{re.escape(name)}``").search(text, start))
        if m:
            break
    if not m:
        return ""
    rest = text[m.start():]
    skip = len(name) + 8  # a separator right after the name ("``rtol``, ``atol``: ...") joins them
    nxt = next((h for h in re.finditer(r"(?<=[.;),]) ``[A-Za-z_][A-Za-z0-9_]*``", rest)
                if h.start() > skip), None)
    chunk = rest if nxt is None else rest[: nxt.start()]
    return chunk.strip().rstrip(";,").strip()


def field_comments(cls: type) -> dict[str, str]:
    """``{field: text}`` of the ``#:`` comments of the annotated class attributes of ``cls`` and
    its bases (the nearest class wins); classes without source (built-ins) add nothing."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        try:
            lines, _ = inspect.getsourcelines(klass)
        except (OSError, TypeError):
            continue
        tree = ast.parse(textwrap.dedent("".join(lines)))
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for node in body:
            if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
                continue
            i = node.lineno - 1                      # index of the field's line in ``lines``
            text = []
            _, _, trailing = lines[i].partition("#:")
            if trailing.strip():
                text.append(trailing.strip())
            j = i - 1
            above = []
            while j >= 0 and lines[j].strip().startswith("#:"):
                above.insert(0, lines[j].strip()[2:].strip())
                j -= 1
            text = above + text
            if text:
                out[node.target.id] = " ".join(text)
    return out


def describe_fields(target: Any, doc: str | None = None) -> list[dict[str, str]]:
    """``[{"name", "type", "default", "doc"}]`` of a dataclass's fields or a factory's parameters."""
    doc = inspect.getdoc(target) if doc is None else doc
    rows = []
    if dataclasses.is_dataclass(target):
        comments = field_comments(target if isinstance(target, type) else type(target))
        items = []
        for f in dataclasses.fields(target):
            default = f.default if f.default is not dataclasses.MISSING else (
                f.default_factory() if f.default_factory is not dataclasses.MISSING else "(required)")
            items.append((f.name, f.type, default,
                          f.metadata.get("doc", "") or comments.get(f.name, "")))
    else:
        items = [(p.name, p.annotation, "(required)" if p.default is p.empty else p.default, "")
                 for p in inspect.signature(target).parameters.values()
                 if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)]
    for name, typ, default, meta_doc in items:
        rows.append({"name": name, "type": _type_text(typ), "default": repr(default),
                     "doc": meta_doc or _doc_for(doc or "", name)})
    return rows


def format_fields(rows: list[dict[str, str]], indent: str = "  ", width: int = 100) -> str:
    """Rows of :func:`describe_fields` as text: name, type and default, then the description
    wrapped to ``width`` columns."""
    lines = []
    for r in rows:
        lines.append(f"{indent}{r['name']} : {r['type'] or '?'} = {r['default']}")
        if r["doc"]:
            lines += textwrap.wrap(r["doc"], width, initial_indent=indent + "    ",
                                   subsequent_indent=indent + "    ", break_on_hyphens=False)
    return "\n".join(lines)
