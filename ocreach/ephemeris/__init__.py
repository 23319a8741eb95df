"""The JPL DE421 ephemeris, offline, as numbers and as smooth CasADi expressions of time.

* :mod:`~ocreach.ephemeris.de421` -- JPL's records (PyPI ``de421`` through ``jplephem``), epochs,
  gravitational parameters, the ICRF and ECLIPJ2000 axes;
* :mod:`~ocreach.ephemeris.fit` -- :class:`EphemerisFit`, Chebyshev refits over a problem's span
  (windows, blends, the bound of a window's error), and the circular stand-in
  :class:`CircularEarthMoon`;
* :mod:`~ocreach.ephemeris.exact_chebyshev` -- exact rational Chebyshev arithmetic for rigorous
  bounds.

The dynamics models built on them (synodic and inertial frames) are in
:mod:`ocreach.models.ephemeris`.  May import: the helpers only.
"""
from ocreach.ephemeris.de421 import (
    AU_KM,
    BODIES,
    DE421_SPK_END_JD,
    ECLIPJ2000_FROM_ICRF,
    FRAMES,
    J2000_JD,
    OBLIQUITY_J2000,
    ORIGINS,
    SECONDS_PER_DAY,
    check_body,
    de421_coverage,
    de421_records,
    epoch_from_et,
    format_jd,
    gm,
    parse_epoch,
)
from ocreach.ephemeris.fit import CircularEarthMoon, EphemerisFit, ephemeris_fit

__all__ = ["AU_KM", "BODIES", "DE421_SPK_END_JD", "ECLIPJ2000_FROM_ICRF", "FRAMES", "J2000_JD",
           "OBLIQUITY_J2000", "ORIGINS", "SECONDS_PER_DAY", "CircularEarthMoon", "EphemerisFit",
           "check_body", "de421_coverage", "de421_records", "ephemeris_fit", "epoch_from_et",
           "format_jd", "gm", "parse_epoch"]
