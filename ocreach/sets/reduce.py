"""Order reduction of zonotopes and polynomial zonotopes.

* ``girard``: Girard (HSCC 2005): keep the largest generators (metric ||g||_1 - ||g||_inf) and
  replace the rest by their interval hull (a box, n generators).
* ``pca``: Kopetzki, Schuermann & Althoff (2017), PCA method: the generators to be removed are
  boxed in the frame of the principal axes of ``[G, -G]`` (left singular vectors of G).
* Polynomial zonotopes (Kochdumper & Althoff 2021; Foss et al. Sec. 2.4 "Reduce(PZ, h_des)"):
  the smallest dependent and independent generators are enclosed by a zonotope, which is reduced
  to a box (``girard``) or PCA box (``pca``) and appended as independent generators.
  Opt-in ``group`` (not in the papers): removed generators that are parallel are
  enclosed together by the range of their scalar polynomial (:func:`enclose_removed`), which
  keeps cancellations that the monomial-wise enclosure loses; measured in
  docs/validation/stt-tightness.md, "Grouped reduction of parallel monomials" (no gain that
  justifies a default).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ocreach.errors import SetError
from ocreach.sets import dispatch
from ocreach.sets._base import SetBase
from ocreach.sets.polyzonotope import PolyZonotope, enclose_monomials, monomial_values
from ocreach.sets.pz_exact import support_bounds
from ocreach.sets.rounding import U as U_ROUND
from ocreach.sets.rounding import rounding_radius, up
from ocreach.sets.zonotope import Zonotope

_METHODS = ("girard", "pca")
#: ``group`` values of :func:`reduce_pz` (None: every removed monomial enclosed on its own;
#: ``"parallel"``: removed parallel monomials enclosed together; ``"parallel-drop"``: also a
#: group split by the kept/removed ranking is removed whole).
GROUPS = (None, "parallel", "parallel-drop")
#: removed generators whose unit directions agree to this (after sign normalisation, on a grid of
#: this spacing) form one group; the residual off the group's direction is boxed on its own.
PARALLEL_RTOL = 1e-6
#: at most this many groups per reduction get the range enclosure (the widest ones).
MAX_GROUPS = 24


def check_group(group: str | None, name: str = "group") -> str | None:
    """``group`` if it is one of :data:`GROUPS`, else a :class:`SetError` naming ``name``."""
    if group not in GROUPS:
        raise SetError(f"reduce: {name} must be one of {GROUPS}; got {group!r}")
    return group


def _check_method(method: str) -> str:
    if method not in _METHODS:
        raise SetError(f"reduce: method must be one of {_METHODS}; got {method!r}")
    return method


def box_generators(G: np.ndarray, method: str, extra: Any = None,
                   abs_G: np.ndarray | None = None) -> np.ndarray:
    """Generators (n, <=n) of a parallelotope enclosing ``{G xi : ||xi||_inf <= 1}``, rigorously
    against floating point (:mod:`ocreach.sets.rounding`).

    ``girard``: the box ``sum_j |g_j|``, rounded up.  ``pca``: ``B = fl(U diag(r))`` with ``U`` the
    computed left singular vectors; as ``U`` is orthogonal only up to rounding and ``B`` is
    rounded, ``r`` bounds ``|U~^{-1} x|`` for the exact ``U~ = B diag(r)^{-1}``: with
    ``D = |fl(U U^T) - I| + gamma_n |U||U^T| + u |U||U^T|`` (``>= |U~ U^T - I|``),
    ``|U~^{-1} x| <= |U^T x| + ||U^T||_inf / (1 - ||D||_inf) ||D |x|||_inf``.

    ``extra``: more generators ``X`` that are not stored but known through ``extra.gram``
    (``X X^T``), ``extra.absum`` (row sums of ``|X|``) and ``extra.proj_abs(U)``
    (``sum_x |U^T x|``, once the frame is known); the box is then the one of ``[G, X]`` (the
    order-3 products the fused STT step prunes, :mod:`ocreach.reach.stt_products`).  The
    rounding of those sums themselves is not bounded: the STT sets they serve are not
    guaranteed enclosures (Foss et al.), unlike the zonotopes of ``taylor``/``sdc``.

    ``abs_G``: ``|G|`` if the caller has it (the same values; saves recomputing it).
    """
    n, h = G.shape
    if h == 0 and extra is None:
        return np.zeros((n, 0))
    absG = (np.abs(G) if abs_G is None else abs_G).sum(axis=1)
    absX = absG if extra is None else absG + extra.absum
    k = h if extra is None else h + 1  # roundings along the sums
    if method == "girard":
        B = np.diag(up(absX, k))
    else:
        gram = G @ G.T if extra is None else G @ G.T + extra.gram
        U, _, _ = np.linalg.svd(gram)
        Ut = U.T
        aU, aUt = np.abs(U), np.abs(Ut)
        proj = np.abs(Ut @ G).sum(axis=1)
        if extra is not None:
            proj = proj + extra.proj_abs(U)
        r = up(proj, k) + rounding_radius(aUt @ up(absX, k), n)
        UUt = aU @ aUt
        D = up(np.abs(U @ Ut - np.eye(n)), 1) + rounding_radius(UUt, n) + up(U_ROUND * UUt, 1)
        d_inf = float(up(D.sum(axis=1), n).max())
        if d_inf >= 0.5:  # not orthogonal at all (cannot happen for an SVD): the sound box instead
            return box_generators(G, "girard", extra)
        ut_inf = float(up(aUt.sum(axis=1), n).max())
        s = float(up(ut_inf / (1.0 - d_inf) * float(up(D @ up(absX, k), n).max()), 4))
        r = up(r + s, 2)
        B = U * r[None, :]
    return B[:, np.any(B != 0, axis=0)]


def _girard_metric(absG: np.ndarray) -> np.ndarray:
    """Girard's metric ``||g||_1 - ||g||_inf`` of every generator, from ``|G|``."""
    return absG.sum(axis=0) - absG.max(axis=0, initial=0.0)


def reduce_zonotope(Z: Zonotope, order: float = 1.0, method: str = "girard") -> Zonotope:
    """Reduce a zonotope to at most ``floor(order * n)`` generators (order >= 1), sound outer approximation."""
    _check_method(method)
    n, h = Z.dim, Z.n_generators
    if not np.isfinite(order) or order < 1:
        raise SetError(f"reduce: order must be >= 1; got {order!r}")
    h_max = int(np.floor(order * n))
    if h <= h_max:
        return Z
    n_keep = h_max - n
    absG = np.abs(Z.G)
    metric = _girard_metric(absG) if method == "girard" else np.linalg.norm(Z.G, axis=0)
    order_idx = np.argsort(-metric, kind="stable")
    keep, drop = order_idx[:n_keep], order_idx[n_keep:]
    absD = absG[:, drop]
    # the girard box reads only |G|: no copy of the dropped generators themselves
    B = box_generators(absD if method == "girard" else Z.G[:, drop], method, abs_G=absD)
    if not np.isfinite(B).all():
        raise SetError("reduce: the box of the removed generators overflowed (generators near the "
                       "largest float)")
    return Zonotope.trusted(Z.c, np.concatenate([Z.G[:, keep], B], axis=1))  # Z valid, B finite


def parallel_groups(G: np.ndarray, rtol: float = PARALLEL_RTOL, limit: int | None = None) -> list[np.ndarray]:
    """Column indices of ``G`` (n, m) in groups of at least two (nearly) parallel columns.

    Each nonzero column is scaled to a unit vector whose largest-magnitude entry is positive and
    rounded to a grid of spacing ``rtol``; equal grid points form a group (parallel columns of
    either sign meet; columns near a grid boundary may miss their group, which costs tightness
    only: a column outside every group is enclosed on its own).  ``limit``: only the ``limit``
    groups of largest ``sum |G_i|`` (all if None)."""
    nrm = np.linalg.norm(G, axis=0)
    idx = np.flatnonzero(nrm > 0)
    if idx.size < 2:
        return []
    U = G[:, idx] / nrm[idx]
    sgn = np.sign(U[np.argmax(np.abs(U), axis=0), np.arange(idx.size)])
    key = np.round(U * sgn / rtol).astype(np.int64)
    _, inv, cnt = np.unique(key.T, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    multi = np.flatnonzero(cnt > 1)
    if limit is not None and multi.size > limit:      # the widest groups (sum of the norms)
        width = np.bincount(inv, weights=nrm[idx], minlength=cnt.size)[multi]
        multi = multi[np.argsort(-width, kind="stable")[:limit]]
    sel = np.flatnonzero(np.isin(inv, multi))
    sel = sel[np.argsort(inv[sel], kind="stable")]
    bounds = np.flatnonzero(np.diff(inv[sel])) + 1
    return [idx[g] for g in np.split(sel, bounds)] if sel.size else []


def scalar_range(alpha: np.ndarray, E: np.ndarray, tol: float = 0.02, max_boxes: int = 256,
                 max_iter: int = 12) -> tuple[float, float]:
    """Bounds ``lo <= sum_j alpha_j prod_k a_k^E[k, j] <= hi`` over ``a in [-1, 1]^p``.

    The upper bounds of the branch and bound of :func:`ocreach.sets.pz_exact.support_bounds` on the
    1-D polynomial zonotope ``<0, alpha, [], E>`` in the directions +1 and -1, intersected with
    the monomial-wise interval sum (odd monomials ``[-|alpha|, |alpha|]``, all-even ones between 0
    and ``alpha``), so the range is never wider than the separate enclosures it replaces.  When
    points of ``{-1, 0, 1}^p`` (all for p <= 5, else 243 fixed random ones) attain the interval
    sum within ``tol`` of its width, the interval sum is returned at once (it is then the range
    up to ``tol``; most groups of generic sets are such).
    """
    E = np.asarray(E, dtype=np.int64)
    used = np.any(E > 0, axis=1)
    E = E[used]
    const = ~np.any(E, axis=0)
    even = ~np.any(E & 1, axis=0) & ~const
    odd = ~(even | const)
    c0 = float(alpha[const].sum())
    hi_n = c0 + float(np.maximum(alpha[even], 0).sum() + np.abs(alpha[odd]).sum())
    lo_n = c0 + float(np.minimum(alpha[even], 0).sum() - np.abs(alpha[odd]).sum())
    keep = ~const
    if not keep.any():
        return c0, c0
    # the interval sum is attained (within tol) at points of {-1, 0, 1}^p: no branch and bound
    p = E.shape[0]
    pts = np.array(np.meshgrid(*[[-1.0, 0.0, 1.0]] * p)).reshape(p, -1).T if p <= 5 else \
        np.random.default_rng(0).integers(-1, 2, (243, p)).astype(float)
    vals = c0 + monomial_values(pts, E[:, keep]) @ alpha[keep]
    slack = tol * (hi_n - lo_n)
    if vals.max() >= hi_n - slack and vals.min() <= lo_n + slack:
        return lo_n, hi_n
    P = PolyZonotope._own(np.array([c0]), alpha[None, keep].astype(float), np.zeros((1, 0)),
                          E[:, keep], np.arange(E.shape[0], dtype=np.int64))
    sb = support_bounds(P, np.array([[1.0], [-1.0]]), tol=tol, max_boxes=max_boxes, max_iter=max_iter)
    hi, lo = float(sb.upper[0]), -float(sb.upper[1])
    return max(lo, lo_n), min(hi, hi_n)


def enclose_removed(G: np.ndarray, E: np.ndarray, group: str | None = None,
                    rtol: float = PARALLEL_RTOL, max_groups: int = MAX_GROUPS) -> tuple[np.ndarray, np.ndarray]:
    """Zonotope enclosure (centre shift (n,), generators (n, k)) of the removed dependent part
    ``sum_i a^E_i G_i`` over ``a in [-1, 1]^p``.

    ``group=None``: every monomial on its own (:func:`enclose_monomials`).  ``"parallel"``: the
    columns are first collected in groups of (nearly) parallel generators
    (:func:`parallel_groups`); in a group with direction ``d`` (unit, of its largest member) each
    ``G_i = alpha_i d + r_i``; the residuals ``r_i`` (below ``rtol |G_i|``) are enclosed monomial
    by monomial, and the scalar polynomial ``sum_i alpha_i a^E_i`` by its range ``[lo, hi]``
    (:func:`scalar_range`), giving the centre shift ``d (lo + hi) / 2`` and the generator
    ``d (hi - lo) / 2``.  The sum of the enclosures contains the removed part (each term of
    ``sum_i a^E_i (alpha_i d + r_i)`` is in its own enclosure for every ``a``); the rounding of
    ``alpha_i d + r_i`` is covered by one more box generator per dimension.
    Only the ``max_groups`` groups of largest ``sum_i |G_i|`` are grouped (the range costs
    ~1-100 ms a group); the others are enclosed monomial by monomial as with ``group=None``.
    """
    if group is None:
        return enclose_monomials(G, E)
    check_group(group)                                      # every other value groups
    groups = parallel_groups(G, rtol, max_groups)  # the range costs up to ~0.1 s a group
    if not groups:
        return enclose_monomials(G, E)
    n = G.shape[0]
    in_group = np.zeros(G.shape[1], dtype=bool)
    shift = np.zeros(n)
    gens, resid = [], []
    err = np.zeros(n)
    for g in groups:
        in_group[g] = True
        Gg = G[:, g]
        d = Gg[:, np.argmax(np.linalg.norm(Gg, axis=0))]
        d = d / np.linalg.norm(d)
        alpha = d @ Gg
        R = Gg - d[:, None] * alpha[None, :]
        lo, hi = scalar_range(alpha, E[:, g])
        shift += d * (0.5 * (lo + hi))
        gens.append(d * (0.5 * (hi - lo)))
        resid.append(R)
        # |G - (d alpha + R)| from the rounding of d alpha and of G - d alpha
        err += 4 * U_ROUND * (np.abs(Gg).sum(axis=1) + np.abs(d) * np.abs(alpha).sum())
    rs, rg = enclose_monomials(np.hstack([G[:, ~in_group]] + resid),
                               np.hstack([E[:, ~in_group]] + [E[:, g] for g in groups]))
    return shift + rs, np.hstack([rg, np.column_stack(gens), np.diag(up(err, 2))])


def regroup_drop(G: np.ndarray, dep: np.ndarray, keep: np.ndarray, group: str | None,
                 rtol: float = PARALLEL_RTOL) -> np.ndarray:
    """The kept/removed split ``keep`` (m,) of the candidate generators ``G`` (n, m) (``dep``:
    dependent ones) with ``group="parallel-drop"``: a group of parallel dependent generators
    that the ranking splits is removed whole (then enclosed by its range,
    :func:`enclose_removed`; fewer generators remain).  Other ``group`` values: ``keep``.
    (Keeping such groups whole instead, displacing the smallest other kept generators, was
    measured far looser on nrho-flyby and is not offered: docs/validation/stt-tightness.md.)"""
    if group != "parallel-drop" or keep.all() or not keep.any():
        return keep
    idx = np.flatnonzero(dep)
    mixed = [idx[g] for g in parallel_groups(G[:, idx], rtol) if 0 < keep[idx[g]].sum() < g.size]
    if not mixed:
        return keep
    keep = keep.copy()
    keep[np.concatenate(mixed)] = False
    return keep


def reduce_pz(pz: PolyZonotope, h_max: int, method: str = "pca", group: str | None = None) -> PolyZonotope:
    """Reduce a polynomial zonotope to at most ``h_max`` generators in total (dependent + independent).

    The ``h_max - n`` largest generators (2-norm) are kept; every other dependent generator is
    replaced by its zonotope enclosure (all-even monomials: centre shift + half generator) and,
    with the remaining independent generators, boxed into <= n new independent generators.
    ``group="parallel"``: the removed dependent generators that are (nearly) parallel are
    enclosed together by the range of their scalar polynomial (:func:`enclose_removed`), which
    keeps the cancellations between their monomials; None (default): each on its own.
    ``"parallel-drop"``: as ``"parallel"``, and a group that the ranking splits is removed
    whole (:func:`regroup_drop`).
    """
    _check_method(method)
    check_group(group)
    n = pz.dim
    h_max = int(h_max)
    if h_max < n:
        raise SetError(f"reduce: h_max must be >= the dimension n={n}; got {h_max}")
    h, q = pz.n_dependent, pz.n_independent
    if h + q <= h_max:
        return pz
    norms = np.concatenate([np.linalg.norm(pz.G, axis=0), np.linalg.norm(pz.GI, axis=0)])
    n_keep = h_max - n
    if n_keep > 0:
        keep_idx = np.argpartition(-norms, n_keep - 1)[:n_keep]
    else:
        keep_idx = np.zeros(0, dtype=np.int64)
    keep = np.zeros(h + q, dtype=bool)
    keep[keep_idx] = True
    keep = regroup_drop(np.hstack([pz.G, pz.GI]), np.arange(h + q) < h, keep, group)
    kd, ki = keep[:h], keep[h:]
    # enclose the removed dependent part
    shift, Gz = enclose_removed(pz.G[:, ~kd], pz.E[:, ~kd], group)
    c = pz.c + shift
    Grem = np.hstack([Gz, pz.GI[:, ~ki]])
    GI = np.hstack([pz.GI[:, ki], box_generators(Grem, method)])
    E = pz.E[:, kd]
    used = np.any(E > 0, axis=1) if E.shape[1] else np.zeros(E.shape[0], dtype=bool)
    return PolyZonotope._own(c, pz.G[:, kd], GI, E if used.all() else E[used], pz.id[used])


def reduce(S: SetBase, size: float, method: str | None = None) -> SetBase:
    """Dispatch: ``reduce(pz, h_max, method='pca')`` or ``reduce(z, order, method='girard')``."""
    if isinstance(S, PolyZonotope):
        return reduce_pz(S, size, method or "pca")
    if isinstance(S, Zonotope):
        return reduce_zonotope(S, size, method or "girard")
    if hasattr(S, "reduce"):
        return S.reduce()
    raise SetError(f"reduce: unsupported set type {type(S).__name__}")


@dispatch.reduce.register(Zonotope)
def _reduce_zonotope(Z: Zonotope, order: float = 1.0, method: str = "girard") -> Zonotope:
    return reduce_zonotope(Z, order, method)


@dispatch.reduce.register(PolyZonotope)
def _reduce_pz(pz: PolyZonotope, h_max: int, method: str = "pca") -> PolyZonotope:
    return reduce_pz(pz, h_max, method)
