"""The offline JPL DE421 ephemeris: records, epochs, gravitational parameters, frames.

The dynamics models of Patel & Scheeres (Eq. 11, point-mass gravity of Sun, Earth, Moon, ...) and
Foss et al. (Sec. 2.2.2, Eq. 6, the ephemeris-driven synodic frame) need body positions that are
*symbolic* functions of time, so that CasADi can differentiate the dynamics (Jacobians, STTs up to
order 3, costates) and, in the synodic frame, the frame matrix ``M(t)`` twice in time.

The records come from the PyPI package ``de421``, read through ``jplephem`` (no network):
:func:`de421_records` evaluates JPL's Chebyshev records directly (the truth every fit is checked
against); :class:`ocreach.ephemeris.fit.EphemerisFit` refits them over a problem's span as smooth
CasADi expressions (``tests/test_ephemeris.py`` checks it independently against ``jplephem``).

Conventions
-----------
* Axes: ICRF / J2000 equatorial (DE421's frame).  ``frame="eclipj2000"`` rotates about x by the
  J2000 obliquity 84381.448 arcsec (SPICE's ECLIPJ2000, used by Patel & Scheeres Sec. 6).
* Time: TDB.  ``t`` in ``EphemerisFit.position_expr`` / ``EphemerisFit.position`` is in
  seconds since the epoch (negative values allowed when the span reaches back).
* Lengths in km, velocities in km/s; gravitational parameters in km^3/s^2 (:data:`GM_KM3S2`).
* Planets other than Earth are their *system barycentres* (DE421 gives barycentres; the
  gravitational parameters are the system GMs), which is the usual point-mass model.
"""
from __future__ import annotations

import datetime as _dt
import re
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
import numpy.polynomial.chebyshev as cheb

from ocreach.errors import ProblemError
from ocreach.units import AU

#: Astronomical unit (IAU 2012), km; the default distance unit of heliocentric models.
AU_KM = AU / 1e3

#: Julian date of J2000.0 (2000-01-01 12:00:00 TDB).
J2000_JD = 2451545.0
SECONDS_PER_DAY = 86400.0
#: J2000 mean obliquity of the ecliptic used by SPICE for ECLIPJ2000, rad.
OBLIQUITY_J2000 = np.deg2rad(84381.448 / 3600.0)
_C, _S = np.cos(OBLIQUITY_J2000), np.sin(OBLIQUITY_J2000)
#: Rotation ICRF/J2000 -> ECLIPJ2000 (``r_ecl = R @ r_icrf``).
ECLIPJ2000_FROM_ICRF = np.array([[1.0, 0.0, 0.0], [0.0, _C, _S], [0.0, -_S, _C]])
FRAMES = ("icrf", "eclipj2000")

#: Body names users type.  Planets other than Earth are system barycentres.
BODIES = ("sun", "mercury", "venus", "earth", "moon", "mars", "jupiter", "saturn", "uranus",
          "neptune", "pluto")
#: Extra origins (no gravity): solar-system and Earth-Moon barycentres.
ORIGINS = BODIES + ("ssb", "emb")


@lru_cache(maxsize=1)
def _de421():
    """The DE421 record arrays and constants (``jplephem.Ephemeris`` over the ``de421`` package)."""
    import de421
    from jplephem import Ephemeris

    return Ephemeris(de421)


def _constants() -> dict[str, float]:
    e = _de421()
    au = float(e.AU)  # km
    scale = au**3 / SECONDS_PER_DAY**2  # AU^3/day^2 -> km^3/s^2
    emrat = float(e.EMRAT)
    gmb = float(e.GMB) * scale
    gm = {"sun": float(e.GMS) * scale, "mercury": float(e.GM1) * scale,
          "venus": float(e.GM2) * scale, "earth": gmb * emrat / (1.0 + emrat),
          "moon": gmb / (1.0 + emrat), "mars": float(e.GM4) * scale,
          "jupiter": float(e.GM5) * scale, "saturn": float(e.GM6) * scale,
          "uranus": float(e.GM7) * scale, "neptune": float(e.GM8) * scale,
          "pluto": float(e.GM9) * scale}
    return {"au_km": au, "emrat": emrat, "jd_start": float(e.jalpha), "jd_end": float(e.jomega),
            **{f"gm_{k}": v for k, v in gm.items()}}


def gm(body: str) -> float:
    """Gravitational parameter of ``body`` from the DE421 constants, km^3/s^2.

    Values (DE421 header, AU = 149597870.6996262 km): Sun 1.32712440041e11, Earth 398600.436233,
    Moon 4902.800076, Venus 324858.592, Mars system 42828.375214, Jupiter system 126712764.8.
    Earth and Moon are split from ``GMB`` with ``EMRAT = 81.30056907``.
    """
    check_body(body, BODIES, "body")
    return _constants()[f"gm_{body}"]


#: End of the official DE421 SPK file (de421.bsp): 2053-10-09 00:00 TDB.  JPL's DE421 spans
#: 1899-07-29 .. 2053-10-09; the PyPI ``de421`` arrays hold 1899-12-04 .. 2200 (JPL's ASCII
#: release).  We use the intersection so results are reproducible with the SPK file.
DE421_SPK_END_JD = 2471184.5


def de421_coverage() -> tuple[float, float]:
    """First and last Julian date (TDB) usable: 1899-12-04 (start of the PyPI ``de421`` arrays;
    DE421 itself starts 1899-07-29) and 2053-10-09 (end of DE421)."""
    c = _constants()
    return c["jd_start"], min(c["jd_end"], DE421_SPK_END_JD)


def check_body(name: str, allowed: Sequence[str], what: str) -> str:
    """``name`` lower-cased if it is one of ``allowed`` (a body, origin or frame name); raises
    :class:`ProblemError` naming ``what``, the value and the allowed names otherwise."""
    if not isinstance(name, str) or name.lower() not in allowed:
        raise ProblemError(f"{what} must be one of {list(allowed)}; got {name!r}")
    return name.lower()


# ---------------------------------------------------------------------------------------- epochs
_EPOCH_RE = re.compile(
    r"^\s*(\d{4})-(\d{1,2})-(\d{1,2})(?:[ T](\d{1,2}):(\d{2})(?::(\d{2}(?:\.\d*)?))?)?"
    r"\s*(?:TDB)?\s*$", re.IGNORECASE)


def parse_epoch(epoch: str | float | tuple) -> tuple[float, float]:
    """Epoch (TDB) as an exact split Julian date ``(jd_day, day_fraction)``.

    ``epoch`` is a TDB calendar string ``"2024-05-01 12:00:00"`` (also ``YYYY-MM-DD``,
    ``...THH:MM[:SS.fff]``, optional suffix ``TDB``), a Julian date (float, TDB) or a split Julian
    date ``(day, fraction)``.  ``jd_day`` ends in .5 (midnight) so that later time offsets keep
    full precision.  Use :func:`epoch_from_et` for seconds past J2000 (SPICE ET, as in the epochs
    of Patel & Scheeres Fig. 1-2).
    """
    if isinstance(epoch, tuple) and len(epoch) == 2:  # split Julian date (day, fraction)
        day, frac = parse_epoch(float(epoch[0]))
        frac += float(epoch[1])
        if not np.isfinite(frac):
            raise ProblemError(f"epoch must be finite; got {epoch!r}")
        return day + np.floor(frac), frac - np.floor(frac)
    if isinstance(epoch, str):
        m = _EPOCH_RE.match(epoch)
        if m is None:
            raise ProblemError(f"epoch must be a TDB date 'YYYY-MM-DD[ HH:MM[:SS]]' or a Julian "
                               f"date; got {epoch!r}")
        y, mo, d = int(m[1]), int(m[2]), int(m[3])
        hh, mm = int(m[4] or 0), int(m[5] or 0)
        ss = float(m[6] or 0.0)
        try:
            day = _dt.date(y, mo, d).toordinal() + 1721424.5
        except ValueError as exc:
            raise ProblemError(f"epoch {epoch!r} is not a valid calendar date: {exc}") from None
        if hh > 23 or mm > 59 or ss >= 61.0:
            raise ProblemError(f"epoch {epoch!r} has an invalid time of day")
        return day, (hh * 3600.0 + mm * 60.0 + ss) / SECONDS_PER_DAY
    try:
        jd = float(epoch)
    except (TypeError, ValueError):
        raise ProblemError(f"epoch must be a TDB date string or a Julian date; got {epoch!r}") from None
    if not np.isfinite(jd):
        raise ProblemError(f"epoch must be finite; got {epoch!r}")
    day = np.floor(jd - 0.5) + 0.5
    return float(day), float(jd - day)


def epoch_from_et(seconds_past_j2000: float) -> tuple[float, float]:
    """Split Julian date (TDB) of ``seconds_past_j2000`` TDB seconds after J2000 (SPICE ET).

    Patel & Scheeres give their epochs this way (Fig. 1: 64.1 s; Fig. 2: 1072864.169 s).
    """
    return parse_epoch((J2000_JD - 0.5, 0.5 + float(seconds_past_j2000) / SECONDS_PER_DAY))


def format_jd(jd: float) -> str:
    day = np.floor(jd - 0.5) + 0.5
    date = _dt.date.fromordinal(int(day - 1721424.5))
    secs = (jd - day) * SECONDS_PER_DAY
    return f"{date.isoformat()} {int(secs // 3600):02d}:{int(secs % 3600 // 60):02d} TDB (JD {jd:.6f})"


# -------------------------------------------------------------------------- raw DE421 records
#: Each body as a linear combination of DE421 record series (positions w.r.t. the SSB, km).
#: ``moon`` is the geocentric Moon record, ``earthmoon`` the Earth-Moon barycentre.
def series_combination(body: str) -> dict[str, float]:
    c = _constants()
    es = 1.0 / (1.0 + c["emrat"])
    ms = c["emrat"] / (1.0 + c["emrat"])
    if body == "ssb":
        return {}
    if body == "emb":
        return {"earthmoon": 1.0}
    if body == "earth":
        return {"earthmoon": 1.0, "moon": -es}
    if body == "moon":
        return {"earthmoon": 1.0, "moon": ms}
    return {body: 1.0}


def relative_series(body: str, origin: str) -> dict[str, float]:
    """Series combination of ``body - origin``; exactly cancelling terms are dropped."""
    out = dict(series_combination(body))
    for k, v in series_combination(origin).items():
        out[k] = out.get(k, 0.0) - v
    # earth - moon etc.: moon coefficients es + ms are 1 up to rounding; keep them, drop zeros only
    return {k: v for k, v in out.items() if v != 0.0}


def de421_records(series: str, jd_day: float, days: np.ndarray, derivative: int = 0) -> np.ndarray:
    """Evaluate one DE421 record series at ``jd_day + days`` (split date, full precision).

    Returns shape ``(len(days), 3)``: position in km (``derivative=0``) or its ``derivative``-th
    time derivative in km/s^k.  This is a direct evaluation of JPL's Chebyshev records (the truth
    the fit is checked against when it is built).
    """
    e = _de421()
    rec = e.load(series)  # (n_sets, 3, n_coef)
    n_sets = rec.shape[0]
    span = (e.jomega - e.jalpha) / n_sets
    days = np.atleast_1d(np.asarray(days, dtype=float))
    base = jd_day - e.jalpha
    k0 = np.floor(base / span)
    off = (base - k0 * span) + days
    dk = np.floor(off / span)
    idx = (k0 + dk).astype(int)
    off = off - dk * span
    last = idx == n_sets  # the very last instant belongs to the last record
    idx[last] -= 1
    off[last] += span
    if np.any(idx < 0) or np.any(idx >= n_sets):
        bad = days[(idx < 0) | (idx >= n_sets)]
        raise ProblemError(f"time outside DE421 coverage {format_jd(e.jalpha)} .. "
                           f"{format_jd(e.jomega)}: got {bad.size} time(s) from JD {jd_day:.1f} "
                           f"{bad.min():+.6g} to {bad.max():+.6g} days")
    tau = 2.0 * off / span - 1.0
    coef = rec[idx]  # (m, 3, n_coef)
    if derivative:
        coef = cheb.chebder(coef, m=derivative, axis=2, scl=2.0 / (span * SECONDS_PER_DAY))
    T = cheb.chebvander(tau, coef.shape[2] - 1)  # (m, n_coef)
    return np.einsum("mk,mck->mc", T, coef)
