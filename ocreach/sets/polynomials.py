"""Polynomials in the factors as ``{exponent tuple: coefficient}`` and the polynomial zonotope
whose components they are (the unit-ball constructions of :mod:`ocreach.sets.convert` and
:mod:`ocreach.sets.ball_pz` are written in them)."""
from __future__ import annotations

import itertools
from typing import Any

import numpy as np

from ocreach.sets.polyzonotope import PolyZonotope


def poly_mul(p: dict, q: dict) -> dict:
    """Product of two polynomials."""
    out: dict = {}
    for (ea, ca), (eb, cb) in itertools.product(p.items(), q.items()):
        e = tuple(x + y for x, y in zip(ea, eb))
        out[e] = out.get(e, 0.0) + ca * cb
    return out


def poly_add(p: dict, q: dict, s: float = 1.0) -> dict:
    """``p + s q``."""
    out = dict(p)
    for e, c in q.items():
        out[e] = out.get(e, 0.0) + s * c
    return out


def components_pz(comps: list[dict], ids: Any = None) -> PolyZonotope:
    """The polynomial zonotope ``x_i = sum_e comps[i][e] a^e`` (centre 0): one generator along axis
    ``i`` per term ``{exponent tuple: coefficient}`` of component ``i``, in the dicts' order."""
    n = len(comps)
    cols, exps = [], []
    for i, poly in enumerate(comps):
        for e, v in poly.items():
            g = np.zeros(n)
            g[i] = v
            cols.append(g)
            exps.append(e)
    return PolyZonotope(np.zeros(n), np.array(cols).T, None, np.array(exps, dtype=np.int64).T, ids)
