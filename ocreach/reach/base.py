"""Method base class, the method registry and ``reach()``.

A method is a class with a nested ``Options`` dataclass (defaults documented, validated in
``Options.__post_init__``) and ``solve(problem) -> ReachResult``.
"""
from __future__ import annotations

import dataclasses
import functools
import importlib
import importlib.util
import platform
import time
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ocreach._version import __version__
from ocreach.errors import (
    OcreachError,
    ProblemError,
    UnknownNameError,
    _to_float,
    check_count,
    check_tolerances,
)

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
    "poly": "ocreach.reach.poly:PolyReachMethod",
    "cut": "ocreach.reach.cut:CUTMoments",
}


#: Options every method takes besides its own ``Options`` fields: name -> (default, description).
COMMON_OPTIONS: dict[str, tuple[Any, str]] = {
    "divergence_factor": (100.0, "stop with a SolverError (keeping the truncated part) when a set "
                          "or sample is non-finite or ||x||_inf exceeds this factor times the "
                          "problem scale max(1, ||x0||_inf, ||initial set||_inf) (ocreach.reach.guard); "
                          "> 1, inf disables the size check"),
    "max_memory_gb": (4.0, "refuse, before any work, a run whose estimated memory (samples x "
                      "times kept x values x 8 B x 4 copies, Method.memory_estimate) exceeds "
                      "this many GB; > 0"),
    "coordinates": ("cartesian", "propagate in other coordinates and convert the results back "
                    "soundly (ocreach.models.coordinates: cartesian, mee, mee-longitude, sundman; "
                    "NAME:key=value,... for settings); overrides the problem's coordinates"),
}

#: Bytes per stored number and working copies in :meth:`Method.memory_estimate`.
_BYTES, _COPIES = 8, 4


class Method:
    """Base class of reachability methods.

    Subclasses implement ``solve(problem)``; the base class wraps it so that, for every method,
    the problem is checked before work starts (:meth:`applicable`, :meth:`memory_estimate` against
    ``max_memory_gb``) and the returned result is checked by the divergence guard
    (:func:`ocreach.reach.guard.check_result`) -- no method returns non-finite or diverged sets.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    #: True if the method, with its default options, returns guaranteed enclosures of the
    #: continuous-time flow: every admissible trajectory lies in every set (and tube) it returns.
    #: Read before anything is solved (the soundness harness, ``ocreach.testing``, runs every
    #: registered method that declares it); each result still says it in ``meta["guaranteed"]``,
    #: which an option may turn off (``sdc`` with ``base="origin"``) or narrow
    #: (``meta["guaranteed_for"]``: ``taylor`` with ``alg="dt"``).
    guaranteed: ClassVar[bool] = False

    @dataclasses.dataclass
    class Options:
        pass

    def __init__(self, **options: Any) -> None:
        from ocreach.errors import check_real
        from ocreach.options import strict_bools

        common = {k: options.pop(k, d) for k, (d, _) in COMMON_OPTIONS.items()}
        fields = {f.name for f in dataclasses.fields(self.Options)}
        unknown = sorted(set(options) - fields)
        if unknown:
            raise ProblemError(f"method {self.name!r} has no option(s) {unknown}; "
                               f"allowed: {sorted(fields | set(COMMON_OPTIONS))} "
                               f"(see `ocreach methods {self.name}`)")
        factor = _to_float(common["divergence_factor"])
        if not factor > 1:
            raise ProblemError(f"divergence_factor must be a number > 1 (inf: no size check); "
                               f"got {common['divergence_factor']!r}")
        self.divergence_factor = factor
        self.max_memory_gb = check_real("max_memory_gb", common["max_memory_gb"])
        if not self.max_memory_gb > 0:
            raise ProblemError(f"max_memory_gb must be > 0; got {common['max_memory_gb']!r}")
        from ocreach.models.coordinates import parse

        self.coordinates = str(parse(common["coordinates"]))
        values = strict_bools(self.Options, options, f"{self.name} option ")
        try:
            self.options = self.Options(**values)
        except (TypeError, ValueError) as exc:  # a check an Options class missed: still named
            if isinstance(exc, OcreachError):
                raise
            raise ProblemError(f"method {self.name!r}: invalid option value(s) {values!r} "
                               f"({type(exc).__name__}: {exc})") from None

    def __init_subclass__(cls, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        inner = cls.__dict__.get("solve")
        if inner is None or getattr(inner, "_checked", False):
            return

        @functools.wraps(inner)
        def solve(self, problem, *args, **kwargs):
            if getattr(self, "_solving", False):  # a subclass calling super().solve()
                return inner(self, problem, *args, **kwargs)
            coords = self.coordinates if self.coordinates != "cartesian" else problem.coordinates
            if coords != "cartesian" and not getattr(self, "_in_chart", False):
                # ocreach.reach.coordinates runs this solve on the problem carried into the chart
                from ocreach.reach.coordinates import solve_in_coordinates
                from ocreach.reach.guard import check_result

                return self._labelled(check_result(solve_in_coordinates(self, problem, coords),
                                                   problem, self.divergence_factor))
            self.check_before(problem)
            self._solving = True
            try:
                result = inner(self, problem, *args, **kwargs)
            finally:
                self._solving = False
            from ocreach.interrupt import check_interrupt
            from ocreach.reach.guard import check_result

            check_interrupt()  # a Ctrl-C swallowed by native code is not lost
            return self._labelled(check_result(result, problem, self.divergence_factor))

        solve._checked = True
        cls.solve = solve

    def solve(self, problem: Problem) -> ReachResult:
        """The reachable-set estimate of ``problem`` (each method implements this)."""
        raise NotImplementedError

    def _labelled(self, result: ReachResult) -> ReachResult:
        """``result`` with ``meta["guaranteed"] = False`` when an estimate method left it out (a
        guaranteed method must say it itself: the soundness harness checks that it does)."""
        meta = getattr(result, "meta", None)
        if not type(self).guaranteed and isinstance(meta, dict):
            meta.setdefault("guaranteed", False)
        return result

    # ------------------------------------------------------------------ checks before work
    @classmethod
    def applicable(cls, problem: Problem) -> tuple[bool, str]:
        """``(True, "")`` if the method can run on ``problem``, else ``(False, reason)``.
        The default accepts every problem; methods refine it."""
        return True, ""

    def applicable_with_options(self, problem: Problem) -> tuple[bool, str]:
        """:meth:`applicable` refined by this instance's options (default: the same)."""
        return self.applicable(problem)

    def memory_estimate(self, problem: Problem) -> float:
        """Estimated peak bytes: ``samples x times x (n_x + n_u) x 8 B x 4`` for sample-based
        methods (0 for the others)."""
        samples = getattr(self.options, "samples", None)
        if samples is None:
            return 0.0
        m = problem.model
        return float(samples) * problem.grid.size * (m.n_x + m.n_u) * _BYTES * _COPIES

    def check_before(self, problem: Problem) -> None:
        """Raise :class:`ProblemError` before any work if the method does not apply or the run
        would exceed ``max_memory_gb``."""
        from ocreach.hybrid import check_hybrid

        check_hybrid(problem)  # a method's solve() would ignore the automaton
        ok, why = self.applicable_with_options(problem)
        if not ok:
            raise ProblemError(f"method {self.name!r} does not apply to problem {problem.id!r}: {why}")
        need = self.memory_estimate(problem) / 1e9
        if need > self.max_memory_gb:
            samples = getattr(self.options, "samples", "?")
            raise ProblemError(
                f"samples = {samples} of method {self.name!r} on problem {problem.id!r} "
                f"({problem.grid.size} grid times, {problem.model.n_x + problem.model.n_u} values per "
                f"time) needs about {need:.3g} GB, more than max_memory_gb = {self.max_memory_gb:g}; "
                f"use fewer samples or a shorter horizon, or raise max_memory_gb (--set max_memory_gb=...)")

    def base_meta(self, problem: Problem, runtime: dict[str, float]) -> dict[str, Any]:
        """The ``meta`` every result carries: method, options, runtime breakdown, versions."""
        import casadi

        return {
            "method": self.name,
            "options": dataclasses.asdict(self.options),
            "problem": problem.id,
            "runtime": runtime,
            "guard": {"divergence_factor": self.divergence_factor, "max_memory_gb": self.max_memory_gb},
            "versions": {"ocreach": __version__, "casadi": casadi.__version__,
                         "numpy": np.__version__, "python": platform.python_version()},
        }


def requirements(problem: Problem, *, bounded: bool = False, control_affine: bool = False,
                 thrust: bool = False, stochastic: bool = False,
                 initial_sets: tuple[str, ...] | None = None) -> tuple[bool, str]:
    """``(ok, reason)`` for the usual needs of a method (used by ``Method.applicable``):
    a bounded control set, a control-affine model, a declared thrust parameter, a stochastic
    problem, an initial set of one of the named types (or none)."""
    from ocreach.model import find_thrust_param

    model = problem.model
    if stochastic and problem.stochastic is None:
        return False, ("needs a stochastic problem (Gaussian initial state and controls); the problem "
                       "has no stochastic specification")
    if bounded and problem.control_set.kind not in ("ball", "box"):
        return False, (f"needs a bounded control set ('ball' or 'box'); the problem's controls are "
                       f"{problem.control_set.kind!r}")
    if control_affine and not model.control_affine:
        return False, f"needs a control-affine model (f = f0 + G u); {model.name} is not"
    if thrust and not find_thrust_param(model):
        return False, (f"needs a declared thrust parameter (Model thrust_param); {model.name} has "
                       f"{list(model.param_names)}")
    if (initial_sets is not None and problem.initial_set is not None
            and type(problem.initial_set).__name__ not in initial_sets):
        return False, (f"handles initial sets of type {list(initial_sets)} only; the problem has "
                       f"{type(problem.initial_set).__name__}")
    return True, ""


@dataclasses.dataclass
class SamplingOptions:
    """Options every sample-based method shares (``mc``, ``ode``, ``ffoe``, ``ole``, ``bvp``).
    Subclasses add fields and call ``super().__post_init__()``."""

    #: number of trajectories (or directions), integer >= 1
    samples: int = 100
    #: seed of the random numbers, integer >= 0 (None: fresh entropy, not reproducible)
    seed: int | None = 0
    #: relative tolerance of the integrator, in (0, 1e-3)
    rtol: float = 1e-10
    #: absolute tolerance of the integrator, finite and >= 0 (model units)
    atol: float = 1e-12

    def __post_init__(self) -> None:
        self.samples = check_count("samples", self.samples, 1)
        if self.seed is not None:
            self.seed = check_count("seed", self.seed, 0)
        self.rtol, self.atol = check_tolerances(self.rtol, self.atol)


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
    ``STTReach(h_max=400).solve(p)``.  A :class:`~ocreach.hybrid.HybridProblem` is solved through
    its automaton (:func:`ocreach.reach.hybrid.reach_hybrid`).  ``threads``: threads of the native batch kernels (default
    :func:`ocreach.parallel.threads`); the method runs under the BLAS thread limit of
    :func:`ocreach.parallel.blas_limit` (neither changes results).
    """
    from ocreach import parallel
    from ocreach.problem import Problem
    from ocreach.registry import get_problem

    if not isinstance(problem, Problem):
        problem = get_problem(str(problem))
    from ocreach.hybrid import HybridProblem

    if isinstance(problem, HybridProblem):  # follow the automaton's transitions
        from ocreach.reach.hybrid import reach_hybrid

        with parallel.settings(threads=threads):
            return reach_hybrid(problem, method, method_class(method), **options)
    cls = method_class(method)
    merged = {**problem.options_for(method), **options}
    with parallel.settings(threads=threads):
        return cls(**merged).solve(problem)
