"""Containment checks and containment constraints (cvxpy + Clarabel, CasADi).

* points in a zonotope, batched in ONE call: exact halfspace test when the facet count is small,
  otherwise cheap exact certificates (inside: a least-norm factor vector in the unit box; outside:
  a separating direction among a fixed direction set) and block-diagonal LPs (HiGHS dual simplex
  through scipy, 100 points per LP; a block ``min ||e_k||_1 s.t. G xi_k + e_k = x_k - c,
  |xi_k| <= 1`` per undecided point).  HiGHS is used here because on this bounded-variable
  structure it is ~4x faster than Clarabel's interior point method;
* zonotope in zonotope: Sadraddini & Tedrake (2019) sufficient LP, exact vertex enumeration for
  few generators;
* zonotope in halfspaces / interval (exact, Patel & Subbarao Eq. 1), point in ellipsoid;
* :func:`containment_constraints` (cvxpy) and :func:`casadi_containment` (CasADi, for MPC).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from math import comb
from typing import Any

import numpy as np
import scipy.sparse as sp

from ocreach.errors import SetError, SolverError
from ocreach.sets import dispatch
from ocreach.sets._base import SetBase, as_matrix, as_points, as_vector
from ocreach.sets.ellipsoid import Ellipsoid
from ocreach.sets.zonotope import Zonotope

#: Frank-Wolfe iterations of the certificates before the LP, and of the LP-free certificates
#: (:func:`certified_in_zonotope`, a first pass whose failures go to an LP anyway: the truth
#: check of the ARCH spacecraft flowpipe took 35 s of CPU with 2, 80 s with 30, 2026-12-03)
CERT_ITERS, FAST_CERT_ITERS = 30, 2
#: largest number of (n-1)-subsets of generators for which facets are enumerated
MAX_FACET_SUBSETS = 20_000
#: (n-1)-subsets of generators whose sine volume is at most this (but not 0) leave a zonotope
#: without a halfspace form (:func:`_facets`)
DEGENERATE_SINE = 1e-10
#: points per block-diagonal LP
LP_CHUNK = 100


# ------------------------------------------------------------------------------------------------
# halfspace representation
# ------------------------------------------------------------------------------------------------
def zonotope_halfspaces(Z, max_subsets: int = MAX_FACET_SUBSETS) -> tuple[np.ndarray, np.ndarray] | None:
    """Exact halfspace form ``H x <= b`` (unit normals) of a full-dimensional zonotope, or None if
    the generators do not span R^n, there are more than ``max_subsets`` (n-1)-subsets, or a
    subset is too close to degenerate for its facet normal to be computed (see
    :func:`_facets`).

    Each facet normal is the generalised cross product of n-1 generators (Althoff, Stursberg &
    Buss 2010); offset ``b = n.c + sum_i |n.g_i|``.
    """
    fc = _facets(Z, max_subsets)
    return None if fc is None else fc[:2]


def _facets(Z, max_subsets: int = MAX_FACET_SUBSETS
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(H, b, tilt)``: the halfspaces of :func:`zonotope_halfspaces` and, per row, a bound on
    the angle between the computed unit normal and the exact one.

    A facet's normal is computed from ``n - 1`` generators whose (scale-free) sine volume
    ``|cross| / prod |g_j|`` is ``s``; its components are determinants with a rounding error of
    about ``n eps prod |g_j|``, so the angle error is about ``n eps / s`` (``tilt``, with a factor
    16 of margin).  A subset whose computed cross product is exactly 0 is degenerate (exactly
    parallel generators, e.g. two box generators on one axis) and spans no facet.  A subset with
    ``0 < s <= DEGENERATE_SINE`` may span a facet whose normal cannot be computed; dropping it
    would leave the halfspaces of a larger polytope (possibly unbounded: a flat zonotope made
    full-dimensional by a tiny generator), so there is then no halfspace form (None)."""
    n, G = Z.dim, np.asarray(Z.G)
    G = G[:, np.any(G != 0, axis=0)]
    h = G.shape[1]
    if h < n or np.linalg.matrix_rank(G) < n:
        return None
    if n == 1:
        r = np.abs(G).sum()
        return (np.array([[1.0], [-1.0]]), np.array([Z.c[0] + r, -Z.c[0] + r]),
                np.zeros(2))
    if comb(h, n - 1) > max_subsets:
        return None
    idx = np.array(list(itertools.combinations(range(h), n - 1)), dtype=np.int64)
    M = G[:, idx].transpose(1, 0, 2)  # (K, n, n-1)
    normals = np.empty((idx.shape[0], n))
    for i in range(n):
        minor = np.delete(M, i, axis=1)
        normals[:, i] = (-1) ** i * (np.linalg.det(minor) if n > 2 else minor[:, 0, 0])
    nrm = np.linalg.norm(normals, axis=1)
    sine = nrm / np.prod(np.linalg.norm(G, axis=0)[idx], axis=1)
    if np.any((nrm > 0) & (sine <= DEGENERATE_SINE)):
        return None
    ok = nrm > 0
    N = normals[ok] / nrm[ok, None]
    tilt = 16.0 * n * np.finfo(float).eps / sine[ok] if n > 2 else np.zeros(N.shape[0])
    spread = np.abs(N @ G).sum(axis=1)
    nc = N @ Z.c
    return (np.vstack([N, -N]), np.concatenate([nc + spread, -nc + spread]),
            np.concatenate([tilt, tilt]))


def _facet_slack(Z, P: np.ndarray, H: np.ndarray, b: np.ndarray, tilt: np.ndarray) -> np.ndarray:
    """``max_i (H_i x - b_i + m_i(x))`` per point: <= 0 proves ``x`` in ``Z`` despite the rounding
    of the halfspaces.  ``m_i`` bounds what a normal tilted by ``tilt_i`` from the exact one, with
    its offset the support in the tilted direction, lets through beyond the exact facet
    (``tilt_i (sum |g|_2 + |x - c|_2)``: the support function is sublinear with Lipschitz constant
    ``sum |g|_2``), plus the rounding of the products (``(n + h + 2) eps`` of their magnitude,
    at most ``|x|_2 + |c|_2 + sum |g|_2`` for a unit normal)."""
    G = np.asarray(Z.G)
    size = float(np.linalg.norm(G, axis=0).sum())
    dist = np.linalg.norm(P - Z.c, axis=1)
    mag = np.linalg.norm(P, axis=1) + float(np.linalg.norm(Z.c)) + size
    k = (Z.dim + G.shape[1] + 2) * np.finfo(float).eps
    return (P @ H.T - b + tilt * (size + dist[:, None])).max(axis=1) + k * mag


# ------------------------------------------------------------------------------------------------
# points in zonotope
# ------------------------------------------------------------------------------------------------
def _lp_residual(Gr: np.ndarray, R: np.ndarray) -> np.ndarray:
    """For each column r_k of R: ``min ||e_k||_1 s.t. Gr xi_k + e_k = r_k, -1 <= xi_k <= 1``, all
    points in ONE block-diagonal LP (HiGHS dual simplex, bounded variables).  The point is in the
    zonotope iff the optimal residual is 0.  Returns the residuals (K,) of the solver's factor
    vectors (clipped to the box), recomputed from ``Gr`` and ``R``."""
    from scipy.optimize import linprog

    k_rows, h = Gr.shape
    K = R.shape[1]
    nv = h + 2 * k_rows
    blk = sp.csr_matrix(np.hstack([Gr, np.eye(k_rows), -np.eye(k_rows)]))
    A = sp.kron(sp.identity(K, format="csr"), blk, format="csc")
    cost = np.tile(np.concatenate([np.zeros(h), np.ones(2 * k_rows)]), K)
    lb = np.tile(np.concatenate([-np.ones(h), np.zeros(2 * k_rows)]), K)
    ub = np.tile(np.concatenate([np.ones(h), np.full(2 * k_rows, np.inf)]), K)
    # HiGHS's default feasibility tolerance (1e-7) lets the optimum's residual be wrong by more than
    # the callers' tolerances (points ~3x beyond the l1 tolerance were reported inside): 1e-10
    res = linprog(cost, A_eq=A, b_eq=R.T.ravel(), bounds=np.column_stack([lb, ub]), method="highs-ds",
                  options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10})
    if res.status != 0:
        raise SolverError(f"points_in_zonotope: HiGHS returned status {res.status} ({res.message}) for the batched LP")
    # the residual of the solver's factors, clipped to the box, recomputed here: an upper bound of
    # the distance that does not rely on the solver's own feasibility tolerance
    xi = np.clip(res.x.reshape(K, nv)[:, :h], -1.0, 1.0)
    err = np.abs(xi @ Gr.T - R.T).sum(axis=1)
    # a point on the boundary keeps a residual at the solver's feasibility tolerance (~1e-10 per
    # row), above the callers' tightest tolerances: one refinement step on the factors off their
    # bounds (least-norm correction of the residual, clipped, recomputed; still an upper bound)
    near = 1e-6 * (1.0 + np.abs(R).max(initial=0.0))
    for k in np.flatnonzero((err > 0) & (err <= near)):
        free = np.abs(xi[k]) < 1.0
        if not free.any():
            continue
        r = R[:, k] - Gr @ xi[k]
        x2 = xi[k].copy()
        x2[free] = np.clip(x2[free] + np.linalg.lstsq(Gr[:, free], r, rcond=None)[0], -1.0, 1.0)
        e2 = np.abs(Gr @ x2 - R[:, k]).sum()
        if e2 < err[k]:
            err[k] = e2
    return err


def _direction_set(n: int, G: np.ndarray, k: int = 256) -> np.ndarray:
    """Fixed direction set for outside certificates: axes, principal axes, quasi-random directions."""
    rng = np.random.default_rng(7)
    U = np.linalg.svd(G, full_matrices=False)[0] if G.shape[1] else np.eye(n)
    D = np.vstack([np.eye(n), U.T, rng.standard_normal((k, n))])
    D = D / np.linalg.norm(D, axis=1, keepdims=True)
    return np.vstack([D, -D])


def _certify(G: np.ndarray, R: np.ndarray, out: np.ndarray, undecided: np.ndarray, atol: float,
             iters: int = 30, outside: bool = True) -> None:
    """Exact certificates, vectorised over points, updating ``out``/``undecided`` in place.

    Inside: a factor vector xi with ``G xi = r`` and ``||xi||_inf <= 1`` (least-norm solution, and
    Frank-Wolfe iterates corrected by the least-norm solution of the residual).  Outside: a
    direction d with ``d.r > sum_i |d.g_i|`` (fixed directions, and the Frank-Wolfe directions
    ``d = r - x_k`` of min ||x - r|| over the zonotope; each is a separating-hyperplane proof).
    ``outside=False``: no fixed directions (a caller that needs the inside certificates only;
    the Frank-Wolfe directions still stop the iterations of the points they prove outside).
    """
    Gp = np.linalg.pinv(G)  # (h, n)
    idx = np.flatnonzero(undecided)
    Rs = R[idx]
    xi = Rs @ Gp.T
    ins = np.abs(xi).max(axis=1) <= 1.0
    if outside:
        D = _direction_set(G.shape[0], G)
        sup = np.abs(D @ G).sum(axis=1)
        outs = np.any(Rs @ D.T > sup + atol, axis=1) & ~ins
    else:
        outs = np.zeros(idx.size, dtype=bool)
    xi = np.clip(xi, -1.0, 1.0)
    X = xi @ G.T
    for _ in range(iters):
        act = ~(ins | outs)
        if not np.any(act):
            break
        a = np.flatnonzero(act)
        d = Rs[a] - X[a]
        s = np.sign(d @ G)
        V = s @ G.T
        outs[a] |= np.einsum("ij,ij->i", d, Rs[a]) > np.einsum("ij,ij->i", d, V) + atol
        step = V - X[a]
        gam = np.clip(np.einsum("ij,ij->i", d, step) / np.maximum(np.einsum("ij,ij->i", step, step), 1e-300), 0, 1)
        xi[a] += gam[:, None] * (s - xi[a])
        X[a] += gam[:, None] * step
        corr = xi[a] + (Rs[a] - X[a]) @ Gp.T
        ins[a] |= (np.abs(corr).max(axis=1) <= 1.0) & ~outs[a]
    out[idx[ins]] = True
    undecided[idx[ins | outs]] = False


def points_in_zonotope(Z, points: Any, tol: float = 1e-7, method: str = "auto",
                       certify: bool = True) -> np.ndarray | bool:
    """Exact membership of many points in a zonotope, in one call (bool array).

    ``method``: ``'auto'`` (halfspaces when there are at most ``MAX_FACET_SUBSETS`` facet subsets,
    else certificates + batched LP), ``'halfspace'``, ``'lp'`` (batched LP for every point).
    ``tol`` is an absolute distance tolerance (l1 distance to the set) relative to
    ``max(1, sum|G|, |c|)``: a point is reported inside iff it lies within that distance.  The
    halfspace test alone cannot give this meaning (near an acute vertex a point far outside violates
    every facet by little), so points that pass the facets only thanks to the tolerance, or pass
    them by less than the computed facets' rounding margin (:func:`_facet_slack`), are re-decided
    by the certificate/LP path.  ``certify=False`` skips the certificates before the
    LP (for points whose certificates already failed, :func:`certified_in_zonotope`).
    """
    n = Z.dim
    P, single = as_points("points", points, n)
    if method not in ("auto", "halfspace", "lp"):
        raise SetError(f"points_in_zonotope: method must be 'auto', 'halfspace' or 'lp'; got {method!r}")
    G = np.asarray(Z.G)
    G = G[:, np.any(G != 0, axis=0)]
    R = P - Z.c
    atol = tol * max(1.0, float(np.abs(G).sum()), float(np.abs(Z.c).max(initial=0.0)))
    if G.shape[1] == 0:
        out = np.all(np.abs(R) <= atol, axis=1)
        return bool(out[0]) if single else out
    hs = _facets(Z) if method in ("auto", "halfspace") else None
    if method == "halfspace" and hs is None:
        raise SetError(f"points_in_zonotope: method='halfspace' needs a full-dimensional zonotope with at most "
                       f"{MAX_FACET_SUBSETS} facet subsets; got n={n}, h={G.shape[1]} (rank "
                       f"{np.linalg.matrix_rank(G)}); use method='auto' or 'lp'")
    if hs is not None:
        H, b, tilt = hs
        viol = (P @ H.T - b).max(axis=1)  # > atol: outside by more than atol (l1 >= l2 distance)
        out = _facet_slack(Z, P, H, b, tilt) <= 0.0
        band = np.flatnonzero(~out & (viol <= atol))
        if band.size:
            out[band] = _points_in_range_lp(G, R[band], atol, certify=certify)
        return bool(out[0]) if single else out
    out = _points_in_range_lp(G, R, atol, certify=certify and method == "auto")
    return bool(out[0]) if single else out


def certified_in_zonotope(Z, points: Any, tol: float = 1e-7) -> np.ndarray:
    """The points proven inside ``Z`` without an LP (bool array; False means *not proven*, the
    point may still be inside): the facet test of :func:`points_in_zonotope` where ``Z`` has few
    facet subsets (points that do not pass every facet by its rounding margin are left unproven,
    :func:`_facet_slack`), else the inside
    certificates of its LP path (a factor vector in the unit box).  The cheap first pass of a
    membership test of many points against many sets, each point inside few of them; ``tol`` as
    in :func:`points_in_zonotope`."""
    P, _ = as_points("points", points, Z.dim)
    G = np.asarray(Z.G)
    G = G[:, np.any(G != 0, axis=0)]
    R = P - Z.c
    atol = tol * max(1.0, float(np.abs(G).sum()), float(np.abs(Z.c).max(initial=0.0)))
    if G.shape[1] == 0:
        return np.all(np.abs(R) <= atol, axis=1)
    hs = _facets(Z)
    if hs is not None:
        return _facet_slack(Z, P, *hs) <= 0.0
    return _points_in_range_lp(G, R, atol, certify=True, lp=False)


def _points_in_range_lp(G: np.ndarray, R: np.ndarray, atol: float, certify: bool,
                        lp: bool = True) -> np.ndarray:
    """Membership of the offsets ``R`` (N, n) in ``{G xi : |xi| <= 1}`` up to the l1 distance
    ``atol``: off-range points are outside; then (optionally) exact certificates; the rest by the
    batched LP of :func:`_lp_residual` (``lp=False``: left False, not proven inside)."""
    U, s, _ = np.linalg.svd(G, full_matrices=False)
    rank = int(np.sum(s > 1e-12 * s[0]))
    Ur = U[:, :rank]
    off = np.linalg.norm(R - (R @ Ur) @ Ur.T, axis=1) > atol
    out = np.zeros(R.shape[0], dtype=bool)
    undecided = ~off
    Gr = Ur.T @ G  # (rank, h)
    Rr = R @ Ur  # (N, rank)
    if certify:
        _certify(Gr, Rr, out, undecided, atol, iters=CERT_ITERS if lp else FAST_CERT_ITERS,
                 outside=lp)
    if not lp:
        return out
    idx = np.flatnonzero(undecided)
    for s0 in range(0, idx.size, LP_CHUNK):
        blk = idx[s0: s0 + LP_CHUNK]
        out[blk] = _lp_residual(Gr, Rr[blk].T) <= atol
    return out


# ------------------------------------------------------------------------------------------------
# set in set
# ------------------------------------------------------------------------------------------------
def zonotope_in_zonotope(Z1, Z2, method: str = "auto", tol: float = 1e-7) -> bool:
    """Is ``Z1`` a subset of ``Z2``?

    ``'lp'``: Sadraddini & Tedrake (2019) sufficient condition: exist Gamma, beta with
    ``G1 = G2 Gamma``, ``c2 - c1 = G2 beta``, ``||[Gamma, beta]||_inf <= 1`` (True is certain, False
    means "not certified").  ``'vertex'``: exact, all 2^h1 vertex candidates of Z1 in Z2.
    ``'auto'``: the LP, then vertex enumeration if the LP fails and h1 <= 14.
    """
    import cvxpy as cp

    if Z1.dim != Z2.dim:
        raise SetError(f"zonotope_in_zonotope: dimensions differ ({Z1.dim} vs {Z2.dim})")
    if method not in ("auto", "lp", "vertex"):
        raise SetError(f"zonotope_in_zonotope: method must be 'auto', 'lp' or 'vertex'; got {method!r}")
    if method == "vertex":
        return bool(np.all(points_in_zonotope(Z2, Z1.vertices(), tol=tol)))
    h1, h2 = Z1.n_generators, Z2.n_generators
    if h2 == 0:
        ok = h1 == 0 or not np.any(Z1.G)
        return bool(ok and np.allclose(Z1.c, Z2.c, atol=tol))
    Gam = cp.Variable((h2, max(h1, 1)))
    beta = cp.Variable(h2)
    cons = [Z2.G @ beta == Z2.c - Z1.c]
    if h1:
        cons += [Z2.G @ Gam == Z1.G, cp.sum(cp.abs(Gam), axis=1) + cp.abs(beta) <= 1 + tol]
    else:
        cons += [cp.abs(beta) <= 1 + tol]
    prob = cp.Problem(cp.Minimize(0), cons)
    prob.solve(solver=cp.CLARABEL)
    if prob.status in ("optimal", "optimal_inaccurate"):
        return True
    if prob.status not in ("infeasible", "infeasible_inaccurate"):
        raise SolverError(f"zonotope_in_zonotope: Clarabel returned status {prob.status}")
    if method == "auto" and h1 <= 14:
        return bool(np.all(points_in_zonotope(Z2, Z1.vertices(), tol=tol)))
    return False


def zonotope_in_halfspaces(Z, H: Any, b: Any, tol: float = 1e-9) -> bool:
    """Exact: ``Z`` lies in ``{x : H x <= b}`` iff ``H c + |H G| 1 <= b`` (Patel & Subbarao Eq. 1-2)."""
    H = as_matrix("halfspace normals H", np.atleast_2d(np.asarray(H, float)), cols=Z.dim)
    b = as_vector("halfspace offsets b", np.atleast_1d(np.asarray(b, float)), H.shape[0])
    return bool(np.all(H @ Z.c + np.abs(H @ Z.G).sum(axis=1) <= b + tol))


def zonotope_in_interval(Z, I, tol: float = 1e-9) -> bool:
    """Exact: is the zonotope inside the box ``I``?"""
    if I.dim != Z.dim:
        raise SetError(f"zonotope_in_interval: dimensions differ ({Z.dim} vs {I.dim})")
    E = np.eye(Z.dim)
    return zonotope_in_halfspaces(Z, np.vstack([E, -E]), np.concatenate([I.hi, -I.lo]), tol)


def points_in_ellipsoid(Ell, points: Any, tol: float = 1e-9) -> np.ndarray | bool:
    """Exact vectorised membership ``(x-q)^T Q^-1 (x-q) <= 1`` (pseudo-inverse on degenerate axes)."""
    P, single = as_points("points", points, Ell.dim)
    w, V = Ell.eig
    Y = (P - Ell.q) @ V
    pos = w > 1e-14 * max(1.0, float(w.max(initial=0.0)))
    val = (Y[:, pos] ** 2 / w[pos]).sum(axis=1)
    off = np.all(np.abs(Y[:, ~pos]) <= tol, axis=1)
    out = (val <= 1.0 + tol) & off
    return bool(out[0]) if single else out


# ------------------------------------------------------------------------------------------------
# constraints for optimisation
# ------------------------------------------------------------------------------------------------
def containment_constraints(S, x) -> tuple[list, Any]:
    """cvxpy constraints forcing the expression ``x`` (shape (n,)) into the set ``S``.

    Returns ``(constraints, latent)``; the latent variable is the factor vector ``xi`` of a
    zonotope (``x = c + G xi``, ``-1 <= xi <= 1``), ``u`` of an ellipsoid (``x = q + L u``,
    ``||u||_2 <= 1``) or None for an interval.  A polynomial zonotope is replaced by its zonotope
    enclosure (an over-approximation).
    """
    import cvxpy as cp

    from ocreach.sets.ellipsoid import Ellipsoid
    from ocreach.sets.interval import Interval
    from ocreach.sets.polyzonotope import PolyZonotope
    from ocreach.sets.zonotope import Zonotope

    if isinstance(S, PolyZonotope):
        S = S.to_zonotope()
    if isinstance(S, Interval):
        return [x >= S.lo, x <= S.hi], None
    if isinstance(S, Zonotope):
        if S.n_generators == 0:
            return [x == S.c], None
        xi = cp.Variable(S.n_generators, name="xi")
        return [x == S.c + S.G @ xi, xi >= -1, xi <= 1], xi
    if isinstance(S, Ellipsoid):
        u = cp.Variable(S.dim, name="u")
        return [x == S.q + S.L @ u, cp.norm(u, 2) <= 1], u
    raise SetError(f"containment_constraints: unsupported set type {type(S).__name__}")


@dataclass(frozen=True)
class CasadiContainment:
    """``lbg <= g(x, xi) <= ubg`` and ``lbxi <= xi <= ubxi`` describe ``x in S``; ``xi`` may be None."""

    g: Any
    lbg: np.ndarray
    ubg: np.ndarray
    xi: Any
    lbxi: np.ndarray
    ubxi: np.ndarray


def casadi_containment(S, x_sym) -> CasadiContainment:
    """CasADi containment for MPC: zonotope ``g = x - c - G xi = 0`` with ``-1 <= xi <= 1`` (new
    symbol ``xi`` of the same type as ``x_sym``); interval ``lo <= x <= hi``; ellipsoid
    ``(x-q)^T Q^-1 (x-q) <= 1``; a polynomial zonotope uses its zonotope enclosure."""
    import casadi as ca

    from ocreach.sets.ellipsoid import Ellipsoid
    from ocreach.sets.interval import Interval
    from ocreach.sets.polyzonotope import PolyZonotope
    from ocreach.sets.zonotope import Zonotope

    if not isinstance(x_sym, (ca.SX, ca.MX)) or x_sym.shape != (S.dim, 1):
        raise SetError(f"casadi_containment: x_sym must be a CasADi SX/MX column of size {S.dim}; "
                       f"got {type(x_sym).__name__} {getattr(x_sym, 'shape', None)}")
    empty = np.zeros(0)
    if isinstance(S, PolyZonotope):
        S = S.to_zonotope()
    if isinstance(S, Interval):
        return CasadiContainment(x_sym, S.lo.copy(), S.hi.copy(), None, empty, empty)
    if isinstance(S, Zonotope):
        h = S.n_generators
        xi = type(x_sym).sym("xi", h)
        g = x_sym - ca.DM(S.c) - (ca.mtimes(ca.DM(S.G), xi) if h else 0)
        return CasadiContainment(g, np.zeros(S.dim), np.zeros(S.dim), xi, -np.ones(h), np.ones(h))
    if isinstance(S, Ellipsoid):
        w, V = S.eig
        if np.any(w <= 0):
            raise SetError("casadi_containment: the ellipsoid shape matrix Q must be positive definite")
        Qinv = (V / w) @ V.T
        dx = x_sym - ca.DM(S.q)
        g = ca.mtimes([dx.T, ca.DM(Qinv), dx])
        return CasadiContainment(g, np.array([-np.inf]), np.array([1.0]), None, empty, empty)
    raise SetError(f"casadi_containment: unsupported set type {type(S).__name__}")


# ------------------------------------------------------------------------------------------------
# the set types' methods (ocreach.sets.dispatch)
# ------------------------------------------------------------------------------------------------
@dispatch.contains.register(Zonotope)
def _zonotope_contains(Z: Zonotope, points: Any, tol: float) -> np.ndarray | bool:
    return points_in_zonotope(Z, points, tol=tol)


@dispatch.contains.register(Ellipsoid)
def _ellipsoid_contains(E: Ellipsoid, points: Any, tol: float) -> np.ndarray | bool:
    return points_in_ellipsoid(E, points, tol)


dispatch.containment_constraints.register(SetBase, containment_constraints)
dispatch.casadi_containment.register(SetBase, casadi_containment)
