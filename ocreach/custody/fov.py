"""Fields of view and where a reachable ball falls in them (Tucker et al. Sec. 2.4).

Fields of view (:class:`FOV`): a circular cone (half-angle) or a rectangular pyramid (two
half-angles and a roll about the boresight).  The focal plane is the gnomonic projection
``(v . e1 / v . b, v . e2 / v . b)`` of the line of sight ``v`` on the plane tangent to the unit
sphere at the boresight ``b``.

Custody: the reachable positions at a horizon are over-approximated by a ball (the minimum
enclosing ball of Tucker Sec. 2.3, or the outer ball of :func:`ocreach.geometry.meb.support_outer_ball`).
:func:`ball_in_fov` is the exact containment test (angular for the cone, four plane distances for
the pyramid); :func:`covered_fraction` the fraction of the ball's projected area (its focal-plane
ellipse: the gnomonic image of the cone of sight lines tangent to the ball) inside the FOV;
:func:`custody_probability` is that fraction (1 when the ball is inside).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.errors import ProblemError, check_real


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


def ball_geometry(center, radius, observer_pos):
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
    c, o, r, w, D = ball_geometry(center, radius, observer_pos)
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
    c, o, r, w, D = ball_geometry(center, radius, observer_pos)
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

    c, o, r, w, D = ball_geometry(center, radius, observer_pos)
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


def make_fov(full_deg: float, shape: str) -> FOV:
    if shape == "circle":
        return FOV.circle(full_deg)
    if shape == "square":
        return FOV.rect(full_deg)
    raise ProblemError(f"fov_shape (--fov-shape) must be 'circle' or 'square'; got {shape!r}")
