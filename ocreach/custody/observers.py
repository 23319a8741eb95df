"""Observers of the custody analysis (Tucker et al. Sec. 2.4): positions in the problem's rotating
CR3BP frame (model units).

* :func:`geocentre` -- the centre of the Earth, ``(-mu, 0, 0)``;
* :func:`ground_site` -- a site at geodetic latitude / longitude / altitude on the WGS-84
  ellipsoid, turned with the Earth by the IAU 2000 Earth rotation angle
  ``ERA = 2 pi (0.7790572732640 + 1.00273781191135448 (JD_UT1 - 2451545.0))`` (IERS Conventions
  2010, Eq. 5.15) and placed in the rotating frame whose x-axis points from the Earth to the
  Moon: the frame's orientation at the epoch comes from the DE421 geocentric Moon state and turns
  at the CR3BP rate (1 rad/TU) about the Moon's orbit normal afterwards.  Precession-nutation and
  polar motion are ignored (the Earth's pole is the ICRF z-axis, ~0.4 deg off in 2026).  UT1 is
  the epoch's TDB minus the constant :data:`TT_MINUS_UT1_S` = 69.2 s (TDB - TT < 2 ms is
  neglected); without it the Earth would be turned 0.29 deg too far (69 s x 15.04 arcsec/s, 32 km
  at the equator).  The constant is the 2018-2026 value of TT - UT1 to within about 0.3 s (4.5 arcsec,
  0.14 km); far from those years give the IERS value as ``tt_minus_ut1_s`` (it was 64 s in 2000,
  and is not predictable to better than ~1 s a few years ahead).  A site only sees objects above
  its elevation mask;
* :func:`orbit_observer` -- a spacecraft on an unpowered trajectory of the same CR3BP (e.g. any
  problem's initial state, propagated with :func:`ocreach.dynamics.flow.propagate`).
* :func:`parse_observer` -- the observer a user names on the command line or in a sweep.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ocreach.errors import ProblemError, check_real

WGS84_A_KM = 6378.137
#: TT - UT1 (s) used for ground sites: 32.184 s + (TAI - UTC = 37 s) - (UT1 - UTC ~ 0 s); the
#: 2018-2026 values (68.9-69.4 s) lie within about 0.3 s of it; give the epoch's value otherwise
TT_MINUS_UT1_S = 69.2
WGS84_F = 1.0 / 298.257223563


@dataclass(frozen=True)
class Observer:
    """An observer: ``position(t)`` in the rotating frame (model units) for model times ``t``
    (``(T,)`` -> ``(T, 3)``), and for ground sites the local vertical ``up(t)`` and an elevation
    mask (deg)."""

    name: str
    kind: str
    position_fn: Callable[[np.ndarray], np.ndarray]
    up_fn: Callable[[np.ndarray], np.ndarray] | None = None
    elevation_mask_deg: float = 0.0
    info: dict = field(default_factory=dict)

    def position(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return np.asarray(self.position_fn(t), dtype=float).reshape(t.size, 3)

    def visible(self, t, targets) -> np.ndarray:
        """Mask: target positions ``(T, 3)`` at times ``t`` above the elevation mask (always True
        for observers in space)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        P = np.asarray(targets, dtype=float).reshape(t.size, 3)
        if self.up_fn is None:
            return np.ones(t.size, dtype=bool)
        v = P - self.position(t)
        up = np.asarray(self.up_fn(t)).reshape(t.size, 3)
        sin_el = np.einsum("ij,ij->i", v, up) / np.linalg.norm(v, axis=1)
        return sin_el >= np.sin(np.deg2rad(self.elevation_mask_deg))


def geocentre(mu: float) -> Observer:
    """The Earth's centre, fixed at ``(-mu, 0, 0)`` in the rotating frame."""
    mu = check_real("mu", mu)
    return Observer("geocentre", "geocentre", lambda t: np.tile([-mu, 0.0, 0.0], (t.size, 1)))


def earth_rotation_angle(jd_ut1) -> np.ndarray:
    """IAU 2000 Earth rotation angle (rad, in [0, 2 pi)) at the UT1 Julian date(s) ``jd_ut1``
    (IERS Conventions 2010, Eq. 5.15), with the fractional-day split for precision."""
    jd = np.asarray(jd_ut1, dtype=float)
    tu = jd - 2451545.0
    frac = np.mod(jd, 1.0)
    # 2 pi * 1.0027... * tu = 2 pi * (tu + 0.0027... tu) and frac(tu) = frac(jd) (2451545.0 is whole)
    return 2 * np.pi * np.mod(frac + 0.7790572732640 + 0.00273781191135448 * tu, 1.0)


def geodetic_to_ecef_km(lat_deg: float, lon_deg: float, alt_km: float) -> tuple[np.ndarray, np.ndarray]:
    """Earth-fixed position (km) and the unit local vertical of a WGS-84 geodetic site."""
    lat, lon = np.deg2rad(lat_deg), np.deg2rad(lon_deg)
    e2 = WGS84_F * (2 - WGS84_F)
    N = WGS84_A_KM / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    r = np.array([(N + alt_km) * np.cos(lat) * np.cos(lon), (N + alt_km) * np.cos(lat) * np.sin(lon),
                  (N * (1 - e2) + alt_km) * np.sin(lat)])
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    return r, up


def earth_moon_frame(epoch) -> np.ndarray:
    """Rows ``x, y, z`` (ICRF) of the Earth-Moon rotating frame at ``epoch`` (TDB date or JD): x
    from the Earth to the Moon, z along the Moon's orbital angular momentum (DE421)."""
    from ocreach.ephemeris import de421_records, parse_epoch

    day, frac = parse_epoch(epoch)
    r = de421_records("moon", day, np.array([frac]))[0]
    v = de421_records("moon", day, np.array([frac]), derivative=1)[0]
    x = r / np.linalg.norm(r)
    z = np.cross(r, v)
    z /= np.linalg.norm(z)
    return np.vstack([x, np.cross(z, x), z])


def ground_site(lat_deg: float, lon_deg: float, alt_km: float, epoch, *, mu: float, units,
                elevation_mask_deg: float = 0.0, tt_minus_ut1_s: float | None = None) -> Observer:
    """A ground telescope (see the module docstring) for a CR3BP with ``mu`` and ``units``;
    model time 0 is ``epoch`` (TDB date string or Julian date); the Earth rotation angle is taken
    at ``JD_UT1 = JD_TDB - tt_minus_ut1_s / 86400`` (default :data:`TT_MINUS_UT1_S`)."""
    from ocreach.ephemeris import parse_epoch

    lat, lon, alt = (check_real("latitude", lat_deg), check_real("longitude", lon_deg),
                     check_real("altitude", alt_km))
    if not -90 <= lat <= 90:
        raise ProblemError(f"latitude must be in [-90, 90] deg; got {lat_deg!r}")
    if not -1.0 < alt < 100.0:
        raise ProblemError(f"altitude must be in (-1, 100) km for a ground site; got {alt_km!r}")
    mask = check_real("elevation_mask_deg", elevation_mask_deg)
    if not -90 <= mask < 90:
        raise ProblemError(f"elevation_mask_deg must be in [-90, 90); got {elevation_mask_deg!r}")
    dut = TT_MINUS_UT1_S if tt_minus_ut1_s is None else check_real("tt_minus_ut1_s", tt_minus_ut1_s)
    if not abs(dut) < 600:
        raise ProblemError(f"tt_minus_ut1_s (TT - UT1 in seconds) must be within 600 s; got {tt_minus_ut1_s!r}")
    day, frac = parse_epoch(epoch)
    F0 = earth_moon_frame((day, frac))
    ut1_frac = frac - dut / 86400.0
    r_ecef, up_ecef = geodetic_to_ecef_km(lat, lon, alt)
    du_km, tu_s = units.length / 1e3, units.time

    def _rot(t: np.ndarray, vec: np.ndarray) -> np.ndarray:
        era = earth_rotation_angle(day + ut1_frac + t * tu_s / 86400.0)
        c, s = np.cos(era), np.sin(era)
        inertial = np.stack([c * vec[0] - s * vec[1], s * vec[0] + c * vec[1],
                             np.full_like(era, vec[2])], axis=1)  # Earth pole = ICRF z
        th = t  # the CR3BP frame turns at 1 rad/TU about its z-axis
        ex = np.cos(th)[:, None] * F0[0] + np.sin(th)[:, None] * F0[1]
        ey = -np.sin(th)[:, None] * F0[0] + np.cos(th)[:, None] * F0[1]
        return np.stack([np.einsum("ij,ij->i", inertial, ex), np.einsum("ij,ij->i", inertial, ey),
                         inertial @ F0[2]], axis=1)

    def pos(t):
        return _rot(t, r_ecef) / du_km + np.array([-mu, 0.0, 0.0])

    return Observer(f"ground({lat:g},{lon:g},{alt:g})", "ground", pos, lambda t: _rot(t, up_ecef),
                    elevation_mask_deg=mask,
                    info={"lat_deg": lat, "lon_deg": lon, "alt_km": alt, "epoch_jd": day + frac,
                          "tt_minus_ut1_s": dut})


def orbit_observer(model, x0, params=None, name: str = "orbit", rtol: float = 1e-11) -> Observer:
    """A spacecraft observer on the unpowered trajectory of ``model`` from ``x0`` at ``t = 0``
    (positions by :func:`ocreach.dynamics.flow.propagate`, thrust off)."""
    from ocreach.dynamics.flow import propagate
    from ocreach.reach.indirect import thrust_param

    p = np.array(model.p_default if params is None else params, dtype=float)
    try:
        p[model.param_names.index(thrust_param(model))] = 0.0
    except ProblemError:
        pass
    x0 = model.validate_state(x0, "observer x0")

    def pos(t):
        t = np.asarray(t, dtype=float)
        order = np.argsort(t)
        ts = np.concatenate([[0.0], t[order]])
        keep = np.concatenate([[True], np.diff(ts) > 0])
        grid = ts[keep]
        if grid.size == 1:
            return np.tile(x0[:3], (t.size, 1))
        states = propagate(model, x0, np.zeros((grid.size - 1, model.n_u)), grid, p=p, rtol=rtol,
                           atol=1e-13)
        out = np.empty((t.size, 3))
        idx = np.searchsorted(grid, t[order])
        out[order] = states[idx, :3]
        return out

    return Observer(name, "orbit", pos, info={"x0": x0.tolist()})


def parse_observer(spec: str, problem, epoch: str = "2026-01-01") -> Observer:
    """``geocentre`` | ``L1`` ... ``L5`` (fixed at the Lagrange point) | ``ground:LAT,LON,ALT`` (deg,
    deg, km) | ``orbit:PROBLEM`` for ``problem``'s CR3BP."""
    spec = str(spec).strip()
    mu = problem.model.param("mu", problem.params)
    if spec in ("geocentre", "geocenter", "earth"):
        return geocentre(mu)
    if spec.upper() in ("L1", "L2", "L3", "L4", "L5"):
        from ocreach.orbits import lagrange_points

        pt = lagrange_points(mu)[int(spec[1]) - 1]
        return Observer(spec.upper(), "fixed", lambda t: np.tile(pt, (t.size, 1)))
    if spec.startswith("ground:"):
        parts = spec[7:].split(",")
        if len(parts) != 3:
            raise ProblemError(f"--observer ground:LAT,LON,ALT needs three numbers (deg, deg, km); got {spec!r}")
        return ground_site(*parts, epoch, mu=mu, units=problem.units)
    if spec.startswith("orbit:"):
        from ocreach.registry import get_problem

        other = get_problem(spec[6:])
        if not other.model.name.startswith("cr3bp") or other.model.n_x != 6 or \
                abs(other.model.param("mu", other.params) - mu) > 1e-9:
            raise ProblemError(f"--observer {spec}: the observer's problem must be a spatial CR3BP with "
                               f"mu = {mu}; {other.id} has model {other.model.name}")
        return orbit_observer(other.model, other.x0, other.params, name=f"orbit:{other.id}")
    raise ProblemError(f"--observer must be geocentre, L1..L5, ground:LAT,LON,ALT or orbit:PROBLEM; got {spec!r}")
