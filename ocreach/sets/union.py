"""Finite unions of zonotopes: the reachable set of a split zonotope method (``taylor``, ``sdc``).

When a reachable set is split into parts (Patel & Subbarao Eq. 16 and the splitting rule after it)
every part is propagated on its own; the set at a time is the union of the parts.  A
:class:`ZonotopeUnion` keeps the parts and answers the usual set queries exactly for the union.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ocreach.errors import SetError, SolverError
from ocreach.sets._base import SetBase, as_directions, as_points, as_rng, check_parts
from ocreach.sets.zonotope import Zonotope

#: points per block-diagonal gauge LP
GAUGE_CHUNK = 100
#: tolerance of the membership test used as the inside certificate (relative to the set's size)
CERT_TOL = 1e-11


class ZonotopeUnion(SetBase):
    """The union of zonotopes ``parts`` (all of the same dimension; at least one)."""

    def __init__(self, parts: Sequence[Any]):
        ps = [p.to_zonotope() if not isinstance(p, Zonotope) else p for p in parts]
        self.parts = check_parts("ZonotopeUnion", ps)
        self._freeze()

    @property
    def dim(self) -> int:
        return self.parts[0].dim

    @property
    def n_parts(self) -> int:
        return len(self.parts)

    def __repr__(self) -> str:
        return f"ZonotopeUnion(dim={self.dim}, parts={self.n_parts})"

    def support(self, d: Any) -> np.ndarray | float:
        """Exact support function of the union: the max over the parts."""
        D, single = as_directions(d, self.dim)
        val = np.max(np.vstack([p.support(D) for p in self.parts]), axis=0)
        return float(val[0]) if single else val

    def contains(self, points: Any, tol: float = 1e-7) -> np.ndarray | bool:
        """Membership in any part (exact per part, see :meth:`Zonotope.contains`)."""
        P, single = as_points("points", points, self.dim)
        out = np.zeros(P.shape[0], dtype=bool)
        for p in self.parts:
            todo = ~out
            if not np.any(todo):
                break
            out[todo] = np.asarray(p.contains(P[todo], tol=tol), dtype=bool)
        return bool(out[0]) if single else out

    def interval_hull(self):
        from ocreach.sets.interval import Interval

        hs = [p.interval_hull() for p in self.parts]
        return Interval(np.min([h.lo for h in hs], axis=0), np.max([h.hi for h in hs], axis=0))

    def project(self, dims: Any) -> ZonotopeUnion:
        return ZonotopeUnion([p.project(dims) for p in self.parts])

    def __rmatmul__(self, M):
        return ZonotopeUnion([M @ p for p in self.parts])

    def __add__(self, other):
        if isinstance(other, SetBase) and not isinstance(other, ZonotopeUnion):
            return ZonotopeUnion([p + other for p in self.parts])
        v = np.asarray(other, dtype=float) if not isinstance(other, SetBase) else None
        if v is not None and v.ndim == 1:
            return ZonotopeUnion([p + v for p in self.parts])
        return NotImplemented

    def sample(self, n: int, rng: Any = None, mode: str = "uniform") -> np.ndarray:
        """(n, dim) points: each drawn from a part chosen uniformly at random."""
        g = as_rng(rng)
        which = g.integers(0, self.n_parts, size=int(n))
        out = np.empty((int(n), self.dim))
        for j, p in enumerate(self.parts):
            idx = np.flatnonzero(which == j)
            if idx.size:
                out[idx] = p.sample(idx.size, g, mode)
        return out

    def to_zonotope(self) -> Zonotope:
        """A single zonotope enclosing the union (the interval hull; exact for one part)."""
        if self.n_parts == 1:
            return self.parts[0]
        return self.interval_hull().to_zonotope()

    def reduce(self, order: float = 1.0, method: str = "girard") -> ZonotopeUnion:
        return ZonotopeUnion([p.reduce(order, method) for p in self.parts])

    def outline(self, dims: Any = (0, 1)) -> list[np.ndarray]:
        """The parts' 2-D outlines (a list of polygons, as :meth:`PolyZonotope.outline` gives)."""
        return [p.outline(dims) for p in self.parts]

    def plot(self, ax, dims=(0, 1), **kw):
        """Draw every part's projection on ``dims`` (one label for the union)."""
        from ocreach.sets.plot import plot_set

        label = kw.pop("label", None)
        out = None
        for i, p in enumerate(self.parts):
            out = plot_set(p, ax, dims=dims, label=label if i == 0 else None, **kw)
        return out

    def volume_bound(self) -> float:
        """Sum of the parts' volumes: an upper bound of the union's volume (exact if disjoint)."""
        return float(sum(p.volume() for p in self.parts))


def gauge(Z: Zonotope, points: Any, exact: bool = False, lp: bool | str = True) -> np.ndarray:
    """Scaled gauge ``min {t >= 0 : x in c + t G}`` of each point (inf if ``x - c`` is outside
    the range of ``G``); ``x`` is in ``Z`` iff the gauge is <= 1.

    Unless ``exact``, points certified inside by the exact membership test
    (:func:`ocreach.sets.contains.points_in_zonotope` on the row-scaled set, distance tolerance
    ``CERT_TOL`` of the set's size) are reported with the upper bound ``1.0`` without a gauge LP;
    then the LP ``min t s.t. G xi = x - c, -t <= xi <= t`` for the remaining points,
    ``GAUGE_CHUNK`` of them per block-diagonal LP (HiGHS).  ``lp`` chooses how far this goes:

    * ``True``: membership test, then the gauge LP for the points not inside;
    * ``False``: the exact membership test only (its certificates and LP); the points not inside
      get ``inf``;
    * ``"membership-lp"``: as ``False`` without the membership test's certificates first (for
      points whose LP-free certificates already failed);
    * ``"certificates"``: no LP at all: the points proven inside by the LP-free certificates
      (:func:`ocreach.sets.contains.certified_in_zonotope`) get ``1.0``, every other point
      ``inf`` (not proven inside, which is not proven outside).
    """
    if not (isinstance(lp, (bool, np.bool_)) or lp in ("membership-lp", "certificates")):
        raise SetError(f"gauge: lp must be True, False, 'membership-lp' or 'certificates'; got "
                       f"{lp!r}")
    P, single = as_points("points", points, Z.dim)
    G = np.asarray(Z.G)
    G = G[:, np.any(G != 0, axis=0)]
    R = P - Z.c
    out = np.full(P.shape[0], np.inf)
    if G.shape[1] == 0:
        out[np.all(R == 0, axis=1)] = 0.0
        return float(out[0]) if single else out
    # row scaling leaves the gauge unchanged and gives the LP entries of order one
    row = np.abs(G).sum(axis=1)
    live = row > 0
    off = np.any(R[:, ~live] != 0, axis=1)
    G = G[live] / row[live, None]
    R = R[:, live] / row[live]
    if G.shape[0] == 0:
        out[~off] = 0.0
        return float(out[0]) if single else out
    if exact:
        ok = np.zeros(R.shape[0], dtype=bool)
    else:
        from ocreach.sets.contains import certified_in_zonotope, points_in_zonotope

        # exact membership up to an l1 distance of ~6e-11 of the (row-scaled, unit-size) set
        Zs = Zonotope(np.zeros(G.shape[0]), G)
        if lp == "certificates":
            inside = certified_in_zonotope(Zs, R, tol=CERT_TOL)
        else:
            inside = points_in_zonotope(Zs, R, tol=CERT_TOL, certify=lp != "membership-lp")
        ok = ~off & np.asarray(inside, dtype=bool)
        out[ok] = 1.0
    gauge_lp = isinstance(lp, (bool, np.bool_)) and bool(lp)
    todo = np.flatnonzero(~ok & ~off) if gauge_lp else np.zeros(0, dtype=np.int64)
    for s0 in range(0, todo.size, GAUGE_CHUNK):
        blk = todo[s0: s0 + GAUGE_CHUNK]
        out[blk] = _gauge_lp(G, R[blk])
    return float(out[0]) if single else out


def _gauge_lp(G: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``min t_k s.t. G xi_k = r_k, -t_k <= xi_k <= t_k`` for all rows ``r_k`` of ``R`` in ONE
    block-diagonal LP (HiGHS); the objective is the sum, which separates over the blocks.  If
    the batch fails, the points one by one; a point whose simplex fails numerically (status 4,
    seen at these tolerances on a generator of a row 100 times the others) by HiGHS's interior
    point method, then, if that fails too, the lower bound ``max_i |r_i| / sum_j |G_ij|`` when
    that is > 1 (outside either way), else the error."""
    import scipy.sparse as sp
    from scipy.optimize import linprog

    n, h = G.shape
    K = R.shape[0]
    nv = h + 1
    eq = sp.csr_matrix(np.hstack([G, np.zeros((n, 1))]))
    ub = sp.csr_matrix(np.vstack([np.hstack([np.eye(h), -np.ones((h, 1))]),
                                  np.hstack([-np.eye(h), -np.ones((h, 1))])]))
    I = sp.identity(K, format="csr")
    c = np.tile(np.r_[np.zeros(h), 1.0], K)
    bounds = [(None, None)] * h + [(0, None)]
    def solve(method: str):
        return linprog(c, A_ub=sp.kron(I, ub, format="csc"), b_ub=np.zeros(2 * h * K),
                       A_eq=sp.kron(I, eq, format="csc"), b_eq=R.ravel(), bounds=bounds * K,
                       method=method, options={"primal_feasibility_tolerance": 1e-10,
                                               "dual_feasibility_tolerance": 1e-10})

    res = solve("highs")
    if res.status == 4 and K == 1:  # the simplex's numerical failure: HiGHS's interior point
        res = solve("highs-ipm")
    if res.status != 0 and K > 1:
        # infeasible (some point is off the range of G), or HiGHS's numerical failure (status 4)
        # on blocks of very different scales (points far outside one sub-step tube of a union
        # next to points inside it): the same LPs one by one
        return np.concatenate([_gauge_lp(G, R[k:k + 1]) for k in range(K)])
    if res.status == 2:
        return np.array([np.inf])
    if res.status != 0:
        # |r_i| = |sum_j G_ij xi_j| <= t sum_j |G_ij|: a lower bound of the gauge; a point it
        # puts outside (e.g. far from one sub-step tube of a union) needs no exact value
        lower = (np.abs(R) / np.abs(G).sum(axis=1)).max(axis=1)
        if np.all(lower > 1.0):
            return lower
        raise SolverError(f"gauge LP failed (HiGHS status {res.status}: {res.message})")
    return res.x.reshape(K, nv)[:, -1]


def union_gauge(S: Any, points: Any, exact: bool = False, within: float | None = None
                ) -> np.ndarray:
    """Smallest gauge over the parts of a :class:`ZonotopeUnion` (or of one zonotope).

    Unless ``exact``, a point certified inside some part is reported as ``1.0`` (see :func:`gauge`):
    first by the LP-free certificates, then by the LP of the exact membership test, each part
    tried only on the points inside its interval hull (widened by ``1e-6`` of its magnitude); the
    exact LP gauge over every part is computed only for points inside no part.

    ``within`` (> 1: a caller's escape threshold such as ``1 + 1e-9``) settles the points near a
    boundary without a gauge LP: after the certificates on the parts, the certificates and then
    the membership LP run on the parts scaled by ``within`` about their centres (a point is in a
    scaled part iff its gauge is at most ``within``), and the points found inside those are
    reported as ``within``, an upper bound of their gauge.  The states from the vertices of an
    initial box lie on the sets' boundary, where the unscaled tests fail by rounding alone; their
    exact gauge LPs were most of the ARCH truth check's time (PRDE20 P: 66 s -> 13 s for 400
    samples).  Only the points inside no scaled part get their exact gauge."""
    if within is not None and not (isinstance(within, (int, float, np.integer, np.floating))
                                   and np.isfinite(within) and within > 1.0):
        raise SetError(f"union_gauge: within must be a finite number > 1 (the gauge threshold); "
                       f"got {within!r}")
    parts = S.parts if isinstance(S, ZonotopeUnion) else (S.to_zonotope(),)
    P, single = as_points("points", points, parts[0].dim)
    out = np.full(P.shape[0], np.inf)
    todo = np.ones(P.shape[0], dtype=bool)
    if not exact:
        _settle_inside(parts, P, out, todo, 1.0, "certificates")
        if within is None:
            _settle_inside(parts, P, out, todo, 1.0, "membership-lp")
        elif todo.any():
            wide = [scaled(p, within) for p in parts]
            _settle_inside(wide, P, out, todo, float(within), "certificates")
            _settle_inside(wide, P, out, todo, float(within), "membership-lp")
    idx = np.flatnonzero(todo)
    if idx.size:
        vals = np.vstack([np.atleast_1d(gauge(p, P[idx], exact=True)) for p in parts])
        out[idx] = vals.min(axis=0)
    return float(out[0]) if single else out


def scaled(Z: Any, scale: float) -> Zonotope:
    """The zonotope ``Z`` (or its enclosure) scaled by ``scale`` about its centre: a point is in
    it iff its gauge in ``Z`` is at most ``scale``."""
    Z = Z if isinstance(Z, Zonotope) else Z.to_zonotope()
    return Zonotope.trusted(Z.c, scale * np.asarray(Z.G))


def _settle_inside(parts: Sequence[Zonotope], P: np.ndarray, out: np.ndarray, todo: np.ndarray,
                   value: float, lp: str) -> None:
    """The points ``todo`` proven inside some of ``parts`` (the parts of the union scaled by
    ``value``) by the test ``lp`` of :func:`gauge` (``"certificates"`` or ``"membership-lp"``;
    each part only on the points in its widened box) get ``value`` times their gauge bound in the
    scaled part (``1.0``, or ``0.0`` at the centre of a flat part) in ``out`` and leave ``todo``
    (both updated in place)."""
    for p in parts:
        idx = np.flatnonzero(todo)
        if idx.size == 0:
            return
        lo, hi = _box(p)
        idx = idx[np.all((P[idx] >= lo) & (P[idx] <= hi), axis=1)]
        if idx.size == 0:
            continue
        g = np.atleast_1d(gauge(p, P[idx], lp=lp))
        hit = g <= 1.0
        out[idx[hit]] = value * g[hit]
        todo[idx[hit]] = False


def _box(Z: Zonotope) -> tuple[np.ndarray, np.ndarray]:
    """The interval hull of ``Z`` widened by ``1e-6`` of its magnitude: a point outside it is not
    in ``Z``, nor within the membership tests' tolerance of it (``CERT_TOL`` times the generator
    count, relative)."""
    r = np.abs(Z.G).sum(axis=1)
    tol = 1e-6 * (1.0 + np.abs(Z.c) + r)
    return Z.c - r - tol, Z.c + r + tol
