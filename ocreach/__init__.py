"""ocreach: reachability analysis and optimal control of low-thrust vehicles on CasADi.

Public API::

    import ocreach
    p = ocreach.get_problem("dro")
    r = ocreach.reach(p, "mc", samples=500)
    r.support([1, 0, 0, 0])
    ocreach.compare(p, ["mc", "ode"])
"""
from ocreach import _blas_start  # noqa: F401  (first, before numpy loads OpenBLAS)
from ocreach._version import __version__
from ocreach.compare import compare
from ocreach.dynamics.flow import integrate_batch, propagate, stm, stt
from ocreach.errors import OcreachError, ProblemError, SetError, SolverError, UnknownNameError
from ocreach.model import Model
from ocreach.problem import ControlSet, Problem, Reference
from ocreach.reach import Method, ReachResult, available_methods, load, method_class, reach
from ocreach.registry import get_problem, list_problems, load_problem_file
from ocreach.units import Units

__all__ = [
    "__version__",
    "ControlSet",
    "Method",
    "Model",
    "OcreachError",
    "Problem",
    "ProblemError",
    "ReachResult",
    "Reference",
    "SetError",
    "SolverError",
    "Units",
    "UnknownNameError",
    "available_methods",
    "compare",
    "get_problem",
    "integrate_batch",
    "list_problems",
    "load",
    "load_problem_file",
    "method_class",
    "propagate",
    "reach",
    "stm",
    "stt",
]
