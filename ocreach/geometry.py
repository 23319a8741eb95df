"""Small geometric helpers shared by plots and metrics (convex hulls, polygon areas, directions)."""
from __future__ import annotations

import numpy as np

from ocreach.errors import SetError


def convex_hull_polygon(points: np.ndarray) -> np.ndarray | None:
    """Counter-clockwise vertices of the convex hull of 2-D ``points`` (None if degenerate)."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.asarray(points, dtype=float)
    if pts.shape[0] < 3:
        return None
    try:
        hull = ConvexHull(pts)
    except QhullError:
        return None
    return pts[hull.vertices]


def polygon_area(vertices: np.ndarray | None) -> float:
    """Area of a simple polygon by the shoelace formula (0 for None)."""
    if vertices is None or len(vertices) < 3:
        return 0.0
    x, y = np.asarray(vertices, dtype=float).T
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def union_of_polygons(polygons):
    """Union of 2-D polygons (list of (k, 2) vertex arrays) as a shapely geometry.

    Used for the outline of a split polynomial zonotope, whose pieces overlap: the union is the
    (possibly non-convex) outer approximation of the projection.
    """
    from shapely.geometry import Polygon
    from shapely.ops import unary_union

    polys = [Polygon(np.asarray(p, dtype=float)) for p in polygons if p is not None and len(p) >= 3]
    return unary_union([p.buffer(0) for p in polys])


def outline_area(outline) -> float:
    """Area of an outline: one polygon (k, 2), or a list of overlapping polygons (their union)."""
    if outline is None:
        return 0.0
    if isinstance(outline, (list, tuple)):
        return float(union_of_polygons(outline).area)
    return polygon_area(outline)


def points_in_polygons(points: np.ndarray, polygons, tol: float = 1e-9) -> np.ndarray:
    """Mask of 2-D ``points`` inside the union of polygons (list of (k, 2) vertex arrays, any
    orientation), with a boundary tolerance of ``tol`` times each polygon's extent.

    Used for coverage tests against a polynomial zonotope's :meth:`outline` pieces, which are a
    much tighter outer approximation than the single zonotope enclosure ``contains`` tests.
    """
    from matplotlib.path import Path

    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 2:
        raise SetError(f"points must have shape (m, 2); got {P.shape}")
    ok = np.zeros(P.shape[0], dtype=bool)
    for poly in polygons:
        poly = np.asarray(poly, dtype=float)
        if poly.shape[0] < 3:
            continue
        todo = ~ok
        if not np.any(todo):
            break
        path = Path(poly)
        r = tol * max(1.0, float(np.ptp(poly, axis=0).max()))
        # matplotlib's radius sign depends on the orientation: accept either
        ok[todo] = path.contains_points(P[todo], radius=r) | path.contains_points(P[todo], radius=-r)
    return ok


def hull_area(points: np.ndarray) -> float:
    """Area of the convex hull of 2-D points."""
    return polygon_area(convex_hull_polygon(points))


def circle_directions(m: int) -> np.ndarray:
    """``m`` unit vectors evenly spaced on the circle, shape ``(m, 2)``."""
    th = np.linspace(0.0, 2 * np.pi, m, endpoint=False)
    return np.column_stack([np.cos(th), np.sin(th)])


def in_convex_hull(points: np.ndarray, hull_points: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """Boolean mask: which ``points`` lie in the convex hull of ``hull_points`` (2-D or n-D)."""
    from scipy.spatial import Delaunay, QhullError

    try:
        tri = Delaunay(np.asarray(hull_points, dtype=float))
    except QhullError:
        return np.zeros(len(points), dtype=bool)
    return tri.find_simplex(np.asarray(points, dtype=float), tol=tol) >= 0


# minimum enclosing balls live in their own module (exact Welzl solver, support-function outer ball)
from ocreach.meb import EnclosingBall, minimum_enclosing_ball, support_outer_ball  # noqa: E402,F401
