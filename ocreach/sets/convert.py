"""Conversions between set types and polynomial-zonotope forms of the unit ball.

* interval -> zonotope -> polynomial zonotope (exact);
* unit ball -> polynomial zonotope (Foss et al. Eq. 16 for n = 2; a cube-to-ball polynomial for
  n = 3, see :func:`unit_ball_pz`) and -> outer zonotope with k generators.
"""
from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.errors import SetError

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

    Directions: the n axes plus quasi-uniform directions (2-D: angles pi j / k, a regular 2k-gon);
    all generators get the common length ``1 / r_in``, where ``r_in`` is the inradius of the
    zonotope of unit directions (minimum facet offset), so the ball touches the facets from inside.
    """
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


def _poly_mul(p: dict, q: dict) -> dict:
    out: dict = {}
    for (ea, ca), (eb, cb) in itertools.product(p.items(), q.items()):
        e = tuple(x + y for x, y in zip(ea, eb))
        out[e] = out.get(e, 0.0) + ca * cb
    return out


def _poly_add(p: dict, q: dict, s: float = 1.0) -> dict:
    out = dict(p)
    for e, c in q.items():
        out[e] = out.get(e, 0.0) + s * c
    return out


def _sqrt_series(t: dict, nvars: int) -> dict:
    """1 - t/2 - t^2/8 - t^3/16: the order-3 Taylor polynomial of sqrt(1 - t); for t in [0, 1] it is
    >= sqrt(1 - t) because every dropped term is negative."""
    one = {(0,) * nvars: 1.0}
    t2 = _poly_mul(t, t)
    t3 = _poly_mul(t2, t)
    out = _poly_add(one, t, -0.5)
    out = _poly_add(out, t2, -1.0 / 8.0)
    return _poly_add(out, t3, -1.0 / 16.0)


def unit_ball_pz(n: int, ids: Any = None) -> PolyZonotope:
    """Polynomial zonotope approximating the unit Euclidean ball ``{||u||_2 <= 1}``.

    * n = 1: the interval [-1, 1].
    * n = 2: Foss et al. Eq. 16, ``<I2 (x) [1, -1/4, -1/32, -1/128], I2 (x) 1_{1x4} +
      [[0,1],[1,0]] (x) [0,2,4,6], id>``, i.e. ``u1 = a1 s(a2)``, ``u2 = a2 s(a1)`` with
      ``s(a) = 1 - a^2/4 - a^4/32 - a^6/128``, the order-3 Taylor polynomial of ``sqrt(1 - a^2/2)``
      (square-to-disk map).  The truncated series is >= the square root, so the image of the
      square's boundary lies on or outside the circle: the set contains the disk, touching it at
      (+-1, 0), (0, +-1) (slight over-approximation, at most ~0.5 % near the diagonals).
    * n = 3: the cube-to-ball map ``u1 = a1 sqrt(1 - a2^2/2 - a3^2/2 + a2^2 a3^2 / 3)`` (cyclic),
      with the square root replaced by its order-3 Taylor polynomial in
      ``t = a2^2/2 + a3^2/2 - a2^2 a3^2/3`` in [0, 2/3] (same outward argument as n = 2; points
      reach radius ~1.025 near the cube corners).
    * n > 3: the outer zonotope :func:`unit_ball_zonotope` (2n generators) as a PZ.

    Why n = 2, 3 contain the ball.  Write the map as ``F(a)_i = a_i s_i(a)`` and the exact
    square/cube-to-ball map as ``F0(a)_i = a_i r_i(a)`` with ``r_i = sqrt(1 - t_i)``.  Every dropped
    term of the series of ``sqrt(1 - t)`` is negative for ``t`` in [0, 1], so ``s_i >= r_i >= 0``.
    On the boundary of the box ``|F0| = 1``, hence ``|F_l|^2 = sum_i a_i^2 s_{l,i}^2 >= 1`` for every
    ``F_l = (1 - l) F0 + l F``, ``l`` in [0, 1]: the straight-line homotopy never meets the open
    ball on the boundary.  ``F0`` maps the box homeomorphically onto the ball (degree 1 about every
    interior point), so ``F`` has degree 1 about every point of the open ball too, and a point
    with non-zero degree lies in the image; the image is closed, so it holds the closed ball.
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
    if n == 3:
        cols, exps = [], []
        for i in range(3):
            j, k = [x for x in range(3) if x != i]
            def mono(pw):
                e = [0, 0, 0]
                for var, pow_ in pw:
                    e[var] = pow_
                return tuple(e)
            t = {mono([(j, 2)]): 0.5, mono([(k, 2)]): 0.5, mono([(j, 2), (k, 2)]): -1.0 / 3.0}
            s = _sqrt_series(t, 3)
            poly = _poly_mul({mono([(i, 1)]): 1.0}, s)
            for e, cval in poly.items():
                if cval != 0.0:
                    g = np.zeros(3)
                    g[i] = cval
                    cols.append(g)
                    exps.append(e)
        return PolyZonotope(np.zeros(3), np.array(cols).T, None, np.array(exps, dtype=int).T, ids).compact()
    return PolyZonotope.from_zonotope(unit_ball_zonotope(n), ids)
