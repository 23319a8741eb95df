"""Set library: intervals, zonotopes, sparse polynomial zonotopes, ellipsoids, matrix zonotopes,
and finite unions of zonotopes (:class:`ZonotopeUnion`) and of polynomial zonotopes
(:class:`PZUnion`, the parts of a split ``stt`` set).

Sets are immutable numpy-backed values: ``M @ S`` (linear map), ``S + v`` (translation),
``S1 + S2`` (Minkowski sum; exact for polynomial zonotopes with shared identifiers), ``support``,
``sample``, ``contains``, ``reduce``, ``interval_hull``, ``to_zonotope``, ``project``, ``plot``.
"""
from ocreach.sets._base import new_ids
from ocreach.sets.contains import (
                                   CasadiContainment,
                                   casadi_containment,
                                   containment_constraints,
                                   points_in_ellipsoid,
                                   points_in_zonotope,
                                   zonotope_halfspaces,
                                   zonotope_in_halfspaces,
                                   zonotope_in_interval,
                                   zonotope_in_zonotope,
)
from ocreach.sets.convert import (
                                   interval_to_zonotope,
                                   to_polyzonotope,
                                   to_zonotope,
                                   unit_ball_pz,
                                   unit_ball_zonotope,
                                   zonotope_support_range,
)
from ocreach.sets.ellipsoid import Ellipsoid
from ocreach.sets.interval import Interval
from ocreach.sets.matzonotope import MatrixZonotope, matzonotope_times_zonotope
from ocreach.sets.plot import plot_set
from ocreach.sets.polyzonotope import PolyZonotope, cartesian_product, merge_monomials, tensor_map
from ocreach.sets.pz_union import PZUnion
from ocreach.sets.reduce import reduce, reduce_pz, reduce_zonotope
from ocreach.sets.union import ZonotopeUnion
from ocreach.sets.zonotope import Zonotope, polygon_area, zonotope_polygon

__all__ = [
    "CasadiContainment", "Ellipsoid", "Interval", "MatrixZonotope", "PZUnion", "PolyZonotope",
    "Zonotope", "ZonotopeUnion",
    "cartesian_product", "casadi_containment", "containment_constraints", "interval_to_zonotope",
    "matzonotope_times_zonotope", "merge_monomials", "new_ids", "plot_set", "points_in_ellipsoid",
    "points_in_zonotope", "polygon_area", "reduce", "reduce_pz", "reduce_zonotope", "tensor_map",
    "to_polyzonotope", "to_zonotope", "unit_ball_pz", "unit_ball_zonotope", "zonotope_halfspaces", "zonotope_support_range",
    "zonotope_in_halfspaces", "zonotope_in_interval", "zonotope_in_zonotope", "zonotope_polygon",
]
