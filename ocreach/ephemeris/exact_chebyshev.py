"""Exact (rational) Chebyshev-series arithmetic for rigorous bounds on polynomial differences.

A float is a rational number, so a Chebyshev series with float coefficients, composed with an
affine map whose constants are floats, has exact rational Chebyshev coefficients in the new
variable.  Python's integers and :class:`fractions.Fraction` compute them without rounding, so a
bound such as ``sup_{|s| <= 1} |sum_j e_j T_j(s)| <= sum_j |e_j|`` (``|T_j| <= 1`` on
``[-1, 1]``) is exact up to the one upward rounding of the final sum to a float
(:func:`float_up`).  Used by :meth:`ocreach.ephemeris.EphemerisFit.window_error_bound` (the
difference between a DE421 fit piece and its re-expansion on a window; docs/ephemeris.md).

Series are lists of :class:`~fractions.Fraction` (or ``int``) ``c`` meaning ``sum_j c[j] T_j(s)``.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from fractions import Fraction


def _x_times(c: Sequence) -> list:
    """``s * sum_j c_j T_j(s)`` as a series (``s T_0 = T_1``,
    ``s T_j = (T_(j+1) + T_(j-1)) / 2``)."""
    out = [Fraction(0)] * (len(c) + 1)
    for j, cj in enumerate(c):
        if j == 0:
            out[1] += cj
        else:
            out[j + 1] += Fraction(cj) / 2
            out[j - 1] += Fraction(cj) / 2
    return out


def affine_times(c: Sequence, alpha: Fraction, beta: Fraction) -> list:
    """``(alpha s + beta) * sum_j c_j T_j(s)`` as a series."""
    xc = _x_times(c)
    return [alpha * xc[j] + (beta * c[j] if j < len(c) else 0) for j in range(len(xc))]


def add(a: Sequence, b: Sequence, wb: Fraction | int = 1) -> list:
    """``a + wb * b`` as a series."""
    n = max(len(a), len(b))
    return [(a[j] if j < len(a) else 0) + (wb * b[j] if j < len(b) else 0) for j in range(n)]


def product(a: Sequence, b: Sequence) -> list:
    """``a * b`` as a series (``T_i T_j = (T_(i+j) + T_|i-j|) / 2``)."""
    out = [Fraction(0)] * (len(a) + len(b) - 1)
    for i, ai in enumerate(a):
        if ai == 0:
            continue
        for j, bj in enumerate(b):
            h = Fraction(ai) * bj / 2
            out[i + j] += h
            out[abs(i - j)] += h
    return out


def compose_affine(rows: Sequence[Sequence[float]], alpha: Fraction, beta: Fraction) -> list[list]:
    """Series in ``s`` of ``sum_k c_k T_k(alpha s + beta)`` for each row ``c`` (floats, read
    exactly): ``T_k(alpha s + beta)`` from the three-term recurrence in exact arithmetic (integer
    numerators ``W_k`` over the common denominator ``D^k``, ``alpha = a / D``, ``beta = b / D``)."""
    n = max(len(r) for r in rows)
    D = math.lcm(alpha.denominator, beta.denominator)
    a, b = int(alpha * D), int(beta * D)
    # V_k = W_k / D^k: W_(k+1) = a X(W_k) + 2 b W_k - D^2 W_(k-1), X(W) = 2 s W (integer)
    W = [[1], [b, a]]
    D2 = D * D
    for _ in range(2, n):
        w, wm = W[-1], W[-2]
        x = [0] * (len(w) + 1)
        for j, v in enumerate(w):
            if j == 0:
                x[1] += 2 * v
            else:
                x[j + 1] += v
                x[j - 1] += v
        W.append([a * x[j] + (2 * b * w[j] if j < len(w) else 0)
                  - (D2 * wm[j] if j < len(wm) else 0) for j in range(len(x))])
    out = []
    for row in rows:
        ratios = [float(ck).as_integer_ratio() for ck in row]
        den = max(d for _, d in ratios)  # powers of two: the largest is a common denominator
        acc = [0] * n
        for k, (num, d) in enumerate(ratios):
            if num == 0:
                continue
            scale = num * (den // d) * D ** (n - 1 - k)
            for j, v in enumerate(W[k]):
                acc[j] += scale * v
        total = den * D ** (n - 1)
        out.append([Fraction(v, total) for v in acc])
    return out


def derivative_at(n: int, x: Fraction, k: int) -> list:
    """``[T_j^(k)(x) for j in 0..n]`` exactly (``T_(j+1)^(k) = 2 x T_j^(k) + 2 k T_j^(k-1) -
    T_(j-1)^(k)``, the k-th derivative of the three-term recurrence).  For ``x >= 1`` this bounds
    ``|T_j^(k)|`` on ``[-x, x]``: all zeros of ``T_j`` and its derivatives lie in ``(-1, 1)``
    (Gauss-Lucas), so ``T_j^(k)`` grows on ``[1, oo)``, and on ``[-1, 1]`` its largest magnitude is at ``+-1``
    (V. Markov)."""
    x = Fraction(x)
    prev = [Fraction(1), x][: n + 1]
    while len(prev) < n + 1:
        prev.append(2 * x * prev[-1] - prev[-2])
    for order in range(1, k + 1):
        cur = [Fraction(0), Fraction(1 if order == 1 else 0)][: n + 1]
        while len(cur) < n + 1:
            j = len(cur) - 1
            cur.append(2 * x * cur[j] + 2 * order * prev[j] - cur[j - 1])
        prev = cur
    return prev


def sup_bound(c: Sequence, rho: Fraction = Fraction(1), k: int = 0) -> Fraction:
    """``sum_j |c_j| max_{|s| <= rho} |T_j^(k)(s)|`` (``rho >= 1``): an upper bound of the
    ``k``-th derivative of the series on ``[-rho, rho]``."""
    if rho < 1:
        rho = Fraction(1)
    m = derivative_at(len(c) - 1, Fraction(rho), k) if len(c) else []
    return sum((abs(Fraction(cj)) * mj for cj, mj in zip(c, m, strict=True)), Fraction(0))


def float_up(x: Fraction) -> float:
    """The smallest float ``>= x``."""
    f = float(x)
    return f if Fraction(f) >= x else math.nextafter(f, math.inf)


__all__ = ["add", "affine_times", "compose_affine", "derivative_at", "float_up", "product",
           "sup_bound"]
