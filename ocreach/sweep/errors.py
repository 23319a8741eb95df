"""The sweep layer's error type."""
from __future__ import annotations

from ocreach.errors import ProblemError


class SweepError(ProblemError):
    """Invalid sweep spec, catalog, output folder or executor (raised before any task runs)."""
