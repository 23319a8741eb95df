"""Conversions between set types and polynomial-zonotope forms of the unit ball.

* interval -> zonotope -> polynomial zonotope (exact);
* unit ball -> polynomial zonotope (Foss et al. Eq. 16 for n = 2; a cube-to-ball polynomial for
  n = 3..5, the compact products of :mod:`ocreach.sets.ball_pz` for n > 5, see
  :func:`unit_ball_pz`) and -> outer zonotope with k generators.
"""
from __future__ import annotations

import functools
import itertools
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.errors import SetError
from ocreach.sets import dispatch
from ocreach.sets.ellipsoid import Ellipsoid
from ocreach.sets.polynomials import components_pz, poly_add, poly_mul

if TYPE_CHECKING:
    from ocreach.sets._base import SetBase
    from ocreach.sets.interval import Interval
    from ocreach.sets.polyzonotope import PolyZonotope
    from ocreach.sets.zonotope import Zonotope


def interval_to_zonotope(I: Interval) -> Zonotope:
    return I.to_zonotope()


def to_zonotope(S: SetBase) -> Zonotope:
    """Zonotope enclosure of any set (exact for intervals/zonotopes)."""
    return S.to_zonotope()


def to_polyzonotope(S: SetBase, ids: Any = None) -> PolyZonotope:
    """Polynomial zonotope of an interval/zonotope (exact, fresh identifiers) or a PZ itself."""
    from ocreach.sets.polyzonotope import PolyZonotope

    if isinstance(S, PolyZonotope):
        return S
    return PolyZonotope.from_zonotope(S.to_zonotope(), ids)


def unit_ball_zonotope(n: int, k: int | None = None) -> Zonotope:
    """Outer zonotope of the unit Euclidean ball with ``k >= n`` generators (default 2n, 8 in 2-D).

    Directions: 2-D: angles pi j / k (a regular 2k-gon, support in [1, 1 / cos(pi / 2k)]: 1.035 at
    k = 6, 1.026 at 7, 1.020 at 8); 3-D with k = 10: the axes through opposite vertices of the
    regular dodecahedron (support in [1, 1.096]); 3-D with k = 30: the spread directions of
    :data:`ocreach.sets.ball_directions.SPREAD_3D_30` (support in [1, 1.027]); 4-D with k = 16
    / 24: the spread directions ``SPREAD_4D_16`` / ``SPREAD_4D_24`` (support in [1, 1.147] /
    [1, 1.099]; no 3 % zonotope in 4-D); otherwise the n
    axes plus pseudo-random unit directions (seeded; **loose**: no tightness guarantee, 2n
    generators in 4-D and up are far looser than 3 %, [1, 2.75] in 4-D with 8; a tight n-D ball
    is :func:`ocreach.sets.ball_pz.compact_ball_pz` or :func:`unit_ball_pz`).  All generators
    get the common length ``1 / r_in``, where ``r_in`` is the inradius of the zonotope of unit
    directions (minimum facet offset), so the ball touches the facets from inside.
    :func:`zonotope_support_range` gives the exact support range over the unit sphere.
    """
    from ocreach.sets.ball_directions import SPREAD
    from ocreach.sets.contains import zonotope_halfspaces
    from ocreach.sets.zonotope import Zonotope

    n = int(n)
    if n < 1:
        raise SetError(f"unit_ball_zonotope: n must be >= 1; got {n}")
    if k is None:
        k = 8 if n == 2 else 2 * n
    k = int(k)
    if k < n:
        raise SetError(f"unit_ball_zonotope: k must be >= n={n}; got {k}")
    if n == 1:
        return Zonotope(np.zeros(1), np.ones((1, 1)))
    if n == 2:
        t = np.pi * np.arange(k) / k
        D = np.vstack([np.cos(t), np.sin(t)])
    elif n == 3 and k == 10:
        D = _dodecahedron_axes()
    elif (n, k) in SPREAD:
        D = (SPREAD[n, k] / np.linalg.norm(SPREAD[n, k], axis=1, keepdims=True)).T
    else:
        extra = k - n
        rng = np.random.default_rng(11)
        X = rng.standard_normal((extra, n))
        X[:, 0] = np.abs(X[:, 0])
        D = np.hstack([np.eye(n), (X / np.linalg.norm(X, axis=1, keepdims=True)).T])
    hs = zonotope_halfspaces(Zonotope(np.zeros(n), D), max_subsets=2_000_000)
    if hs is None:
        raise SetError(f"unit_ball_zonotope: too many generators k={k} for facet enumeration in n={n}")
    r_in = float(np.min(hs[1]))
    return Zonotope(np.zeros(n), D / r_in)


def zonotope_support_range(Z: Zonotope, max_ties: int = 16) -> tuple[float, float]:
    """Exact minimum and maximum of the support function ``h(d) = c.d + sum_i |g_i . d|`` of a
    zonotope over the unit sphere ``||d|| = 1`` (for a zonotope centred at the origin: its
    inradius and circumradius).

    The minimum of ``h`` over the sphere is the smallest facet offset (a polytope containing
    the origin: the nearest boundary point lies on a facet, Althoff et al. 2010 facet
    enumeration, :func:`ocreach.sets.contains.zonotope_halfspaces`).  The maximum is
    ``max_{z in Z} ||z||``, attained at a vertex; every vertex lies on a facet with unit normal
    ``m``, whose vertices are ``c + sum_{m.g_i != 0} sign(m.g_i) g_i + sum_{m.g_j = 0} +-g_j``,
    so the facets' sign patterns enumerate all vertices (up to ``2**max_ties`` per facet).
    """
    from ocreach.sets.contains import zonotope_halfspaces

    hs = zonotope_halfspaces(Z, max_subsets=2_000_000)
    if hs is None:
        raise SetError("zonotope_support_range: zonotope not full-dimensional or too many generators "
                       f"(dim {Z.dim}, {Z.G.shape[1]} generators)")
    H, b = hs
    c, G = np.asarray(Z.c, float), np.asarray(Z.G, float)
    G = G[:, np.any(G != 0, axis=0)]
    P = H @ G                                             # (facets, generators)
    tol = 1e-10 * np.abs(P).max()
    r_max = 0.0
    for row in range(H.shape[0]):
        p = P[row]
        tie = np.abs(p) <= tol
        if tie.sum() > max_ties:
            raise SetError(f"zonotope_support_range: {int(tie.sum())} generators in one facet "
                           f"(max_ties = {max_ties})")
        base = c + G[:, ~tie] @ np.sign(p[~tie])
        T = G[:, tie]
        S = np.array(list(itertools.product((1.0, -1.0), repeat=T.shape[1]))).T
        r_max = max(r_max, float(np.linalg.norm(base[:, None] + T @ S, axis=0).max()))
    return float(b.min()), r_max


def _dodecahedron_axes() -> np.ndarray:
    """(3, 10) unit directions through the 20 vertices of the regular dodecahedron, one per
    opposite pair: ``(+-1, +-1, +-1)`` and the cyclic shifts of ``(0, +-1/g, +-g)``, g the golden
    ratio, with the first non-zero coordinate of each kept direction positive."""
    g = (1 + 5 ** 0.5) / 2
    V = [np.array(s, dtype=float) for s in itertools.product((1, -1), repeat=3)]
    V += [np.roll([0.0, s1 / g, s2 * g], c) for s1 in (1, -1) for s2 in (1, -1) for c in range(3)]
    out = []
    for v in V:
        v = v / np.linalg.norm(v)
        if v[np.flatnonzero(v)[0]] > 0:
            out.append(v)
    return np.array(out).T


def unit_ball_pz(n: int, ids: Any = None) -> PolyZonotope:
    """Polynomial zonotope approximating the unit Euclidean ball ``{||u||_2 <= 1}``.

    * n = 1: the interval [-1, 1].
    * n = 2: Foss et al. Eq. 16, ``<I2 (x) [1, -1/4, -1/32, -1/128], I2 (x) 1_{1x4} +
      [[0,1],[1,0]] (x) [0,2,4,6], id>``, i.e. ``u1 = a1 s(a2)``, ``u2 = a2 s(a1)`` with
      ``s(a) = 1 - a^2/4 - a^4/32 - a^6/128``, the order-3 Taylor polynomial of ``sqrt(1 - a^2/2)``
      (square-to-disk map).  The truncated series is >= the square root, so the image of the
      square's boundary lies on or outside the circle: the set contains the disk, touching it at
      (+-1, 0), (0, +-1) (slight over-approximation, at most ~0.5 % near the diagonals).
    * 3 <= n <= 5: the n-D cube-to-ball map ``u_i = a_i sqrt(1 - t_i)``, ``1 - t_i = sum over
      subsets S of the other factors of (-1)^|S| prod_{j in S} a_j^2 / (|S| + 1)`` (= integral_0^1
      prod_{j != i} (1 - s a_j^2) ds, so ``sum_i u_i^2 = 1 - prod_j (1 - a_j^2) = 1`` on the cube's
      boundary; n = 3: ``u1 = a1 sqrt(1 - a2^2/2 - a3^2/2 + a2^2 a3^2 / 3)``), with the square root
      replaced by the polynomial :func:`_upper_sqrt_poly` of degree 3 (n = 3, 4; 48 / 256
      generators) or 2 (n = 5; 405) fitted from above on ``[0, 1 - 1/n]`` (the range of ``t``):
      radius at most 1.003 / 1.003 / 1.023 on dense boundary samples (n = 3 / 4 / 5; proved
      <= 1.0012 / 1.0030 / 1.0230 by Bernstein bounds of ``|F|^2`` in tests/test_ball_pz.py).
      The cube-to-ball polynomial is not extended beyond n = 5: ``t_i`` has ``2^(n-1) - 1``
      monomials and its powers many more (n = 6 with degree 2: ~1,500 generators).
    * n > 5: :func:`ocreach.sets.ball_pz.compact_ball_pz` (products of small balls, radius
      <= 1.03 by construction: 48 / 72 / 96 generators for n = 6 / 7 / 8; 8 / 11 / 14 factors,
      so ``ids``, if given, needs one identifier per factor).

    Why n = 2..5 contain the ball.  Write the map as ``F(a)_i = a_i s_i(a)`` and the exact
    square/cube-to-ball map as ``F0(a)_i = a_i r_i(a)`` with ``r_i = sqrt(1 - t_i)``.  Every dropped
    term of the series of ``sqrt(1 - t)`` is negative for ``t`` in [0, 1] (n = 2), and the fitted polynomial is
    lifted above ``sqrt(1 - t)`` (n = 3..5), so ``s_i >= r_i >= 0``.
    On the boundary of the box ``|F0| = 1``, hence ``|F_l|^2 = sum_i a_i^2 s_{l,i}^2 >= 1`` for every
    ``F_l = (1 - l) F0 + l F``, ``l`` in [0, 1]: the straight-line homotopy never meets the open
    ball on the boundary.  ``F0`` is odd (``F0(-a) = -F0(a)``) and maps the box boundary onto the
    sphere, so by Borsuk's theorem its boundary map has odd degree, hence the (Brouwer) degree of
    ``F0`` about every point of the open ball is odd; by homotopy invariance ``F`` has the same
    non-zero degree there, and a point with non-zero degree lies in the image; the image is
    closed, so it holds the closed ball.
    The tests check the two facts numerically (``|F| >= 1`` on the box boundary, support >= 1).
    """
    from ocreach.sets.polyzonotope import PolyZonotope

    n = int(n)
    if n < 1:
        raise SetError(f"unit_ball_pz: n must be >= 1; got {n}")
    if n == 1:
        return PolyZonotope(np.zeros(1), np.ones((1, 1)), None, np.ones((1, 1), dtype=int), ids)
    if n == 2:
        G = np.kron(np.eye(2), [1.0, -1 / 4, -1 / 32, -1 / 128])
        E = np.kron(np.eye(2), np.ones((1, 4))) + np.kron(np.array([[0, 1], [1, 0]]), [0, 2, 4, 6])
        return PolyZonotope(np.zeros(2), G, None, E.astype(int), ids)
    if n <= 5:
        return components_pz(_cube_ball_components(n), ids).compact()
    from ocreach.sets.ball_pz import compact_ball_pz

    return compact_ball_pz(n, ids)


@functools.lru_cache(maxsize=8)
def _cube_ball_components(n: int) -> tuple[dict, ...]:
    """Component polynomials ``{exponent tuple: coefficient}`` of the cube-to-ball map of
    :func:`unit_ball_pz` for n = 3..5 (cached: the square-root fit is a linear programme of
    ~30 ms and ``stt`` asks for the ball at every step; callers must not modify the dicts)."""
    deg = 3 if n <= 4 else 2
    coef = _upper_sqrt_poly(1.0 - 1.0 / n, deg)
    comps: list[dict] = []
    for i in range(n):
        others = [x for x in range(n) if x != i]
        t: dict = {}
        for r in range(1, n):
            for S in itertools.combinations(others, r):
                e = [0] * n
                for j in S:
                    e[j] = 2
                t[tuple(e)] = -((-1.0) ** r) / (r + 1)      # t = 1 - (1 - t)
        s_poly: dict = {(0,) * n: coef[0]}
        tp = {(0,) * n: 1.0}
        for k in range(1, deg + 1):
            tp = poly_mul(tp, t)
            s_poly = poly_add(s_poly, tp, coef[k])
        e_i = [0] * n
        e_i[i] = 1
        comps.append({e: cval for e, cval in poly_mul({tuple(e_i): 1.0}, s_poly).items()
                      if cval != 0.0})
    return tuple(comps)


def _upper_sqrt_poly(t_max: float, deg: int) -> np.ndarray:
    """Coefficients ``c_0..c_deg`` of a polynomial ``s(t) >= sqrt(1 - t)`` on ``[0, t_max]`` with the
    smallest maximum excess (linear programme on a dense grid of 4001 points, then lifted by the
    largest deficit found on a 10x denser grid plus 1e-12, so the inequality holds everywhere up
    to the interpolation error of a smooth function on that grid)."""
    from scipy.optimize import linprog

    t = np.linspace(0.0, t_max, 4001)
    V = np.vander(t, deg + 1, increasing=True)
    f = np.sqrt(1.0 - t)
    # variables c (deg+1) and e: min e s.t. f <= V c <= f + e
    A = np.vstack([np.c_[-V, np.zeros(t.size)], np.c_[V, -np.ones(t.size)]])
    b = np.r_[-f, f]
    res = linprog(np.r_[np.zeros(deg + 1), 1.0], A_ub=A, b_ub=b, bounds=[(None, None)] * (deg + 2))
    if not res.success:  # pragma: no cover - a tiny LP
        raise SetError(f"unit_ball_pz: fitting the square-root polynomial failed: {res.message}")
    c = res.x[: deg + 1]
    tf = np.linspace(0.0, t_max, 40001)
    deficit = np.max(np.sqrt(1.0 - tf) - np.vander(tf, deg + 1, increasing=True) @ c)
    c[0] += max(deficit, 0.0) + 1e-12
    return c


@dispatch.to_zonotope.register(Ellipsoid)
def _ellipsoid_to_zonotope(E: Ellipsoid, k: int | None = None) -> Zonotope:
    """Outer zonotope of an ellipsoid: its linear map of :func:`unit_ball_zonotope` with ``k``
    generators."""
    return E.L @ unit_ball_zonotope(E.dim, k) + E.q
