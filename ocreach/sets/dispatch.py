"""The operations every set answers to, dispatched on the set's type.

The set types (:mod:`~ocreach.sets.interval`, :mod:`~ocreach.sets.zonotope`,
:mod:`~ocreach.sets.polyzonotope`, :mod:`~ocreach.sets.ellipsoid`, the unions) stand apart from
the operations (:mod:`~ocreach.sets.contains`, :mod:`~ocreach.sets.reduce`,
:mod:`~ocreach.sets.convert`, :mod:`~ocreach.sets.plot`), as in LazySets.jl.  A type's method
that needs an operation defined above it (``Zonotope.reduce`` needs :mod:`ocreach.sets.reduce`,
``Interval.to_zonotope`` needs the zonotope type) calls the generic function here; the module that
implements the operation registers it for the types it handles (``@reduce.register``).  Every
module of :mod:`ocreach.sets` is imported with the package, so the registrations are in place
whenever a set exists.  Nothing here imports another module of the package.
"""
from __future__ import annotations

from functools import singledispatch
from typing import Any

from ocreach.errors import SetError


def _missing(op: str, s: Any) -> SetError:
    return SetError(f"{op} is not defined for {type(s).__name__}")


@singledispatch
def to_zonotope(s: Any, *args: Any, **kwargs: Any) -> Any:
    """Zonotope of ``s`` (exact for intervals; an outer zonotope for an ellipsoid)."""
    raise _missing("to_zonotope", s)


@singledispatch
def to_polyzonotope(s: Any, ids: Any = None) -> Any:
    """Polynomial zonotope of ``s`` (exact for intervals and zonotopes; fresh identifiers unless
    ``ids`` are given)."""
    raise _missing("to_polyzonotope", s)


@singledispatch
def contains(s: Any, points: Any, tol: float) -> Any:
    """Batched point membership of ``points`` in ``s`` (one bool per point)."""
    raise _missing("contains", s)


@singledispatch
def reduce(s: Any, *args: Any, **kwargs: Any) -> Any:
    """Sound order reduction of ``s``."""
    raise _missing("reduce", s)


@singledispatch
def plot(s: Any, ax: Any, dims: Any = (0, 1), **kwargs: Any) -> Any:
    """Draw the 2-D projection of ``s`` on ``dims`` into matplotlib axes ``ax``."""
    raise _missing("plot", s)


@singledispatch
def containment_constraints(s: Any, x: Any) -> Any:
    """cvxpy constraints ``x in s`` and the latent factor variable (or None)."""
    raise _missing("containment_constraints", s)


@singledispatch
def casadi_containment(s: Any, x_sym: Any) -> Any:
    """CasADi containment ``g(x, xi)`` of ``x_sym`` in ``s`` with its bounds."""
    raise _missing("casadi_containment", s)
