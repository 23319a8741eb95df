"""Navigation for orbit maintenance: the controllers act on an orbit-determination (OD) estimate.

Model: at every OD fix the estimate is the true state plus a Gaussian error
``e ~ N(0, diag(sigma_r^2 I_3, sigma_v^2 I_3))`` per axis in the controllers' coordinates (the
CR3BP rotating frame fixed at the epoch), independent from fix to fix.  Between fixes the
estimate is dead-reckoned with the controllers' own model, so its error evolves with the
reference's state-transition matrices, ``e_{k+1} = Phi_k e_k``, and a burn adds the part of the
commanded Delta-V that was not executed (the estimator books the commanded burn).  No filter:
an EKF on simulated range / range-rate would replace the independent per-fix errors.

Defaults (1-sigma per axis): 1 km / 3 and 1 cm/s / 3, i.e. 1 km and 1 cm/s at 3 sigma, the OD
errors used for 9:2 NRHO stationkeeping Monte Carlos by Zhang et al., "Performance analysis of
impulsive station-keeping strategies for cis-lunar orbits with the ephemeris model", Acta
Astronautica 2022 (read through a secondary summary; the Gateway papers' own figures, Davis et
al. AAS 17-269 and Newman et al. AAS 18-388, were not available here beyond their abstracts).
A fix at every scheduled burn (the OD error per burn), and every ``od_interval_h`` hours for the
event-triggered and continuous controllers (default 48 h: the 2-day OD interval of Zhang et al.).

:meth:`NavigationErrors.box` is the ``k``-sigma box of the error ellipsoid (half-widths
``k sigma`` per axis, ``k`` = :data:`ENCLOSURE_SIGMA`): the set the drift tubes of the
event-triggered controller start from and are widened by (it contains the 6-D Gaussian error
with probability 0.999, the chi-square quantile).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ocreach.control.stationkeeping.srp import check_nonnegative
from ocreach.errors import ProblemError

#: 1-sigma position / velocity OD errors per axis (km, m/s): 1 km and 1 cm/s at 3 sigma.
DEFAULT_POSITION_SIGMA_KM = 1.0 / 3.0
DEFAULT_VELOCITY_SIGMA_MPS = 0.01 / 3.0
DEFAULT_OD_INTERVAL_H = 48.0
#: k of the k-sigma box: sqrt of the chi-square(6) quantile 0.999 (22.458).
ENCLOSURE_SIGMA = float(np.sqrt(22.457744484825323))


@dataclass(frozen=True)
class NavigationErrors:
    """Gaussian OD errors (module doc): ``position_sigma_km``, ``velocity_sigma_mps`` (1-sigma per
    axis, >= 0; 0 and 0 is perfect navigation) and ``od_interval_h`` (hours between fixes of the
    event-triggered and continuous controllers, > 0)."""

    position_sigma_km: float = DEFAULT_POSITION_SIGMA_KM
    velocity_sigma_mps: float = DEFAULT_VELOCITY_SIGMA_MPS
    od_interval_h: float = DEFAULT_OD_INTERVAL_H

    def __post_init__(self) -> None:
        object.__setattr__(self, "position_sigma_km", check_nonnegative(
            "nav_position_sigma_km (1-sigma OD position error per axis, km)",
            self.position_sigma_km))
        object.__setattr__(self, "velocity_sigma_mps", check_nonnegative(
            "nav_velocity_sigma_mps (1-sigma OD velocity error per axis, m/s)",
            self.velocity_sigma_mps))
        h = check_nonnegative("od_interval_h (hours between OD fixes)", self.od_interval_h,
                              "a finite number > 0")
        if h <= 0:
            raise ProblemError(f"od_interval_h (hours between OD fixes) must be a finite number "
                               f"> 0; got {self.od_interval_h!r}")
        object.__setattr__(self, "od_interval_h", h)

    def sigma(self, units) -> np.ndarray:
        """1-sigma per state component in model units (6,)."""
        return np.r_[np.full(3, self.position_sigma_km * 1e3 / units.length),
                     np.full(3, self.velocity_sigma_mps / units.velocity)]

    def draw(self, rng: np.random.Generator, units) -> np.ndarray:
        """One OD error (6,), model units."""
        return self.sigma(units) * rng.standard_normal(6)

    def box(self, units, k: float = ENCLOSURE_SIGMA) -> np.ndarray:
        """Half-widths (6,) of the ``k``-sigma box of the error ellipsoid, model units."""
        return k * self.sigma(units)

    def as_dict(self) -> dict:
        return {**asdict(self), "enclosure_sigma": ENCLOSURE_SIGMA}


__all__ = ["DEFAULT_OD_INTERVAL_H", "DEFAULT_POSITION_SIGMA_KM", "DEFAULT_VELOCITY_SIGMA_MPS",
           "ENCLOSURE_SIGMA", "NavigationErrors"]
