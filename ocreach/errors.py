"""Exceptions raised by ocreach.

Every message names the parameter, the offending value and what is allowed.
"""
from __future__ import annotations


class OcreachError(Exception):
    """Base class of every ocreach error."""


class ProblemError(OcreachError, ValueError):
    """Invalid problem definition or invalid user input (shape, value, option)."""


class SetError(OcreachError, ValueError):
    """Invalid set construction or an operation on incompatible sets."""


class SolverError(OcreachError, RuntimeError):
    """A numerical solver (integrator, NLP, LP, continuation) failed."""


class UnknownNameError(OcreachError, KeyError):
    """An unknown problem id or method name."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


def check_finite(name: str, value) -> None:
    """Raise :class:`ProblemError` if ``value`` holds NaN or inf."""
    import numpy as np

    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ProblemError(f"{name} must be finite; got {arr!r}")


def check_positive(name: str, value: float) -> float:
    """Raise :class:`ProblemError` unless ``value`` is a finite number > 0."""
    import numpy as np

    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ProblemError(f"{name} must be a finite number > 0; got {value!r}")
    return v
