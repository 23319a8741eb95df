"""The probability of custody at one horizon (Tucker et al. Eq. 13-14, corrected).

Tucker's Eq. 14 defines ``p_c = (A_r - A_fov) / A_r`` for ``A_r > A_fov`` with
``A_fov = (|rho| sin theta)^2`` (Eq. 13, "the square area of the observer FOV") and
``A_r = pi r^2``: that is the fraction of the ball's disc *outside* the FOV (the ratio is
inverted: it grows to 1 as custody is lost), and Algorithm 1 compares an area with
``(1 - p_c) / A_fov`` where ``A_fov = |rho| sin theta`` is a length, and increments ``t`` after the
last evaluation, so it returns one day after the first failing horizon.  ``model="tucker-eq14"``
and :func:`tucker_algorithm1` implement the paper as printed, only to show the difference.
"""
from __future__ import annotations

import numpy as np

from ocreach.custody.fov import FOV, ball_geometry, covered_fraction
from ocreach.errors import ProblemError, check_real

MODELS = ("covered", "tucker-eq14")


def custody_probability(center, radius, observer_pos, fov: FOV, axis=None, *,
                        model: str = "covered") -> float:
    """Probability of custody at one horizon.

    ``"covered"`` (default, the corrected measure): the fraction of the ball's focal-plane image
    inside the FOV, 1 when the ball is inside (:func:`covered_fraction`).  ``"tucker-eq14"``: the
    paper's Eq. 13-14 as printed, ``d_fov = |rho| sin(theta)`` with ``theta`` the full FOV angle,
    ``A_fov = d_fov^2``, ``A_r = pi r^2``, ``p = 1`` if ``A_r < A_fov`` else ``(A_r - A_fov) / A_r``
    (the fraction *outside*; kept only for comparison).
    """
    if model not in MODELS:
        raise ProblemError(f"model must be one of {MODELS}; got {model!r}")
    if model == "covered":
        return covered_fraction(center, radius, observer_pos, fov, axis)
    c, o, r, w, D = ball_geometry(center, radius, observer_pos)
    A_fov = (D * np.sin(2 * fov.half_x)) ** 2
    A_r = np.pi * r**2
    return 1.0 if A_r < A_fov else float((A_r - A_fov) / A_r)


def check_probability(p_required) -> float:
    """``p_required`` as a float in (0, 1] or a :class:`ProblemError`."""
    p = check_real("p (required custody probability)", p_required)
    if not 0 < p <= 1:
        raise ProblemError(f"p (required custody probability) must be in (0, 1]; got {p_required!r}")
    return p
