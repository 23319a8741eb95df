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

    # ------------------------------------------------------------------ pieces
    def _bounds(self, C: np.ndarray, R: np.ndarray):
        """Interval outputs on the point boxes ``[c, c]`` (columns 0..B-1) and the boxes
        ``[c - r, c + r]`` (columns B..2B-1) of ``B`` zonotopes (``C``, ``R``: (n, B))."""
        # the boxes rounded outward, so that they contain the zonotopes
        lo = np.concatenate([C, np.nextafter(C - R, -np.inf)], axis=1)
        hi = np.concatenate([C, np.nextafter(C + R, np.inf)], axis=1)
        try:
            return self.iv([lo, self.p], [hi, self.p], check=False)
        except IntervalDomainError as exc:
            k = exc.box % C.shape[1] if exc.box >= 0 else 0
            raise ChartDomainError(f"{self.name}: the set [{np.array2string(lo[:, k], precision=6)}, "
                                   f"{np.array2string(hi[:, k], precision=6)}] cannot be converted: "
                                   f"{exc} ({self.why})") from None

    def pieces(self, Zs: list[Zonotope]) -> list[Piece]:
        """The second-order enclosures of ``F(Z)`` for every ``Z`` (no splitting; one interval
        evaluation for all of them)."""
        n, m, B = self.n_in, self.n_out, len(Zs)
        C = np.stack([np.asarray(Z.c, dtype=float) for Z in Zs], axis=1)
        R = np.stack([up(np.abs(Z.G).sum(axis=1), Z.G.shape[1] + 1) for Z in Zs], axis=1)
        (ylo, yhi), (Jlo, Jhi), (Hlo, Hhi), (vlo, _) = self._bounds(C, R)
        if self.n_valid and not np.all(vlo[:, B:] > 0):
            bad, k = np.unravel_index(int(np.argmin(vlo[:, B:])), (self.n_valid, B))
            raise ChartDomainError(f"{self.name}: the set [{np.array2string(C[:, k] - R[:, k], precision=6)}, "
                                   f"{np.array2string(C[:, k] + R[:, k], precision=6)}] reaches a "
                                   f"singularity of the coordinates (validity expression {bad} has "
                                   f"lower bound {vlo[bad, B + k]:.3g} <= 0): {self.why}")
        # F(c), J(c): the point boxes; J column-major (m x n), H (m n, n) column-major per box
        yc = 0.5 * (ylo[:, :B] + yhi[:, :B])
        y_rad = up(np.maximum(yhi[:, :B] - yc, yc - ylo[:, :B]), 1)
        Jm = 0.5 * (Jlo[:, :B] + Jhi[:, :B])
        J_rad = up(np.maximum(Jhi[:, :B] - Jm, Jm - Jlo[:, :B]), 1).reshape(n, m, B).transpose(2, 1, 0)
        Jm = Jm.reshape(n, m, B).transpose(2, 1, 0)                                   # (B, m, n)
        Hl = Hlo[:, B:].reshape(n, m, n, B).transpose(3, 1, 2, 0)                       # (B, m, n, n)
        Hh = Hhi[:, B:].reshape(n, m, n, B).transpose(3, 1, 2, 0)
        Hmag = np.maximum(np.abs(Hl), np.abs(Hh))
        r = R.T                                                                         # (B, n)
        r2 = r**2
        # 1/2 d^T H d over d in [-r, r]: off-diagonal terms +- |H_ab| r_a r_b, diagonal in
        # [min(0, Hlo) r^2, max(0, Hhi) r^2] (d_a^2 in [0, r_a^2])
        full = np.einsum("kiab,ka,kb->ki", Hmag, r, r)
        diag_mag = np.einsum("kiaa,ka->ki", Hmag, r2)
        off = full - diag_mag
        q_lo = 0.5 * np.einsum("kiaa,ka->ki", np.minimum(Hl, 0.0), r2) - 0.5 * off
        q_hi = 0.5 * np.einsum("kiaa,ka->ki", np.maximum(Hh, 0.0), r2) + 0.5 * off
        q_slack = rounding_radius(0.5 * full, 2 * n * n + 4)      # the float sums of these terms
        q_lo, q_hi = q_lo - q_slack, q_hi + q_slack
        qc = 0.5 * (q_lo + q_hi)
        q_rad = up(np.maximum(q_hi - qc, qc - q_lo), 1)
        scores_w = Hmag.sum(axis=1) @ r[:, :, None]                                   # (B, n, 1)
        out = []
        for k, Z in enumerate(Zs):
            G = np.asarray(Z.G, dtype=float)
            JG = Jm[k] @ G
            lin_abs = np.abs(Jm[k]) @ np.abs(G).sum(axis=1)
            fp = rounding_radius(lin_abs + np.abs(yc[:, k]) + np.abs(qc[k]), n + G.shape[1] + 4)
            box = up(y_rad[:, k] + q_rad[k] + J_rad[k] @ r[k] + fp, 4)
            lin = np.abs(JG).sum()
            excess = float(box.sum() / lin) if G.shape[1] and lin > 0 else 0.0
            gens = np.concatenate([JG, np.diag(box)[:, box > 0]], axis=1)
            scores = (np.abs(G).T @ scores_w[k, :, 0]) if G.shape[1] else None
            out.append(Piece(Zonotope.trusted(yc[:, k] + qc[k], gens), excess, scores))
        return out

    def piece(self, Z: Zonotope) -> Piece:
        """The second-order enclosure of ``F(Z)`` (one zonotope, no splitting)."""
        return self.pieces([Z])[0]

    def images(self, sets: list, *, tol: float = SPLIT_TOL, max_pieces: int = MAX_PIECES) -> list:
        """``F(S)`` enclosed for every ``S`` of ``sets`` (zonotopes, unions, boxes, or sets with
        ``to_zonotope`` such as polynomial zonotopes, through their zonotope enclosure).  Each
        zonotope is split while its quadratic term exceeds ``tol`` times its linear part (the
        sums of the radii over the outputs), at most ``max_pieces`` pieces per zonotope; all
        pieces of a round are evaluated in one interval call."""
        todo: list[tuple[int, Zonotope]] = []
        for i, S in enumerate(sets):
            todo += [(i, Z) for Z in _zonotopes(S, self.name)]
        budget = {j: 1 for j in range(len(todo))}
        result: list[list[Zonotope]] = [[] for _ in sets]
        pending = [(j, i, Z) for j, (i, Z) in enumerate(todo)]
        while pending:
            done = self.pieces([Z for _, _, Z in pending])
            nxt = []
            for (j, i, Z), pc in zip(pending, done):
                if pc.excess <= tol or pc.scores is None or budget[j] + 1 > max_pieces:
                    result[i].append(pc.Z)
                    continue
                budget[j] += 1
                a, b = Z.split(int(np.argmax(pc.scores)))
                nxt += [(j, i, a), (j, i, b)]
            pending = nxt
        return [parts[0] if len(parts) == 1 else ZonotopeUnion(parts) for parts in result]

    def image(self, S, **kw) -> Zonotope | ZonotopeUnion:
        """``F(S)`` enclosed (:meth:`images` of one set)."""
        return self.images([S], **kw)[0]

    def point(self, W: np.ndarray) -> np.ndarray:
        """``F`` at points ``W`` (N, n_in) in floating point (for samples; not an enclosure)."""
        W = np.atleast_2d(np.asarray(W, dtype=float))
        f = self.iv.fun
        out = f.map(W.shape[0])(W.T, self.p)
        return np.asarray(out[0]).T


def _zonotopes(S, name: str) -> list[Zonotope]:
    """The zonotopes of a set: itself, a union's parts, a box, or the enclosure of a set with
    ``to_zonotope``."""
    if isinstance(S, Zonotope):
        return [S]
    if isinstance(S, Interval):
        return [S.to_zonotope()]
    if hasattr(S, "parts"):
        return [Z for P in S.parts for Z in _zonotopes(P, name)]
    if hasattr(S, "to_zonotope"):
        return [S.to_zonotope()]
    raise ChartDomainError(f"{name}: cannot convert a {type(S).__name__}; expected a zonotope, a "
                           "union, a box or a polynomial zonotope")


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
