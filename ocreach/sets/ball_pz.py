"""Compact polynomial zonotopes of the unit ball: few factors, low degree.

Two facts make them (docs/stt.md, "Ball input"):

**Lemma 1 (containment).**  Let ``F: [-1, 1]^n -> R^n`` be continuous and odd, ``F(-a) = -F(a)``,
with ``|F(a)| >= 1`` on the boundary of the cube.  Then ``F([-1, 1]^n)`` contains the closed unit
ball.  Proof: for ``|y| < 1`` the straight-line homotopy ``F - s y`` (``s`` in [0, 1]) has no zero
on the boundary (``|F| >= 1 > |s y|``), so the Brouwer degree ``deg(F, cube, y) = deg(F, cube, 0)``,
which is the degree of the odd map ``F / |F|`` of the cube's boundary (a sphere) to the sphere,
odd by Borsuk's theorem; a non-zero degree puts ``y`` in the image, and the image is closed.
(This is the argument of :func:`ocreach.sets.unit_ball_pz` with the homotopy taken in the target;
it needs no componentwise comparison with an exact cube-to-ball map.)

**Lemma 2 (product).**  ``B^(p+q) = {(c x, s y) : (c, s) in B^2, x in B^p, y in B^q}``
(take ``c = |x'|, s = |y'|``), so if ``D ⊇ B^2``, ``X ⊇ B^p``, ``Y ⊇ B^q`` are polynomial
zonotopes with their own factors and radii ``R_D, R_X, R_Y``, the polynomial zonotope
``{(c x, s y)}`` (products of monomials in disjoint factors: exact) contains ``B^(p+q)`` and has radius at most
``R_D max(R_X, R_Y)`` (``|c x|^2 + |s y|^2 <= (c^2 + s^2) max(|x|^2, |y|^2)``); its support over the
unit sphere is in ``[1, R]``.

The leaves, each ``u_i = a_i p(a_j^2, ...)`` (odd, so Lemma 1 applies; coefficients fitted by
minimising the radius subject to ``|F| >= 1`` on the boundary, then ``c_0`` lifted by 5e-4 so the
inequality holds with a margin that a finite certificate can see):

* ``"d4"``: 2-D, ``u1 = a1 (c0 + c1 a2^2)``, ``u2 = a2 (c0 + c1 a1^2)``: 4 generators, degree 3;
* ``"d6"``: 2-D, ``p = c0 + c1 a^2 + c2 a^4``: 6 generators, degree 5;
* ``"b3"``: 3-D, ``u_i = a_i (c0 + c1 (a_j^2 + a_k^2) + c2 a_j^2 a_k^2)``: 12 generators, degree 5;
* ``"i"``: 1-D, the interval [-1, 1].

:data:`LEAF_RADIUS` holds radii proved in tests/test_ball_pz.py (``|F| >= 1`` on the boundary and
``max |F| <= R`` over the cube, by Bernstein bounds of ``|F|^2`` as a polynomial in the squared
factors with subdivision, i.e. a finite proof, not a sample; done in floating point and, for the
leaves, again in exact rational arithmetic, so it holds for the coefficients as stored).  :func:`compact_ball_pz` builds the n-D ball from the leaves
by Lemma 2 with the fewest generators whose radius bound is at most :data:`RADIUS_TARGET`.
The products' coefficients are float products of the leaves' (relative error ~1e-16); the leaves
used as the disk keep ``|F| >= 1.0004`` on the boundary (proved exactly in tests/test_ball_pz.py;
d6 touches ``c0 = 1.0005`` at ``a2 = 0``, d4 ~1.0006), so the exact product contains 1.0004 times
the ball (scale ``(c, s)`` in the proof of Lemma 2) and the rounding (~1e-15 per point) stays far
inside that margin.
"""
from __future__ import annotations

import functools
import itertools
from typing import Any

import numpy as np

from ocreach.errors import SetError
from ocreach.sets.polynomials import components_pz, poly_mul

#: the target: the input set's support within 3 % of the ball's
RADIUS_TARGET = 1.03
#: coefficients of the leaves (see the module docstring)
LEAF_COEF: dict[str, tuple[float, ...]] = {
    "d4": (1.0113990, -0.2960854),
    "d6": (1.0005000, -0.2425090, -0.0497418),
    "b3": (1.0156577, -0.2973328, 0.1656095),
}
#: proved upper bounds of ``max |u|`` over the factor box (tests/test_ball_pz.py)
LEAF_RADIUS: dict[str, float] = {"i": 1.0, "d4": 1.0117, "d6": 1.0017, "b3": 1.0161}
LEAF_DIM = {"i": 1, "d4": 2, "d6": 2, "b3": 3}


def _leaf(kind: str) -> list[dict]:
    """Component polynomials ``{exponent tuple: coefficient}`` of a leaf over its own factors."""
    n = LEAF_DIM[kind]
    if kind == "i":
        return [{(1,): 1.0}]
    c = LEAF_COEF[kind]
    comps = []
    for i in range(n):
        others = [j for j in range(n) if j != i]
        poly: dict = {}
        if kind.startswith("d"):
            for k, ck in enumerate(c):
                e = [0] * n
                e[i], e[others[0]] = 1, 2 * k
                poly[tuple(e)] = ck
        else:  # b3: c0 + c1 (x_j + x_k) + c2 x_j x_k
            terms = (((), c[0]), ((others[0],), c[1]), ((others[1],), c[1]), (tuple(others), c[2]))
            for sub, ck in terms:
                e = [0] * n
                e[i] = 1
                for j in sub:
                    e[j] = 2
                poly[tuple(e)] = ck
        comps.append(poly)
    return comps


def _shift(poly: dict, before: int, after: int) -> dict:
    return {(0,) * before + e + (0,) * after: v for e, v in poly.items()}


def _build(tree: Any) -> tuple[list[dict], int]:
    """Component polynomials and factor count of a plan tree: a leaf name or
    ``(disk, left, right)`` (Lemma 2)."""
    if isinstance(tree, str):
        return _leaf(tree), LEAF_DIM[tree]
    disk, left, right = tree
    D, md = _build(disk)
    X, mx = _build(left)
    Y, my = _build(right)
    m = md + mx + my
    c = _shift(D[0], 0, mx + my)
    s = _shift(D[1], 0, mx + my)
    comps = ([poly_mul(c, _shift(x, md, my)) for x in X]
             + [poly_mul(s, _shift(y, md + mx, 0)) for y in Y])
    return comps, m


def _count(tree: Any) -> int:
    comps, _ = _build(tree)
    return sum(len(p) for p in comps)


@functools.lru_cache(maxsize=64)
def compact_ball_plan(n: int, target: float = RADIUS_TARGET) -> tuple[Any, int, float]:
    """``(tree, generators, radius bound)`` of the compact n-D ball: among the leaves and the
    Lemma-2 products of smaller plans (all splits ``n = p + q``, both 2-D leaves as the disk), the
    one with the fewest generators whose radius bound is <= ``target`` (ties: smaller radius).

    n = 2: ``"d4"`` (4 generators, radius 1.0117); n = 3: ``("d4", "i", "d4")`` (10, 1.0235);
    n = 4: ``("d4", "d4", "d4")`` (16, 1.0235); n = 5..8: 32 / 48 / 72 / 96 generators; the
    count grows about like ``n^2.6`` (tests/test_ball_pz.py checks n <= 8).
    """
    n = int(n)
    if n < 1:
        raise SetError(f"compact_ball_plan: n must be >= 1; got {n}")
    if not 1.0 <= target:
        raise SetError(f"compact_ball_plan: target must be >= 1; got {target}")
    front = _front(n)
    ok = [f for f in front if f[2] <= target]
    if not ok:
        raise SetError(f"compact_ball_plan: no plan with radius <= {target} in n={n}; "
                       f"the tightest has {min(f[2] for f in front):.4f}")
    return min(ok, key=lambda f: (f[1], f[2]))


@functools.lru_cache(maxsize=64)
def _front(n: int) -> tuple[tuple[Any, int, float], ...]:
    """Pareto front (generators, radius) of plans for the n-D ball."""
    cand = [(k, _count(k), LEAF_RADIUS[k]) for k, d in LEAF_DIM.items() if d == n]
    for p in range(1, n // 2 + 1):
        for (tl, gl, rl), (tr, gr, rr) in itertools.product(_front(p), _front(n - p)):
            for disk in ("d4", "d6"):
                per = len(_leaf(disk)[0])
                cand.append(((disk, tl, tr), per * (gl + gr), LEAF_RADIUS[disk] * max(rl, rr)))
    cand.sort(key=lambda f: (f[1], f[2]))
    front, best = [], np.inf
    for f in cand:
        if f[2] < best - 1e-12:
            front.append(f)
            best = f[2]
    return tuple(front)


def compact_ball_pz(n: int, ids: Any = None, plan: Any = None):
    """Polynomial zonotope containing the unit ball ``{||u||_2 <= 1}`` in R^n with support over
    the unit sphere in ``[1, R]``, ``R <= 1.03``, and few generators (plan from
    :func:`compact_ball_plan`, or an explicit ``plan`` tree).  Containment: Lemma 1 for the
    leaves, Lemma 2 for the products (module docstring)."""
    n = int(n)
    if n < 1:
        raise SetError(f"compact_ball_pz: n must be >= 1; got {n}")
    tree = compact_ball_plan(n)[0] if plan is None else plan
    comps, m = _build(tree)
    if len(comps) != n:
        raise SetError(f"compact_ball_pz: plan {tree!r} is {len(comps)}-D, not n={n}")
    if ids is not None and np.atleast_1d(np.asarray(ids)).shape != (m,):
        raise SetError(f"compact_ball_pz: ids must hold one identifier per factor, {m} for n={n} "
                       f"(plan {tree!r}); got shape {np.atleast_1d(np.asarray(ids)).shape}")
    return components_pz(comps, ids)


def plan_radius(tree: Any) -> float:
    """Radius bound of a plan tree (Lemma 2 applied recursively to :data:`LEAF_RADIUS`)."""
    if isinstance(tree, str):
        return LEAF_RADIUS[tree]
    disk, left, right = tree
    return LEAF_RADIUS[disk] * max(plan_radius(left), plan_radius(right))
