"""Exact minimum enclosing balls of point sets, and an outer ball from support values.

Tucker et al. Sec. 2.3 over-approximate the position reachable set by the minimum enclosing ball
(MEB) of its samples, computed with Welzl's algorithm (Welzl 1991).  Here:

* :func:`minimum_enclosing_ball` -- Welzl's move-to-front recursion with Gaertner's
  "pivoting" safeguards (a point is pushed onto the support set only if the support stays
  affinely independent, so collinear / co-spherical / duplicate points cannot produce a
  singular circumsphere), run on a small *working set* inside a core-set loop over all points:
  exact MEB of the working set, one vectorised farthest-point sweep over all points, add the
  farthest violators, repeat until no point lies outside ``r (1 + eps)``.  The ball of a support
  set ``B`` (centre in the affine hull of ``B``, every point of ``B`` on the sphere) is the
  solution of the small linear system ``2 A A^T lam = diag(A A^T)`` with ``A = [q_j - q_0]``.
  The result carries a certificate: the largest distance ratio over all points (every point is
  within ``r (1 + eps)``) and the barycentric coefficients of the centre in the support points
  (all >= 0: the centre is in their convex hull, which with the support points on the sphere is
  the optimality condition of the MEB).
* :func:`support_outer_ball` -- the MEB of the vertices of the polytope
  ``{x : d_j . x <= h_j}`` of supporting halfspaces.  The MEB of boundary *samples* is an inner
  estimate of the true set's ball; when the ``h_j`` are upper bounds of the support function, the
  polytope contains the set and so does this ball.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.errors import ProblemError, SetError, SolverError

#: Relative tolerance of the containment test inside the exact solver and of the certificate.
EPS = 1e-12
_RANK_TOL = 1e-11  # relative singular-value threshold for an affinely independent support set
_CHUNK = 1 << 17


@dataclass(frozen=True)
class EnclosingBall:
    """A ball ``{x : |x - center| <= radius}`` with its support points and certificate.

    ``support`` (k, d) are input points on the sphere (``support_index`` their rows in the input),
    ``barycentric`` (k,) the coefficients with ``center = barycentric @ support`` (sum 1);
    ``max_ratio`` is ``max_i |p_i - center| / radius`` over every input point (<= 1 + eps when the
    certificate holds), ``iterations`` the number of core-set sweeps.
    """

    center: np.ndarray
    radius: float
    support: np.ndarray
    support_index: np.ndarray
    barycentric: np.ndarray
    max_ratio: float
    iterations: int = 0

    @property
    def dim(self) -> int:
        return int(self.center.size)

    def certificate(self, eps: float = 1e-10) -> bool:
        """True if every point is within ``radius (1 + eps)`` and the centre is in the convex hull
        of the support points (barycentric coefficients >= -eps)."""
        return bool(self.max_ratio <= 1 + eps and np.all(self.barycentric >= -eps)
                    and abs(self.barycentric.sum() - 1) <= 1e-9)

    def contains(self, points, tol: float = 1e-9) -> np.ndarray:
        """Mask of ``points`` (m, d) inside the ball enlarged by the relative tolerance ``tol``."""
        P = np.atleast_2d(np.asarray(points, dtype=float))
        return np.linalg.norm(P - self.center, axis=1) <= self.radius * (1 + tol) + 1e-300


def _check_points(points, name: str = "points") -> np.ndarray:
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[0] == 0 or P.shape[1] == 0:
        raise SetError(f"{name} must be a non-empty (m, d) array; got shape {P.shape}")
    bad = ~np.all(np.isfinite(P), axis=1)
    if np.any(bad):
        raise SetError(f"{name} must be finite; rows {np.flatnonzero(bad)[:10].tolist()} hold NaN or inf")
    return P


class _Support:
    """An affinely independent support set ``B`` with its circumcentre in ``aff(B)``.

    Kept incrementally (Gaertner's push): an orthonormal basis ``Q`` of the directions
    ``q_j - q_0``; pushing ``p`` adds the residual ``v`` of ``p - q_0`` orthogonal to ``Q`` and moves
    the centre along ``v`` by ``t = (|p - c|^2 - r^2) / (2 |v|^2)``, which keeps it equidistant from
    every point of ``B`` and puts ``p`` on the sphere.  The push is refused (pivot check) when
    ``|v| <= tol |p - q_0|``: ``B + p`` would be affinely dependent (collinear, co-spherical or
    duplicate points), and no sphere with centre in the affine hull would pass through it.
    """

    __slots__ = ("idx", "q0", "Q", "c", "r2")

    def __init__(self, idx, q0, Q, c, r2):
        self.idx, self.q0, self.Q, self.c, self.r2 = idx, q0, Q, c, r2

    @classmethod
    def empty(cls, d: int) -> _Support:
        return cls([], None, np.zeros((0, d)), None, -1.0)

    def push(self, i: int, p: np.ndarray) -> _Support | None:
        if self.q0 is None:
            return _Support([i], p, self.Q, p.copy(), 0.0)
        a = p - self.q0
        v = a - (self.Q @ a) @ self.Q if self.Q.shape[0] else a.copy()
        nv2 = float(v @ v)
        if nv2 <= (_RANK_TOL ** 2) * float(a @ a) or nv2 == 0.0:
            return None
        e = p - self.c
        t = (float(e @ e) - self.r2) / (2.0 * nv2)
        c = self.c + t * v
        e0, e1 = self.q0 - c, p - c
        r2 = max(float(e0 @ e0), float(e1 @ e1))
        return _Support(self.idx + [i], self.q0, np.vstack([self.Q, v / np.sqrt(nv2)]), c, r2)


def barycentric(B: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Coefficients ``w`` with ``c = w @ B``, ``sum(w) = 1`` (least squares; exact when ``c`` is in
    the affine hull of the rows of ``B``)."""
    if B.shape[0] == 1:
        return np.ones(1)
    A = (B[1:] - B[0]).T
    lam = np.linalg.lstsq(A, c - B[0], rcond=None)[0]
    return np.concatenate([[1.0 - lam.sum()], lam])


def circumball(B: np.ndarray) -> tuple[np.ndarray, float, np.ndarray] | None:
    """Centre, squared radius and barycentric coefficients of the smallest sphere through the
    rows of ``B`` (k, d): the sphere through ``B`` with centre in its affine hull (the linear
    system ``2 A A^T lam = diag(A A^T)``, ``A = [q_j - q_0]``); ``None`` if ``B`` is affinely
    dependent (relative singular-value tolerance)."""
    B = np.asarray(B, dtype=float)
    q0 = B[0]
    if B.shape[0] == 1:
        return q0.copy(), 0.0, np.ones(1)
    A = B[1:] - q0
    s = np.linalg.svd(A, compute_uv=False)
    if s[0] == 0 or s[-1] <= _RANK_TOL * s[0]:
        return None
    lam = np.linalg.solve(2.0 * (A @ A.T), np.einsum("ij,ij->i", A, A))
    c = q0 + lam @ A
    r2 = float(np.max(np.einsum("ij,ij->i", B - c, B - c)))
    return c, r2, np.concatenate([[1.0 - lam.sum()], lam])


class _Welzl:
    """Welzl's move-to-front MEB on a small working set (Gaertner's mtf_mb with pivot checks).

    The containment scan of each level is vectorised: it finds the first point of the current
    prefix outside the ball with one numpy expression, recurses with that point on the boundary,
    moves it to the front and continues behind it.
    """

    def __init__(self, W: np.ndarray) -> None:
        self.W = W
        self.d = W.shape[1]
        self.order = list(range(W.shape[0]))

    def solve(self) -> _Support:
        return self._mtf(len(self.order), _Support.empty(self.d))

    def _mtf(self, end: int, S: _Support) -> _Support:
        best = S
        if len(S.idx) == self.d + 1:
            return best
        i = 0
        while i < end:
            if best.c is None:
                j = i
            else:
                diff = self.W[self.order[i:end]] - best.c
                viol = np.flatnonzero(np.einsum("ij,ij->i", diff, diff) > best.r2 * (1 + EPS))
                if viol.size == 0:
                    break
                j = i + int(viol[0])
            p = self.order[j]
            pushed = S.push(p, self.W[p])
            if pushed is not None:  # pivot check: the support stays affinely independent
                best = self._mtf(j, pushed)
                self.order.insert(0, self.order.pop(j))
            i = j + 1
        return best


def minimum_enclosing_ball(points, *, eps: float = EPS, batch: int | None = None,
                           max_iter: int = 1000, verify: bool = False) -> EnclosingBall:
    """Exact minimum enclosing ball of ``points`` (m, d) (Tucker et al. Sec. 2.3; Welzl 1991).

    Core-set loop: the exact MEB ``(c, r)`` (:class:`_Welzl`) of a small working set (it starts
    with the first point; the move-to-front order is kept between sweeps, newest points first); a
    vectorised sweep (squared distances by one matrix-vector product, the data shifted near the
    origin so that ``|p|^2 - 2 p.c + |c|^2`` does not cancel) finds the points outside
    ``r (1 + eps)``, and the ``batch`` farthest (default ``d + 1``) join the working set.  The sweep
    also drops points for good: with ``rho`` the largest distance from ``c``, every later
    working-set centre lies within ``delta = sqrt(rho^2 - r^2)`` of ``c`` (the centre of the MEB of a
    subset is within ``sqrt(R^2 - r^2)`` of any enclosing ball's centre of radius ``R``), so a point
    with ``|p - c| <= r - delta`` can never be outside a later ball.  Terminates because the
    working-set radius grows strictly.  The near-boundary distances are recomputed directly for the
    certificate; ``verify=True`` recomputes every distance.  Raises :class:`SetError` for an empty
    or non-finite point set.
    """
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[0] == 0 or P.shape[1] == 0:
        raise SetError(f"points must be a non-empty (m, d) array; got shape {P.shape}")
    m, d = P.shape
    if not (np.isfinite(eps) and 0 <= eps < 1e-3):
        raise ProblemError(f"eps must be in [0, 1e-3); got {eps!r}")
    batch = d + 1 if batch is None else int(batch)
    # shift to a point near the data unless the data already surrounds the origin
    sub = P[:: max(1, m // 512)]
    lo, hi = sub.min(axis=0), sub.max(axis=0)
    if np.all(np.isfinite(lo)) and np.linalg.norm(0.5 * (lo + hi)) <= 2.0 * np.linalg.norm(hi - lo):
        shift, X = np.zeros(d), P
    else:
        shift = 0.5 * (lo + hi) if np.all(np.isfinite(lo)) else np.zeros(d)
        X = P - shift
    Pn = np.einsum("ij,ij->i", X, X)
    if not np.isfinite(Pn.max()):
        _check_points(P)  # names the offending rows
        raise SetError("points are too large: their squared norms overflow")
    err = 8 * np.finfo(float).eps * (float(Pn.max()) + 1.0e-300)
    active: np.ndarray | None = None  # None: every point is still active
    Xa, Pa = X, Pn
    order: list[int] = [0]  # working set (indices into X) in move-to-front order
    it = 0
    while True:
        it += 1
        solver = _Welzl(X[order])
        S = solver.solve()
        sup_idx = [order[k] for k in S.idx]
        order = [order[k] for k in solver.order]
        c, r2 = S.c, S.r2
        d2 = Pa - 2.0 * (Xa @ c) + float(c @ c)
        tol = r2 * (1 + eps) ** 2 + 4 * err
        viol = np.flatnonzero(d2 > tol)
        if viol.size == 0:
            break
        if it >= max_iter:
            raise SolverError(f"minimum_enclosing_ball did not converge in {max_iter} core-set sweeps")
        k = min(batch, viol.size)
        top = viol[np.argpartition(d2[viol], -k)[-k:]] if viol.size > k else viol
        known = set(order)
        glob = top if active is None else active[top]
        new = [int(t) for t in glob if int(t) not in known]
        if not new:  # only working-set points look outside: check their exact distances
            diff = Xa[top] - c
            if np.all(np.einsum("ij,ij->i", diff, diff) <= r2 * (1 + eps) ** 2):
                break
            raise SolverError(f"minimum_enclosing_ball: working-set points remain outside the ball "
                              f"after {it} sweeps (degenerate input in {d}-D)")
        order = new + order
        # drop the points that no later working-set ball can have outside (see docstring)
        rho2 = max(float(d2.max()), r2)
        delta = np.sqrt(max(rho2 - r2, 0.0))
        r = np.sqrt(max(r2, 0.0))
        if r > delta:
            keep = d2 > (r - delta) ** 2 - 4 * err
            if np.count_nonzero(keep) < 0.5 * keep.size:
                active = np.flatnonzero(keep) if active is None else active[keep]
                Xa, Pa = X[active], Pn[active]
    r = float(np.sqrt(max(r2, 0.0)))
    # certificate: exact distances of every point that the fast sweep puts near the sphere
    near = np.flatnonzero(d2 >= r2 * (1 - 1e-6) - 4 * err)
    near = np.arange(m) if verify else (near if active is None else active[near])
    dmax = 0.0
    for s0 in range(0, near.size, _CHUNK):
        diff = X[near[s0:s0 + _CHUNK]] - c
        dmax = max(dmax, float(np.sqrt(np.max(np.einsum("ij,ij->i", diff, diff)))))
    idx = np.asarray(sup_idx, dtype=int)
    w = barycentric(X[idx], c)
    ratio = dmax / r if r > 0 else (1.0 if dmax == 0 else np.inf)
    return EnclosingBall(center=c + shift, radius=r, support=P[idx].copy(), support_index=idx,
                         barycentric=np.asarray(w, float), max_ratio=float(ratio), iterations=it)


def support_outer_ball(directions, values) -> EnclosingBall:
    """Ball around the polytope ``{x : d_j . x <= h_j}`` of supporting halfspaces.

    ``directions`` (N, d) (need not be unit), ``values`` (N,) support values ``h_j``.  The polytope
    contains every set whose support function is below ``h`` in those directions, so the MEB of
    its vertices (scipy's halfspace intersection from the LP Chebyshev centre) encloses the set.
    Raises :class:`SetError` if the polytope is unbounded (directions not surrounding the origin)
    or empty.
    """
    from scipy.optimize import linprog
    from scipy.spatial import HalfspaceIntersection, QhullError

    D = _check_points(directions, "directions")
    h = np.asarray(values, dtype=float).ravel()
    if h.shape != (D.shape[0],) or not np.all(np.isfinite(h)):
        raise SetError(f"values must be {D.shape[0]} finite support values; got shape {h.shape}")
    nrm = np.linalg.norm(D, axis=1)
    if np.any(nrm == 0):
        raise SetError("directions must be non-zero")
    Dn, hn = D / nrm[:, None], h / nrm
    d = D.shape[1]
    # Chebyshev centre: max t s.t. Dn x + t <= hn (t <= 1e6 * scale keeps the LP bounded)
    scale = float(np.max(np.abs(hn))) + 1.0
    res = linprog(np.r_[np.zeros(d), -1.0], A_ub=np.c_[Dn, np.ones(len(hn))], b_ub=hn,
                  bounds=[(None, None)] * d + [(None, 1e6 * scale)], method="highs")
    if res.status != 0 or res.x[-1] <= 0:
        raise SetError(f"support_outer_ball: the halfspaces have no interior (status {res.status})")
    if res.x[-1] >= 1e6 * scale * (1 - 1e-9):
        raise SetError("support_outer_ball: the polytope is unbounded; the directions must "
                       "surround the origin (positively span R^d)")
    try:
        hs = HalfspaceIntersection(np.c_[Dn, -hn], res.x[:d])
    except QhullError as exc:
        raise SetError(f"support_outer_ball: halfspace intersection failed: {exc}") from None
    V = hs.intersections
    if not np.all(np.isfinite(V)) or np.abs(V).max() > 1e5 * scale:
        raise SetError("support_outer_ball: the polytope is unbounded; the directions must "
                       "surround the origin")
    return minimum_enclosing_ball(V)
