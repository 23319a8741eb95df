"""Containment checks of the soundness harness: is a truth point inside a guaranteed set?

A point escapes a set when it lies outside the set enlarged by the box of radius
``ABS_TOL (1 + |x|_inf)`` (the truth's own error is ~1e-11 on the harness's horizons, see
:mod:`ocreach.testing.truth`), decided per set type:

* :class:`Zonotope`, :class:`Interval` and :class:`ZonotopeUnion`: the scaled gauge of the
  enlarged set (:func:`ocreach.sets.union.union_gauge`: exact membership certificate, else the
  gauge LP ``min t : x in c + t G``), an escape when it exceeds ``1 + GAUGE_TOL``;
* :class:`PolyZonotope` and :class:`PZUnion`: the verified three-valued membership of
  :func:`ocreach.sets.pz_witness.classify` on the enlarged set: a certificate of exclusion (a
  direction ``d`` with ``d^T x`` above a rigorous upper bound of the support, of the zonotope
  enclosure or of the polynomial itself, rounding included) is an escape, a witness (factors in
  the box mapping within the tolerance, rounding included) is inside, and a point neither proved
  in nor out is counted as *undecided* (reported, not an escape);
* any other set: the support test in the ``2 n`` axis directions and the direction from the set's
  box centre to the point (``d^T x > support(d) + tol`` is an escape, since ``support`` is an upper
  bound for a set result); weaker, and reported as such (``Verdict.exact = False``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.sets.interval import Interval
from ocreach.sets.polyzonotope import PolyZonotope
from ocreach.sets.pz_union import PZUnion
from ocreach.sets.union import ZonotopeUnion, union_gauge
from ocreach.sets.zonotope import Zonotope

#: absolute enlargement of the sets, times (1 + |x|_inf): the truth's error is ~1e-11
ABS_TOL = 1e-9
#: relative tolerance of the gauge (as in the per-scenario soundness tests)
GAUGE_TOL = 1e-9


@dataclass(frozen=True)
class Verdict:
    """Per point: ``gauge`` (> 1 + GAUGE_TOL outside; for a polynomial zonotope inf for a
    certified exclusion, else 1.0), ``escaped`` and ``undecided`` masks;
    ``exact``: the check decides membership exactly (zonotopes) or by certificates (PZ)."""

    gauge: np.ndarray
    escaped: np.ndarray
    undecided: np.ndarray
    exact: bool


def tolerance(points: np.ndarray) -> float:
    """The absolute enlargement used for ``points`` (module docstring)."""
    return ABS_TOL * (1.0 + float(np.max(np.abs(points), initial=0.0)))


def _enlarged(Z: Zonotope, eps: float) -> Zonotope:
    return Zonotope(Z.c, np.hstack([Z.G, eps * np.eye(Z.dim)]))


def _zonotope_parts(S) -> list[Zonotope] | None:
    if isinstance(S, ZonotopeUnion):
        return list(S.parts)
    if isinstance(S, Zonotope):
        return [S]
    if isinstance(S, Interval):
        return [S.to_zonotope()]
    return None


def check_points(S, points: np.ndarray) -> Verdict:
    """The verdict of every row of ``points`` (N, n) against the guaranteed set ``S``."""
    P = np.atleast_2d(np.asarray(points, dtype=float))
    N = P.shape[0]
    eps = tolerance(P)
    zs = _zonotope_parts(S)
    if zs is not None:
        g = np.atleast_1d(union_gauge(ZonotopeUnion([_enlarged(z, eps) for z in zs]), P))
        return Verdict(g, g > 1 + GAUGE_TOL, np.zeros(N, bool), True)
    if isinstance(S, (PolyZonotope, PZUnion)):
        return _check_pz(S, P, eps)
    return _check_support(S, P, eps)


def _check_pz(S: PolyZonotope | PZUnion, P: np.ndarray, eps: float) -> Verdict:
    from ocreach.sets.pz_witness import classify

    v = classify(S, P, eps)
    gauge = np.where(v.outside, np.inf, 1.0)
    return Verdict(gauge, v.outside, v.undecided, True)


def _check_support(S, P: np.ndarray, eps: float) -> Verdict:
    n = P.shape[1]
    hull = S.interval_hull()
    mid = 0.5 * (hull.lo + hull.hi)
    D = P - mid
    norm = np.linalg.norm(D, axis=1, keepdims=True)
    D = np.where(norm > 0, D / np.where(norm > 0, norm, 1.0), 0.0)
    dirs = np.vstack([np.eye(n), -np.eye(n)])
    h_axes = np.atleast_1d(S.support(dirs))
    ex_axes = (P @ dirs.T - h_axes[None] - eps).max(axis=1)
    h_own = np.atleast_1d(S.support(D))
    ex_own = np.einsum("ij,ij->i", P, D) - h_own - eps
    escaped = (ex_axes > 0) | (ex_own > 0)
    return Verdict(np.where(escaped, np.inf, 1.0), escaped, np.zeros(P.shape[0], bool), False)


def check_flowpipe(pieces, points: np.ndarray, times: np.ndarray, locations) -> Verdict:
    """The verdict of every truth state of a hybrid automaton: row ``i`` of ``points`` (its
    state and global time, the coordinates of the pieces) at ``times[i]`` in ``locations[i]``
    is inside when some piece of that location whose time range contains ``times[i]`` (widened by
    :func:`tolerance`) contains it (:func:`check_points`); its gauge is the least over those
    pieces (inf where no piece covers its time)."""
    P = np.atleast_2d(np.asarray(points, dtype=float))
    t = np.asarray(times, dtype=float)
    loc = np.asarray(locations, dtype=object)
    N = P.shape[0]
    g = np.full(N, np.inf)
    inside = np.zeros(N, bool)
    undecided = np.zeros(N, bool)
    exact = True
    eps = tolerance(t)
    for pc in pieces:
        idx = np.flatnonzero(~inside & (loc == pc.location) & (t >= pc.t_lo - eps)
                             & (t <= pc.t_hi + eps))
        if idx.size:  # a point outside the piece's box (enlarged) is not in the piece
            box = pc.set.interval_hull()
            pad = tolerance(P[idx]) * (1 + 1e-6)
            idx = idx[np.all((P[idx] >= box.lo - pad) & (P[idx] <= box.hi + pad), axis=1)]
        if idx.size == 0:
            continue
        v = check_points(pc.set, P[idx])
        exact &= v.exact
        g[idx] = np.minimum(g[idx], v.gauge)
        inside[idx[~v.escaped & ~v.undecided]] = True
        undecided[idx[v.undecided]] = True
    undecided &= ~inside
    return Verdict(g, ~inside & ~undecided, undecided, exact)
