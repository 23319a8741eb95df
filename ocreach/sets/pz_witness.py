"""Membership of points in a sparse polynomial zonotope, decided by witnesses and certificates.

Exact membership ``x in PZ`` asks for factors ``a in [-1, 1]^p``, ``b in [-1, 1]^q`` with
``c + G m(a) + GI b = x``: a non-convex problem.  :func:`classify` decides a point three ways:

* **outside**: outside the zonotope enclosure (gauge LP), or a certificate -- a direction ``d``
  with ``d^T x`` above the rigorous upper support bound of
  :func:`ocreach.sets.pz_exact.support_bounds` -- by more than the tolerance;
* **inside**: a witness, factors in the box whose image lies within the tolerance of ``x``
  (:func:`witness_search`, vectorised projected Levenberg-Marquardt, then SciPy's bounded least
  squares for the points near the boundary, :func:`witness_lsq`);
* **undecided**: neither (reported, never counted as inside).

Used to check guaranteed polynomial-zonotope sets against sampled trajectories
(``examples/poly_validation.py``, ``tests/test_poly.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.sets.polyzonotope import PolyZonotope
from ocreach.sets.pz_union import PZUnion
from ocreach.sets.union import ZonotopeUnion, union_gauge
from ocreach.sets.zonotope import Zonotope


@dataclass(frozen=True)
class Classified:
    """Masks per point: ``outside`` (proved), ``inside`` (witnessed), ``undecided``; and the
    largest gauge of the points in the zonotope enclosure (<= 1 inside it)."""

    outside: np.ndarray
    inside: np.ndarray
    undecided: np.ndarray
    max_gauge: float


def _enlarged(Z: Zonotope, eps: float) -> Zonotope:
    return Zonotope(Z.c, np.hstack([Z.G, eps * np.eye(Z.dim)]))


def classify(S: PolyZonotope | PZUnion, P: np.ndarray, eps: float) -> Classified:
    """Classify the points ``P`` (N, n) against ``S`` enlarged by the box of radius ``eps``
    (module docstring)."""
    from ocreach.sets.pz_exact import membership

    P = np.atleast_2d(np.asarray(P, dtype=float))
    N = P.shape[0]
    parts = list(S.parts) if isinstance(S, PZUnion) else [S]
    gz = np.atleast_1d(union_gauge(ZonotopeUnion([_enlarged(p.to_zonotope(), eps) for p in parts]), P))
    outside = gz > 1 + 1e-9
    todo = np.flatnonzero(~outside)
    inside = np.zeros(N, bool)
    excluded = np.ones(N, bool)          # excluded from every part so far
    for part in parts:
        idx = todo[~inside[todo]]
        if idx.size == 0:
            break
        ok, guess = witness_search(part, P[idx], eps)
        inside[idx[ok]] = True
        guess, idx = guess[~ok], idx[~ok]
        if idx.size:
            inside[idx[witness_lsq(part, P[idx], eps, guess)]] = True
            idx = idx[~inside[idx]]
        if idx.size:   # no witness: the exclusion certificate, beyond the tolerance
            mem = membership(part, P[idx], tol=eps, witness_iters=5)
            inside[idx[mem.inside]] = True
            excess = np.einsum("ij,ij->i", P[idx], mem.direction) - mem.bound
            excluded[idx[~(mem.outside & (excess > eps))]] = False
    cert = np.zeros(N, bool)
    cert[todo] = excluded[todo] & ~inside[todo]
    return Classified(outside | cert, inside, ~outside & ~cert & ~inside,
                      float(gz.max(initial=0.0)))


def factor_slots(E: np.ndarray) -> np.ndarray:
    """``(h, d)`` factor indices of every monomial with repetition (-1: none) from ``E`` (p, h)."""
    deg = E.sum(axis=0)
    d = int(deg.max(initial=1))
    out = np.full((E.shape[1], d), -1, dtype=np.int64)
    for j in range(E.shape[1]):
        idx = np.repeat(np.arange(E.shape[0]), E[:, j])
        out[j, : idx.size] = idx
    return out


def witness_search(S: PolyZonotope, P: np.ndarray, eps: float, iters: int = 80, starts: int = 6,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(found, best)``: the points of ``P`` (N, n) for which factors ``(a, b)`` in the box were
    found whose image lies within ``eps`` (a witness that the point is in ``S``), and the best
    factors per point.  Projected Levenberg-Marquardt with minimum-norm steps (factors that a step
    would push off the box are held), vectorised over the points, from the centre and random
    starts."""
    from scipy import sparse

    p, q, h, n = S.n_factors, S.n_independent, S.n_dependent, S.dim
    N = P.shape[0]
    sl = factor_slots(np.asarray(S.E))
    d = sl.shape[1]
    onehot = [sparse.csr_matrix((np.ones(int((sl[:, s] >= 0).sum())),
                                 (np.flatnonzero(sl[:, s] >= 0), sl[sl[:, s] >= 0, s])), shape=(h, p))
              for s in range(d)]
    G, GI = np.asarray(S.G), np.asarray(S.GI)
    rng = np.random.default_rng(seed)
    found = np.zeros(N, bool)
    best_r = np.full(N, np.inf)
    best = np.zeros((N, p + q))

    def values(A):                     # monomials (N, h) and their slot derivatives (N, h, d)
        V = np.where(sl[None] >= 0, A[:, np.maximum(sl, 0)], 1.0)
        M = V.prod(axis=2)
        D = np.empty((A.shape[0], h, d))
        for s in range(d):
            D[:, :, s] = np.where(sl[None, :, s] >= 0, np.delete(V, s, axis=2).prod(axis=2), 0.0)
        return M, D

    def residual(A, B, X):
        M, D = values(A)
        return S.c + M @ G.T + B @ GI.T - X, D

    for st in range(starts):
        idx = np.flatnonzero(~found)
        if idx.size == 0:
            break
        X = P[idx]
        A = np.zeros((idx.size, p)) if st == 0 else rng.uniform(-1, 1, (idx.size, p))
        B = np.zeros((idx.size, q)) if st == 0 else rng.uniform(-1, 1, (idx.size, q))
        lam = np.full(idx.size, 1e-3)
        R, D = residual(A, B, X)
        r = np.linalg.norm(R, axis=1)
        for _ in range(iters):
            # J (N, n, p + q): sum over slots of (G * D_s) scattered onto the slot's factor
            J = np.zeros((idx.size, n, p + q))
            for s in range(d if h else 0):
                GD = (D[:, :, s][:, None, :] * G[None]).reshape(-1, h)
                J[:, :, :p] += (onehot[s].T @ GD.T).T.reshape(idx.size, n, p)
            J[:, :, p:] = GI
            Z = np.hstack([A, B])
            for _pass in range(2):   # again without the factors the step would push off the box
                JJ = np.einsum("Nik,Njk->Nij", J, J)
                scale = np.trace(JJ, axis1=1, axis2=2) / n + 1e-300
                JJ = JJ + (lam * scale)[:, None, None] * np.eye(n)
                y = np.linalg.solve(JJ, R[..., None])[..., 0]
                stp = np.einsum("Nik,Ni->Nk", J, y)
                blocked = ((Z >= 1) & (stp < 0)) | ((Z <= -1) & (stp > 0))
                if not blocked.any():
                    break
                J = np.where(blocked[:, None, :], 0.0, J)
            A2 = np.clip(A - stp[:, :p], -1, 1)
            B2 = np.clip(B - stp[:, p:], -1, 1)
            R2, D2 = residual(A2, B2, X)
            r2 = np.linalg.norm(R2, axis=1)
            better = r2 < r
            A = np.where(better[:, None], A2, A)
            B = np.where(better[:, None], B2, B)
            R = np.where(better[:, None], R2, R)
            D = np.where(better[:, None, None], D2, D)
            r = np.where(better, r2, r)
            lam = np.clip(np.where(better, lam * 0.3, lam * 10.0), 1e-12, 1e12)
            if np.all(r <= eps):
                break
        found[idx[r <= eps]] = True
        imp = r < best_r[idx]
        best_r[idx[imp]] = r[imp]
        best[idx[imp]] = np.hstack([A, B])[imp]
    return found, best


def witness_lsq(S: PolyZonotope, P: np.ndarray, eps: float, guess: np.ndarray,
                starts: int = 3, max_nfev: int = 200) -> np.ndarray:
    """Points of ``P`` for which SciPy's bounded least squares (``trf``, from ``guess`` and
    random starts, analytic Jacobian, at most ``max_nfev`` evaluations per start) finds factors
    whose image lies within ``eps``: slower than
    :func:`witness_search`, one point at a time, but sure-footed when the witness lies close to
    the factor box's faces (points near the set's boundary)."""
    from scipy.optimize import least_squares

    p, q = S.n_factors, S.n_independent
    E, G, GI = np.asarray(S.E), np.asarray(S.G), np.asarray(S.GI)
    rng = np.random.default_rng(1)
    found = np.zeros(P.shape[0], bool)

    def jac(z, x=None):
        """``[G dm/da, GI]``: ``dm_j/da_k = E_kj a_k^(E_kj - 1) prod_(l != k) a_l^E_lj``."""
        a = z[:p]
        Apow = a[:, None] ** E                                    # (p, h)
        dA = np.where(E > 0, E * a[:, None] ** np.maximum(E - 1, 0), 0.0)
        Jm = np.empty((p, E.shape[1]))
        for k in range(p):
            row = Apow[k].copy()
            Apow[k] = dA[k]
            Jm[k] = Apow.prod(axis=0)
            Apow[k] = row
        return np.hstack([G @ Jm.T, GI])

    class _Witnessed(Exception):
        """Raised by the residual as soon as a factor vector (in the box) is within ``eps``."""

    for i, x in enumerate(P):
        def fun(z, x=x):
            r = S.evaluate(z[:p], z[p:] if q else None) - x
            if np.linalg.norm(r) <= eps and np.all(np.abs(z) <= 1.0):
                raise _Witnessed
            return r
        for s in range(starts):
            z0 = np.clip(guess[i], -1, 1) if s == 0 else rng.uniform(-1, 1, p + q)
            try:
                sol = least_squares(fun, z0, jac=jac, bounds=(-1.0, 1.0), xtol=1e-15, ftol=1e-15,
                                    gtol=1e-15, max_nfev=max_nfev)
            except _Witnessed:
                found[i] = True
                break
            if np.linalg.norm(sol.fun) <= eps:
                found[i] = True
                break
    return found


