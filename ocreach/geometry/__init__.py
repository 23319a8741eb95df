"""Geometry of point clouds and directions, below the set library.

* :mod:`~ocreach.geometry.hulls` -- convex hulls, polygon areas and unions, points in hulls;
* :mod:`~ocreach.geometry.meb` -- exact minimum enclosing balls (Welzl) and outer balls from
  support values (Tucker et al. Sec. 2.3);
* :mod:`~ocreach.geometry.directions` -- direction sets on circles and spheres for support
  functions, and the state dimensions users name (``pos``, ``vel``).

May import: the helpers (:mod:`ocreach.errors`) only.
"""
from ocreach.geometry.hulls import (
    circle_directions,
    convex_hull_polygon,
    hull_area,
    in_convex_hull,
    outline_area,
    points_in_polygons,
    polygon_area,
    union_of_polygons,
)
from ocreach.geometry.meb import EnclosingBall, minimum_enclosing_ball, support_outer_ball

__all__ = ["EnclosingBall", "circle_directions", "convex_hull_polygon", "hull_area",
           "in_convex_hull", "minimum_enclosing_ball", "outline_area", "points_in_polygons",
           "polygon_area", "support_outer_ball", "union_of_polygons"]
