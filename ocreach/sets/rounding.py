"""Rigorous bounds of the floating-point rounding of set arithmetic (zonotope maps, sums, boxes).

Every IEEE 754 operation ``fl(a op b) = (a op b)(1 + delta)``, ``|delta| <= u = 2^-53`` (no
underflow).  An expression made of sums and products whose longest chain of roundings has ``k``
operations (a dot product of length ``n`` has ``k = n``) therefore satisfies (Higham, *Accuracy
and Stability of Numerical Algorithms*, 2nd ed., Lemma 3.1 and Sec. 3.1, any summation order,
FMA or not)

    |fl(e) - e| <= gamma_k |e|_abs,    gamma_k = k u / (1 - k u),

where ``|e|_abs`` is the same expression evaluated on the absolute values of its inputs with
every subtraction made an addition.  A zonotope ``(c, G)`` computed with such errors contains
the exact one if its box ``gamma_k (|c|_abs + sum_j |g_j|_abs)`` is added.

The callers compute ``|e|_abs`` themselves in floating point (all terms non-negative), which
rounds it down by at most a factor ``1 - gamma_k``; :func:`rounding_radius` uses ``gamma_{2k+2}``
(``>= gamma_k / ((1 - gamma_k)(1 - u))``) and rounds the product up, so the returned radius is a
rigorous bound.  Underflow adds at most ``2^-1075`` per product; :data:`TINY` absorbs it for up
to ``2^75`` products.
"""
from __future__ import annotations

import numpy as np

#: unit round-off of IEEE double precision
U = 2.0**-53
#: absolute term covering underflow of the products
TINY = 2.0**-1000


def gamma(k: int) -> float:
    """``gamma_k = k u / (1 - k u)`` (Higham Lemma 3.1); ``k u < 1/2`` is required."""
    k = int(k)
    if k < 0 or k * U >= 0.5:
        raise ValueError(f"gamma: k must be in 0 .. 2^52; got {k}")
    return k * U / (1.0 - k * U)


def rounding_radius(abs_value: np.ndarray, k: int) -> np.ndarray:
    """Rigorous bound of the rounding error of an expression with at most ``k`` roundings along
    any chain, given ``abs_value`` = the expression evaluated on absolute values (computed in
    floating point; module docstring)."""
    r = gamma(2 * int(k) + 2) * np.asarray(abs_value, dtype=float)
    return np.nextafter(r, np.inf) + TINY


def up(x: np.ndarray, k: int = 1) -> np.ndarray:
    """A non-negative quantity computed with ``<= k`` roundings of non-negative terms, rounded up:
    ``fl(x) >= x_exact (1 - gamma_k)``, so ``fl(x) (1 + gamma_{2k+2})`` rounded up bounds
    ``x_exact``."""
    x = np.asarray(x, dtype=float)
    return np.nextafter(x * (1.0 + gamma(2 * int(k) + 2)), np.inf)


def two_sum_error(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(s, e)`` with ``s = fl(a + b)`` and ``a + b = s + e`` exactly (Knuth's TwoSum, round to
    nearest, no overflow)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    s = a + b
    bb = s - a
    e = (a - (s - bb)) + (b - bb)
    return s, e
