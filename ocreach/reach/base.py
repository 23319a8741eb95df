"""Method base class, the method registry and ``reach()``.

A method is a class with a nested ``Options`` dataclass (defaults documented, validated in
``Options.__post_init__``) and ``solve(problem) -> ReachResult``.
"""
from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import platform
import time
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ocreach.errors import ProblemError, UnknownNameError, check_count, check_tolerances

if TYPE_CHECKING:
    from ocreach.problem import Problem
    from ocreach.reach.result import ReachResult

#: method name -> "module:Class".  Modules are imported lazily, so a method whose module is not
#: installed yet simply does not appear in :func:`list_methods`.
METHOD_PATHS: dict[str, str] = {
    "mc": "ocreach.reach.mc:MonteCarlo",
    "ode": "ocreach.reach.extremal:ExtremalODE",
    "ffoe": "ocreach.reach.indirect:FFOE",
    "ole": "ocreach.reach.indirect:OLE",
    "bvp": "ocreach.reach.bvp:BVPContinuation",
    "stt": "ocreach.reach.stt:STTReach",
    "taylor": "ocreach.reach.taylor:TaylorZonotope",
    "sdc": "ocreach.reach.sdc:SDCZonotope",
    "cut": "ocreach.reach.cut:CUTMoments",
}


class Method:
    """Base class of reachability methods."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""

    @dataclasses.dataclass
    class Options:
        pass

    def __init__(self, **options: Any) -> None:
        fields = {f.name for f in dataclasses.fields(self.Options)}
        unknown = sorted(set(options) - fields)
        if unknown:
            raise ProblemError(f"method {self.name!r} has no option(s) {unknown}; "
                               f"allowed: {sorted(fields)}")
        self.options = self.Options(**options)

    def solve(self, problem: Problem) -> ReachResult:
        """The reachable-set estimate of ``problem`` (each method implements this)."""
        raise NotImplementedError

    def base_meta(self, problem: Problem, runtime: dict[str, float]) -> dict[str, Any]:
        """The ``meta`` every result carries: method, options, runtime breakdown, versions."""
        import casadi

        return {
            "method": self.name,
            "options": dataclasses.asdict(self.options),
            "problem": problem.id,
            "runtime": runtime,
            "versions": {"ocreach": _version(), "casadi": casadi.__version__,
                         "numpy": np.__version__, "python": platform.python_version()},
        }


@dataclasses.dataclass
class SamplingOptions:
    """Options every sample-based method shares (``mc``, ``ode``; ``ffoe``/``ole`` can adopt it).

    ``samples``: number of trajectories (integer >= 1); ``seed``: RNG seed (integer >= 0, or
    None for fresh entropy); ``rtol``: relative integrator tolerance in (0, 1e-3); ``atol``:
    absolute tolerance (finite, >= 0).  Subclasses add fields and call ``super().__post_init__()``.
    """

    samples: int = 100
    seed: int | None = 0
    rtol: float = 1e-10
    atol: float = 1e-12

    def __post_init__(self) -> None:
        self.samples = check_count("samples", self.samples, 1)
        if self.seed is not None:
            self.seed = check_count("seed", self.seed, 0)
        self.rtol, self.atol = check_tolerances(self.rtol, self.atol)


def _version() -> str:
    from ocreach import __version__

    return __version__


class Timer:
    """Accumulates wall time of named phases: ``with timer("stt_generation"): ...``."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}

    def __call__(self, key: str):
        timer = self

        class _Ctx:
            def __enter__(self):
                self.t0 = time.perf_counter()

            def __exit__(self, *exc):
                timer.times[key] = timer.times.get(key, 0.0) + time.perf_counter() - self.t0

        return _Ctx()

    @property
    def total(self) -> float:
        return sum(self.times.values())


def method_class(name: str) -> type[Method]:
    """The class implementing method ``name``."""
    if name not in METHOD_PATHS:
        raise UnknownNameError(f"unknown method {name!r}; available: {sorted(available_methods())}")
    mod_name, cls_name = METHOD_PATHS[name].split(":")
    try:
        mod = importlib.import_module(mod_name)
    except ModuleNotFoundError as exc:
        if exc.name == mod_name:
            raise UnknownNameError(f"method {name!r} is not implemented in this version; "
                                   f"available: {sorted(available_methods())}") from None
        raise
    return getattr(mod, cls_name)


def available_methods() -> dict[str, str]:
    """``{name: description}`` of the methods that are installed."""
    out = {}
    for name, path in METHOD_PATHS.items():
        mod_name, cls_name = path.split(":")
        if importlib.util.find_spec(mod_name) is None:
            continue
        cls = getattr(importlib.import_module(mod_name), cls_name, None)
        if cls is not None:
            out[name] = cls.description
    return out


def reach(problem: Problem | str, method: str, *, threads: int | None = None,
          **options: Any) -> ReachResult:
    """Solve ``problem`` (a :class:`Problem` or a problem id) with ``method``.

    Options not given fall back to the problem's ``method_options[method]`` and then to the
    method's defaults.  ``ocreach.reach(p, "stt", h_max=400)`` is sugar for
    ``STTReach(h_max=400).solve(p)``.  ``threads``: threads of the native batch kernels (default
    :func:`ocreach.parallel.threads`); the method runs under the BLAS thread limit of
    :func:`ocreach.parallel.blas_limit` (neither changes results).
    """
    from ocreach import parallel
    from ocreach.problem import Problem, get_problem

    if not isinstance(problem, Problem):
        problem = get_problem(str(problem))
    cls = method_class(method)
    merged = {**problem.options_for(method), **options}
    with parallel.settings(threads=threads):
        return cls(**merged).solve(problem)
