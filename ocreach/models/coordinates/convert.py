"""Sound enclosures of sets under a smooth change of coordinates, and of a tube's slice at a time.

**Image of a zonotope** (:class:`MapEnclosure`).  For ``Z = c + G xi`` inside the box
``B = [c - r, c + r]`` (``r = sum_j |g_j|`` rounded up) and a twice continuously differentiable
map ``y = F(w)``, Taylor's theorem with the Lagrange remainder gives, row by row,

    F_i(w) = F_i(c) + J_i(c) (w - c) + 1/2 (w - c)^T H_i(zeta_i) (w - c),   zeta_i in B,

so ``F(Z)`` lies in the zonotope ``F(c) + J(c) G xi`` plus the box of the quadratic term with the
interval Hessian ``[H]`` over ``B`` (:mod:`ocreach.intervals`, outward rounded).  ``F(c)`` and
``J(c)`` are enclosed by the same interval evaluation on the point box ``[c, c]``; the float
product ``mid(J(c)) G`` gets its rigorous rounding box (:mod:`ocreach.sets.rounding`), and the
width of ``J(c)``'s enclosure times ``r`` is added too.  The map's validity expressions
(``Chart.valid_*``) are bounded on ``B`` in the same call: a set that reaches a singularity of the
chart is reported (:class:`ChartDomainError`), never converted wrongly.

The quadratic term grows with the square of the set's size; where it exceeds ``tol`` times the
linear part (in any output coordinate), the zonotope is split along the generator with the largest
contribution and both halves are converted (at most ``max_pieces`` pieces per set), so a large set
comes back as a :class:`~ocreach.sets.union.ZonotopeUnion`.

**Slice of a tube** (:func:`slice_at`).  For a time-transformed chart the propagated state is
``(z, t)`` and the time-interval sets (tubes) are zonotopes in it; the states of a tube at the time
``t = tau`` are ``{c + G xi : a^T xi = tau - c_t}`` (``a`` the time row of ``G``).  Eliminating the
factor ``xi_j`` with the largest ``|a_j|`` (and dropping its bound ``|xi_j| <= 1``) gives a zonotope
in ``z`` that contains the slice: ``c_z + g_j (tau - c_t) / a_j + sum_{i != j} (g_i - g_j a_i / a_j) xi_i``
(the approach of Girard & Le Guernic, HSCC 2008, for guards; here without the optimisation over
directions), with its rounding bounded.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ocreach.errors import SolverError
from ocreach.intervals import IntervalDomainError, interval_function
from ocreach.sets.interval import Interval
from ocreach.sets.rounding import rounding_radius, up
from ocreach.sets.union import ZonotopeUnion
from ocreach.sets.zonotope import Zonotope

#: default relative size of the quadratic term above which a zonotope is split before conversion
SPLIT_TOL = 0.02
#: default largest number of pieces a converted set may have
MAX_PIECES = 16


class ChartDomainError(SolverError):
    """A set reaches a singularity of the coordinates (or an interval bound of the map fails)."""


@dataclass
class Piece:
    """One converted piece and what it cost."""

    Z: Zonotope
    excess: float   # largest ratio of the quadratic term to the linear part over the outputs
    scores: np.ndarray | None   # each input generator's share of the quadratic term


class MapEnclosure:
    """Sound images of zonotopes (and unions, boxes, polynomial zonotopes through their
    zonotope enclosure) under ``y = F(w; p)`` (module docstring).

    ``w``: ``SX`` symbol of the input; ``y``: expression of the output; ``p``: parameter symbol and
    ``p_value`` its value; ``valid``: expressions of ``w`` that must be > 0 on every converted set
    (may be empty); ``why``: what a failure of ``valid`` means, for the error message.
    """

    def __init__(self, name: str, w: ca.SX, y: ca.SX, p: ca.SX, p_value: np.ndarray,
                 valid: ca.SX | None = None, why: str = "", *, cache=None):
        self.name = name
        self.n_in, self.n_out = w.numel(), y.numel()
        self.p = np.asarray(p_value, dtype=float)
        self.why = why
        valid = ca.SX(0, 1) if valid is None else ca.SX(valid)
        self.n_valid = valid.numel()
        J = ca.jacobian(y, w)
        H = ca.jacobian(ca.reshape(J.T, -1, 1), w)
        fun = ca.Function(f"{name}_map".replace("-", "_"), [w, p], [y, J, H, valid])

        def build():
            return interval_function(fun, native=True)

        self.iv = build() if cache is None else cache(("map_enclosure", name), build)

    # ------------------------------------------------------------------ one zonotope
    def _bounds(self, c: np.ndarray, r: np.ndarray):
        lo = np.stack([c, c - r], axis=1)
        hi = np.stack([c, c + r], axis=1)
        try:
            return self.iv([lo, self.p], [hi, self.p], check=False)
        except IntervalDomainError as exc:
            raise ChartDomainError(f"{self.name}: the set [{np.array2string(c - r, precision=6)}, "
                                   f"{np.array2string(c + r, precision=6)}] cannot be converted: "
                                   f"{exc} ({self.why})") from None

    def piece(self, Z: Zonotope) -> Piece:
        """The second-order enclosure of ``F(Z)`` (one zonotope, no splitting)."""
        n, m = self.n_in, self.n_out
        c = np.asarray(Z.c, dtype=float)
        G = np.asarray(Z.G, dtype=float)
        r = up(np.abs(G).sum(axis=1), G.shape[1] + 1)
        (ylo, yhi), (Jlo, Jhi), (Hlo, Hhi), (vlo, _) = self._bounds(c, r)
        if self.n_valid and not np.all(vlo[:, 1] > 0):
            bad = int(np.argmin(vlo[:, 1]))
            raise ChartDomainError(f"{self.name}: the set [{np.array2string(c - r, precision=6)}, "
                                   f"{np.array2string(c + r, precision=6)}] reaches a singularity "
                                   f"of the coordinates (validity expression {bad} has lower bound "
                                   f"{vlo[bad, 1]:.3g} <= 0): {self.why}")
        # F(c) and J(c): the point box; J column-major (m x n), H (m n, n) column-major
        yc = 0.5 * (ylo[:, 0] + yhi[:, 0])
        y_rad = up(np.maximum(yhi[:, 0] - yc, yc - ylo[:, 0]), 1)
        Jm = 0.5 * (Jlo[:, 0] + Jhi[:, 0])
        J_rad = up(np.maximum(Jhi[:, 0] - Jm, Jm - Jlo[:, 0]), 1).reshape(n, m).T
        Jm = Jm.reshape(n, m).T
        Hmag = np.maximum(np.abs(Hlo[:, 1]), np.abs(Hhi[:, 1])).reshape(n, m, n).transpose(1, 2, 0)
        Hlo_d = np.einsum("iaa->ia", Hlo[:, 1].reshape(n, m, n).transpose(1, 2, 0))
        Hhi_d = np.einsum("iaa->ia", Hhi[:, 1].reshape(n, m, n).transpose(1, 2, 0))
        # 1/2 d^T H d over d in [-r, r]: off-diagonal terms +- |H_ab| r_a r_b, diagonal in
        # [min(0, Hlo) r^2, max(0, Hhi) r^2] (d_a^2 in [0, r_a^2])
        rr = np.outer(r, r)
        off = (Hmag * rr[None]).sum(axis=(1, 2)) - (np.einsum("iaa->ia", Hmag) * r**2).sum(axis=1)
        q_lo = 0.5 * (np.minimum(Hlo_d, 0.0) * r**2).sum(axis=1) - 0.5 * off
        q_hi = 0.5 * (np.maximum(Hhi_d, 0.0) * r**2).sum(axis=1) + 0.5 * off
        q_mag = 0.5 * (Hmag * rr[None]).sum(axis=(1, 2))
        q_slack = rounding_radius(q_mag, 2 * n * n + 4)        # the float sums of these terms
        q_lo, q_hi = q_lo - q_slack, q_hi + q_slack
        qc = 0.5 * (q_lo + q_hi)
        q_rad = up(np.maximum(q_hi - qc, qc - q_lo), 1)
        JG = Jm @ G
        lin_abs = np.abs(Jm) @ np.abs(G).sum(axis=1)
        fp = rounding_radius(lin_abs + np.abs(yc) + np.abs(qc), n + G.shape[1] + 4)
        box = up(y_rad + q_rad + J_rad @ r + fp, 4)
        centre = yc + qc
        lin = np.abs(JG).sum(axis=1)
        excess = float(np.max(box / np.maximum(lin, 1e-300))) if G.shape[1] else 0.0
        gens = np.concatenate([JG, np.diag(box)[:, box > 0]], axis=1)
        scores = (np.abs(G).T @ (Hmag.sum(axis=0) @ r)) if G.shape[1] else None
        return Piece(Zonotope.trusted(centre, gens), excess, scores)

    def zonotope_image(self, Z: Zonotope, *, tol: float = SPLIT_TOL,
                       max_pieces: int = MAX_PIECES) -> Zonotope | ZonotopeUnion:
        """``F(Z)`` enclosed, splitting ``Z`` while the quadratic term exceeds ``tol`` times the
        linear part (at most ``max_pieces`` pieces)."""
        done: list[Zonotope] = []
        queue = [(Z, self.piece(Z))]
        while queue:
            queue.sort(key=lambda e: e[1].excess)
            Zi, pc = queue.pop()
            if pc.excess <= tol or len(done) + len(queue) + 2 > max_pieces or pc.scores is None:
                done.append(pc.Z)
                continue
            a, b = Zi.split(int(np.argmax(pc.scores)))
            queue += [(a, self.piece(a)), (b, self.piece(b))]
        return done[0] if len(done) == 1 else ZonotopeUnion(done)

    def image(self, S, **kw) -> Zonotope | ZonotopeUnion:
        """``F(S)`` enclosed for a zonotope, a union of sets, a box, or any set with
        ``to_zonotope`` (a polynomial zonotope: through its zonotope enclosure)."""
        if isinstance(S, ZonotopeUnion):
            parts = []
            for P in S.parts:
                out = self.image(P, **kw)
                parts.extend(out.parts if isinstance(out, ZonotopeUnion) else [out])
            return parts[0] if len(parts) == 1 else ZonotopeUnion(parts)
        if isinstance(S, Interval):
            S = S.to_zonotope()
        elif not isinstance(S, Zonotope):
            if hasattr(S, "parts"):
                return self.image(ZonotopeUnion([P.to_zonotope() for P in S.parts]), **kw)
            if not hasattr(S, "to_zonotope"):
                raise ChartDomainError(f"{self.name}: cannot convert a {type(S).__name__}; "
                                       "expected a zonotope, a union, a box or a polynomial "
                                       "zonotope")
            S = S.to_zonotope()
        return self.zonotope_image(S, **kw)

    def point(self, W: np.ndarray) -> np.ndarray:
        """``F`` at points ``W`` (N, n_in) in floating point (for samples; not an enclosure)."""
        W = np.atleast_2d(np.asarray(W, dtype=float))
        f = self.iv.fun
        out = f.map(W.shape[0])(W.T, self.p)
        return np.asarray(out[0]).T


# ------------------------------------------------------------------------------------------------
# slices of time-transformed tubes
# ------------------------------------------------------------------------------------------------
def time_range(T: Zonotope, row: int) -> tuple[float, float]:
    """The range of coordinate ``row`` over the zonotope ``T``, rounded outward."""
    a = np.abs(T.G[row]).sum()
    rad = float(up(a + rounding_radius(np.abs(T.c[row]) + a, T.G.shape[1] + 1), 1))
    return float(T.c[row] - rad), float(T.c[row] + rad)


def slice_at(T: Zonotope, row: int, value: float) -> Zonotope | None:
    """A zonotope (without the coordinate ``row``) that contains ``{w in T : w_row = value}``, or
    None if that slice is empty (module docstring)."""
    lo, hi = time_range(T, row)
    if not lo <= value <= hi:
        return None
    keep = np.arange(T.dim) != row
    c, G = np.asarray(T.c, float), np.asarray(T.G, float)
    a = G[row]
    if G.shape[1] == 0 or not np.any(a != 0):
        return Zonotope(c[keep], G[keep])
    j = int(np.argmax(np.abs(a)))
    beta = (value - c[row]) / a[j]
    ratio = a / a[j]
    gj = G[keep, j]
    Gn = G[keep] - np.outer(gj, ratio)
    Gn = np.delete(Gn, j, axis=1)
    cn = c[keep] + gj * beta
    # rounding: beta (2 ops), ratio (1), the products and differences (2), the centre (2)
    abs_beta = np.abs(beta) + rounding_radius(np.abs(value) + np.abs(c[row]), 2) / abs(a[j])
    err = rounding_radius(np.abs(c[keep]) + np.abs(gj) * abs_beta
                          + np.abs(G[keep]).sum(axis=1) + np.abs(gj) * np.abs(ratio).sum(),
                          G.shape[1] + 6)
    err = up(err + np.abs(gj) * (abs_beta - np.abs(beta)), 2)
    Gn = np.concatenate([Gn, np.diag(err)[:, err > 0]], axis=1)
    return Zonotope.trusted(cn, Gn)
