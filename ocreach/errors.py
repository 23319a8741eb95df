"""Exceptions raised by ocreach.

Every message names the parameter, the offending value and what is allowed.  The ``check_*``
functions are the shared argument checks (numbers, counts, tolerances) that raise these errors.
"""
from __future__ import annotations

import math
from typing import Any


class OcreachError(Exception):
    """Base class of every ocreach error."""


class ProblemError(OcreachError, ValueError):
    """Invalid problem definition or invalid user input (shape, value, option)."""


class SetError(OcreachError, ValueError):
    """Invalid set construction or an operation on incompatible sets."""


class SolverError(OcreachError, RuntimeError):
    """A numerical solver (integrator, NLP, LP, continuation) failed.

    ``partial``: the part of the result computed before the failure (a ``ReachResult`` with
    ``meta["truncated"] = True``), or None.  The CLI saves it beside the message.
    """

    def __init__(self, *args: Any, partial: Any = None) -> None:
        super().__init__(*args)
        self.partial = partial


class UnknownNameError(OcreachError, KeyError):
    """An unknown problem id or method name."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


def _to_float(value: Any) -> float:
    """``float(value)``, or NaN for booleans and values that are not numbers."""
    if isinstance(value, bool):
        return float("nan")
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        return float("nan")


def check_real(name: str, value: Any) -> float:
    """``value`` as a finite float (ints, floats, numeric strings from the CLI); raises
    :class:`ProblemError` naming ``name`` otherwise."""
    out = _to_float(value)
    if not math.isfinite(out):
        raise ProblemError(f"{name} must be a finite number; got {value!r}")
    return out


def check_count(name: str, value: Any, minimum: int) -> int:
    """``value`` as an int ``>= minimum`` (integral floats such as ``1e3`` from the CLI accepted);
    raises :class:`ProblemError` naming ``name`` otherwise (also for 2.5, True, "x", inf)."""
    v = _to_float(value) if not isinstance(value, str) else float("nan")
    if math.isfinite(v) and v == int(v) and int(v) >= minimum:
        return int(v)
    raise ProblemError(f"{name} must be an integer >= {minimum}; got {value!r}")


def check_tolerances(rtol: Any, atol: Any) -> tuple[float, float]:
    """Integrator tolerances checked: ``rtol`` in (0, 1e-3), ``atol`` finite and >= 0."""
    r, a = _to_float(rtol), _to_float(atol)
    if not 0 < r < 1e-3:
        raise ProblemError(f"rtol must be in (0, 1e-3); got {rtol!r}")
    if not (math.isfinite(a) and a >= 0):
        raise ProblemError(f"atol must be a finite number >= 0; got {atol!r}")
    return r, a


def check_finite(name: str, value: Any) -> None:
    """Raise :class:`ProblemError` if ``value`` holds NaN or inf."""
    import numpy as np

    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ProblemError(f"{name} must be finite; got {arr!r}")


def check_positive(name: str, value: float) -> float:
    """Raise :class:`ProblemError` unless ``value`` is a finite number > 0."""
    import numpy as np

    v = _to_float(value)
    if not np.isfinite(v) or v <= 0:
        raise ProblemError(f"{name} must be a finite number > 0; got {value!r}")
    return v
