"""DE421 body positions as smooth CasADi expressions of time (Chebyshev refits, windows).

:class:`EphemerisFit` refits the DE421 Chebyshev records (:mod:`ocreach.ephemeris.de421`) over a
problem's time span with one Chebyshev series per coordinate (piecewise over equal sub-intervals,
blended, only for long spans), so that CasADi can differentiate the dynamics that use them;
:meth:`EphemerisFit.window_error_bound` bounds the error of a window's re-expansion with exact
rational arithmetic (:mod:`ocreach.ephemeris.exact_chebyshev`).  :class:`CircularEarthMoon` is a
stand-in with the same interface.  Conventions (axes, TDB, km, km/s) as in
:mod:`ocreach.ephemeris.de421`.
"""
from __future__ import annotations

from collections.abc import Iterable
from functools import lru_cache
from math import comb

import casadi as ca
import numpy as np
import numpy.polynomial.chebyshev as cheb

from ocreach.ephemeris.de421 import (
    BODIES,
    ECLIPJ2000_FROM_ICRF,
    FRAMES,
    ORIGINS,
    SECONDS_PER_DAY,
    check_body,
    de421_coverage,
    de421_records,
    format_jd,
    gm,
    parse_epoch,
    relative_series,
    series_combination,
)
from ocreach.errors import ProblemError, check_count


class EphemerisFit:
    """Chebyshev refit of DE421 body positions over ``[epoch + d0, epoch + d1]`` (days).

    Parameters
    ----------
    bodies : body names (see :data:`BODIES`); positions relative to any of them, to ``"ssb"`` or
        (with Earth or Moon in ``bodies``) to ``"emb"`` are available.
    epoch_tdb : TDB date string or Julian date (:func:`parse_epoch`); model time 0.
    span_days : ``d1`` (span ``[0, d1]``; negative for ``[d1, 0]``) or a pair ``(d0, d1)``.
    tol_km : required max position error of the fit over the span (default 1e-5 km = 1 cm),
        checked against the DE421 records on a grid of 8 points per coefficient.
    max_degree : largest Chebyshev degree per piece; longer spans are split into equal pieces.
    margin_days : the fit extends this far beyond the span on both sides (integrators overshoot);
        default ``max(0.25, 0.02 |d1 - d0|)``.

    Outside the fitted interval the polynomials diverge; the numeric methods raise, the CasADi
    expressions cannot, so keep model times inside ``span``.
    """

    def __init__(self, bodies: Iterable[str], epoch_tdb: str | float, span_days,
                 *, tol_km: float = 1e-5, max_degree: int = 64,
                 margin_days: float | None = None) -> None:
        self.bodies = tuple(sorted({check_body(b, BODIES, "bodies entry") for b in bodies}))
        if not self.bodies:
            raise ProblemError("bodies must name at least one body; got an empty list")
        self.epoch = parse_epoch(epoch_tdb)
        self.epoch_tdb = epoch_tdb
        if np.ndim(span_days) == 0:
            s = float(span_days)
            if not np.isfinite(s) or s == 0.0:
                raise ProblemError(f"span_days must be a non-zero finite number of days or a pair "
                                   f"(d0, d1); got {span_days!r}")
            d0, d1 = min(0.0, s), max(0.0, s)
        else:
            if len(span_days) != 2:
                raise ProblemError(f"span_days must be a number or a pair (d0, d1); got {span_days!r}")
            d0, d1 = float(span_days[0]), float(span_days[1])
            if not (np.isfinite(d0) and np.isfinite(d1) and d0 < d1):
                raise ProblemError(f"span_days (d0, d1) must be finite with d0 < d1; got {span_days!r}")
        self.span_days = (d0, d1)
        if not (float(tol_km) > 0):
            raise ProblemError(f"tol_km must be > 0; got {tol_km!r}")
        if int(max_degree) < 8:
            raise ProblemError(f"max_degree must be an integer >= 8; got {max_degree!r}")
        margin = max(0.25, 0.02 * (d1 - d0)) if margin_days is None else float(margin_days)
        if not margin >= 0:
            raise ProblemError(f"margin_days must be >= 0; got {margin_days!r}")
        self.fit_days = (d0 - margin, d1 + margin)

        jd_start, jd_end = de421_coverage()
        jd0 = self.epoch[0] + self.epoch[1]
        if jd0 + self.fit_days[0] < jd_start or jd0 + self.fit_days[1] > jd_end:
            raise ProblemError(
                f"epoch {epoch_tdb!r} ({format_jd(jd0)}) with span_days {span_days!r} (plus a "
                f"fit margin of {margin:g} d) leaves DE421's coverage {format_jd(jd_start)} .. "
                f"{format_jd(jd_end)} (DE421 spans 1899-07-29 to 2053-10-09; the de421 package starts "
                f"1899-12-04)")

        self.series = tuple(sorted({s for b in self.bodies for s in series_combination(b)}))
        self.tol_km = float(tol_km)
        self._fit(int(max_degree))
        self._cache: dict = {}

    # ------------------------------------------------------------------ fitting
    def _truth(self, days: np.ndarray) -> np.ndarray:
        """DE421 record positions of all series, shape ``(len(days), 3 * n_series)``."""
        return np.concatenate([de421_records(s, self.epoch[0], self.epoch[1] + days)
                               for s in self.series], axis=1)

    def _fit_piece(self, a: float, b: float, max_degree: int):
        check = np.linspace(a, b, 8 * max_degree + 1)
        truth = self._truth(check)
        xc = (2.0 * check - (a + b)) / (b - a)
        deg = 8
        while True:
            m = deg + 1
            nodes = np.cos(np.pi * (np.arange(m) + 0.5) / m)
            coef = cheb.chebfit(nodes, self._truth(0.5 * (a + b) + 0.5 * (b - a) * nodes), deg)
            err = np.abs(cheb.chebval(xc, coef).T - truth).max()
            if err <= self.tol_km:
                return coef.T, deg, err  # (3 n_series, deg + 1)
            if deg >= max_degree:
                return None, deg, err
            deg = min(max_degree, int(np.ceil(deg * 1.25 / 4) * 4))

    def _fit(self, max_degree: int) -> None:
        """One piece if possible, else ``n`` equal pieces that overlap by ``2 * blend`` days."""
        a, b = self.fit_days
        for n_pieces in range(1, int(np.ceil((b - a) / 2.0)) + 2):
            edges = np.linspace(a, b, n_pieces + 1)
            blend = BLEND_FRACTION * (b - a) / n_pieces
            bounds = [(max(a, edges[i] - blend), min(b, edges[i + 1] + blend))
                      for i in range(n_pieces)]
            pieces = [self._fit_piece(lo, hi, max_degree) for lo, hi in bounds]
            if all(p[0] is not None for p in pieces):
                self.edges_days = edges
                self.blend_days = blend
                self.piece_bounds_days = bounds
                self.coefficients = [p[0] for p in pieces]
                self.degrees = tuple(p[1] for p in pieces)
                self.fit_error_km = max(p[2] for p in pieces)
                return
        raise ProblemError(f"could not fit the ephemeris to tol_km = {self.tol_km} with "
                           f"max_degree = {max_degree}; raise one of them")

    # ------------------------------------------------------------------ helpers
    def gm(self, body: str) -> float:
        """Gravitational parameter of ``body`` (DE421), km^3/s^2."""
        return gm(body)

    @property
    def epoch_jd(self) -> float:
        return self.epoch[0] + self.epoch[1]

    @property
    def span_seconds(self) -> tuple[float, float]:
        return self.span_days[0] * SECONDS_PER_DAY, self.span_days[1] * SECONDS_PER_DAY

    def _matrix(self, body: str, origin: str, piece: int) -> np.ndarray:
        """Chebyshev coefficients (3, deg+1) of ``body - origin`` on one piece."""
        body = check_body(body, ORIGINS, "body")
        origin = check_body(origin, ORIGINS, "origin")
        comb = relative_series(body, origin)
        missing = [s for s in comb if s not in self.series]
        if missing:
            raise ProblemError(f"position of {body!r} relative to {origin!r} needs bodies that are "
                               f"not in this fit (bodies = {list(self.bodies)})")
        C = self.coefficients[piece]
        out = np.zeros((3, C.shape[1]))
        for s, w in comb.items():
            i = self.series.index(s)
            out += w * C[3 * i:3 * i + 3]
        return out

    @staticmethod
    def _rotation(frame: str) -> np.ndarray | None:
        frame = check_body(frame, FRAMES, "frame")
        return None if frame == "icrf" else ECLIPJ2000_FROM_ICRF

    # ------------------------------------------------------------------ numeric
    def position(self, body: str, t, origin: str = "ssb", *, derivative: int = 0,
                 frame: str = "icrf") -> np.ndarray:
        """Fitted position (km) of ``body`` w.r.t. ``origin`` at ``t`` seconds after the epoch.

        ``derivative = k`` gives the k-th time derivative (km/s^k) of the fit.  ``t`` may be an
        array; the result has shape ``t.shape + (3,)``.  Raises :class:`ProblemError` outside the
        fitted interval.
        """
        t = np.asarray(t, dtype=float)
        days = t / SECONDS_PER_DAY
        a, b = self.fit_days
        if np.any(~np.isfinite(days)) or np.any(days < a - 1e-9) or np.any(days > b + 1e-9):
            raise ProblemError(f"t must lie in the fitted interval [{a * SECONDS_PER_DAY:.6g}, "
                               f"{b * SECONDS_PER_DAY:.6g}] s after the epoch; got values in "
                               f"[{np.min(days) * SECONDS_PER_DAY:.6g}, "
                               f"{np.max(days) * SECONDS_PER_DAY:.6g}]")
        flat = days.ravel()
        k = int(derivative)
        out = _piece_deriv(self, body, origin, 0, flat, k)
        for j in range(1, len(self.coefficients)):
            e, d = self.edges_days[j], self.blend_days
            after = flat >= e + d
            if np.any(after):
                out[after] = _piece_deriv(self, body, origin, j, flat[after], k)
            mid = (flat > e - d) & ~after
            if np.any(mid):  # r = p + w (q - p); Leibniz rule for the k-th derivative
                x = flat[mid]
                s_ = (x - (e - d)) / (2 * d)
                res = _piece_deriv(self, body, origin, j - 1, x, k)
                for i in range(k + 1):
                    wi = _SMOOTHSTEP.deriv(i)(s_) / (2 * d * SECONDS_PER_DAY) ** i
                    dq = _piece_deriv(self, body, origin, j, x, k - i) \
                        - _piece_deriv(self, body, origin, j - 1, x, k - i)
                    res = res + comb(k, i) * wi[:, None] * dq
                out[mid] = res
        R = self._rotation(frame)
        if R is not None:
            out = out @ R.T
        return out.reshape(t.shape + (3,))

    def velocity(self, body: str, t, origin: str = "ssb", *, frame: str = "icrf") -> np.ndarray:
        """Fitted velocity (km/s): the exact time derivative of :meth:`position`."""
        return self.position(body, t, origin, derivative=1, frame=frame)

    # ------------------------------------------------------------------ symbolic
    def position_expr(self, body: str, t: ca.SX | ca.MX, origin: str = "ssb", *,
                      frame: str = "icrf", window: tuple[float, float] | None = None
                      ) -> ca.SX | ca.MX:
        """CasADi expression (3x1, km) of the fitted position; ``t`` in seconds after the epoch.

        A polynomial in ``t`` on each piece, hence smooth to any order there; when the span has
        several pieces (selected with ``if_else``), neighbours are blended over their overlap with
        the degree-9 smoothstep (:data:`_SMOOTHSTEP`), so the expression is C^4 everywhere and
        ``ca.jacobian(expr, t)`` is the exact velocity of the fit.  Only valid inside the fitted
        interval.

        ``window = (lo, hi)`` (seconds after the epoch, ``lo < hi``): the expression only for
        ``lo <= t <= hi``, one polynomial on the whole window: the fit interpolated at Chebyshev
        nodes of the window (:meth:`_window_matrix`; on a window inside one branch of the
        ``if_else`` chain, the branch's polynomial re-expanded; across branches -- a piece and a
        blend -- the C^4 fit approximated to rounding level), its difference to the fit bounded
        by :meth:`window_error_bound` (docs/intervals.md "Ephemeris positions over a time
        interval"): no ``if_else`` (a model a sound reachability method accepts), and an
        interval extension over a step that is not blown up by the piece's degree-48
        recurrence.
        """
        if window is not None:
            w_lo, w_hi = _check_window(window)
            C = self._window_matrix(body, origin, w_lo, w_hi)
            out = ca.mtimes(ca.DM(C), _basis((2.0 * t - (w_lo + w_hi)) / (w_hi - w_lo),
                                              C.shape[1] - 1))
            R = self._rotation(frame)
            return out if R is None else ca.mtimes(ca.DM(R), out)
        vals = []
        for k, (lo, hi) in enumerate(self.piece_bounds_days):
            lo, hi = lo * SECONDS_PER_DAY, hi * SECONDS_PER_DAY
            C = self._matrix(body, origin, k)
            vals.append(ca.mtimes(ca.DM(C), _basis((2.0 * t - (lo + hi)) / (hi - lo),
                                                     C.shape[1] - 1)))
        out = vals[0]
        for k in range(1, len(vals)):
            e0, e1 = self._blend_seconds(k)
            w = _smoothstep_expr((t - e0) / (e1 - e0))
            out = ca.if_else(t < e0, out, ca.if_else(t < e1, out + w * (vals[k] - out), vals[k]))
        R = self._rotation(frame)
        return out if R is None else ca.mtimes(ca.DM(R), out)

    def _blend_seconds(self, k: int) -> tuple[float, float]:
        """Start and end (seconds after the epoch) of the blend of pieces ``k - 1`` and ``k``."""
        return ((self.edges_days[k] - self.blend_days) * SECONDS_PER_DAY,
                (self.edges_days[k] + self.blend_days) * SECONDS_PER_DAY)

    def _branches(self) -> list[tuple[int, bool, float, float]]:
        """The branches of :meth:`position_expr`'s ``if_else`` chain in time order, each as
        ``(k, blended, start, end)`` (seconds after the epoch; ``-inf`` / ``inf`` at the ends):
        ``(k, False, ...)`` piece ``k`` on ``[e1_k, e0_(k+1))``, ``(k, True, ...)`` the blend of
        pieces ``k - 1`` and ``k`` on ``[e0_k, e1_k)``, ``[e0_k, e1_k]`` the blend's
        :meth:`_blend_seconds` (the chain's comparisons ``t < e0``, ``t < e1``)."""
        out, start = [], -np.inf
        for k in range(1, len(self.coefficients)):
            e0, e1 = self._blend_seconds(k)
            out += [(k - 1, False, start, e0), (k, True, e0, e1)]
            start = e1
        return out + [(len(self.coefficients) - 1, False, start, np.inf)]

    def _window_branches(self, w_lo: float, w_hi: float
                         ) -> list[tuple[int, bool, float, float]]:
        """The branches (:meth:`_branches`) that hold somewhere in ``[w_lo, w_hi]`` (seconds),
        each with the closed sub-window ``[s0, s1]`` it holds on (its half-open domain
        ``[start, end)`` met with the window, closed: a superset).  A branch that holds at the
        window's end only (``start == w_hi``) gets ``[w_hi, min(end, w_hi + 1e-6 (w_hi -
        w_lo))]``: still inside its own domain, so the bound on it stays a bound of the fit."""
        out = []
        for k, blended, start, end in self._branches():
            if start > w_hi or end <= w_lo:
                continue
            s0, s1 = max(start, w_lo), min(end, w_hi)
            if s1 <= s0:  # start == w_hi: a single point of the window
                s1 = min(end, w_hi + 1e-6 * (w_hi - w_lo))
                if not s1 > s0:
                    s1 = float(np.nextafter(s0, np.inf))
            out.append((k, blended, s0, s1))
        return out

    def _branch_degree(self, k: int, blended: bool) -> int:
        """Degree of branch ``(k, blended)``: the piece's, or in a blend the larger of the two
        pieces' plus 9 (:data:`_SMOOTHSTEP`)."""
        if not blended:
            return self.degrees[k]
        return max(self.degrees[k - 1], self.degrees[k]) + _SMOOTHSTEP.degree()

    def window_error_bound(self, body: str, origin: str, w_lo: float, w_hi: float, *,
                           derivative: int = 0) -> np.ndarray:
        """Rigorous bound (3 ICRF coordinates, km/s^k) of ``|d^k/dt^k (p(t) - q(t))|`` for
        ``w_lo <= t <= w_hi`` (seconds), ``p`` the fit as :meth:`position_expr` defines it (its
        ``if_else`` chain read as exact real arithmetic on its float constants) and ``q`` its
        re-expansion ``position_expr(..., window=(w_lo, w_hi))``.

        The window may meet several branches of the chain (pieces and blends,
        :meth:`_window_branches`); at every ``t`` the fit is the polynomial of the branch that
        holds there, so the bound is the largest over the branches of a bound on the branch's
        closed sub-window ``[s0, s1]``.  There, with ``u`` in ``[-1, 1]`` the sub-window's own
        variable (``s = m + h u``, ``s = (2 t - fl(w_lo + w_hi)) / fl(w_hi - w_lo)`` the
        window's, ``m``, ``h`` exact rationals), the branch -- the piece's series ``sum c_j
        T_j(tau)`` with ``tau = alpha u + beta``, in a blend also the smoothstep of ``gamma u +
        delta`` -- and ``q`` are re-expanded in ``u`` with exact rational arithmetic
        (:mod:`ocreach.ephemeris.exact_chebyshev`), subtracted, and ``sup |sum e_j T_j^(k)(u)|
        <= sum |e_j| T_j^(k)(1)`` times ``(2 / (fl(w_hi - w_lo) h))^k``, rounded up to a float
        once.  Only the sub-window enters, so a piece's polynomial outside its domain (where it
        does not hold) never does.  This covers the interpolation's rounding, the blend's kink
        (the fit is C^4 there, ``q`` one polynomial) and the dropped tail
        (:data:`WINDOW_TAIL_ULPS`) together.  It does not cover the rounding of a float
        evaluation of either expression (the plant's integrator works at a far coarser
        tolerance).  :class:`ProblemError` unless ``w_lo < w_hi`` are finite and ``derivative``
        is an integer >= 0."""
        from fractions import Fraction

        from ocreach.ephemeris import exact_chebyshev as xc

        w_lo, w_hi = _check_window((w_lo, w_hi))
        derivative = check_count("derivative (order k of d^k/dt^k)", derivative, 0)
        key = ("window-bound", body, origin, w_lo, w_hi, derivative)
        if key in self._cache:
            return self._cache[key]
        q = list(self._window_matrix(body, origin, w_lo, w_hi))
        A_w, B_w = Fraction(w_lo + w_hi), Fraction(w_hi - w_lo)  # the floats the expression uses
        out = np.zeros(3)
        for k, blended, s0, s1 in self._window_branches(w_lo, w_hi):
            # the window's s on the sub-window: s = m + h u, u in [-1, 1]
            sa, sb = (2 * Fraction(s0) - A_w) / B_w, (2 * Fraction(s1) - A_w) / B_w
            m, h = (sa + sb) / 2, (sb - sa) / 2
            rows = self._branch_series(body, origin, k, blended, h * B_w, m * B_w + A_w)
            qu = xc.compose_affine(q, h, m)
            scale = (2 / (B_w * h)) ** derivative
            out = np.maximum(out, [xc.float_up(xc.sup_bound(xc.add(r, qr, -1), Fraction(1),
                                                            derivative) * scale)
                                   for r, qr in zip(rows, qu, strict=True)])
        self._cache[key] = out
        return out

    def _branch_series(self, body: str, origin: str, k: int, blended: bool, a_u, b_u) -> list:
        """Branch ``(k, blended)`` of ``body - origin`` (ICRF) as exact rational Chebyshev
        series in ``u``, for ``2 t = a_u u + b_u`` (``a_u``, ``b_u`` exact rationals): the
        piece's series in ``tau = (2 t - fl(lo + hi)) / fl(hi - lo)``, in a blend ``p + w (r -
        p)`` with ``w`` the smoothstep of ``(t - e0) / fl(e1 - e0)``, all with the float
        constants of :meth:`position_expr`."""
        from fractions import Fraction

        from ocreach.ephemeris import exact_chebyshev as xc

        def affine(a: Fraction, b: Fraction) -> tuple[Fraction, Fraction]:
            """``(2 t - a) / b`` as ``alpha u + beta``."""
            return a_u / b, (b_u - a) / b

        def piece(j: int) -> list:
            lo, hi = self.piece_bounds_days[j]
            lo, hi = lo * SECONDS_PER_DAY, hi * SECONDS_PER_DAY
            return xc.compose_affine(list(self._matrix(body, origin, j)),
                                     *affine(Fraction(lo + hi), Fraction(hi - lo)))

        rows = piece(k)
        if not blended:
            return rows
        prev = piece(k - 1)
        e0, e1 = self._blend_seconds(k)
        # (t - e0) / fl(e1 - e0) = (2 t - 2 e0) / (2 fl(e1 - e0))
        gamma, delta = affine(2 * Fraction(e0), 2 * Fraction(e1 - e0))
        w = [Fraction(0)]
        for c in _SMOOTHSTEP.coef[::-1]:  # Horner, as _smoothstep_expr
            w = xc.add(xc.affine_times(w, gamma, delta), [Fraction(float(c))])
        return [xc.add(p, xc.product(w, xc.add(r, p, -1))) for p, r in zip(prev, rows, strict=True)]

    def _window_matrix(self, body: str, origin: str, w_lo: float, w_hi: float) -> np.ndarray:
        """Chebyshev coefficients (3, D+1) of ``body - origin`` (ICRF) re-expanded on the window
        ``[w_lo, w_hi]`` (seconds): the interpolant of the fit (:meth:`position`) at the ``D + 1``
        Chebyshev nodes of the window, ``D`` the largest degree of the branches the window meets
        (:meth:`_window_branches`, :meth:`_branch_degree`).  On a window inside one branch the
        fit is that polynomial and the interpolant is exact up to rounding; across a blend's
        boundary the fit is C^4 (its 5th derivative jumps by ``w^(5)(0) (p_k - p_(k-1)) / (e1 -
        e0)^5``, 3e-31 .. 1e-30 km/s^5 on a 74-day fit) and the interpolant is as close
        (docs/intervals.md "Ephemeris positions over a time interval"; :meth:`window_error_bound`
        bounds the difference).

        Why: the interval extension of the three-term recurrence ``T_k = 2 tau T_(k-1) -
        T_(k-2)`` widens by up to ``1 + sqrt(2)`` per degree near ``|tau| = 1``, which for the
        degree-48 pieces near a piece's end is 1e4 times the true variation of a position over a
        1-hour step; on a window of days the coefficients fall off like ``(omega H / 2)^k / k!``
        (H the half-width, omega the body's angular rate) and that growth is harmless."""
        key = ("window", body, origin, w_lo, w_hi)
        if key not in self._cache:
            D = max(self._branch_degree(k, blended)
                    for k, blended, _, _ in self._window_branches(w_lo, w_hi))
            nodes = np.cos(np.pi * (np.arange(D + 1) + 0.5) / (D + 1))
            ts = 0.5 * (w_lo + w_hi) + 0.5 * (w_hi - w_lo) * nodes
            C = cheb.chebfit(nodes, self.position(body, ts, origin), D).T
            # drop the trailing coefficients at the rounding floor of the interpolation (they
            # are noise, 1e-16 of the position, but the interval recurrence multiplies them by up
            # to (1 + sqrt(2))^k): the series changes by at most their sum.  The floor: 16 ulps
            # of the row's magnitude sum, raised to 4 times the plateau of the last eighth of
            # the coefficients (capped at 64 ulps of the largest row): the noise of the fit's
            # values is absolute, the same in every coordinate (a degree-60 piece evaluates to
            # 5-16 ulps of the position), and a 7-hour window kept 44 coefficients of it in its
            # smallest row with the row's floor alone; the cap keeps a window nearly as long as
            # a piece, whose last coefficients are still signal, from losing them
            eps = np.finfo(float).eps
            rows = np.abs(C).sum(axis=1, keepdims=True)
            plateau = 4.0 * float(np.abs(C[:, -max(1, C.shape[1] // 8):]).max())
            floor = np.maximum(WINDOW_TAIL_ULPS * eps * rows,
                               min(plateau, WINDOW_NOISE_ULPS * eps * float(rows.max())))
            above = np.nonzero((np.abs(C) > floor).any(axis=0))[0]
            self._cache[key] = C[:, : max(2, int(above[-1]) + 1 if above.size else 2)]
        return self._cache[key]

    def __repr__(self) -> str:
        return (f"EphemerisFit(bodies={list(self.bodies)}, epoch={format_jd(self.epoch_jd)}, "
                f"span_days={self.span_days}, pieces={len(self.coefficients)}, "
                f"degrees={self.degrees}, fit_error_km={self.fit_error_km:.2e})")


#: Coefficients of a fit re-expanded on a window (:meth:`EphemerisFit._window_matrix`) below this
#: many ulps of their row's magnitude sum (or below 4 times the plateau of the last eighth of the
#: coefficients, up to :data:`WINDOW_NOISE_ULPS` of the largest row) are dropped: rounding noise
#: of the interpolation
#: (measured with it: the window's positions are within 4e-9 km (Earth) and 3.4e-7 km (Sun, 10
#: ulps) of the fit's, whose own error to DE421 is 4.4e-7 km; docs/intervals.md).
WINDOW_TAIL_ULPS = 16.0
#: Cap (ulps of the largest row's magnitude sum) of the noise plateau floor of a window's series.
WINDOW_NOISE_ULPS = 64.0
#: Overlap of neighbouring pieces, as a fraction of the piece length (on each side of an edge).
BLEND_FRACTION = 0.05
#: Degree-9 smoothstep on [0, 1]: 0 -> 1 with zero derivatives of orders 1..4 at both ends (C^4).
_SMOOTHSTEP = np.polynomial.Polynomial(
    [0.0] * 5 + [comb(4 + j, j) * comb(9, 4 - j) * (-1.0) ** j for j in range(5)])


def _check_window(window) -> tuple[float, float]:
    """``window = (lo, hi)`` (seconds after the epoch) as floats; :class:`ProblemError` unless
    both are finite and ``lo < hi``."""
    try:
        w_lo, w_hi = (float(w) for w in window)
    except (TypeError, ValueError) as err:
        raise ProblemError(f"window must be (lo, hi) seconds with lo < hi; got {window!r}") from err
    if not (np.isfinite(w_lo) and np.isfinite(w_hi) and w_lo < w_hi):
        raise ProblemError(f"window must be (lo, hi) seconds with lo < hi; got {window!r}")
    return w_lo, w_hi


def _smoothstep_expr(s):
    """:data:`_SMOOTHSTEP` as a CasADi expression (Horner)."""
    out = 0.0
    for c in _SMOOTHSTEP.coef[::-1]:
        out = out * s + c
    return out


def _piece_deriv(fit: EphemerisFit, body: str, origin: str, j: int, x, k: int) -> np.ndarray:
    """``k``-th time derivative (km/s^k) of piece ``j`` of ``body - origin`` at ``x`` days."""
    lo, hi = fit.piece_bounds_days[j]
    C = fit._matrix(body, origin, j)
    if k:
        C = cheb.chebder(C, m=k, axis=1, scl=2.0 / ((hi - lo) * SECONDS_PER_DAY))
    return cheb.chebval((2.0 * x - (lo + hi)) / (hi - lo), C.T).T


def _basis(tau, degree: int):
    """Column ``[T_0(tau), ..., T_degree(tau)]`` of Chebyshev polynomials (SX/MX ``tau``)."""
    T = [1.0 + 0.0 * tau, tau]
    for _ in range(2, degree + 1):
        T.append(2.0 * tau * T[-1] - T[-2])
    return ca.vertcat(*T[:degree + 1])


@lru_cache(maxsize=32)
def _cached_fit(bodies: tuple, epoch: tuple, span, tol_km: float, max_degree: int):
    return EphemerisFit(bodies, epoch, span, tol_km=tol_km, max_degree=max_degree)


def ephemeris_fit(bodies: Iterable[str], epoch_tdb: str | float, span_days,
                  *, tol_km: float = 1e-5, max_degree: int = 64) -> EphemerisFit:
    """Cached :class:`EphemerisFit` keyed by (bodies, epoch, span, tolerance): fit once per problem."""
    key_b = tuple(sorted({check_body(b, BODIES, "bodies entry") for b in bodies}))
    ep = parse_epoch(epoch_tdb)
    span = float(span_days) if np.ndim(span_days) == 0 else tuple(float(s) for s in span_days)
    return _cached_fit(key_b, ep, span, float(tol_km), int(max_degree))


class CircularEarthMoon:
    """Stand-in ephemeris: Earth and Moon on circular orbits about a fixed barycentre (at the SSB).

    The Earth-Moon vector is ``a [cos(n t), sin(n t), 0]`` in the ICRF x-y plane with
    ``n = sqrt((GM_E + GM_M) / a^3)`` (Kepler), so in the synodic frame of Foss Eq. 6 the dynamics
    reduce to the CR3BP.  For tests and for comparisons with :mod:`ocreach.models.cr3bp`.
    Same interface as :class:`EphemerisFit` (``position_expr``, ``position``, ``gm``).
    """

    bodies = ("earth", "moon")

    def __init__(self, distance_km: float = 384400.0, *, gm_earth: float | None = None,
                 gm_moon: float | None = None, span_days=(-1e6, 1e6)) -> None:
        if not float(distance_km) > 0:
            raise ProblemError(f"distance_km must be > 0; got {distance_km!r}")
        self.a = float(distance_km)
        self._gm = {"earth": gm("earth") if gm_earth is None else float(gm_earth),
                    "moon": gm("moon") if gm_moon is None else float(gm_moon)}
        self.n = np.sqrt((self._gm["earth"] + self._gm["moon"]) / self.a**3)  # rad/s
        self.span_days = tuple(span_days)

    def gm(self, body: str) -> float:
        return self._gm[check_body(body, self.bodies, "body")]

    def _share(self, body: str) -> float:
        body = check_body(body, ("earth", "moon", "emb", "ssb"), "body")
        total = self._gm["earth"] + self._gm["moon"]
        return {"earth": -self._gm["moon"] / total, "moon": self._gm["earth"] / total,
                "emb": 0.0, "ssb": 0.0}[body]

    def position_expr(self, body: str, t: ca.SX | ca.MX, origin: str = "ssb", *,
                      frame: str = "icrf", window: tuple[float, float] | None = None
                      ) -> ca.SX | ca.MX:
        """One smooth expression for all ``t`` (``window``, as in
        :meth:`EphemerisFit.position_expr`, changes nothing)."""
        if check_body(frame, FRAMES, "frame") != "icrf":
            raise ProblemError(f"CircularEarthMoon supports frame='icrf' only; got frame={frame!r}")
        w = (self._share(body) - self._share(origin)) * self.a
        return ca.vertcat(w * ca.cos(self.n * t), w * ca.sin(self.n * t), 0.0 * t)

    def position(self, body: str, t, origin: str = "ssb", *, derivative: int = 0,
                 frame: str = "icrf") -> np.ndarray:
        if check_body(frame, FRAMES, "frame") != "icrf":
            raise ProblemError(f"CircularEarthMoon supports frame='icrf' only; got frame={frame!r}")
        t = np.asarray(t, dtype=float)
        w = (self._share(body) - self._share(origin)) * self.a * self.n**derivative
        ph = self.n * t + derivative * np.pi / 2
        return np.stack([w * np.cos(ph), w * np.sin(ph), 0.0 * t], axis=-1)
