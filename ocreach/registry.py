"""Where problems come from: the bundled problems of ``ocreach.problems`` and users' problem files.

A scenario module in ``problems/`` (installed as ``ocreach.problems``) exposes a dict
``PROBLEMS = {id: factory}``; a user's file ``f.py`` does the same, or defines a function
``problem()``, and is named as ``f.py`` or ``f.py:ID``.  A factory's keyword arguments are the
problem's overrides (``--set problem.KEY=VALUE``), checked by name and type before the call.
"""
from __future__ import annotations

import importlib
import importlib.util
import inspect
import pkgutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ocreach.errors import ProblemError, UnknownNameError
from ocreach.problem import Problem


def _registry() -> dict[str, Callable[..., Problem]]:
    import ocreach.problems as pkg

    found: dict[str, Callable[..., Problem]] = {}
    for info in pkgutil.iter_modules(pkg.__path__):
        mod = importlib.import_module(f"ocreach.problems.{info.name}")
        found.update(getattr(mod, "PROBLEMS", {}))
    return found


def problem_factories() -> dict[str, Callable[..., Problem]]:
    """``{id: factory}`` of every bundled problem (one scan of ``ocreach.problems``)."""
    return _registry()


def list_problems() -> dict[str, str]:
    """``{id: one-line description}`` of every bundled problem."""
    out = {}
    for pid, fac in sorted(_registry().items()):
        doc = (inspect.getdoc(fac) or "").strip().splitlines()
        out[pid] = doc[0] if doc else ""
    return out


def _call_factory(pid: str, factory: Callable[..., Problem], overrides: dict[str, Any]) -> Problem:
    overrides = dict(overrides)
    coordinates = overrides.pop("coordinates", None)   # every problem takes it (Problem.coordinates)
    if coordinates is not None:
        prob = _call_factory(pid, factory, overrides)
        prob.coordinates = coordinates
        return prob.validate()
    sig = inspect.signature(factory)
    accepts_any = any(p.kind is p.VAR_KEYWORD for p in sig.parameters.values())
    allowed = [n for n, p in sig.parameters.items() if p.kind is not p.VAR_KEYWORD]
    unknown = [k for k in overrides if k not in allowed]
    if unknown and not accepts_any:
        raise ProblemError(f"problem {pid!r} has no option(s) {unknown}; allowed: {allowed}")
    from ocreach.options import strict_bools, typed_number

    overrides = strict_bools(factory, overrides, "problem option ")
    overrides = {k: typed_number(k, v, sig.parameters[k].annotation) if k in sig.parameters else v
                 for k, v in overrides.items()}
    prob = factory(**overrides)
    if not isinstance(prob, Problem):
        raise ProblemError(f"factory for {pid!r} must return a Problem; got {type(prob).__name__}")
    return prob


def _file_table(path: Path) -> dict[str, Callable[..., Problem]]:
    if not path.is_file():
        raise ProblemError(f"problem file {str(path)!r} does not exist")
    spec = importlib.util.spec_from_file_location(f"ocreach_user_{path.stem}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    table: dict[str, Callable[..., Problem]] = dict(getattr(mod, "PROBLEMS", {}))
    if not table and hasattr(mod, "problem"):
        table = {path.stem: mod.problem}
    if not table:
        raise ProblemError(f"{path} defines neither PROBLEMS = {{id: factory}} nor problem()")
    return table


def split_file_id(spec: str) -> tuple[Path, str | None] | None:
    """``"dir/f.py"`` -> ``(Path, None)``, ``"dir/f.py:ID"`` -> ``(Path, "ID")``, else None."""
    spec = str(spec)
    if spec.endswith(".py"):
        return Path(spec), None
    head, sep, tail = spec.rpartition(":")
    if sep and head.endswith(".py") and tail:
        return Path(head), tail
    return None


def problem_factory(pid: str) -> tuple[str, Callable[..., Problem]]:
    """``(id, factory)`` of a bundled problem id, a file ``f.py`` (one problem) or ``f.py:ID``."""
    file_spec = split_file_id(pid)
    if file_spec is not None:
        path, sub = file_spec
        table = _file_table(path)
        if sub is None:
            if len(table) != 1:
                raise ProblemError(f"{path} defines several problems {sorted(table)}; name one as "
                                   f"{path}:ID (e.g. {path}:{sorted(table)[0]})")
            sub = next(iter(table))
        if sub not in table:
            raise UnknownNameError(f"unknown problem {sub!r} in {path}; available: {sorted(table)}")
        return sub, table[sub]
    reg = _registry()
    if pid not in reg:
        raise UnknownNameError(f"unknown problem {pid!r}; available: {sorted(reg)} "
                               "(or a file FILE.py / FILE.py:ID)")
    return pid, reg[pid]


def load_problem_file(path: str | Path, pid: str | None = None, **overrides: Any) -> Problem:
    """Load a user problem from a Python file defining ``PROBLEMS`` or a ``problem()`` function."""
    sub, factory = problem_factory(str(path) + (f":{pid}" if pid is not None else ""))
    return _call_factory(sub, factory, overrides)


def get_problem(pid: str, **overrides: Any) -> Problem:
    """Return the bundled problem ``pid`` (or a file ``f.py`` / ``f.py:ID``) with keyword overrides."""
    sub, factory = problem_factory(str(pid))
    return _call_factory(sub, factory, overrides)
