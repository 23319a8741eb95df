"""Sound reachable sets of a linear system over one step: the step shared by ``taylor`` and ``sdc``.

For ``d' = A d + u_c + w(t)`` with ``d(0)`` in a zonotope ``R0``, a constant input ``u_c`` and an
uncertain input ``w(t)`` in a zonotope ``W`` that contains the origin (``W`` is centred at 0 by
moving its centre into ``u_c``), this module encloses the time-point set ``R(h)`` and the
time-interval set ``R([0, h])`` (Althoff, Stursberg & Buss, CDC 2008; Girard, HSCC 2005; Althoff's
thesis 2010, Sec. 3.2).  Every approximation is an enclosure:

* **Exponential-matrix remainder.**  With ``T_i = (A h)^i / i!`` (``i = 0..eta``) the tail
  ``e^{A t} - sum_{i<=eta} (A t)^i / i!`` is bounded elementwise for every ``t`` in ``[0, h]`` by
  ``E``: ``|sum_{i>eta} (A t)^i / i!| <= sum_{i>eta} (|A| h)^i / i! = P M`` with ``P = (|A| h)^{eta+1}``
  and ``M = sum_k (|A| h)^k / (eta+1+k)!``, whose entries are at most
  ``1 / ((eta+1)! (1 - a / (eta+2)))``, ``a = ||A h||_inf < eta + 2``; so
  ``E_ij = rowsum_i(P) / ((eta+1)! (1 - a/(eta+2)))``, plus the floating-point error of the
  computed ``T_i`` and their sums, ``2 (eta+1)(n+2) u sum_i (|A| h)^i / i!`` (:func:`expm_terms`).
* **Time point** (Eq. 3.5 of the thesis): ``R(h) = e^{A h} R0 + Gamma(h) u_c + R_W`` with
  ``e^{A h} in Phi_T + [-E, E]``, ``Phi_T = sum T_i``; ``Gamma(h) = int_0^h e^{A s} ds in
  h sum T_i / (i+1) + [-E h, E h]``; and the input solution
  ``R_W = sum_{i=0}^{eta} h/(i+1) T_i W  +  [-E h, E h] W``: the i-th term of
  ``int_0^h e^{A (h-s)} w(s) ds`` is ``int (h-s)^i / i! A^i w(s) ds``, a non-negative weight of total
  ``h^{i+1} / (i+1)!`` times points of the convex set ``A^i W``, hence in ``h^{i+1}/(i+1)! A^i W``.
* **Time interval** (Prop. 3.7 of the thesis, the curvature correction): for ``t`` in ``[0, h]``
  ``e^{A t} d0 = d0 + (t/h)(Phi_T - I) d0 + F(t) d0`` with
  ``F(t) in F = sum_{i=2}^{eta} [q_i, 0] T_i + [-E, E]``, ``q_i = i^{-i/(i-1)} - i^{-1/(i-1)}``
  (the minimum of ``tau^i - tau`` on ``[0, 1]``), and ``Gamma(t) u_c = (t/h) Gamma_T u_c + F~(t) u_c``
  with ``F~ = sum_{i=1}^{eta} [q_{i+1}, 0] h/(i+1) T_i + [-E h, E h]``.  The segment
  ``d0 + lambda (Phi_T d0 + Gamma_T u_c - d0)``, lambda in [0, 1], with the *same* ``d0`` is enclosed
  by the zonotope convex-hull formula ``((c1+c2)/2, [(G1+G2)/2, (c1-c2)/2, (G1-G2)/2])``; the input
  solution at any ``t <= h`` lies in ``R_W`` because ``0`` is in ``W`` (each term scales a convex set
  containing 0 by a factor in [0, 1]) and the remainder bound grows with ``t``.  So
  ``R([0, h]) = CH(R0, Phi_T R0 + Gamma_T u_c) + F R0 + F~ u_c + R_W``.

Interval matrices act on zonotopes through ``M Z in mid(M) Z + box(rad(M) (|c| + sum |g|))``.

**Floating point.**  The zonotope arithmetic of a step (the products with ``Phi``, ``Gamma``,
``T_i``, ``F``, the Minkowski sums, the boxes) is a sum-of-products expression of the float inputs
``R0``, ``u_c``, ``W`` and the computed matrices, so its rounding error is at most ``gamma_k`` times
the same expression on absolute values (:mod:`ocreach.sets.rounding`, Higham Lemma 3.1).  With
``M = sum_i |T_i| + E`` (which bounds ``|Phi|``, every ``|T_i|``, ``|F|`` and ``|Gamma| / h``) and
``a_R = |c_0| + sum |g_0|`` (``|R0|`` evaluated absolutely), ``a_u = |u_c|``, ``a_W = sum |w_j|``,
both the time-point and the time-interval set are within
``gamma_k (2 a_R + 3 M (a_R + h a_u + h a_W) + |x*|)`` of the exact ones, ``k`` the longest chain of
roundings (``n + eta`` for the matrices and their products plus the number of generators summed in
a radius, :func:`step_rounding`); that box is added to every set (:func:`pad`).  The matrices
themselves are enclosures: ``E`` contains the rounding of the computed ``T_i`` and ``Phi``, and
``F_rad``/``Ft_rad`` are rounded up past the rounding of their sums.
"""
from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np

from ocreach.errors import SolverError
from ocreach.sets.rounding import rounding_radius, up
from ocreach.sets.zonotope import Zonotope

#: largest number of Taylor terms of the exponential matrix
MAX_TERMS = 40
#: the tail bound must be below this (relative to ||A h||) before the series is truncated
TAIL_TOL = 1e-16


@dataclass(frozen=True)
class ExpmTerms:
    """Truncated exponential series of ``A h`` with a sound remainder (see module docstring).

    ``T[i] = (A h)^i / i!`` for ``i = 0..eta`` (shape ``(eta+1, n, n)``), ``E`` the elementwise
    remainder bound ``(n, n)`` valid for every ``t`` in ``[0, h]``, ``Phi = sum T``,
    ``Gamma = h sum T_i / (i+1)`` (the series part of ``int_0^h e^{A s} ds``),
    ``F_mid``/``F_rad`` midpoint and radius of the interval matrix ``F``, ``Ft_mid``/``Ft_rad``
    of ``F~``; ``M = sum_i |T_i| + E`` bounds the magnitude of every matrix of the step (the
    floating-point analysis of :func:`step_rounding`).
    """

    h: float
    eta: int
    T: np.ndarray
    E: np.ndarray
    Phi: np.ndarray
    Gamma: np.ndarray
    F_mid: np.ndarray
    F_rad: np.ndarray
    Ft_mid: np.ndarray
    Ft_rad: np.ndarray
    M: np.ndarray


def _q(i: int) -> float:
    """``min_{tau in [0,1]} tau^i - tau = i^{-i/(i-1)} - i^{-1/(i-1)}`` (i >= 2), rounded down."""
    v = i ** (-i / (i - 1)) - i ** (-1 / (i - 1))
    return v * (1 + 1e-12)


#: machine epsilon ``2^-52`` (twice the unit round-off)
_EPS = float(np.finfo(float).eps)
#: ``i!`` as floats (``float(factorial(i))``, exact up to 22!, correctly rounded beyond)
_FACT = [float(factorial(i)) for i in range(MAX_TERMS + 3)]
#: ``_Q[i] = q_i`` of :func:`_q` for ``i >= 2`` (0 for ``i < 2``), up to the most terms used
_Q = np.array([0.0, 0.0] + [_q(i) for i in range(2, MAX_TERMS + 3)])


def expm_terms(A: np.ndarray, h: float) -> ExpmTerms:
    """Taylor terms of ``e^{A h}`` with the remainder bound ``E`` and the matrices ``F``, ``F~``
    (Althoff CDC 2008, Eq. 6-8; module docstring).  Raises :class:`SolverError` if ``||A h||`` is so
    large that ``MAX_TERMS`` terms do not bound the tail (the step must be shortened)."""
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    Ah = A * h
    absAh = np.abs(Ah)
    a = float(np.max(absAh.sum(axis=1))) if n else 0.0
    T = [np.eye(n)]
    P = np.eye(n)  # (|A| h)^i
    S_abs = np.eye(n)  # sum_i (|A| h)^i / i!, bounds sum_i |T_i| and the rounding of the sums
    eta = 0
    while True:
        eta += 1
        T.append(T[-1] @ Ah / eta)
        P = P @ absAh
        S_abs = S_abs + P / _FACT[eta]
        # tail after eta terms: uses (|A|h)^(eta+1)
        if a < eta + 2:
            scalar = a ** (eta + 1) / _FACT[eta + 1] / (1.0 - a / (eta + 2))
            if eta >= 2 and scalar <= TAIL_TOL * max(1.0, a):
                break
        if eta >= MAX_TERMS:
            raise SolverError(f"exponential-matrix remainder: ||A h||_inf = {a:.4g} is too large for "
                              f"{MAX_TERMS} Taylor terms (step h = {h:.4g}); use a shorter step")
    P1 = P @ absAh  # (|A| h)^(eta+1)
    E_row = P1.sum(axis=1) / _FACT[eta + 1] / (1.0 - a / (eta + 2))
    # plus the rounding of the computed T_i and their sums: (eta + 1)(n + 2) u sum_i (|A| h)^i / i!
    # (first-order error bound of the recursive products T_i = T_{i-1} A h / i and the sums)
    u = _EPS
    E = (np.repeat(E_row[:, None], n, axis=1) * (1 + 1e-10)
         + 2.0 * (eta + 1) * (n + 2) * u * S_abs + 1e-300)
    Tarr = np.array(T)
    absT = np.abs(Tarr)
    Phi = Tarr.sum(axis=0)
    # weighted sums of the T_i as one matrix product each: Gamma = h sum T_i / (i+1),
    # F = sum_{i>=2} [q_i, 0] T_i, F~ = sum_{i>=1} [q_{i+1}, 0] h/(i+1) T_i (as midpoint/radius)
    inv = 1.0 / np.arange(1, eta + 2)
    wF = 0.5 * _Q[: eta + 1]               # _Q[i] = q_i (0 for i < 2)
    wFt = 0.5 * _Q[1: eta + 2] * (h * inv)  # 0.5 q_{i+1} h / (i+1)
    Tflat, absTflat = Tarr.reshape(eta + 1, n * n), absT.reshape(eta + 1, n * n)
    Gamma = weighted_sum(h * inv, Tflat, n)
    F_mid = weighted_sum(wF, Tflat, n)
    F_rad = E + weighted_sum(np.abs(wF), absTflat, n)
    Ft_mid = weighted_sum(wFt, Tflat, n)
    Ft_rad = E * h + weighted_sum(np.abs(wFt), absTflat, n)
    # the computed F_mid, Ft_mid carry the rounding of their sums (<= eta + 3 operations, abs value
    # <= F_rad): the radii are widened by that bound and rounded up
    k = eta + 4
    F_rad = up(F_rad + rounding_radius(F_rad, k), 2)
    Ft_rad = up(Ft_rad + rounding_radius(Ft_rad, k), 2)
    M = up(absT.sum(axis=0), eta + 1) + E
    return ExpmTerms(h=float(h), eta=eta, T=Tarr, E=E, Phi=Phi, Gamma=Gamma, F_mid=F_mid,
                     F_rad=F_rad, Ft_mid=Ft_mid, Ft_rad=Ft_rad, M=M)


def weighted_sum(w: np.ndarray, Tflat: np.ndarray, n: int) -> np.ndarray:
    """``sum_i w_i T_i`` for ``Tflat`` the ``(k, n n)`` rows of the ``T_i``: the one matrix product
    ``np.tensordot(w, T, axes=1)`` makes (bit for bit the same), without its Python overhead."""
    return np.dot(w.reshape(1, -1), Tflat).reshape(n, n)


def diag_columns(r: np.ndarray) -> np.ndarray:
    """The box generators ``diag(r)`` without the zero columns.  A NaN radius (a bound that
    overflowed) keeps its column, so that the set is visibly not finite for the callers'
    finiteness checks instead of silently losing that direction's width."""
    return np.diag(r)[:, r != 0]


def abs_extent(Z: Zonotope) -> np.ndarray:
    """``|c| + sum_j |g_j|``: the largest magnitude of each component over ``Z``."""
    return np.abs(Z.c) + np.abs(Z.G).sum(axis=1)


def box_zonotope(c: np.ndarray, r: np.ndarray) -> Zonotope:
    """The box ``c +- r`` as a zonotope (zero radii give no generator)."""
    return Zonotope.trusted(np.asarray(c, dtype=float), diag_columns(np.asarray(r, dtype=float)))


def interval_matrix_times(M_mid: np.ndarray, M_rad: np.ndarray, Z: Zonotope) -> Zonotope:
    """Enclosure of ``{M x : M in [M_mid -+ M_rad], x in Z}``: ``M_mid Z + box(M_rad |Z|)``."""
    r = M_rad @ abs_extent(Z)
    return Zonotope.trusted(M_mid @ Z.c, np.concatenate([M_mid @ Z.G, diag_columns(r)], axis=1))


def zsum(*parts: Zonotope | np.ndarray) -> Zonotope:
    """Minkowski sum of zonotopes and translation vectors (internal, :meth:`Zonotope.trusted`)."""
    cs, Gs = [], []
    for P in parts:
        if isinstance(P, Zonotope):
            cs.append(P.c)
            Gs.append(P.G)
        else:
            cs.append(P)
    c = cs[0]
    for v in cs[1:]:
        c = c + v
    return Zonotope.trusted(np.asarray(c, dtype=float), np.concatenate(Gs, axis=1))


def pad(Z: Zonotope, r: np.ndarray) -> Zonotope:
    """``Z`` plus the box of radii ``r`` (a rounding bound, :func:`step_rounding`)."""
    r = np.asarray(r, dtype=float)
    return Zonotope.trusted(Z.c, np.concatenate([Z.G, diag_columns(r)], axis=1))


def set_abs(R: Zonotope, xs: np.ndarray) -> np.ndarray:
    """``a_R = |c| + |x*| + sum_j |g_j|``: ``R - x*`` evaluated on absolute values (the factor of the
    floating-point bound of :func:`step_rounding`)."""
    return np.abs(R.c) + np.abs(np.asarray(xs, dtype=float)) + np.abs(R.G).sum(axis=1)


def step_rounding(et: ExpmTerms, R: Zonotope, xs: np.ndarray, u_abs: np.ndarray,
                  W_abs: np.ndarray, n_sum: int, aR: np.ndarray | None = None) -> np.ndarray:
    """Rigorous bound of the floating-point error of the time-point and time-interval sets of one
    step (module docstring, "Floating point") from the set ``R`` shifted by the linearisation
    point (the step maps ``R0 = R - x*`` and adds ``x*`` back; ``xs = 0`` if ``R`` is ``R0``),
    ``u_abs >= |u_c|_abs``, ``W_abs >= sum_j |w_j|_abs`` (the uncertain input's generators,
    absolutely evaluated), ``n_sum`` the most terms summed in one entry outside the matrix
    products (generators in a radius, inputs in a generator); ``aR`` is :func:`set_abs` of ``R``
    and ``xs`` if already computed (it does not change within a step)."""
    xs_abs = np.abs(np.asarray(xs, dtype=float))
    aR = set_abs(R, xs) if aR is None else aR
    h = et.h
    total = 2.0 * aR + 3.0 * (et.M @ (aR + h * (u_abs + W_abs))) + xs_abs
    k = 2 * R.dim + et.eta + int(n_sum) + 12
    return rounding_radius(total, k)


def input_solution(W: Zonotope, et: ExpmTerms) -> Zonotope:
    """Enclosure ``R_W`` of ``{int_0^t e^{A (t-s)} w(s) ds : t in [0, h], w(s) in W}`` for ``W``
    containing the origin (module docstring); ``W``'s centre must be 0 (put it into ``u_c``)."""
    if np.any(W.c != 0):
        raise SolverError("input_solution: the uncertain input set must be centred at 0 "
                          "(move the centre into the constant input u_c)")
    return Zonotope.trusted(np.zeros(W.dim), input_generators(W.G, et))


def input_generators(WG: np.ndarray, et: ExpmTerms) -> np.ndarray:
    """Generators of :func:`input_solution` for the uncertain input's generators ``WG``
    (centre 0): ``h/(i+1) T_i WG`` for ``i = 0..eta`` side by side, then the box ``E h sum |w_j|``."""
    n = WG.shape[0]
    if WG.shape[1] == 0:
        return np.zeros((n, 0))
    h = et.h
    # blocks h/(i+1) T_i W.G for i = 0..eta, side by side (one batched product)
    TG = (et.T @ WG) * (h / np.arange(1, et.eta + 2))[:, None, None]
    blocks = TG.transpose(1, 0, 2).reshape(n, -1)
    r = (et.E * h) @ np.abs(WG).sum(axis=1)
    return np.concatenate([blocks, diag_columns(r)], axis=1)


@dataclass(frozen=True)
class LinearStep:
    """Time-point set ``point`` (at ``h``) and time-interval set ``tube`` (over ``[0, h]``)."""

    point: Zonotope | None
    tube: Zonotope


@dataclass(frozen=True)
class StateMaps:
    """The products of a step that do not depend on the input: ``Phi_T R0``, ``F R0`` and
    ``E |R0|`` (reused when the step is recomputed with another constant input)."""

    PR: Zonotope
    FR: Zonotope
    ER: np.ndarray


def state_maps(R0: Zonotope, et: ExpmTerms) -> StateMaps:
    return StateMaps(PR=Zonotope.trusted(et.Phi @ R0.c, et.Phi @ R0.G),
                     FR=interval_matrix_times(et.F_mid, et.F_rad, R0), ER=et.E @ abs_extent(R0))


def homogeneous_step(R0: Zonotope, u_c: np.ndarray, et: ExpmTerms,
                     maps: StateMaps | None = None, with_point: bool = True) -> LinearStep:
    """The part of the step without the uncertain input: ``e^{A h} R0 + Gamma(h) u_c`` and
    ``CH(R0, Phi_T R0 + Gamma_T u_c) + F R0 + F~ u_c`` (module docstring); ``maps`` are
    :func:`state_maps` of ``R0`` if already computed; ``with_point=False`` leaves the time-point
    set out (``point`` is None) when only the tube is needed."""
    u_c = np.asarray(u_c, dtype=float)
    h = et.h
    maps = state_maps(R0, et) if maps is None else maps
    # time point: Phi_T R0 + [-E, E] R0 + Gamma_T u_c + [-E h, E h] u_c
    PR = maps.PR
    c_end = PR.c + et.Gamma @ u_c
    point = None
    if with_point:
        r_pt = maps.ER + (et.E * h) @ np.abs(u_c)
        point = Zonotope.trusted(c_end, np.concatenate([PR.G, diag_columns(r_pt)], axis=1))
    # time interval: convex hull of R0 and Phi_T R0 + Gamma_T u_c with common factors
    c1, G1 = R0.c, R0.G
    c2, G2 = c_end, PR.G
    ch_c = 0.5 * (c1 + c2)
    FR = maps.FR
    Ftu_c = et.Ft_mid @ u_c
    Ftu_r = et.Ft_rad @ np.abs(u_c)
    tube = Zonotope.trusted(ch_c + FR.c + Ftu_c,
                            np.concatenate([0.5 * (G1 + G2), 0.5 * (c1 - c2)[:, None],
                                            0.5 * (G1 - G2), FR.G, diag_columns(Ftu_r)], axis=1))
    return LinearStep(point=point, tube=tube)


def linear_step(R0: Zonotope, A: np.ndarray, h: float, u_c: np.ndarray, W: Zonotope | None = None,
                et: ExpmTerms | None = None) -> LinearStep:
    """Sound time-point and time-interval sets of ``d' = A d + u_c + w``, ``w(t) in W`` (``W`` any
    zonotope; its centre is moved into ``u_c``) from ``d(0) in R0`` over ``[0, h]``."""
    et = expm_terms(A, h) if et is None else et
    u_c = np.asarray(u_c, dtype=float)
    if W is not None:
        u_c = u_c + W.c
        W0 = Zonotope(np.zeros(W.dim), W.G)
    else:
        W0 = Zonotope(np.zeros(R0.dim))
    hs = homogeneous_step(R0, u_c, et)
    RW = input_solution(W0, et)
    W_abs = np.abs(W0.G).sum(axis=1) if W is None else np.abs(W.G).sum(axis=1)
    u_abs = np.abs(u_c) if W is None else np.abs(u_c) + 2 * np.abs(W.c)
    r = step_rounding(et, R0, np.zeros(R0.dim), u_abs, W_abs,
                      max(R0.n_generators, W0.n_generators) + 2)
    point, tube = pad(zsum(hs.point, RW), r), pad(zsum(hs.tube, RW), r)
    check_finite(point, tube)
    return LinearStep(point=point, tube=tube)


def all_finite(*sets: Zonotope) -> bool:
    """True if every centre and generator entry of ``sets`` is finite."""
    return all(np.all(np.isfinite(Z.c)) and np.all(np.isfinite(Z.G)) for Z in sets)


def check_finite(*sets: Zonotope) -> None:
    """Raise :class:`SolverError` if a computed set is not finite (overflow)."""
    if not all_finite(*sets):
        raise SolverError("the linear step's set is not finite (overflow); use a shorter step")
