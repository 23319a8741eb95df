"""Execution of impulsive orbit-maintenance burns: magnitude and pointing errors, a minimum burn
size, and skipped burns.

A commanded burn ``dv`` (m/s) is executed as ``(1 + eps) |dv| R(theta) dv/|dv|``: ``eps ~ N(0,
sigma_m^2)`` (magnitude, relative), ``R(theta)`` a tilt of the direction by two independent
angles ``N(0, sigma_p^2)`` about two axes perpendicular to it.  A command smaller than
``min_burn_mps`` is not executed (status ``"below_minimum"``); a skipped burn (status
``"skipped"``: a missed opportunity, e.g. a safe mode) is not executed either.  Skips: the
burns whose index (0, 1, ... in the order the controller plans them) is in ``skipped_burns``,
and any burn with probability ``skip_probability``.

Defaults (1-sigma): magnitude 1 % (Zhang et al., Acta Astronautica 2022, through a secondary
summary: 1 % 1-sigma), pointing 1/3 deg (1 deg at 3 sigma; no stored source gave a pointing
figure, 1 deg 3-sigma is the value chosen for this study), minimum burn 1 cm/s (Zhang et al.:
commands below 1 cm/s are not executed).  CAPSTONE flew with a larger, varying minimum after a
thruster-valve problem (Advanced Space mission update, April 2023).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ocreach.control.stationkeeping.srp import check_nonnegative
from ocreach.errors import ProblemError, check_count

DEFAULT_MAGNITUDE_SIGMA = 0.01
DEFAULT_POINTING_SIGMA_DEG = 1.0 / 3.0
DEFAULT_MIN_BURN_MPS = 0.01
STATUSES = ("executed", "below_minimum", "skipped")


@dataclass(frozen=True)
class ExecutionErrors:
    """Burn execution (module doc): ``magnitude_sigma`` (relative, >= 0), ``pointing_sigma_deg``
    (>= 0), ``min_burn_mps`` (>= 0), ``skip_probability`` in [0, 1], ``skipped_burns`` (burn
    indices, integers >= 0)."""

    magnitude_sigma: float = DEFAULT_MAGNITUDE_SIGMA
    pointing_sigma_deg: float = DEFAULT_POINTING_SIGMA_DEG
    min_burn_mps: float = DEFAULT_MIN_BURN_MPS
    skip_probability: float = 0.0
    skipped_burns: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        for name, what in (("magnitude_sigma", "1-sigma relative burn magnitude error"),
                           ("pointing_sigma_deg", "1-sigma burn pointing error, deg"),
                           ("min_burn_mps", "smallest executable burn, m/s")):
            object.__setattr__(self, name, check_nonnegative(f"{name} ({what})",
                                                             getattr(self, name)))
        p = check_nonnegative("skip_probability", self.skip_probability, "a number in [0, 1]")
        if p > 1:
            raise ProblemError(f"skip_probability must be a number in [0, 1]; got "
                               f"{self.skip_probability!r}")
        object.__setattr__(self, "skip_probability", p)
        if isinstance(self.skipped_burns, (str, bytes)) or np.ndim(self.skipped_burns) != 1:
            raise ProblemError(f"skipped_burns must be a list of burn indices (integers >= 0); "
                               f"got {self.skipped_burns!r}")
        object.__setattr__(self, "skipped_burns", tuple(sorted(
            {check_count("skipped_burns entry (burn index)", i, 0) for i in self.skipped_burns})))

    def execute(self, dv_mps: np.ndarray, index: int,
                rng: np.random.Generator) -> tuple[np.ndarray, str]:
        """The executed burn (m/s, (3,)) and its status for the commanded ``dv_mps`` of burn
        number ``index``."""
        dv = np.asarray(dv_mps, float)
        mag = float(np.linalg.norm(dv))
        draws = rng.standard_normal(3)  # always drawn: the stream does not depend on the outcome
        skip = rng.random() < self.skip_probability
        if index in self.skipped_burns or skip:
            return np.zeros(3), "skipped"
        if mag < self.min_burn_mps or mag == 0.0:
            return np.zeros(3), "below_minimum"
        d = dv / mag
        a = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(d, a)
        tilt = np.deg2rad(self.pointing_sigma_deg) * (draws[1] * a + draws[2] * b)
        d_new = d + tilt
        d_new /= np.linalg.norm(d_new)
        return (1.0 + self.magnitude_sigma * draws[0]) * mag * d_new, "executed"

    def as_dict(self) -> dict:
        out = asdict(self)
        out["skipped_burns"] = list(self.skipped_burns)
        return out


__all__ = ["DEFAULT_MAGNITUDE_SIGMA", "DEFAULT_MIN_BURN_MPS", "DEFAULT_POINTING_SIGMA_DEG",
           "ExecutionErrors", "STATUSES"]
