"""Quadrature rules for expectation integrals: CUT, UT, tensor Gauss-Hermite / Gauss-Legendre.

Every rule integrates against a *standard* density: the standard normal N(0, I_n)
(``density="gaussian"``) or the uniform density on the cube [-1, 1]^n (``density="uniform"``);
weights sum to one, so ``sum_i w_i f(x_i)`` approximates ``E[f(x)]``. :func:`to_gaussian` and
:func:`to_box` map the points to N(mean, cov) or to a box, :func:`moments` returns the weighted mean
and covariance of ``f(points)``.

Conjugate Unscented Transformation (CUT), Adurthi, Singla & Singh, "Conjugate Unscented
Transformation: applications to estimation and control", ASME JDSMC 140(3) 030907 (2018), used by
Jain et al. (Eqs. 10-15) for the moments of the reachable-state density. A CUT rule of order
``2k`` is a fully symmetric point set (invariant under coordinate permutations and sign flips)
built from a few *orbits*:

* centre point,
* principal axes  sigma:   ``r * (+-e_i)``                                    (2n points),
* conjugate axes  c^(m):   ``r * (+-1, ..., +-1, 0, ..., 0)`` and permutations,
  exactly m nonzero entries                                                    (2^m C(n, m) points),
* scaled conjugate axes s^(n): ``(+-a, +-b, ..., +-b)`` and permutations, i.e. c^(n) with one
  coordinate scaled by h = a / b                                               (n 2^n points).

Symmetry makes every odd moment vanish, so a rule that matches the even moments up to degree
``2k`` is exact for all polynomials of degree ``2k + 1``. The remaining conditions are one equation
per even partition ``(a_1 >= a_2 >= ...)`` of degree <= 2k (the moment
``E[x_1^{a_1} x_2^{a_2} ...]``), in the unknown radii and orbit weights. They are solved here in code
(:func:`_solve_cut`), never read from a table.
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Literal

import numpy as np
from scipy.optimize import least_squares

from ocreach.errors import ProblemError, SolverError

Density = Literal["gaussian", "uniform"]

__all__ = [
    "CUT_SUPPORTED",
    "CutOrbit",
    "cut_rule",
    "cut_structure",
    "gauss_hermite_rule",
    "gauss_legendre_rule",
    "moments",
    "to_box",
    "to_gaussian",
    "unscented_rule",
]

#: Supported (order -> {density: (n_min, n_max)}) for :func:`cut_rule`.
CUT_SUPPORTED: dict[int, dict[str, tuple[int, int]]] = {
    4: {"gaussian": (1, 9), "uniform": (1, 8)},
    6: {"gaussian": (1, 9), "uniform": (1, 2)},
    8: {"gaussian": (1, 6), "uniform": (1, 4)},
}

_RESIDUAL_TOL = 1e-13  # max relative moment error accepted from the solve


# ---------------------------------------------------------------------------------------------
# Orbits (symmetric point sets)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CutOrbit:
    """One fully symmetric orbit of a CUT rule (Adurthi et al. 2018, Sec. 3).

    ``kind`` is ``"centre"``, ``"sigma"`` (principal axes), ``"conj"`` (conjugate axes c^(m)) or
    ``"scaled"`` (scaled conjugate axes s^(n)); ``m`` is the number of nonzero coordinates.
    """

    kind: str
    m: int = 0

    def n_params(self) -> int:
        """Number of unknowns: weight, plus one radius (two for ``scaled``: a and b)."""
        return {"centre": 1, "sigma": 2, "conj": 2, "scaled": 3}[self.kind]

    def label(self, n: int) -> str:
        if self.kind == "conj":
            return f"c^({'n' if self.m == n else self.m})"
        return {"centre": "centre", "sigma": "sigma", "scaled": "s^(n)"}[self.kind]


def _sign_patterns(m: int) -> np.ndarray:
    """All 2^m vectors of +-1 (rows)."""
    return np.array(list(itertools.product((1.0, -1.0), repeat=m))).reshape(2**m, m)


def _conjugate_axes(n: int, m: int) -> np.ndarray:
    """Unit conjugate axes c^(m): rows with exactly m entries +-1, the rest 0."""
    signs = _sign_patterns(m)
    blocks = []
    for idx in itertools.combinations(range(n), m):
        blk = np.zeros((signs.shape[0], n))
        blk[:, idx] = signs
        blocks.append(blk)
    return np.vstack(blocks)


def _orbit_points(n: int, orbit: CutOrbit, p: np.ndarray) -> np.ndarray:
    """Points of one orbit for its parameters ``p`` (radius first, weight last)."""
    if orbit.kind == "centre":
        return np.zeros((1, n))
    if orbit.kind == "sigma":
        eye = np.eye(n)
        return p[0] * np.vstack([eye, -eye])
    if orbit.kind == "conj":
        return p[0] * _conjugate_axes(n, orbit.m)
    # scaled conjugate axes: c^(n) with coordinate k multiplied by h = a / b, for every k
    a, b = p[0], p[1]
    base = b * _sign_patterns(n)
    blocks = []
    for k in range(n):
        blk = base.copy()
        blk[:, k] *= a / b
        blocks.append(blk)
    return np.vstack(blocks)


def _orbit_size(n: int, orbit: CutOrbit) -> int:
    return {
        "centre": 1,
        "sigma": 2 * n,
        "conj": 2**orbit.m * math.comb(n, orbit.m),
        "scaled": n * 2**n,
    }[orbit.kind]


def _orbit_moment(n: int, orbit: CutOrbit, p, part: tuple[int, ...]):
    """Sum over the orbit's points of ``x_1^{a_1} ... x_j^{a_j}`` (even a_i), per unit weight.

    Closed forms from the orbit structure (``p`` may be complex for complex-step derivatives):
    sigma gives 2 r^a for a single exponent and 0 for mixed ones; c^(m) gives
    2^m C(n-j, m-j) r^{|a|} for j <= m nonzero exponents; s^(n) gives
    2^n [(n-j) b^{|a|} + sum_i a^{a_i} b^{|a|-a_i}].
    """
    j = len(part)
    deg = sum(part)
    if orbit.kind == "centre":
        return 1.0 if j == 0 else 0.0
    if orbit.kind == "sigma":
        if j == 0:
            return 2.0 * n
        return 2.0 * p[0] ** deg if j == 1 else 0.0
    if orbit.kind == "conj":
        if j > orbit.m:
            return 0.0
        return 2.0**orbit.m * math.comb(n - j, orbit.m - j) * p[0] ** deg
    a, b = p[0], p[1]
    return 2.0**n * ((n - j) * b**deg + sum(a**ai * b ** (deg - ai) for ai in part))


# ---------------------------------------------------------------------------------------------
# Moment equations
# ---------------------------------------------------------------------------------------------
def _even_partitions(order: int, n: int) -> list[tuple[int, ...]]:
    """Nonincreasing tuples of positive even integers, length <= n, sum <= order (incl. ())."""
    out: list[tuple[int, ...]] = []

    def rec(rem: int, largest: int, cur: tuple[int, ...]) -> None:
        out.append(cur)
        if len(cur) == n:
            return
        for part in range(min(rem, largest), 1, -1):
            if part % 2 == 0:
                rec(rem - part, part, cur + (part,))

    rec(order, order, ())
    return out


def _exact_1d(k: int, density: str) -> float:
    """E[x^k] for the standard normal ((k-1)!!) or uniform on [-1, 1] (1/(k+1)); k even."""
    if density == "gaussian":
        return float(math.prod(range(k - 1, 0, -2)))
    return 1.0 / (k + 1)


def _exact_moment(part: tuple[int, ...], density: str) -> float:
    return math.prod(_exact_1d(k, density) for k in part)


def _split(structure: tuple[CutOrbit, ...], theta):
    """Split the flat unknown vector into per-orbit parameter vectors (radii..., weight)."""
    out, i = [], 0
    for orb in structure:
        k = orb.n_params()
        out.append(theta[i : i + k])
        i += k
    return out


class _MomentSystem:
    """The CUT moment-constraint equations in array form (Adurthi et al. 2018).

    Orbit o contributes ``w_o * sum_t C[e,o,t] a_o^P[e,o,t] b_o^Q[e,o,t]`` to equation e (one
    equation per even partition), with a_o the radius (b_o = 1 except for s^(n)). The closed-form
    orbit sums of :func:`_orbit_moment` are expanded into these terms once; the relative residual
    and its exact Jacobian are then a few vectorised numpy operations.
    """

    def __init__(self, n: int, structure: tuple[CutOrbit, ...], density: str, order: int):
        self.n, self.structure = n, structure
        self.parts = _even_partitions(order, n)
        self.mu = np.array([_exact_moment(p, density) for p in self.parts])
        ne, no, nt = len(self.parts), len(structure), n + 1
        C, P, Q = np.zeros((ne, no, nt)), np.zeros((ne, no, nt)), np.zeros((ne, no, nt))
        for e, part in enumerate(self.parts):
            j, deg = len(part), sum(part)
            for o, orb in enumerate(structure):
                if orb.kind == "scaled":  # 2^n [(n-j) b^deg + sum_i a^{a_i} b^{deg-a_i}]
                    C[e, o, 0], Q[e, o, 0] = 2.0**n * (n - j), deg
                    for t, ai in enumerate(part):
                        C[e, o, t + 1], P[e, o, t + 1], Q[e, o, t + 1] = 2.0**n, ai, deg - ai
                else:
                    C[e, o, 0] = _orbit_moment(n, orb, np.array([1.0]), part)
                    P[e, o, 0] = deg
        self.C, self.P, self.Q = C, P, Q
        self.Pm1, self.Qm1 = np.maximum(P - 1, 0), np.maximum(Q - 1, 0)
        self.idx_w, self.idx_a, self.idx_b = [], [], []
        i = 0
        for orb in structure:
            k = orb.n_params()
            self.idx_w.append(i + k - 1)
            self.idx_a.append(i if k > 1 else -1)
            self.idx_b.append(i + 1 if k == 3 else -1)
            i += k
        self.size = i
        self.has_a = np.array([i >= 0 for i in self.idx_a])
        self.has_b = np.array([i >= 0 for i in self.idx_b])

    def _abw(self, theta):
        theta = np.asarray(theta, dtype=float)
        a = np.where(self.has_a, theta[np.maximum(self.idx_a, 0)], 1.0)
        b = np.where(self.has_b, theta[np.maximum(self.idx_b, 0)], 1.0)
        return a[None, :, None], b[None, :, None], theta[self.idx_w]

    def residual(self, theta) -> np.ndarray:
        A, B, w = self._abw(theta)
        val = np.sum(self.C * A**self.P * B**self.Q, axis=2)
        return (val @ w) / self.mu - 1.0

    def jacobian(self, theta) -> np.ndarray:
        A, B, w = self._abw(theta)
        J = np.zeros((len(self.parts), self.size))
        J[:, self.idx_w] = np.sum(self.C * A**self.P * B**self.Q, axis=2)
        da = np.sum(self.C * self.P * A**self.Pm1 * B**self.Q, axis=2) * w
        db = np.sum(self.C * self.Q * A**self.P * B**self.Qm1, axis=2) * w
        ia, ib = np.flatnonzero(self.has_a), np.flatnonzero(self.has_b)
        J[:, np.asarray(self.idx_a)[ia]] = da[:, ia]
        J[:, np.asarray(self.idx_b)[ib]] = db[:, ib]
        return J / self.mu[:, None]


# ---------------------------------------------------------------------------------------------
# Structures per (n, order, density)
# ---------------------------------------------------------------------------------------------
def _structure(n: int, order: int, density: str) -> tuple[CutOrbit, ...]:
    """Orbits of the CUT rule (see docs/quadrature.md for the point-count table).

    CUT4: sigma + c^(n) without the centre (2n + 2^n points, Adurthi et al. 2018 CUT4; n = 6 gives
    76). For the Gaussian with n = 2 that system has no finite solution (r_c^2 = (n+2)/(n-2)), so
    the centre is added (9 points). CUT6: centre + sigma + c^(n) + c^(2) (1 + 2n + 2^n + 2n(n-1);
    n = 6 gives 137; for n = 2, c^(2) and c^(n) are two rings of different radius); for n >= 7
    c^(3) replaces c^(2), whose system has a negative centre weight there. CUT8: centre +
    sigma + c^(n) twice + c^(2) + c^(3) + s^(n) (1 + 2n + 2^(n+1) + 2n(n-1) + 4n(n-1)(n-2)/3 + n 2^n;
    n = 6 gives 745); orbits that coincide with c^(n) in low dimension are dropped (c^(3) for
    n = 3, c^(2) for n = 2, which gives 59 and 21 points).
    """
    C, S, Z = CutOrbit("centre"), CutOrbit("sigma"), CutOrbit("scaled", n)
    cn = CutOrbit("conj", n)
    if order == 4:
        if density == "gaussian" and n == 2:
            return (C, S, cn)
        return (S, cn)
    if order == 6:
        if n >= 7:  # with c^(2) the centre weight turns negative for n = 7 (docs/quadrature.md)
            return (C, S, cn, CutOrbit("conj", 3))
        return (C, S, cn, CutOrbit("conj", 2))
    # order 8
    orbits = [C, S, cn, cn]
    if n > 2:
        orbits.append(CutOrbit("conj", 2))
    if n > 3:
        orbits.append(CutOrbit("conj", 3))
    orbits.append(Z)
    return tuple(orbits)


def _check_supported(n, order, density) -> None:
    allowed = ", ".join(
        f"order {o}: " + ", ".join(f"{d} n={lo}..{hi}" for d, (lo, hi) in dd.items())
        for o, dd in CUT_SUPPORTED.items()
    )
    if density not in ("gaussian", "uniform"):
        raise ProblemError(f"density must be 'gaussian' or 'uniform'; got {density!r}")
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order not in CUT_SUPPORTED:
        raise ProblemError(f"order must be one of 4, 6, 8; got {order!r}. Supported: {allowed}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
        raise ProblemError(f"n must be an int; got {n!r}")
    lo, hi = CUT_SUPPORTED[int(order)][density]
    if not lo <= n <= hi:
        raise ProblemError(
            f"CUT{order} with density={density!r} is supported for n = {lo}..{hi}; got n={n}. "
            f"Supported: {allowed}"
        )


# ---------------------------------------------------------------------------------------------
# Solve
# ---------------------------------------------------------------------------------------------
def _bounds(n, structure, density):
    """Box bounds on (radii, weights). Uniform rules keep every point in [-1, 1]^n except CUT4,
    whose principal axes leave the cube for n >= 6 (r_sigma^2 = (5n+4)/30, see the docs)."""
    box = density == "uniform" and not (len(structure) == 2 and n >= 6)
    rmax = 1.0 if box else 4.0 + math.sqrt(n)
    lo, hi = [], []
    for orb in structure:
        nr = orb.n_params() - 1
        lo += [1e-2] * nr + [0.0]
        hi += [rmax] * nr + [1.0]
    return np.array(lo), np.array(hi)


def _polish(system: _MomentSystem, theta, iters: int = 8):
    """Gauss-Newton (minimum-norm) steps with the exact Jacobian, to machine precision."""
    for _ in range(iters):
        r = system.residual(theta)
        if np.max(np.abs(r)) < 1e-15:
            break
        theta = theta + np.linalg.lstsq(system.jacobian(theta), -r, rcond=None)[0]
    return theta


def _weights_ok(structure, theta) -> bool:
    ws = [p[-1] for orb, p in zip(structure, _split(structure, theta)) if orb.kind != "centre"]
    w0 = [p[-1] for orb, p in zip(structure, _split(structure, theta)) if orb.kind == "centre"]
    return min(ws) > 1e-12 and all(w >= 0.0 for w in w0)


def _min_weight(structure, theta) -> float:
    return float(min(p[-1] for orb, p in zip(structure, _split(structure, theta))
                     if orb.kind != "centre"))


def _extent(structure, theta) -> float:
    """Largest |coordinate| of the rule (radius, or a for s^(n))."""
    return max(float(np.max(p[:-1])) for orb, p in zip(structure, _split(structure, theta))
               if orb.kind != "centre")


_CACHE_VERSION = 1  # bump when the root selection of _solve_cut changes


def _disk_cache_path(n: int, order: int, density: str):
    from ocreach.native.compile import cache_dir

    return cache_dir("cut_rules") / f"cut{order}_{density}_n{n}_v{_CACHE_VERSION}.npy"


def _disk_cache_load(n: int, order: int, density: str, size: int) -> np.ndarray | None:
    """The solved unknowns of a CUT rule from the on-disk cache (``$OCREACH_CACHE_DIR/cut_rules``), or None."""
    try:
        theta = np.load(_disk_cache_path(n, order, density))
    except (OSError, ValueError):
        return None
    return theta if theta.shape == (size,) and np.all(np.isfinite(theta)) else None


def _disk_cache_store(n: int, order: int, density: str, theta: np.ndarray) -> None:
    """Store the unknowns atomically; an unwritable cache only costs the solve next time."""
    import io

    from ocreach.native.compile import write_atomic

    buf = io.BytesIO()
    np.save(buf, np.asarray(theta, dtype=float))
    try:
        write_atomic(_disk_cache_path(n, order, density), buf.getvalue())
    except OSError:
        pass


@cache
def _solve_cut(n: int, order: int, density: str) -> tuple[tuple[CutOrbit, ...], tuple[np.ndarray, ...]]:
    """Solve the CUT moment equations for the orbit radii and weights.

    Unknowns: per orbit a weight and a radius (two radii a, b for s^(n)). Equations: one per even
    partition of degree <= order with at most n parts (relative residuals). Solved by bounded
    nonlinear least squares (scipy TRF, exact Jacobian) from a deterministic sequence of starting
    points, then polished by Gauss-Newton (the chosen root is cached on disk in
    ``$OCREACH_CACHE_DIR/cut_rules`` and re-verified on load, so the solve is a one-off per machine). Several roots (or, where the system is
    underdetermined - CUT8, and CUT4 with a centre - a family) exist; among the first converged
    candidates with a smallest orbit weight within a factor 100 of the best one the most compact
    (smallest largest coordinate) is kept. Raises
    :class:`SolverError` if no solution with positive weights and relative residual < 1e-13 exists
    among the starts.
    """
    structure = _structure(n, order, density)
    system = _MomentSystem(n, structure, density, order)
    lo, hi = _bounds(n, structure, density)

    def valid(theta) -> bool:
        in_box = np.all(theta >= lo - 1e-12) and np.all(theta <= hi + 1e-12)
        return bool(np.max(np.abs(system.residual(theta))) < _RESIDUAL_TOL and in_box
                    and _weights_ok(structure, theta))

    cached = _disk_cache_load(n, order, density, system.size)
    if cached is not None and valid(cached):  # re-verified: a stale or corrupt file is re-solved
        return structure, tuple(np.array(p, dtype=float) for p in _split(structure, cached))
    rng = np.random.default_rng([n, order, 0 if density == "gaussian" else 1])
    want = 1 if system.size <= len(system.parts) and order == 4 else 4
    found: list[np.ndarray] = []
    for _ in range(300):
        x0 = lo + (hi - lo) * rng.uniform(0.05, 0.95, lo.size)
        sol = least_squares(system.residual, x0, jac=system.jacobian, bounds=(lo, hi), xtol=1e-12,
                            ftol=1e-12, gtol=1e-12, max_nfev=200)
        if np.max(np.abs(sol.fun)) > 1e-8:
            continue
        theta = _polish(system, sol.x)
        if valid(theta):
            found.append(theta)
            if len(found) >= want:
                break
    if not found:
        raise SolverError(
            f"CUT{order} ({density}, n={n}): no solution of the moment equations with positive "
            "weights found"
        )
    minw = [_min_weight(structure, th) for th in found]
    eligible = [th for th, mw in zip(found, minw) if mw >= 1e-2 * max(minw)]
    best = min(eligible, key=lambda th: _extent(structure, th))
    _disk_cache_store(n, order, density, best)
    return structure, tuple(np.array(p, dtype=float) for p in _split(structure, best))


@cache
def _cut_arrays(n: int, order: int, density: str) -> tuple[np.ndarray, np.ndarray]:
    if n == 1:  # 1-D: the symmetric rule with order/2 + 1 nodes is Gauss-Hermite / Legendre
        m = order // 2 + 1
        return (gauss_hermite_rule(1, m) if density == "gaussian" else gauss_legendre_rule(1, m))
    structure, params = _solve_cut(n, order, density)
    pts, wts = [], []
    for orb, p in zip(structure, params):
        if orb.kind == "centre" and p[-1] == 0.0:
            continue
        x = _orbit_points(n, orb, p)
        pts.append(x)
        wts.append(np.full(x.shape[0], p[-1]))
    return np.vstack(pts), np.concatenate(wts)


def cut_rule(n: int, order: int, density: Density = "gaussian") -> tuple[np.ndarray, np.ndarray]:
    """Conjugate Unscented Transformation rule CUT``order`` for the standard density.

    Adurthi, Singla & Singh (JDSMC 2018); used by Jain et al. Eqs. 10-15. Exact for every
    polynomial of total degree <= ``order + 1`` under N(0, I_n) (``density="gaussian"``) or the
    uniform density on [-1, 1]^n (``density="uniform"``). Weights are positive and sum to one.
    Point counts (Gaussian): CUT4 2n + 2^n (9 for n = 2), CUT6 1 + 2n + 2^n + 2n(n-1),
    CUT8 745 for n = 6 and 21 for n = 2; n = 1 gives the (order/2 + 1)-point Gauss rule.
    Results are cached; the returned arrays are fresh copies.

    Returns ``(points (N, n), weights (N,))``.
    """
    _check_supported(n, order, density)
    pts, wts = _cut_arrays(int(n), int(order), density)
    return pts.copy(), wts.copy()


def cut_structure(n: int, order: int, density: Density = "gaussian") -> list[dict]:
    """Orbit table of a CUT rule: label, number of points, radius (a, b for s^(n)) and weight."""
    _check_supported(n, order, density)
    if n == 1:
        m = order // 2 + 1
        return [{"orbit": "gauss-1d", "points": m, "radius": None, "weight": None}]
    structure, params = _solve_cut(int(n), int(order), density)
    rows = []
    for orb, p in zip(structure, params):
        rows.append({
            "orbit": orb.label(n),
            "points": _orbit_size(n, orb),
            "radius": None if orb.kind == "centre" else tuple(float(v) for v in p[:-1]),
            "weight": float(p[-1]),
        })
    return rows


# ---------------------------------------------------------------------------------------------
# Comparison rules
# ---------------------------------------------------------------------------------------------
def _check_dim(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ProblemError(f"{name} must be an int >= {minimum}; got {value!r}")
    return int(value)


def unscented_rule(n: int, kappa: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Julier-Uhlmann unscented transformation for N(0, I_n): 2n + 1 points.

    Points 0 and +-sqrt(n + kappa) e_i, weights kappa/(n + kappa) and 1/(2(n + kappa)); exact to
    degree 3 (Julier & Uhlmann 1997). The default ``kappa = 3 - n`` also matches E[x_i^4] = 3;
    for n > 3 it gives a negative centre weight. Requires n + kappa > 0.
    """
    n = _check_dim("n", n)
    k = 3.0 - n if kappa is None else float(kappa)
    if not np.isfinite(k) or n + k <= 0:
        raise ProblemError(f"kappa must be finite with n + kappa > 0 (n={n}); got {kappa!r}")
    eye = np.sqrt(n + k) * np.eye(n)
    pts = np.vstack([np.zeros((1, n)), eye, -eye])
    w = np.full(2 * n + 1, 0.5 / (n + k))
    w[0] = k / (n + k)
    return pts, w


def _tensor(nodes: np.ndarray, weights: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    grids = np.meshgrid(*([nodes] * n), indexing="ij")
    wgrids = np.meshgrid(*([weights] * n), indexing="ij")
    pts = np.stack([g.ravel() for g in grids], axis=1)
    w = np.prod(np.stack([g.ravel() for g in wgrids], axis=1), axis=1)
    return pts, w


def gauss_hermite_rule(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Tensor Gauss-Hermite rule (probabilists', N(0, I_n)), m nodes per axis, m^n points.

    Exact for every monomial whose degree in each variable is <= 2m - 1.
    """
    n, m = _check_dim("n", n), _check_dim("m", m)
    x, w = np.polynomial.hermite_e.hermegauss(m)
    return _tensor(x, w / math.sqrt(2.0 * math.pi), n)


def gauss_legendre_rule(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Tensor Gauss-Legendre rule for the uniform density on [-1, 1]^n, m^n points.

    Exact for every monomial whose degree in each variable is <= 2m - 1.
    """
    n, m = _check_dim("n", n), _check_dim("m", m)
    x, w = np.polynomial.legendre.leggauss(m)
    return _tensor(x, w / 2.0, n)


# ---------------------------------------------------------------------------------------------
# Mapping and moments
# ---------------------------------------------------------------------------------------------
def _points_2d(points) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2:
        raise ProblemError(f"points must be a 2-D array (N, n); got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ProblemError("points must be finite")
    return p


def to_gaussian(points, mean, cov) -> np.ndarray:
    """Map standard-normal points to N(mean, cov): ``x = mean + L z`` with ``L L^T = cov``.

    L is the Cholesky factor, or ``V sqrt(Lambda)`` from the eigen-decomposition when ``cov`` is
    only positive semidefinite (e.g. Jain et al. Eq. 25, zero variances). Raises
    :class:`ProblemError` naming ``cov`` if it is not symmetric positive semidefinite.
    """
    z = _points_2d(points)
    n = z.shape[1]
    mu = np.asarray(mean, dtype=float).reshape(-1)
    if mu.shape != (n,) or not np.all(np.isfinite(mu)):
        raise ProblemError(f"mean must be a finite vector of length {n}; got {mean!r}")
    P = np.asarray(cov, dtype=float)
    if P.ndim == 0 and n == 1:
        P = P.reshape(1, 1)
    if P.shape != (n, n) or not np.all(np.isfinite(P)):
        raise ProblemError(f"cov must be a finite ({n}, {n}) matrix; got shape {P.shape}")
    scale = max(float(np.max(np.abs(P))), 1e-300)
    if np.max(np.abs(P - P.T)) > 1e-10 * scale:
        raise ProblemError(f"cov must be symmetric; got {P!r}")
    P = 0.5 * (P + P.T)
    try:
        L = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        lam, V = np.linalg.eigh(P)
        if lam.min() < -1e-10 * scale:
            raise ProblemError(
                f"cov must be positive semidefinite; smallest eigenvalue {lam.min():.3e}"
            ) from None
        L = V * np.sqrt(np.clip(lam, 0.0, None))
    return mu + z @ L.T


def to_box(points, lo, hi) -> np.ndarray:
    """Map points of the cube [-1, 1]^n affinely onto the box [lo, hi]."""
    z = _points_2d(points)
    n = z.shape[1]
    a = np.broadcast_to(np.asarray(lo, dtype=float), (n,))
    b = np.broadcast_to(np.asarray(hi, dtype=float), (n,))
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ProblemError(f"lo and hi must be finite; got lo={lo!r}, hi={hi!r}")
    if np.any(b < a):
        raise ProblemError(f"hi must be >= lo componentwise; got lo={lo!r}, hi={hi!r}")
    return 0.5 * (a + b) + 0.5 * (b - a) * z


def moments(points, weights, f: Callable[[np.ndarray], np.ndarray] | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and covariance of ``y = f(points)`` (Jain et al. Eqs. 10-11).

    ``f`` maps an (N, n) array to (N,) or (N, m) (vectorised); ``None`` means the identity.
    Returns ``(mean (m,), cov (m, m))`` with ``cov = sum_i w_i (y_i - mean)(y_i - mean)^T``.
    """
    x = _points_2d(points)
    w = np.asarray(weights, dtype=float).reshape(-1)
    if w.shape != (x.shape[0],) or not np.all(np.isfinite(w)):
        raise ProblemError(f"weights must be a finite vector of length {x.shape[0]}; got shape {w.shape}")
    y = x if f is None else np.asarray(f(x), dtype=float)
    if y.ndim == 1:
        y = y[:, None]
    if y.ndim != 2 or y.shape[0] != x.shape[0]:
        raise ProblemError(f"f(points) must have shape (N,) or (N, m) with N={x.shape[0]}; got {y.shape}")
    if not np.all(np.isfinite(y)):
        raise ProblemError("f(points) returned non-finite values")
    mean = w @ y
    d = y - mean
    cov = (d * w[:, None]).T @ d
    return mean, 0.5 * (cov + cov.T)
