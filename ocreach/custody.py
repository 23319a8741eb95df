"""Telescope custody of a manoeuvring space object (Tucker et al., Sec. 2.4 and 3).

Observers (position in the problem's rotating CR3BP frame, model units):

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
  problem's initial state, propagated with :func:`ocreach.flow.propagate`).

Fields of view (:class:`FOV`): a circular cone (half-angle) or a rectangular pyramid (two
half-angles and a roll about the boresight).  The focal plane is the gnomonic projection
``(v . e1 / v . b, v . e2 / v . b)`` of the line of sight ``v`` on the plane tangent to the unit
sphere at the boresight ``b``.

Custody: the reachable positions at a horizon are over-approximated by a ball (the minimum
enclosing ball of Tucker Sec. 2.3, or the outer ball of :func:`ocreach.meb.support_outer_ball`).
:func:`ball_in_fov` is the exact containment test (angular for the cone, four plane distances for
the pyramid); :func:`covered_fraction` the fraction of the ball's projected area (its focal-plane
ellipse: the gnomonic image of the cone of sight lines tangent to the ball) inside the FOV;
:func:`custody_probability` is that fraction (1 when the ball is inside).

Tucker's Eq. 14 defines ``p_c = (A_r - A_fov) / A_r`` for ``A_r > A_fov`` with
``A_fov = (|rho| sin theta)^2`` (Eq. 13, "the square area of the observer FOV") and
``A_r = pi r^2``: that is the fraction of the ball's disc *outside* the FOV (the ratio is
inverted: it grows to 1 as custody is lost), and Algorithm 1 compares an area with
``(1 - p_c) / A_fov`` where ``A_fov = |rho| sin theta`` is a length, and increments ``t`` after the
last evaluation, so it returns one day after the first failing horizon.  ``model="tucker-eq14"``
and :func:`tucker_algorithm1` implement the paper as printed, only to show the difference.

The custody-loss horizon (:func:`custody_horizon`) is the first time the probability falls below
the requirement, bracketed on a scan and refined by bisection: ``t_safe`` (last time known to
hold the requirement) and ``t_loss`` (first time known to fail) with ``t_loss - t_safe <= tol``
when ``converged``; the start time is evaluated too (custody already lost there is reported as
such, with no horizon).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ocreach.errors import ProblemError, SolverError, check_count, check_real

WGS84_A_KM = 6378.137
#: TT - UT1 (s) used for ground sites: 32.184 s + (TAI - UTC = 37 s) - (UT1 - UTC ~ 0 s); the
#: 2018-2026 values (68.9-69.4 s) lie within about 0.3 s of it; give the epoch's value otherwise
TT_MINUS_UT1_S = 69.2
WGS84_F = 1.0 / 298.257223563
MODELS = ("covered", "tucker-eq14")


# ====================================================================== observers
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
    (positions by :func:`ocreach.flow.propagate`, thrust off)."""
    from ocreach.flow import propagate
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


# ====================================================================== fields of view
@dataclass(frozen=True)
class FOV:
    """A field of view: ``"circle"`` (cone, ``half_x`` = half-angle) or ``"rect"`` (pyramid with
    half-angles ``half_x``, ``half_y`` along the focal-plane axes, turned by ``roll``); radians."""

    shape: str
    half_x: float
    half_y: float
    roll: float = 0.0

    def __post_init__(self) -> None:
        if self.shape not in ("circle", "rect"):
            raise ProblemError(f"FOV shape must be 'circle' or 'rect'; got {self.shape!r}")
        for name, v in (("half_x", self.half_x), ("half_y", self.half_y)):
            if not (np.isfinite(v) and 0 < v < np.pi / 2):
                raise ProblemError(f"FOV {name} must be in (0, 90) deg (full angle in (0, 180)); got "
                                   f"{np.rad2deg(v) if np.isfinite(v) else v!r} deg")
        if not np.isfinite(self.roll):
            raise ProblemError(f"FOV roll must be finite; got {self.roll!r}")

    @classmethod
    def circle(cls, full_deg: float) -> FOV:
        """Circular FOV of full angle ``full_deg`` (in (0, 180))."""
        return cls("circle", *(2 * [_half(full_deg, "fov")]))

    @classmethod
    def rect(cls, full_x_deg: float, full_y_deg: float | None = None, roll_deg: float = 0.0) -> FOV:
        """Rectangular FOV of full angles ``full_x_deg`` x ``full_y_deg`` (square if omitted)."""
        hx = _half(full_x_deg, "fov")
        hy = hx if full_y_deg is None else _half(full_y_deg, "fov_y")
        return cls("rect", hx, hy, np.deg2rad(check_real("roll", roll_deg)))

    @property
    def full_deg(self) -> float:
        return float(np.rad2deg(2 * self.half_x))

    def label(self) -> str:
        if self.shape == "circle":
            return f"circle {self.full_deg:g} deg"
        return f"rect {self.full_deg:g} x {np.rad2deg(2 * self.half_y):g} deg"

    def polygon(self, n: int = 2048) -> np.ndarray:
        """The FOV boundary in the focal plane (gnomonic coordinates), ``(n, 2)`` or 4 corners."""
        if self.shape == "circle":
            th = np.linspace(0, 2 * np.pi, n, endpoint=False)
            # circumscribed polygon of the circle would overstate; use vertices on the circle
            return np.tan(self.half_x) * np.column_stack([np.cos(th), np.sin(th)])
        a, b = np.tan(self.half_x), np.tan(self.half_y)
        return np.array([[a, b], [-a, b], [-a, -b], [a, -b]])

    def contains_plane(self, XY: np.ndarray) -> np.ndarray:
        """Mask of focal-plane points ``(m, 2)`` inside the FOV."""
        XY = np.asarray(XY, dtype=float)
        if self.shape == "circle":
            return np.hypot(XY[:, 0], XY[:, 1]) <= np.tan(self.half_x)
        return (np.abs(XY[:, 0]) <= np.tan(self.half_x)) & (np.abs(XY[:, 1]) <= np.tan(self.half_y))


def _half(full_deg, name: str) -> float:
    v = check_real(name, full_deg)
    if not 0 < v < 180:
        raise ProblemError(f"{name} (full angle) must be in (0, 180) deg; got {full_deg!r}")
    return float(np.deg2rad(v) / 2)


def boresight_frame(axis, roll: float = 0.0) -> np.ndarray:
    """Rows ``e1, e2, b``: the focal-plane axes and the unit boresight ``b`` (``e1`` is the
    rotating frame's z-axis projected out of ``b``, turned by ``roll``; x-axis if ``b`` is along z)."""
    b = np.asarray(axis, dtype=float)
    nb = np.linalg.norm(b)
    if not np.isfinite(nb) or nb == 0:
        raise ProblemError(f"boresight axis must be a finite non-zero vector; got {axis!r}")
    b = b / nb
    ref = np.array([0.0, 0.0, 1.0]) if abs(b[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    e1 = ref - (ref @ b) * b
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(b, e1)
    c, s = np.cos(roll), np.sin(roll)
    return np.vstack([c * e1 + s * e2, -s * e1 + c * e2, b])


def gnomonic(points, observer_pos, axis, roll: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Focal-plane coordinates ``(m, 2)`` of ``points`` (m, 3) seen from ``observer_pos`` with
    boresight ``axis``, and the mask of points in front of the observer (``v . b > 0``)."""
    P = _points3(points)
    F = boresight_frame(axis, roll)
    v = (P - np.asarray(observer_pos, dtype=float)) @ F.T
    front = v[:, 2] > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        XY = v[:, :2] / v[:, 2:3]
    XY[~front] = np.inf
    return XY, front


def _points3(points) -> np.ndarray:
    P = np.atleast_2d(np.asarray(points, dtype=float))
    if P.ndim != 2 or P.shape[1] != 3 or P.shape[0] == 0:
        raise ProblemError(f"points must be a non-empty (m, 3) array of positions; got shape {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ProblemError(f"points must be finite; rows {np.flatnonzero(~np.all(np.isfinite(P), 1))[:10].tolist()} "
                           "hold NaN or inf")
    return P


def points_in_fov(points, observer_pos, fov: FOV, axis) -> np.ndarray:
    """Mask of sampled reachable positions ``(m, 3)`` inside the FOV (gnomonic projection)."""
    XY, front = gnomonic(points, observer_pos, axis, fov.roll)
    return front & fov.contains_plane(np.where(front[:, None], XY, 0.0))


def _ball_geometry(center, radius, observer_pos):
    c = np.asarray(center, dtype=float).ravel()
    o = np.asarray(observer_pos, dtype=float).ravel()
    r = check_real("radius", radius)
    if c.shape != (3,) or o.shape != (3,) or not (np.all(np.isfinite(c)) and np.all(np.isfinite(o))):
        raise ProblemError(f"ball centre and observer must be finite 3-vectors; got {center!r}, {observer_pos!r}")
    if r < 0:
        raise ProblemError(f"radius must be >= 0; got {radius!r}")
    w = c - o
    D = float(np.linalg.norm(w))
    if D <= r:
        raise ProblemError(f"the observer at {o.tolist()} is inside the reachable-set ball (distance "
                           f"{D:.6g} <= radius {r:.6g}); custody from inside the set is undefined")
    return c, o, r, w / D, D


def ball_in_fov(center, radius, observer_pos, fov: FOV, axis=None) -> bool:
    """Exact containment of the ball in the FOV cone / pyramid with apex at the observer.

    Circle: ``angle(b, c - o) + asin(r / D) <= half-angle``.  Rectangle: the pyramid is the
    intersection of four half-spaces through the apex; the ball is inside iff its centre is at
    least ``r`` inside each plane.  ``axis`` defaults to the direction of the ball's centre.
    """
    c, o, r, w, D = _ball_geometry(center, radius, observer_pos)
    F = boresight_frame(w if axis is None else axis, fov.roll)
    if fov.shape == "circle":
        beta = float(np.arccos(np.clip(w @ F[2], -1.0, 1.0)))
        return beta + float(np.arcsin(r / D)) <= fov.half_x * (1 + 1e-15)
    v = F @ (c - o)
    for k, h in ((0, fov.half_x), (1, fov.half_y)):
        for sgn in (1.0, -1.0):
            n = np.zeros(3)
            n[k], n[2] = sgn * np.cos(h), -np.sin(h)  # outward unit normal of the side plane
            if n @ v > -r:
                return False
    return True


def ball_outline(center, radius, observer_pos, axis, roll: float = 0.0, n: int = 2048) -> np.ndarray | None:
    """Focal-plane outline ``(n, 2)`` of the ball: the gnomonic image of the cone of sight lines
    tangent to it (an ellipse); None if that cone reaches 90 deg from the boresight."""
    c, o, r, w, D = _ball_geometry(center, radius, observer_pos)
    F = boresight_frame(axis, roll)
    alpha = float(np.arcsin(r / D))
    u1 = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
    u1 /= np.linalg.norm(u1)
    u2 = np.cross(w, u1)
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    d = np.cos(alpha) * w + np.sin(alpha) * (np.cos(phi)[:, None] * u1 + np.sin(phi)[:, None] * u2)
    v = d @ F.T
    if np.any(v[:, 2] <= 1e-9):
        return None
    return v[:, :2] / v[:, 2:3]


def covered_fraction(center, radius, observer_pos, fov: FOV, axis=None, n: int = 4096) -> float:
    """Fraction of the ball's focal-plane image (an ellipse; see :func:`ball_outline`) inside the
    FOV.  On-axis circular FOV: exactly ``min(1, tan^2(half) / tan^2(asin(r/D)))``; otherwise the
    area of the polygon intersection (shapely) of ``n``-gons, relative error ~ 1/n^2.  A ball whose
    tangent cone reaches 90 deg from the boresight (unbounded image) gives 0."""
    from shapely.geometry import Polygon

    c, o, r, w, D = _ball_geometry(center, radius, observer_pos)
    b = w if axis is None else np.asarray(axis, float) / np.linalg.norm(axis)
    if r == 0:
        return 1.0 if ball_in_fov(c, 0.0, o, fov, b) else 0.0
    if ball_in_fov(c, r, o, fov, b):
        return 1.0
    if fov.shape == "circle" and float(w @ b) >= 1 - 1e-15:
        ta = np.tan(np.arcsin(r / D))
        return float(min(1.0, (np.tan(fov.half_x) / ta) ** 2))
    ell = ball_outline(c, r, o, b, fov.roll, n)
    if ell is None:
        return 0.0
    E = Polygon(ell)
    return float(E.intersection(Polygon(fov.polygon(n))).area / E.area)


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
    c, o, r, w, D = _ball_geometry(center, radius, observer_pos)
    A_fov = (D * np.sin(2 * fov.half_x)) ** 2
    A_r = np.pi * r**2
    return 1.0 if A_r < A_fov else float((A_r - A_fov) / A_r)


def check_probability(p_required) -> float:
    """``p_required`` as a float in (0, 1] or a :class:`ProblemError`."""
    p = check_real("p (required custody probability)", p_required)
    if not 0 < p <= 1:
        raise ProblemError(f"p (required custody probability) must be in (0, 1]; got {p_required!r}")
    return p


# ====================================================================== horizon
@dataclass(frozen=True)
class Horizon:
    """Custody-loss horizon found by :func:`custody_horizon`.

    ``t_safe``: last time known to hold ``p >= p_required`` (None when custody is already lost at
    ``t_min``: then there is no horizon and ``t_loss = t_min``); ``t_loss``: first time known to
    fail (None if custody holds at every scanned time up to ``t_max``); ``evaluations``: the
    ``(t, p)`` pairs in order.  ``converged``: the search met its tolerance (``t_loss - t_safe
    <= tol``, or no loss up to ``t_max``, or lost at ``t_min``); False when the bisection stopped
    early with the bracket still valid but wider than ``tol`` (the bisection budget ran out, the
    bracket reached the floating-point resolution of ``t``, or an evaluation inside the bracket
    failed, e.g. a bvp continuation); ``message`` says why.
    """

    t_safe: float | None
    t_loss: float | None
    p_required: float
    evaluations: tuple[tuple[float, float], ...]
    converged: bool
    message: str = ""

    @property
    def lost_at_start(self) -> bool:
        """Custody was already lost at ``t_min`` (no horizon)."""
        return self.t_safe is None


def custody_horizon(probability: Callable[[float], float], p_required: float, t_max: float, *,
                    t_step: float, tol: float, t_min: float = 0.0, max_bisections: int = 100) -> Horizon:
    """First time the custody probability drops below ``p_required`` (Tucker Sec. 3, corrected).

    Evaluate ``t_min`` first (custody already lost there: ``Horizon(t_safe=None, t_loss=t_min)``),
    then scan ``t_min + t_step, t_min + 2 t_step, ... <= t_max`` (t_max always included) for the
    first failing time, then bisect the bracket ``[t_safe, t_loss]`` until it is no longer than
    ``tol`` (``converged``), or until ``max_bisections`` halvings, the float resolution of ``t``
    or a :class:`SolverError` of ``probability`` inside the bracket stop it (not ``converged``; the
    bracket is still valid).  A failure before a bracket exists is raised.  Assumes the
    probability does not recover and fail again inside one scan step.  ``p_required`` must be in
    (0, 1]; ``t_step``, ``tol`` > 0.
    """
    p_req = check_probability(p_required)
    t_max, t_step, tol = check_real("t_max", t_max), check_real("t_step", t_step), check_real("tol", tol)
    t_min = check_real("t_min", t_min)
    max_bisections = check_count("max_bisections", max_bisections, 1)
    if not (t_step > 0 and tol > 0 and t_max > t_min):
        raise ProblemError(f"need t_step > 0, tol > 0 and t_max > t_min; got t_step={t_step!r}, "
                           f"tol={tol!r}, t_min={t_min!r}, t_max={t_max!r}")
    evals: list[tuple[float, float]] = []

    def p_at(t: float) -> float:
        val = float(probability(t))
        if not np.isfinite(val):
            raise ProblemError(f"custody probability at t = {t:g} is not finite ({val!r})")
        evals.append((t, val))
        return val

    p0 = p_at(t_min)
    if p0 < p_req:
        return Horizon(None, t_min, p_req, tuple(evals), True,
                       f"custody already lost at t_min = {t_min:g}: p = {p0:.6g} < {p_req:g}")
    scan = list(np.arange(t_min + t_step, t_max, t_step)) + [t_max]
    lo = t_min
    hi = None
    for t in scan:
        if p_at(float(t)) < p_req:
            hi = float(t)
            break
        lo = float(t)
    if hi is None:
        return Horizon(lo, None, p_req, tuple(evals), True)
    message = ""
    for _ in range(max_bisections):
        if hi - lo <= tol:
            break
        mid = 0.5 * (lo + hi)
        if not lo < mid < hi:
            message = (f"bisection stopped at the floating-point resolution of t: bracket "
                       f"[{lo!r}, {hi!r}] is wider than tol = {tol:g}")
            break
        try:
            failed = p_at(mid) < p_req
        except SolverError as exc:
            message = f"probability evaluation failed at t = {mid:g} inside the bracket: {exc}"
            break
        lo, hi = (lo, mid) if failed else (mid, hi)
    converged = hi - lo <= tol
    if not converged and not message:
        message = (f"bisection budget max_bisections = {max_bisections} used up: bracket width "
                   f"{hi - lo:g} > tol = {tol:g}")
    return Horizon(lo, hi, p_req, tuple(evals), converged, message)


def tucker_algorithm1(area: Callable[[float], float], p_c: float, theta: float, rho: float,
                      max_days: int = 1000) -> float:
    """Tucker et al. Algorithm 1 exactly as printed (for comparison only; see module docstring):
    ``A_fov = rho sin(theta)``, ``A_r-cl = (1 - p_c) / A_fov``; ``t = 0``; while
    ``A_r <= A_r-cl``: ``A_r = computeReach(t)``, ``t = t + 1``.  ``area(t)`` is the enclosing
    ball's area after ``t`` days.  Returns the final ``t`` (days)."""
    A_fov = rho * np.sin(theta)
    A_rcl = (1 - p_c) / A_fov
    A_r, t = 0.0, 0
    while A_r <= A_rcl:
        A_r = float(area(t))
        t += 1
        if t > max_days:
            raise ProblemError(f"tucker_algorithm1: no loss within {max_days} days")
    return float(t)


# ====================================================================== sweep adapter
SWEEP_PARAMS = ("observer", "fov_deg", "fov_shape", "p", "p_required", "t_max_days", "epoch", "model")


def check_sweep_params(params: dict, where: str) -> FOV:
    """The one check of the argument names of :func:`sweep_task` (``keep.custody`` of a sweep,
    checked by the sweep driver before any task runs, and by the task) and of the required
    ``fov_deg`` with ``fov_shape``; returns the FOV.  ``where`` names the caller in the
    message."""
    from ocreach.custody_report import make_fov

    unknown = sorted(set(params) - set(SWEEP_PARAMS))
    if unknown:
        raise ProblemError(f"{where} has unknown argument(s) {unknown}; allowed: "
                           f"{list(SWEEP_PARAMS)}")
    if "fov_deg" not in params:
        raise ProblemError(f"{where} needs fov_deg (full field-of-view angle in degrees, in "
                           f"(0, 180))")
    return make_fov(check_real("fov_deg", params["fov_deg"]),
                    str(params.get("fov_shape", "circle")))


def sweep_task(problem, result, **params) -> dict:
    """Custody of one sweep task (``keep.custody`` of :mod:`ocreach.sweep`): a plain JSON-able dict.

    ``params``: ``observer`` (``geocentre`` (default) | ``L1`` ... ``L5`` | ``ground:LAT,LON,ALT`` |
    ``orbit:PROBLEM``), ``fov_deg`` (full angle, required), ``fov_shape`` (``circle`` | ``square``),
    ``p`` or ``p_required`` (required probability in (0, 1], default 0.95), ``t_max_days`` (only
    times up to it are used), ``epoch`` (ground sites), ``model`` (``covered`` | ``tucker-eq14``).

    At the start and every time of ``result`` after it, the exact minimum enclosing ball of the result's
    position samples (``result.points_at(k, problem.position_dims)``; an inner estimate of the
    ball of the true set when the samples are points of it) is scored by
    :func:`custody_probability` with the boresight on the ball's centre.  The sweep's result is
    fixed, so the horizon is bracketed on the result's own time grid (no bisection; the
    bracket width is ``horizon_resolution_days``): ``t_safe_days`` is the last grid time before
    the first failing one (custody held at every grid time up to it), ``t_loss_days`` the first
    failing one or None when custody holds at every used time; custody already lost at the start
    gives ``t_safe_days`` None, ``t_loss_days`` 0 and ``lost_at_start``.  Radii in km, times in days.
    """
    from ocreach.custody_report import parse_observer
    from ocreach.meb import minimum_enclosing_ball

    fov = check_sweep_params(params, "custody sweep_task")
    shape = str(params.get("fov_shape", "circle"))
    if "p" in params and "p_required" in params and params["p"] != params["p_required"]:
        raise ProblemError(f"custody sweep_task: p={params['p']!r} and p_required={params['p_required']!r} "
                           "disagree; give one of them")
    p_req = check_probability(params.get("p_required", params.get("p", 0.95)))
    model = str(params.get("model", "covered"))
    if model not in MODELS:
        raise ProblemError(f"custody sweep_task: model must be one of {MODELS}; got {model!r}")
    if problem.units is None:
        raise ProblemError(f"custody sweep_task: problem {problem.id!r} has no units (km and days are needed)")
    pos = list(problem.position_dims)
    if len(pos) != 3:
        raise ProblemError(f"custody sweep_task: problem {problem.id!r} needs 3 position dimensions; "
                           f"has {len(pos)}")
    observer = parse_observer(str(params.get("observer", "geocentre")), problem,
                              str(params.get("epoch", "2026-01-01")))
    tu_days = float(problem.units.time) / 86400.0
    km = float(problem.units.length) / 1e3
    times = np.asarray(result.times, dtype=float)
    days = (times - times[0]) * tu_days
    use = np.flatnonzero(days > 0)
    if "t_max_days" in params and params["t_max_days"] is not None:
        t_max = check_real("t_max_days", params["t_max_days"])
        if not t_max > 0:
            raise ProblemError(f"custody sweep_task: t_max_days must be > 0; got {params['t_max_days']!r}")
        use = use[days[use] <= t_max * (1 + 1e-12)]
    if use.size == 0:
        raise ProblemError(f"custody sweep_task: the result has no time after the start within t_max_days "
                           f"(result times {days.tolist()} days)")
    t_safe, t_loss, probs, radii = None, None, [], []
    for k in np.r_[0, use].astype(int):  # the start (k = 0) too: custody may be lost already
        ball = minimum_enclosing_ball(result.points_at(int(k), pos))
        o = observer.position([times[k]])[0]
        pk = custody_probability(ball.center, ball.radius, o, fov, model=model)
        probs.append(float(pk))
        radii.append(float(ball.radius * km))
        if t_loss is None:
            if pk < p_req:
                t_loss = float(days[k])
            else:
                t_safe = float(days[k])
    grid = np.diff(np.r_[0.0, days[use]])
    return {"t_safe_days": t_safe, "t_loss_days": t_loss, "lost": t_loss is not None,
            "lost_at_start": t_safe is None,
            "horizon_resolution_days": float(grid.max()), "t_end_days": float(days[use[-1]]),
            "meb_radius_km": radii[-1], "meb_radius_km_max": float(max(radii)),
            "p_end": probs[-1], "p_min": float(min(probs)), "p_required": p_req,
            "observer": observer.name, "fov_deg": fov.full_deg, "fov_shape": shape, "model": model,
            "ball": "exact MEB of the result's position samples (inner estimate)"}
