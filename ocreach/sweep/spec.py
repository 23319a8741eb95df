"""Sweep specifications: a list and/or product of tasks as plain data, validated before any work.

A spec (JSON; TOML where Python has ``tomllib``) has these top-level keys::

    {"name": "thrust sweep",               # optional text
     "description": "...",                 # optional text
     "base":    {TASK FIELDS},             # defaults every task starts from
     "catalog": {"file": "objects.csv", "limit": 100},   # one task per row (ocreach.sweep.catalog)
     "tasks":   [{TASK FIELDS}, ...],      # an explicit list
     "product": {"options.thrust": [1e-4, 1e-3], "horizon": [{"value": 1, "unit": "d"}]}}

The tasks are ``catalog rows x tasks x product combinations`` (each factor is ``[{}]`` when
absent), each merged onto ``base`` (dict fields merged key by key, later wins).  Product axes
are task fields or dotted paths into them (``options.samples``, ``overrides.thrust``,
``keep.custody.fov_deg``).

Task fields:

* ``problem``: a problem id (``ocreach list``) or a problem file ``FILE.py`` / ``FILE.py:ID``
  (relative to the spec file; its SHA-256 goes into the task so an edited file is a new task);
* ``overrides``: keyword arguments of the problem factory (``thrust``, ``t_final``, ``epoch_s``...);
* ``state``: the initial state, a list in model units or ``{"names", "values", "units"}`` (see
  :mod:`ocreach.sweep.catalog` for the units);
* ``horizon``: the final time, a number in model time units or ``{"value": 3, "unit": "d"}``
  (units ``TU``, ``s``, ``h``, ``d``); the grid keeps the problem's first step length;
* ``method`` and ``options``: as ``ocreach.reach(problem, method, **options)``;
* ``keep``: what to record (:data:`KEEP_DEFAULTS`): ``dims`` (the subspace, default
  ``"position"``), ``extent`` (min/max per dim), ``support`` (directions in that subspace),
  ``meb`` (minimum-enclosing-ball radius), ``volume`` (convex-hull volume), ``custody``
  (keyword arguments of the custody hook, :func:`ocreach.sweep.outputs.custody_outputs`),
  ``result`` (write the full result);
* ``tags``: free labels copied to the table (a catalog row's ``name`` becomes ``tags.object``);
* ``label``: optional text.

Every name is checked (unknown keys, problems, factory arguments and their declared types,
methods, option names and values via the method's ``Options``), and each task's problem is built
once in the driver to check the factory values, the state (catalog columns), the horizon unit and
``keep`` against it (:func:`_check_with_problems`), before any task runs; errors name the task,
the catalog row, the value and what is allowed.
"""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import inspect
import itertools
import json
import math
import sys
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from ocreach.errors import OcreachError
from ocreach.sweep.catalog import UNITS, read_catalog
from ocreach.sweep.errors import SweepError
from ocreach.sweep.keys import canonical_json, digest, task_key
from ocreach.sweep.worker import HORIZON_UNITS, base_problem, build_problem, split_problem_ref

TOP_KEYS = ("name", "description", "base", "catalog", "tasks", "product")
TASK_KEYS = ("problem", "overrides", "state", "horizon", "method", "options", "keep", "tags", "label")
MERGED = ("overrides", "options", "keep", "tags")  # dict fields merged key by key
CATALOG_KEYS = ("file", "limit")
KEEP_DEFAULTS: dict[str, Any] = {"dims": "position", "extent": True, "support": [], "meb": False,
                                 "volume": False, "custody": None, "result": False}
@dataclass
class Spec:
    """An expanded, validated sweep: ``tasks[i]`` is plain data, ``keys[i]`` its key."""

    tasks: list[dict[str, Any]]
    raw: dict[str, Any]
    base_dir: str
    name: str = ""
    path: str | None = None
    package_versions: dict[str, str] | None = field(default=None, repr=False)

    @cached_property
    def keys(self) -> list[str]:
        return [task_key(t, self.package_versions) for t in self.tasks]

    @cached_property
    def spec_hash(self) -> str:
        """Hash of the expanded task list (what a sweep folder belongs to)."""
        return digest(self.tasks)

    def __len__(self) -> int:
        return len(self.tasks)


# ---------------------------------------------------------------------------- loading
def load_spec(path: str | Path) -> Spec:
    """Read, expand and validate the spec file ``path`` (``.json``, or ``.toml`` on Python 3.11+)."""
    path = Path(path)
    if not path.is_file():
        raise SweepError(f"sweep spec {str(path)!r} does not exist")
    text = path.read_text(encoding="utf-8")
    if path.suffix.lower() == ".toml":
        if sys.version_info < (3, 11):
            raise SweepError(f"{path}: TOML specs need Python >= 3.11 (tomllib); write it as JSON")
        import tomllib

        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SweepError(f"{path} is not valid TOML: {exc}") from None
    elif path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise SweepError(f"{path} is not valid JSON: {exc}") from None
    else:
        raise SweepError(f"sweep spec must be a .json or .toml file; got {str(path)!r}")
    spec = spec_from_dict(data, base_dir=path.resolve().parent)
    spec.path = str(path.resolve())
    return spec


def spec_from_dict(data: dict[str, Any], base_dir: str | Path | None = None,
                   package_versions: dict[str, str] | None = None) -> Spec:
    """Expand and validate a spec given as a dict (relative files resolve against ``base_dir``)."""
    base = Path(base_dir or ".").resolve()
    if not isinstance(data, dict):
        raise SweepError(f"a sweep spec must be a JSON object; got {type(data).__name__}")
    _check_keys(data, TOP_KEYS, "the spec")
    if not any(k in data for k in ("catalog", "tasks", "product")):
        raise SweepError("the spec has no tasks: give at least one of 'catalog', 'tasks', 'product'")
    template = data.get("base", {})
    _check_partial(template, "'base'")
    rows: list[dict[str, Any]] = [{}]
    if "catalog" in data:
        cat = data["catalog"]
        if not isinstance(cat, dict) or "file" not in cat:
            raise SweepError(f"'catalog' must be {{\"file\": \"objects.csv\"[, \"limit\": N]}}; got {cat!r}")
        _check_keys(cat, CATALOG_KEYS, "'catalog'")
        limit = cat.get("limit")
        if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 1):
            raise SweepError(f"catalog 'limit' must be an integer >= 1; got {limit!r}")
        rows = read_catalog(base / cat["file"], limit)
    items: list[dict[str, Any]] = [{}]
    if "tasks" in data:
        items = data["tasks"]
        if not isinstance(items, list) or not items:
            raise SweepError(f"'tasks' must be a non-empty list of task objects; got {items!r}")
        for i, item in enumerate(items):
            _check_partial(item, f"tasks[{i}]")
    combos: list[dict[str, Any]] = [{}]
    if "product" in data:
        combos = _product(data["product"])
    tasks, origins = [], []
    for (r, row), item, combo in itertools.product(enumerate(rows), items, combos):
        merged = _merge(_merge(_merge(copy.deepcopy(template), row), item), combo)
        tasks.append(merged)
        origins.append(f"catalog {data['catalog']['file']} data row {r + 1}" if "catalog" in data else "")
    files: dict[str, str] = {}
    normalized = [normalize_task(t, i, base, files) for i, t in enumerate(tasks)]
    spec = Spec(tasks=normalized, raw=data, base_dir=str(base), name=str(data.get("name", "")),
                package_versions=package_versions)
    _check_unique(spec)
    _check_with_problems(spec, origins)
    return spec


# ---------------------------------------------------------------------------- helpers
def _check_keys(obj: dict[str, Any], allowed: tuple[str, ...], where: str) -> None:
    unknown = sorted(set(obj) - set(allowed))
    if unknown:
        raise SweepError(f"{where} has unknown key(s) {unknown}; allowed: {list(allowed)}")


def _check_partial(obj: Any, where: str) -> None:
    if not isinstance(obj, dict):
        raise SweepError(f"{where} must be an object of task fields; got {obj!r}")
    _check_keys(obj, TASK_KEYS, where)
    for name in MERGED:
        if name in obj and not isinstance(obj[name], dict):
            raise SweepError(f"{where}: '{name}' must be an object; got {obj[name]!r}")


def _deep(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = _deep(out[k], v) if isinstance(out.get(k), dict) and isinstance(v, dict) else copy.deepcopy(v)
    return out


def _merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """``b`` over ``a``: the fields in :data:`MERGED` merge key by key (recursively), others replace."""
    out = dict(a)
    for k, v in b.items():
        if k in MERGED and isinstance(out.get(k), dict) and isinstance(v, dict):
            out[k] = _deep(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _product(axes: Any) -> list[dict[str, Any]]:
    if not isinstance(axes, dict) or not axes:
        raise SweepError(f"'product' must be a non-empty object {{axis: [values]}}; got {axes!r}")
    names = list(axes)
    for name in names:
        head, _, rest = name.partition(".")
        if head not in TASK_KEYS:
            raise SweepError(f"product axis {name!r}: {head!r} is not a task field; allowed: "
                             f"{list(TASK_KEYS)} (or FIELD.NAME inside {list(MERGED)})")
        if rest and head not in MERGED:
            raise SweepError(f"product axis {name!r}: only {list(MERGED)} take a dotted name")
        if not isinstance(axes[name], list) or not axes[name]:
            raise SweepError(f"product axis {name!r} must be a non-empty list; got {axes[name]!r}")
    out = []
    for values in itertools.product(*(axes[n] for n in names)):
        combo: dict[str, Any] = {}
        for name, v in zip(names, values):
            *parents, leaf = name.split(".")
            node = combo
            for part in parents:
                node = node.setdefault(part, {})
                if not isinstance(node, dict):
                    raise SweepError(f"product axis {name!r} conflicts with another axis")
            node[leaf] = v
        _check_partial(combo, f"product {combo!r}")
        out.append(combo)
    return out


def _where(i: int, task: dict[str, Any]) -> str:
    tags = task.get("tags") or {}
    label = task.get("label") or tags.get("object")
    return f"task {i}" + (f" ({label})" if label else "")


def _finite(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SweepError(f"{what} must be a finite number; got {value!r}")
    return value


def _problem_factory(ref: str, base: Path, files: dict[str, str], where: str):
    """``(factory, sha256 of the file or None)``; unknown ids, missing or broken files raise."""
    from ocreach.registry import problem_factories, problem_factory

    if not isinstance(ref, str) or not ref:
        raise SweepError(f"{where}: 'problem' must be a problem id or a .py file; got {ref!r}")
    if ref.endswith(".py") or ".py:" in ref:
        if "\0file " + ref in files:
            return files["\0factory " + ref], files["\0file " + ref]
        path, _pid = split_problem_ref(ref)
        full = (base / path).resolve()
        if not full.is_file():
            raise SweepError(f"{where}: problem file {path!r} does not exist (looked in {full})")
        files["\0file " + ref] = hashlib.sha256(full.read_bytes()).hexdigest()
        try:  # imports the file (as the worker will); its factory is called by _check_with_problems
            _sub, factory = problem_factory(str(full) + (f":{_pid}" if _pid is not None else ""))
        except Exception as exc:  # noqa: BLE001 - user code: any error is a bad problem file
            raise SweepError(f"{where}: problem file {path!r} cannot be loaded: "
                             f"{type(exc).__name__}: {exc}") from None
        files["\0factory " + ref] = factory  # type: ignore[assignment]
        return factory, files["\0file " + ref]
    if "\0registry" not in files:
        files["\0registry"] = problem_factories()  # type: ignore[assignment]
    reg = files["\0registry"]
    if ref not in reg:
        raise SweepError(f"{where}: unknown problem {ref!r}; available: {sorted(reg)} or a .py file")
    return reg[ref], None


def _check_overrides(factory, overrides: dict[str, Any], ref: str, where: str) -> None:
    """Override names against the factory's keywords and values against their declared types
    (``bool`` strictly, ``float``/``int`` finite numbers, ``str`` text), as the worker's
    :func:`ocreach.registry.get_problem` will convert them."""
    from ocreach.options import _type_text, strict_bools, typed_number

    sig = inspect.signature(factory)
    params = {n: p for n, p in sig.parameters.items() if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
    if not any(p.kind is p.VAR_KEYWORD for p in sig.parameters.values()):
        unknown = sorted(set(overrides) - set(params))
        if unknown:
            raise SweepError(f"{where}: problem {ref!r} has no override(s) {unknown}; allowed: "
                             f"{list(params)}")
    for k, v in overrides.items():
        if k not in params:
            continue
        ann = params[k].annotation
        declared = _type_text(ann) or "any"
        try:
            strict_bools(factory, {k: v})
            typed_number(k, v, ann)
        except OcreachError as exc:
            raise SweepError(f"{where}: problem {ref!r} override {k!r} = {v!r} does not fit its "
                             f"declared type {declared}: {exc}") from None
        parts = {t.strip() for t in declared.replace("|", ",").split(",")}
        if "str" in parts and parts <= {"str", "None"} and not (isinstance(v, str) or v is None and "None" in parts):
            raise SweepError(f"{where}: problem {ref!r} override {k!r} must be text (declared "
                             f"{declared}); got {v!r}")


def _check_with_problems(spec: Spec, origins: list[str]) -> None:
    """Build each task's problem in the driver, as its worker will, and check the task against it.

    The base problem (factory and overrides) is built once per distinct problem and kept in the
    worker module's per-process cache (a serial run reuses it); then the state (catalog columns:
    names exactly the model's states, units of the right kind), the horizon unit and ``keep``
    (``dims``, ``support`` length, custody arguments) are checked.  Errors name the task, the
    catalog file and data row it came from, the value and what is allowed.
    """
    from ocreach.sweep.outputs import check_keep

    for i, (task, origin) in enumerate(zip(spec.tasks, origins)):
        where = _where(i, task) + (f", {origin}" if origin else "")
        try:
            base_problem(task, spec.base_dir)
        except SweepError as exc:
            raise SweepError(f"{where}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - user factories may raise anything
            raise SweepError(f"{where}: problem {task['problem']!r} with overrides "
                             f"{task['overrides']} cannot be built: {type(exc).__name__}: {exc}") from None
        try:
            check_keep(task["keep"], build_problem(task, spec.base_dir))
        except OcreachError as exc:
            raise SweepError(f"{where}: {exc}") from None


def _check_method(method: Any, options: dict[str, Any], where: str) -> None:
    from ocreach.reach.base import method_class

    if not isinstance(method, str):
        raise SweepError(f"{where}: 'method' must be a method name; got {method!r}")
    try:
        cls = method_class(method)
    except OcreachError as exc:
        raise SweepError(f"{where}: {exc}") from None
    fields = [f.name for f in dataclasses.fields(cls.Options)]
    unknown = sorted(set(options) - set(fields))
    if unknown:
        raise SweepError(f"{where}: method {method!r} has no option(s) {unknown}; allowed: {fields}")
    try:
        cls.Options(**options)
    except (OcreachError, TypeError, ValueError) as exc:
        raise SweepError(f"{where}: bad option value for method {method!r}: {exc}") from None


def _normalize_state(state: Any, where: str) -> dict[str, Any] | None:
    if state is None:
        return None
    if isinstance(state, list):
        state = {"names": None, "values": state, "units": None}
    if not isinstance(state, dict):
        raise SweepError(f"{where}: 'state' must be a list (model units) or "
                         f"{{\"names\", \"values\", \"units\"}}; got {state!r}")
    _check_keys(state, ("names", "values", "units"), f"{where}: 'state'")
    values = state.get("values")
    if not isinstance(values, list) or not values:
        raise SweepError(f"{where}: state 'values' must be a non-empty list; got {values!r}")
    values = [_finite(v, f"{where}: state value") for v in values]
    names, units = state.get("names"), state.get("units")
    for what, seq in (("names", names), ("units", units)):
        if seq is not None and (not isinstance(seq, list) or len(seq) != len(values)):
            raise SweepError(f"{where}: state '{what}' must be a list of {len(values)} entries; "
                             f"got {seq!r}")
    for u in units or []:
        if u not in UNITS:
            raise SweepError(f"{where}: state unit {u!r} is not allowed; allowed: {sorted(UNITS)}")
    return {"names": names, "values": values, "units": units}


def _normalize_horizon(h: Any, where: str) -> dict[str, Any] | None:
    if h is None:
        return None
    if not isinstance(h, dict):
        h = {"value": h, "unit": "TU"}
    _check_keys(h, ("value", "unit"), f"{where}: 'horizon'")
    value = _finite(h.get("value"), f"{where}: horizon value")
    unit = h.get("unit", "TU")
    if unit not in HORIZON_UNITS:
        raise SweepError(f"{where}: horizon unit {unit!r} is not allowed; allowed: {list(HORIZON_UNITS)}")
    if value <= 0:
        raise SweepError(f"{where}: horizon must be > 0 (its direction follows the problem's grid); "
                         f"got {value!r}")
    return {"value": value, "unit": unit}


def _normalize_keep(keep: dict[str, Any], where: str) -> dict[str, Any]:
    _check_keys(keep, tuple(KEEP_DEFAULTS), f"{where}: 'keep'")
    out = {**KEEP_DEFAULTS, **keep}
    for flag in ("extent", "meb", "volume", "result"):
        if not isinstance(out[flag], bool):
            raise SweepError(f"{where}: keep.{flag} must be true or false; got {out[flag]!r}")
    dims = out["dims"]
    if not (dims in ("position", "velocity", "all")
            or (isinstance(dims, list) and dims and all(isinstance(d, int) and not isinstance(d, bool)
                                                        and d >= 0 for d in dims))):
        raise SweepError(f"{where}: keep.dims must be 'position', 'velocity', 'all' or a list of "
                         f"state indices; got {dims!r}")
    sup = out["support"]
    if not isinstance(sup, list) or not all(isinstance(d, list) and d for d in sup):
        raise SweepError(f"{where}: keep.support must be a list of directions (lists of numbers); "
                         f"got {sup!r}")
    for d in sup:
        if len(d) != len(sup[0]):
            raise SweepError(f"{where}: keep.support directions must all have the same length; got {sup!r}")
        for v in d:
            _finite(v, f"{where}: keep.support entry")
        if not any(v != 0 for v in d):
            raise SweepError(f"{where}: keep.support direction {d!r} is zero")
    if out["custody"] is not None and not isinstance(out["custody"], dict):
        raise SweepError(f"{where}: keep.custody must be an object of custody arguments or "
                         f"null; got {out['custody']!r}")
    return out


def normalize_task(task: dict[str, Any], i: int, base: Path, files: dict[str, Any]) -> dict[str, Any]:
    """The canonical plain-data form of a merged task (every field present), validated.

    ``files`` caches work shared by the tasks of one spec (problem-file hashes, the problem
    registry, method/option checks already passed)."""
    where = _where(i, task)
    _check_keys(task, TASK_KEYS, where)
    for req in ("problem", "method"):
        if req not in task:
            raise SweepError(f"{where}: '{req}' is missing (give it in 'base' or in the task)")
    ref = task["problem"]
    factory, sha = _problem_factory(ref, base, files, where)
    overrides = dict(task.get("overrides") or {})
    options = dict(task.get("options") or {})
    _check_overrides(factory, overrides, ref, where)
    checked = "\0method " + canonical_json([task["method"], options]) if _plain(options) else None
    if checked is None or checked not in files:
        _check_method(task["method"], options, where)
        if checked is not None:
            files[checked] = ""
    tags = dict(task.get("tags") or {})
    for k, v in tags.items():
        if not isinstance(v, (str, int, float, bool)) or isinstance(v, float) and not math.isfinite(v):
            raise SweepError(f"{where}: tag {k!r} must be text, a number or a boolean; got {v!r}")
    label = task.get("label")
    if label is not None and not isinstance(label, str):
        raise SweepError(f"{where}: 'label' must be text; got {label!r}")
    out = {
        "problem": ref, "problem_sha256": sha, "overrides": overrides,
        "state": _normalize_state(task.get("state"), where),
        "horizon": _normalize_horizon(task.get("horizon"), where),
        "method": task["method"], "options": options,
        "keep": _normalize_keep(dict(task.get("keep") or {}), where),
        "tags": tags, "label": label,
    }
    try:
        canonical_json(out)
    except (TypeError, ValueError) as exc:
        raise SweepError(f"{where}: the task is not plain JSON data ({exc})") from None
    return out


def _plain(obj: Any) -> bool:
    try:
        canonical_json(obj)
    except (TypeError, ValueError):
        return False
    return True


def _check_unique(spec: Spec) -> None:
    seen: dict[str, int] = {}
    for i, t in enumerate(spec.tasks):
        h = digest(t)
        if h in seen:
            raise SweepError(f"tasks {seen[h]} and {i} are identical ({_where(i, t)}); each task "
                             f"must differ (add a tag or change a field)")
        seen[h] = i
