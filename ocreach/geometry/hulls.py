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
    """Boolean mask: which ``points`` (m, d) lie in the convex hull of ``hull_points`` (n, d).

    Degenerate hulls (fewer than ``d + 1`` affinely independent points: a flat set, a segment, a
    single point, duplicates) are handled exactly: the hull points span an affine subspace of
    dimension ``k < d`` (SVD, relative tolerance 1e-10); a point is inside iff its distance to that
    subspace is at most ``tol`` times the hull's scale (plus ``tol``) and its coordinates in the
    subspace lie in the ``k``-dimensional hull (an interval for ``k = 1``, Delaunay otherwise).
    Raises :class:`SetError` for empty, non-finite or mismatched input.
    """
    from scipy.spatial import Delaunay, QhullError

    H = np.atleast_2d(np.asarray(hull_points, dtype=float))
    P = np.atleast_2d(np.asarray(points, dtype=float))
    if H.ndim != 2 or H.shape[0] == 0 or H.shape[1] == 0:
        raise SetError(f"hull_points must be a non-empty (n, d) array; got shape {H.shape}")
    if P.ndim != 2 or P.shape[1] != H.shape[1]:
        raise SetError(f"points must be an (m, {H.shape[1]}) array like hull_points; got shape {P.shape}")
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(P))):
        raise SetError("in_convex_hull: points and hull_points must be finite (no NaN or inf)")
    if P.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    c0 = H.mean(axis=0)
    A = H - c0
    _, s, Vt = np.linalg.svd(A, full_matrices=False)
    scale = float(s[0]) if s.size else 0.0
    k = int(np.sum(s > 1e-10 * scale)) if scale > 0 else 0
    d = H.shape[1]
    Q = P - c0
    if k == d:
        try:
            return Delaunay(H).find_simplex(P, tol=tol) >= 0
        except QhullError as exc:
            raise SetError(f"in_convex_hull: qhull failed on {H.shape[0]} hull points in {d}-D: {exc}") from None
    basis = Vt[:k]  # orthonormal basis of the hull's affine subspace
    coords = Q @ basis.T
    resid = np.linalg.norm(Q - coords @ basis, axis=1)
    size = float(np.max(np.linalg.norm(A, axis=1)))
    on_plane = resid <= tol * max(size, 1.0) + 1e-12 * size
    if k == 0:
        return on_plane
    hc = A @ basis.T
    if k == 1:
        lo, hi = hc.min(), hc.max()
        slack = tol * max(hi - lo, 1.0)
        return on_plane & (coords[:, 0] >= lo - slack) & (coords[:, 0] <= hi + slack)
    try:
        return on_plane & (Delaunay(hc).find_simplex(coords, tol=tol) >= 0)
    except QhullError as exc:
        raise SetError(f"in_convex_hull: qhull failed on the {k}-D affine hull: {exc}") from None


# minimum enclosing balls live in their own module (exact Welzl solver, support-function outer ball)
from ocreach.geometry.meb import EnclosingBall, minimum_enclosing_ball, support_outer_ball  # noqa: E402,F401
