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

#: module-name prefix of a user's problem file loaded by path
USER_MODULE_PREFIX = "ocreach_user_"


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


def _call_factory(pid: str, factory: Callable[..., Problem], overrides: dict[str, Any],
                  source: Path | None = None) -> Problem:
    """``factory(**overrides)`` checked; ``source``: the user's problem file it came from, whose
    name and line then prefix whatever the factory raises."""
    overrides = dict(overrides)
    coordinates = overrides.pop("coordinates", None)   # every problem takes it (Problem.coordinates)
    if coordinates is not None:
        prob = _call_factory(pid, factory, overrides, source)
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
    if source is None:
        prob = factory(**overrides)
    else:  # a user's factory: whatever it raises is reported with the file and the line
        try:
            prob = factory(**overrides)
        except Exception as exc:
            raise ProblemError(_located(source, exc, f"factory {pid!r} raised")) from exc
    if not isinstance(prob, Problem):
        where = f"{source}: line {_first_line(factory)}: " if source is not None else ""
        raise ProblemError(f"{where}factory for {pid!r} must return an ocreach.Problem; got "
                           f"{type(prob).__name__}")
    return prob


def _first_line(factory: Callable[..., Problem]) -> int | str:
    code = getattr(factory, "__code__", None)
    return code.co_firstlineno if code is not None else "?"


def _located(path: Path, exc: BaseException, what: str = "") -> str:
    """``FILE.py: line N: WHAT: Type: message`` with the last line of ``path`` in the traceback
    (or the line of a syntax error); the type is left out for a ProblemError."""
    line = getattr(exc, "lineno", None) if isinstance(exc, SyntaxError) else None
    target = str(path.resolve())
    tb = exc.__traceback__
    while tb is not None:
        if str(Path(tb.tb_frame.f_code.co_filename).resolve()) == target:
            line = tb.tb_lineno
        tb = tb.tb_next
    msg = exc.msg if isinstance(exc, SyntaxError) else str(exc)
    kind = "" if isinstance(exc, ProblemError) else f"{type(exc).__name__}: "
    where = f"line {line}: " if line else ""
    return f"{path}: {where}" + (f"{what}: " if what else "") + kind + msg


def _file_table(path: Path) -> dict[str, Callable[..., Problem]]:
    if not path.is_file():
        raise ProblemError(f"problem file {str(path)!r} does not exist")
    spec = importlib.util.spec_from_file_location(f"{USER_MODULE_PREFIX}{path.stem}", path)
    if spec is None or spec.loader is None:
        raise ProblemError(f"problem file {str(path)!r} is not a Python file (FILE.py)")
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    except SyntaxError as exc:
        raise ProblemError(_located(path, exc)) from None
    except Exception as exc:
        raise ProblemError(_located(path, exc, "error while importing the problem file")) from exc
    table = getattr(mod, "PROBLEMS", None)
    if table is None and hasattr(mod, "problem"):
        table = {path.stem: mod.problem}
    if table is None:
        raise ProblemError(f"{path} defines neither PROBLEMS = {{id: factory}} nor problem()")
    if not isinstance(table, dict) or not table:
        raise ProblemError(f"{path}: PROBLEMS must be a non-empty dict {{id: factory}}; got "
                           f"{type(table).__name__} {_short(table)}")
    bad = {k: v for k, v in table.items() if not isinstance(k, str) or not callable(v)}
    if bad:
        raise ProblemError(f"{path}: PROBLEMS must map problem ids (str) to factories (callables "
                           f"returning an ocreach.Problem); got {_short(bad)}")
    return dict(table)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


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
    return get_problem(str(path) + (f":{pid}" if pid is not None else ""), **overrides)


def get_problem(pid: str, **overrides: Any) -> Problem:
    """Return the bundled problem ``pid`` (or a file ``f.py`` / ``f.py:ID``) with keyword overrides."""
    sub, factory = problem_factory(str(pid))
    file_spec = split_file_id(str(pid))
    return _call_factory(sub, factory, overrides, file_spec[0] if file_spec else None)
