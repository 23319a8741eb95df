"""Matplotlib plotting of 2-D projections of sets (from their exact or outer outlines)."""
from __future__ import annotations

from typing import Any

import numpy as np

from ocreach.errors import SetError
from ocreach.sets import dispatch
from ocreach.sets._base import SetBase


def _ccw(P: np.ndarray) -> np.ndarray:
    x, y = P[:, 0], P[:, 1]
    area2 = np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))
    return P if area2 >= 0 else P[::-1]


def plot_set(S, ax, dims: Any = (0, 1), pieces: int = 64, **kw):
    """Draw the projection of ``S`` on ``dims`` into ``ax`` and return the artist.

    Convex sets are drawn as one polygon.  A polynomial zonotope is drawn as the union of the
    exact polygons of the zonotope enclosures of ``pieces`` split parts, merged by shapely
    (:meth:`PolyZonotope.outline_union`: exterior rings counter-clockwise, holes clockwise, filled
    with the non-zero rule), so its non-convex boundary can be stroked; if the projection has no
    area the pieces themselves are drawn.  This is an outer approximation that tightens with
    ``pieces``.  Keyword arguments go to
    :class:`matplotlib.patches.PathPatch` (``facecolor``, ``edgecolor``, ``alpha``, ``label``...).
    """
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path

    from ocreach.sets.polyzonotope import PolyZonotope

    dims = tuple(int(d) for d in dims)
    if len(dims) != 2:
        raise SetError(f"plot: dims must name two dimensions; got {dims!r}")
    rings = S.outline_union(dims, pieces=pieces) if isinstance(S, PolyZonotope) else []
    oriented = bool(rings)
    if not rings:
        rings = S.outline(dims, pieces=pieces) if isinstance(S, PolyZonotope) else [S.outline(dims)]
    verts, codes = [], []
    for P in rings:
        P = np.asarray(P, float)
        if P.shape[0] < 3:  # degenerate: point or segment, draw as a thin polygon
            P = np.vstack([P, P[::-1]]) if P.shape[0] == 2 else np.repeat(P, 3, axis=0)
        P = P if oriented else _ccw(P)
        verts.append(np.vstack([P, P[:1]]))
        codes.append([Path.MOVETO] + [Path.LINETO] * (P.shape[0] - 1) + [Path.CLOSEPOLY])
    path = Path(np.vstack(verts), np.concatenate(codes))
    color = kw.pop("color", None)  # one colour for face and edge (PathPatch warns on `color`)
    if color is not None:
        kw.setdefault("facecolor", color)
        kw.setdefault("edgecolor", color)
    kw.setdefault("facecolor", "tab:blue")
    kw.setdefault("alpha", 0.5)
    if isinstance(S, PolyZonotope) and not oriented:
        kw.setdefault("linewidth", 0.0)
    patch = PathPatch(path, **kw)
    ax.add_patch(patch)
    ax.update_datalim(path.vertices)
    ax.autoscale_view()
    return patch


@dispatch.plot.register(SetBase)
def _plot(S: SetBase, ax: Any, dims: Any = (0, 1), **kw: Any) -> Any:
    return plot_set(S, ax, dims=dims, **kw)
