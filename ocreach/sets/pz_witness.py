"""Membership of sampled points in zonotopes and sparse polynomial zonotopes, decided three ways
by verified witnesses and certificates.

A set ``S`` enlarged by the box of radius ``eps`` contains ``x`` iff some factors in the box map
within ``eps`` of ``x`` in every coordinate.  :func:`classify` (polynomial zonotopes) and
:func:`classify_zonotope` (zonotopes, intervals, unions) decide each point:

* **inside**: a *witness*, factors in the box whose image lies within ``eps`` of ``x`` in every
  coordinate, the floating-point rounding of that image bounded rigorously
  (:func:`ocreach.sets.rounding.rounding_radius`) and counted against ``eps``;
* **outside**: a *certificate*, a direction ``d`` with ``d^T x`` above an upper bound of the
  set's support in ``d`` by more than ``eps |d|_1`` plus the rounding of that comparison -- the
  support of a zonotope exactly, of a polynomial zonotope its zonotope enclosure's or the
  branch-and-bound bound of :func:`ocreach.sets.pz_exact.support_bounds` raised by the rigorous
  bound of its own rounding (:func:`ocreach.sets.pz_exact.upper_rounding`);
* **undecided**: neither (reported, never counted as inside).

The searches only propose candidates; a verdict is the verification above.  Witnesses of a
polynomial zonotope come from :func:`witness_search` (Levenberg-Marquardt with the factor box
held exactly: every step the batched minimum-norm solve of :func:`ocreach.sets.box_lsq.box_min_norm`,
from a caller's warm start -- e.g. the same trajectory's witness at the previous grid time,
matched by factor identifier -- the centre and random starts), then, for the few points left near
the set's boundary, SciPy's bounded least squares one point at a time (:func:`witness_lsq`).  A
zonotope's witnesses and certificates come from the same minimum-norm solve on its generators (the
multipliers grow along a separating direction when the point is outside), and an LP (HiGHS) for
the points it leaves, whose primal and dual solutions are verified the same way.

Used to check guaranteed sets against sampled trajectories (``examples/poly_validation.py``,
``benchmarks/bench_coordinates.py``, ``tests/test_poly.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.errors import SetError
from ocreach.sets.box_lsq import box_min_norm
from ocreach.sets.interval import Interval
from ocreach.sets.polyzonotope import PolyZonotope
from ocreach.sets.pz_union import PZUnion
from ocreach.sets.rounding import rounding_radius
from ocreach.sets.union import ZonotopeUnion
from ocreach.sets.zonotope import Zonotope

#: points per block of the witness search and per block-diagonal LP
CHUNK = 2000
LP_CHUNK = 100


@dataclass(frozen=True)
class Classified:
    """Masks per point: ``outside`` (certified), ``inside`` (witnessed), ``undecided``; for a
    polynomial zonotope the witnesses' dependent factor values ``witness`` (N, len(ids), 0 where
    none was found) in the order of the factor identifiers ``ids`` (for warm starts at the next
    grid time, :func:`classify`'s ``start``)."""

    outside: np.ndarray
    inside: np.ndarray
    undecided: np.ndarray
    witness: np.ndarray | None = None
    ids: np.ndarray | None = None


# ------------------------------------------------------------------------------------------------
# zonotopes
# ------------------------------------------------------------------------------------------------
def _zonotope_parts(S) -> list[Zonotope]:
    if isinstance(S, ZonotopeUnion):
        return list(S.parts)
    if isinstance(S, Interval):
        return [S.to_zonotope()]
    if isinstance(S, Zonotope):
        return [S]
    raise TypeError(f"classify_zonotope: expected a Zonotope, Interval or ZonotopeUnion; got {type(S).__name__}")


def _checked(P, n: int, eps) -> tuple[np.ndarray, float]:
    """The points ``P`` as (N, n), finite, and the tolerance ``eps``, finite and >= 0 (a negative
    one would shrink the set and certify points of it outside)."""
    from ocreach.sets._base import as_points

    e = float(eps) if np.ndim(eps) == 0 else float("nan")
    if not (np.isfinite(e) and e >= 0.0):
        raise SetError(f"classify: eps must be a finite number >= 0; got {eps!r}")
    return as_points("P", P, n)[0], e


def verified_inside(c: np.ndarray, G: np.ndarray, xi: np.ndarray, X: np.ndarray, eps: float,
                    pad: float | np.ndarray = 0.0) -> np.ndarray:
    """Rows of ``xi`` (N, h) in ``[-1, 1]^h`` with ``|c + G xi - x|`` at most ``eps - pad`` in
    every coordinate, the rounding of the residual included (``pad``: a rounding radius of
    ``c`` itself, per coordinate)."""
    R = c + xi @ G.T - X
    bound = rounding_radius(np.abs(c) + np.abs(xi) @ np.abs(G).T + np.abs(X), G.shape[1] + 2)
    return np.all(np.abs(xi) <= 1.0, axis=1) & np.all(np.abs(R) + bound + pad <= eps, axis=1)


def verified_outside(c: np.ndarray, G: np.ndarray, D: np.ndarray, X: np.ndarray, eps: float,
                     pad: float | np.ndarray = 0.0) -> np.ndarray:
    """Rows ``d`` of ``D`` (N, n) with ``d^T x > d^T c + sum_j |d^T g_j| + (eps + pad) |d|_1`` by
    more than the rounding of the comparison: ``x`` is outside ``(c, G)`` enlarged by the box of
    radius ``eps`` (and by ``pad``, a rounding radius of ``c``)."""
    dG = D @ G
    val = (D * (X - c)).sum(axis=1) - np.abs(dG).sum(axis=1) - (np.abs(D) * (eps + pad)).sum(axis=1)
    absval = (np.abs(D) * (np.abs(X) + np.abs(c) + eps + pad)).sum(axis=1) + np.abs(D) @ np.abs(G).sum(axis=1)
    ok = np.isfinite(val) & np.all(np.isfinite(D), axis=1)
    return ok & (val > rounding_radius(absval, 2 * (D.shape[1] + G.shape[1]) + 4))


def _zonotope_verdicts(Z: Zonotope, X: np.ndarray, eps: float, pad: float | np.ndarray = 0.0,
                       lp: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``(inside, outside)`` verified for the points ``X`` against ``Z`` enlarged by ``eps``."""
    c, G = np.asarray(Z.c), np.asarray(Z.G)
    G = G[:, np.any(G != 0, axis=0)]
    N, n = X.shape
    inside, outside = np.zeros(N, bool), np.zeros(N, bool)
    if G.shape[1] == 0:
        inside[:] = verified_inside(c, np.zeros((n, 0)), np.zeros((N, 0)), X, eps, pad)
        D = np.zeros((N, n))
        j = np.argmax(np.abs(X - c), axis=1)
        D[np.arange(N), j] = np.sign((X - c)[np.arange(N), j])
        outside[:] = ~inside & verified_outside(c, G, D, X, eps, pad)
        return inside, outside
    # the box of the zonotope first: a point beyond it in one coordinate is outside
    j = np.argmax(np.abs(X - c) - np.abs(G).sum(axis=1), axis=1)
    Dbox = np.zeros((N, n))
    Dbox[np.arange(N), j] = np.sign((X - c)[np.arange(N), j])
    outside[:] = verified_outside(c, G, Dbox, X, eps, pad)
    # rows scaled to unit l1 norm (the solve's conditioning; the verdicts use the original rows),
    # the eps box appended as generators so that points in the band around the set are interior
    row = np.abs(G).sum(axis=1)
    live = row > 0
    Gs = np.hstack([G[live], eps * np.eye(n)[live]]) / row[live, None]
    Rs = (X - c)[:, live] / row[live]
    h = G.shape[1]

    def separated(todo, xi, nu):         # outside: the multipliers' direction, the residual's
        out = np.zeros(todo.size, bool)
        for D in (nu, Rs[todo] - xi @ Gs.T):
            Dfull = np.zeros((todo.size, n))
            Dfull[:, live] = D / row[live]
            out |= verified_outside(c, G, Dfull, X[todo], eps, pad)
        if not live.all():               # rows the generators do not move
            out |= verified_outside(c, G, np.sign(X[todo] - c) * ~live, X[todo], eps, pad)
        return out

    todo = np.flatnonzero(~outside)
    sol = box_min_norm(Gs, Rs[todo], -1.0, 1.0, iters=50, tol=0.25 * eps / row.max())
    inside[todo] = verified_inside(c, G, sol.dz[:, :h], X[todo], eps, pad)
    keep = ~inside[todo]
    todo, xi, nu = todo[keep], sol.dz[keep], sol.nu[keep]
    outside[todo] = separated(todo, xi, nu)
    keep = ~outside[todo]
    todo, xi, nu = todo[keep], xi[keep], nu[keep]
    if todo.size:                        # not decided at the loose stop: on towards F = 0
        more = box_min_norm(Gs, Rs[todo], -1.0, 1.0, nu=nu, iters=50, tol=0.0)
        ins = verified_inside(c, G, more.dz[:, :h], X[todo], eps, pad)
        inside[todo] = ins
        outside[todo[~ins]] = separated(todo[~ins], more.dz[~ins], more.nu[~ins])
    todo = np.flatnonzero(~inside & ~outside)
    if lp:
        for s0 in range(0, todo.size, LP_CHUNK):
            blk = todo[s0: s0 + LP_CHUNK]
            xi, D = _distance_lp(G, X[blk] - c)
            inside[blk] = verified_inside(c, G, xi, X[blk], eps, pad)
            for i in np.flatnonzero(~inside[blk]):   # polish: least-norm correction on the free factors
                free = np.abs(xi[i]) < 1.0
                corr = np.linalg.lstsq(G[:, free], X[blk[i]] - c - G @ xi[i], rcond=None)[0]
                cand = xi[i].copy()
                cand[free] += corr
                inside[blk[i]] = verified_inside(c, G, cand[None], X[blk[i]][None], eps, pad)[0]
            for sign in (1.0, -1.0):
                outside[blk] |= ~inside[blk] & verified_outside(c, G, sign * D, X[blk], eps, pad)
    return inside, outside


def _distance_lp(G: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``min t_k s.t. |G xi_k - r_k|_inf <= t_k, |xi_k|_inf <= 1`` for all rows ``r_k`` of ``R`` in
    ONE block-diagonal LP (HiGHS, tight tolerances): the primal factors ``xi`` (K, h), clipped to the
    box, and the multipliers of the distance rows as directions (K, n), to be verified."""
    import scipy.sparse as sp
    from scipy.optimize import linprog

    n, h = G.shape
    K = R.shape[0]
    nv = h + 1
    ub = sp.csr_matrix(np.vstack([np.hstack([G, -np.ones((n, 1))]), np.hstack([-G, -np.ones((n, 1))])]))
    I = sp.identity(K, format="csr")
    cost = np.tile(np.r_[np.zeros(h), 1.0], K)
    b = np.hstack([R, -R]).ravel()
    bounds = ([(-1.0, 1.0)] * h + [(0.0, None)]) * K
    res = linprog(cost, A_ub=sp.kron(I, ub, format="csc"), b_ub=b, bounds=bounds, method="highs",
                  options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10})
    if res.status != 0 or res.x is None:
        return np.zeros((K, h)), np.zeros((K, n))
    xi = np.clip(res.x.reshape(K, nv)[:, :h], -1.0, 1.0)
    y = np.asarray(res.ineqlin.marginals).reshape(K, 2, n)
    return xi, y[:, 1] - y[:, 0]


def classify_zonotope(S, P: np.ndarray, eps: float, lp: bool = True) -> Classified:
    """Classify the points ``P`` (N, n) against a zonotope, interval or union of zonotopes ``S``
    enlarged by the box of radius ``eps`` (module docstring): inside when some part has a
    witness, outside when every part has a certificate.  With ``lp=False`` the points the
    minimum-norm solve leaves stay undecided."""
    parts = _zonotope_parts(S)
    P, eps = _checked(P, parts[0].dim, eps)
    return _classify_parts(parts, P, eps, lp)


def _classify_parts(parts: list[Zonotope], P: np.ndarray, eps: float, lp: bool,
                    pads: list | None = None) -> Classified:
    """Inside some part / outside every part: the batched solve on every part first, the LP
    only for the points still open and only against the parts that have not excluded them."""
    N = P.shape[0]
    pads = [0.0] * len(parts) if pads is None else pads
    inside = np.zeros(N, bool)
    excluded = np.zeros((len(parts), N), bool)
    for j, Z in enumerate(parts):
        idx = np.flatnonzero(~inside)
        if idx.size == 0:
            break
        ins, outs = _zonotope_verdicts(Z, P[idx], eps, pads[j], lp=False)
        inside[idx[ins]] = True
        excluded[j, idx[outs]] = True
    if lp:
        for j, Z in enumerate(parts):
            idx = np.flatnonzero(~inside & ~excluded.all(axis=0) & ~excluded[j])
            if idx.size == 0:
                continue
            ins, outs = _zonotope_verdicts(Z, P[idx], eps, pads[j], lp=True)
            inside[idx[ins]] = True
            excluded[j, idx[outs]] = True
    outside = excluded.all(axis=0) & ~inside
    return Classified(outside, inside, ~inside & ~outside)


# ------------------------------------------------------------------------------------------------
# polynomial zonotopes
# ------------------------------------------------------------------------------------------------
def factor_slots(E: np.ndarray) -> np.ndarray:
    """``(h, d)`` factor indices of every monomial with repetition (-1: none) from ``E`` (p, h)."""
    deg = E.sum(axis=0)
    d = int(deg.max(initial=1))
    out = np.full((E.shape[1], d), -1, dtype=np.int64)
    for j in range(E.shape[1]):
        idx = np.repeat(np.arange(E.shape[0]), E[:, j])
        out[j, : idx.size] = idx
    return out


class _Residual:
    """``c + G m(a) + GI b - x`` of a polynomial zonotope, its Jacobian in ``(a, b)`` and its
    verification: the monomials as products of their factors one slot at a time (``d`` roundings
    for degree ``d``), so the rounding of the residual is bounded by ``gamma_(d + h + q + 2)``."""

    def __init__(self, S: PolyZonotope):
        from scipy import sparse

        self.p, self.q, self.h, self.n = S.n_factors, S.n_independent, S.n_dependent, S.dim
        self.sl = factor_slots(np.asarray(S.E))
        self.d = self.sl.shape[1]
        sl = self.sl
        self.onehot = [sparse.csr_matrix((np.ones(int((sl[:, s] >= 0).sum())),
                                          (np.flatnonzero(sl[:, s] >= 0), sl[sl[:, s] >= 0, s])),
                                         shape=(self.h, self.p)).T.tocsr() for s in range(self.d)]
        self.c, self.G, self.GI = np.asarray(S.c), np.asarray(S.G), np.asarray(S.GI)
        self.absG = np.abs(self.G)
        self.absGI = np.abs(self.GI)

    def monomials(self, A: np.ndarray, grad: bool):
        if self.p == 0:             # no dependent factors: every monomial is the constant 1
            A = np.ones((A.shape[0], 1))
        V = np.where(self.sl[None] >= 0, A[:, np.maximum(self.sl, 0)], 1.0)       # (N, h, d)
        M = V.prod(axis=2)
        if not grad:
            return M, None
        D = np.empty((A.shape[0], self.h, self.d))
        for s in range(self.d):
            D[:, :, s] = np.where(self.sl[None, :, s] >= 0, np.delete(V, s, axis=2).prod(axis=2), 0.0)
        return M, D

    def value(self, Z: np.ndarray, X: np.ndarray, grad: bool = False):
        A, B = Z[:, : self.p], Z[:, self.p:]
        M, D = self.monomials(A, grad)
        R = self.c + M @ self.G.T + B @ self.GI.T - X
        if not grad:
            return R, None
        N = Z.shape[0]
        J = np.zeros((N, self.n, self.p + self.q))
        for s in range(self.d if self.h else 0):
            GD = (D[:, :, s][:, None, :] * self.G[None]).reshape(-1, self.h)     # (N n, h)
            J[:, :, : self.p] += (self.onehot[s] @ GD.T).T.reshape(N, self.n, self.p)
        J[:, :, self.p:] = self.GI
        return R, J

    def verified(self, Z: np.ndarray, X: np.ndarray, eps: float) -> np.ndarray:
        """Rows of ``Z`` in the box whose image is within ``eps`` of ``x`` in every coordinate, the
        rounding of the residual included."""
        A, B = Z[:, : self.p], Z[:, self.p:]
        M, _ = self.monomials(A, False)
        R = self.c + M @ self.G.T + B @ self.GI.T - X
        absval = np.abs(self.c) + np.abs(M) @ self.absG.T + np.abs(B) @ self.absGI.T + np.abs(X)
        bound = rounding_radius(absval, self.d + self.h + self.q + 2)
        return np.all(np.abs(Z) <= 1.0, axis=1) & np.all(np.abs(R) + bound <= eps, axis=1)


def witness_search(S: PolyZonotope, P: np.ndarray, eps: float, iters: int = 40, starts: int = 5,
                   seed: int = 0, start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(found, best)``: the points of ``P`` (N, n) with a verified witness, and the best factors
    per point (N, p + q).  Levenberg-Marquardt on ``|c + G m(a) + GI b - x|``: each step the
    minimum-norm solve of the linearisation with the factor box held exactly
    (:func:`ocreach.sets.box_lsq.box_min_norm`, damping ``mu``), accepted when it lowers the
    residual; from ``start`` (N, p + q) when given and from its factors near the faces put on
    them, the centre, then random factors."""
    fn = _Residual(S)
    m = fn.p + fn.q
    N = P.shape[0]
    rng = np.random.default_rng(seed)
    found = np.zeros(N, bool)
    best_r = np.full(N, np.inf)
    best = np.zeros((N, m))
    if m == 0:
        found[:] = fn.verified(best, P, eps)
        return found, best
    plan = ([] if start is None else ["warm", "snap"]) + ["centre"] + ["random"] * max(0, starts - 1)
    for s0 in range(0, N, CHUNK):
        chunk = np.arange(s0, min(N, s0 + CHUNK))
        for kind in plan:
            idx = chunk[~found[chunk]]
            if idx.size == 0:
                break
            X = P[idx]
            if kind == "warm":
                Z = np.clip(start[idx], -1.0, 1.0)
            elif kind == "snap":    # the start's factors near the faces put on them (corner witnesses)
                Z = np.clip(start[idx], -1.0, 1.0)
                Z = np.where(np.abs(Z) > 0.5, np.sign(Z), Z)
            elif kind == "centre":
                Z = np.zeros((idx.size, m))
            else:
                Z = rng.uniform(-1, 1, (idx.size, m))
            R, J = fn.value(Z, X, grad=True)
            r = np.linalg.norm(R, axis=1)
            lam = np.full(idx.size, 1e-3)
            live = ~fn.verified(Z, X, eps)
            for _ in range(iters):
                a = np.flatnonzero(live)
                if a.size == 0:
                    break
                Ja = J[a]
                size = np.einsum("Nik,Nik->N", Ja, Ja) / fn.n + 1e-300
                sol = box_min_norm(Ja, -R[a], -1.0 - Z[a], 1.0 - Z[a], mu=lam[a] * size, iters=8)
                Zc = np.clip(Z[a] + sol.dz, -1.0, 1.0)
                Rc, Jc = fn.value(Zc, X[a], grad=True)
                rc = np.linalg.norm(Rc, axis=1)
                up = rc < r[a]
                u = a[up]
                Z[u], R[u], J[u], r[u] = Zc[up], Rc[up], Jc[up], rc[up]
                lam[a] = np.clip(np.where(up, lam[a] * 0.2, lam[a] * 10.0), 1e-14, 1e8)
                live[u] = ~fn.verified(Z[u], X[u], eps)
                live[a[~up]] &= lam[a[~up]] < 1e8                  # no progress at the largest damping
            ok = ~live & fn.verified(Z, X, eps)
            found[idx[ok]] = True
            # a verified witness is the point's best, even where an earlier start came closer in
            # the 2-norm without being within eps in every coordinate
            imp = ok | (r < best_r[idx])
            best_r[idx[imp]] = r[imp]
            best[idx[imp]] = Z[imp]
    return found, best


def witness_lsq(S: PolyZonotope, P: np.ndarray, eps: float, guess: np.ndarray,
                starts: int = 3, max_nfev: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """``(found, witness)``: the points of ``P`` for which SciPy's bounded least squares (``trf``,
    from ``guess`` and random starts, analytic Jacobian, at most ``max_nfev`` evaluations per
    start) finds a verified witness, and those witnesses (N, p + q; ``guess`` where none was
    found): one point at a time, the last resort for points close to the set's boundary."""
    from scipy.optimize import least_squares

    fn = _Residual(S)
    m = fn.p + fn.q
    rng = np.random.default_rng(1)
    found = np.zeros(P.shape[0], bool)
    witness = np.array(guess, dtype=float, copy=True)

    class _Witnessed(Exception):
        """Raised by the residual as soon as a factor vector is a verified witness."""

    for i, x in enumerate(P):
        X = x[None]

        def fun(z, X=X):
            Z = np.clip(z[None], -1.0, 1.0)
            R, _ = fn.value(Z, X)
            if fn.verified(Z, X, eps)[0]:
                raise _Witnessed(Z[0])
            return R[0]

        def jac(z, X=X):
            return fn.value(np.clip(z[None], -1.0, 1.0), X, grad=True)[1][0]

        for s in range(starts):
            z0 = np.clip(guess[i], -1, 1) if s == 0 else rng.uniform(-1, 1, m)
            try:
                least_squares(fun, z0, jac=jac, bounds=(-1.0, 1.0), xtol=1e-15, ftol=1e-15,
                              gtol=1e-15, max_nfev=max_nfev)
            except _Witnessed as w:
                found[i] = True
                witness[i] = w.args[0]
                break
    return found, witness


def carry_witnesses(prev: Classified | None, S: PolyZonotope) -> np.ndarray | None:
    """Warm starts (N, p + q) for ``S`` from the witnesses of ``prev`` (the same points at an
    earlier time): a factor of ``S`` takes its value in ``prev`` where the identifiers match, the
    others start at 0.  None when ``prev`` holds no witnesses."""
    if prev is None or prev.witness is None or prev.ids is None:
        return None
    out = np.zeros((prev.witness.shape[0], S.n_factors + S.n_independent))
    if prev.ids.size == 0:
        return out
    ids = np.asarray(S.id)
    pos = np.clip(np.searchsorted(prev.ids, ids), 0, prev.ids.size - 1)
    hit = np.flatnonzero(prev.ids[pos] == ids)
    out[:, hit] = prev.witness[:, pos[hit]]
    return out


def classify(S: PolyZonotope | PZUnion, P: np.ndarray, eps: float, start: Classified | None = None,
             lsq: bool = True) -> Classified:
    """Classify the points ``P`` (N, n) against ``S`` enlarged by the box of radius ``eps``
    (module docstring).  Witnesses first (warm-started from ``start``, the verdicts of the same
    points at an earlier time, when given); for the rest the zonotope enclosure (a certificate
    against it is an exclusion), the support-bound certificates, a longer search and with ``lsq``
    SciPy's bounded least squares for the points still left."""
    from ocreach.sets.pz_exact import membership, upper_rounding

    parts = list(S.parts) if isinstance(S, PZUnion) else [S]
    P, eps = _checked(P, parts[0].dim, eps)
    N = P.shape[0]
    ids = np.unique(np.concatenate([np.asarray(p.id) for p in parts]))
    W = np.zeros((N, ids.size))
    inside = np.zeros(N, bool)
    guesses = []
    for part in parts:
        idx = np.flatnonzero(~inside)
        if idx.size == 0:
            guesses.append((idx, None))
            continue
        warm = carry_witnesses(start, part)
        ok, best = witness_search(part, P[idx], eps, start=None if warm is None else warm[idx])
        inside[idx[ok]] = True
        W[np.ix_(idx[ok], np.searchsorted(ids, part.id))] = best[ok][:, : part.n_factors]
        guesses.append((idx, best))
    rest = np.flatnonzero(~inside)
    outside = np.zeros(N, bool)
    if rest.size:
        zs, pads = [], []
        for part in parts:          # the enclosure's centre c + shift is rounded: pad it
            zs.append(part.to_zonotope())
            pads.append(rounding_radius(np.abs(part.c) + np.abs(part.G).sum(axis=1), part.n_dependent + 1))
        enc = _classify_parts(zs, P[rest], eps, lp=True, pads=pads)
        outside[rest[enc.outside]] = True
        rest = rest[~enc.outside]
    if rest.size:                   # certificates from the support bounds, beyond the tolerance
        excluded = np.ones(rest.size, bool)
        for part in parts:
            mem = membership(part, P[rest], tol=eps, witness_iters=5)
            # d^T x > bound + eps |d|_1 + the bound's own rounding (its support may exceed it by
            # that), with the rounding of this comparison
            D = np.where(mem.outside[:, None], mem.direction, 0.0)
            bound = np.where(mem.outside, mem.bound, 0.0)
            slack = upper_rounding(part, D)
            eps_d = eps * np.abs(D).sum(axis=1)
            val = np.einsum("ij,ij->i", P[rest], D) - bound - eps_d - slack
            absval = np.abs(P[rest] * D).sum(axis=1) + np.abs(bound) + eps_d + slack
            excluded &= mem.outside & (val > rounding_radius(absval, part.dim + 4))
        outside[rest[excluded]] = True
        rest = rest[~excluded]
    if rest.size:                   # the few left: a longer search, then SciPy one at a time
        for part, (idx, best) in zip(parts, guesses):
            todo = rest[~inside[rest]]
            if todo.size == 0 or best is None:
                continue
            guess = best[np.searchsorted(idx, todo)]
            ok, more = witness_search(part, P[todo], eps, iters=100, starts=8, seed=1, start=guess)
            inside[todo[ok]] = True
            W[np.ix_(todo[ok], np.searchsorted(ids, part.id))] = more[ok][:, : part.n_factors]
            if lsq and not ok.all():
                left = todo[~ok]
                got, wit = witness_lsq(part, P[left], eps, more[~ok])
                inside[left[got]] = True
                W[np.ix_(left[got], np.searchsorted(ids, part.id))] = wit[got][:, : part.n_factors]
    return Classified(outside, inside, ~outside & ~inside, W, ids)
