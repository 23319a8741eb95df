"""ocreach: reachability analysis and optimal control of low-thrust vehicles on CasADi."""
from ocreach.errors import OcreachError, ProblemError, SetError, SolverError, UnknownNameError

__version__ = "0.1.0"
__all__ = ["OcreachError", "ProblemError", "SetError", "SolverError", "UnknownNameError"]
