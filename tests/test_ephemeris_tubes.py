"""Drift tubes along the ephemeris-corrected (non-periodic) reference, and event-triggered / tube
MPC on the DE421 plant with that reference (ocreach.control.stationkeeping.ephemeris_tubes)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ocreach.control.stationkeeping.ephemeris_reference import ephemeris_reference
from ocreach.control.stationkeeping.ephemeris_tubes import along_reference_schedule, interval_tubes
from ocreach.control.stationkeeping.paper import PAPER_W, paper_initial_set
from ocreach.control.stationkeeping.runs import run_station_keeping
from ocreach.control.stationkeeping.tubes import Tube, TubeSchedule
from ocreach.errors import ProblemError
from ocreach.registry import get_problem


@pytest.fixture(scope="module")
def nrho():
    return get_problem("nrho-9-2")


@pytest.fixture(scope="module")
def eph(nrho):
    return ephemeris_reference(nrho, 0.3)  # the orbit corrected over 2 revolutions


def test_tube_along_the_corrected_reference_contains_independent_drift(nrho, eph):
    """Zero-thrust samples from the corners and the inside of the initial deviation set,
    integrated with SciPy on the plant's own Moon-centred ICRF right-hand side (not the rotating
    frame model, restricted to the interval, that the tube is computed in), stay in the
    guaranteed tube at every step."""
    ref, orbit = eph
    end = 21
    G0 = paper_initial_set(nrho)
    sched = along_reference_schedule(nrho, ref, G0, PAPER_W, "taylor", end=end,
                                     model_on=orbit.plant.frame_model_on)
    tubes = [sched.tube(int(r)) for r in sched.refresh_steps(end)]
    assert sched.refresh_step(0) == 0 and all(t.guaranteed for t in tubes)
    assert all("taylor" in t.source for t in tubes)
    g = _plant_drift_gauges(orbit.plant, ref, sched, G0, end, seed=11)
    # corners start on the boundary (gauge 1 at step 0, up to the rounding of the ICRF round
    # trip: ~1e-15 here) and stay within 3e-4 of it: a tight test of the enclosure
    assert g.max() <= 1.0 + 1e-9, g.max()
    assert g.max(axis=1).min() > 0.05  # the samples are not trivially at the centres


def _plant_drift_gauges(plant, ref, sched, G0, end, seed):
    """Gauges (samples x steps) in ``sched`` of zero-thrust drift from the corners and the inside
    of ``x_ref(0) + G0 [-1, 1]^6``, integrated with SciPy on the plant's own Moon-centred ICRF
    right-hand side (not the rotating frame model, restricted to an interval, that the tubes are
    computed in), steps ``0 .. end - 1``."""
    f, p = plant.model.f_fun, np.asarray(plant.model.p_default, float)

    def rhs(t, y):
        return np.asarray(f(y, np.zeros(3), t - plant.t0, p)).ravel()

    rng = np.random.default_rng(seed)
    signs = np.vstack([rng.choice([-1.0, 1.0], size=(6, 6)), rng.uniform(-1, 1, size=(4, 6))])
    ts = ref.time(np.arange(end))
    out = []
    for s in signs:
        x0 = ref.state(0) + s * G0
        sol = solve_ivp(rhs, (ts[0], ts[-1]), plant.to_inertial(ts[0], x0), t_eval=ts,
                        method="DOP853", rtol=1e-12, atol=1e-14)
        assert sol.success
        X = np.stack([plant.from_inertial(t, y) for t, y in zip(ts, sol.y.T, strict=True)])
        out.append([sched.gauge(k, X[k]) for k in range(end)])
    return np.array(out)


def test_event_and_tube_mpc_close_the_loop_on_the_corrected_reference(nrho):
    run = run_station_keeping(nrho, controllers=("event-mpc", "tube-mpc"), revolutions=0.12,
                              plant="ephemeris", reference="ephemeris")
    tubes = run.settings["tubes"]
    assert tubes and tubes[0]["refresh_step"] == 0
    assert run.schedule is not None and not run.reference.periodic
    # independent of the flag's formula: every step the run and its last MPC window reach is
    # covered by a taylor tube (no linear fallback) on the window model with its error bound,
    # and the plant's own drift from the initial set stays in it
    K, n_p = run.settings["n_steps"], run.settings["n_p"]
    sched = run.schedule
    reach = min(K + n_p, sched.end)
    used = {sched.refresh_step(k) for k in range(reach)}
    assert all("taylor" in sched.tube(r).source and "failed" not in sched.tube(r).source
               and "model_error" in sched.tube(r).meta for r in used)
    same_ref, orbit = ephemeris_reference(nrho, 0.12)  # the run's orbit and plant, recomputed
    np.testing.assert_array_equal(same_ref.X, run.reference.X)
    g = _plant_drift_gauges(orbit.plant, run.reference, sched, paper_initial_set(nrho), reach,
                            seed=5)
    assert g.max() <= 1.0 + 1e-9
    for name in ("event-mpc", "tube-mpc"):
        met = run.metrics[name]
        assert met["solver_failures"] == 0, name
        assert met["max_gauge"] is not None and np.isfinite(met["delta_v_mps"])
        assert met["tube_guaranteed"] is True
    ts = run.metrics["tube-mpc"]["terminal_set"]
    assert ts["alpha"] > 0 and ts["contraction"] < 1


def test_fallback_is_labelled_and_a_strict_sound_source_refuses(nrho, eph):
    ref, _ = eph
    G0 = paper_initial_set(nrho)
    why = "taylor refuses the model: an if_else whose condition depends on the state"

    def refused(t_lo, t_hi):
        raise ProblemError(why)

    (t,) = interval_tubes(nrho, ref, 3, 12, G0, PAPER_W, "taylor-or-linear", {}, refused)
    assert (t.k0, len(t), t.guaranteed) == (3, 9, False)
    assert t.meta["fallback_reason"] == why and "linear" in t.source
    with pytest.raises(ProblemError, match="taylor-or-linear"):
        interval_tubes(nrho, ref, 3, 12, G0, PAPER_W, "taylor", {}, refused)


def test_tube_options_may_cap_the_tube_count(nrho, eph):
    """``max_tubes`` in the tube options caps the restarts, as in the periodic schedule (review
    finding: it collided with the interval's own default, a bare TypeError)."""
    ref, orbit = eph
    tubes = interval_tubes(nrho, ref, 0, 5, paper_initial_set(nrho), PAPER_W, "taylor",
                           {"max_tubes": 4}, orbit.plant.frame_model_on)
    assert tubes[0].k0 == 0 and 1 <= len(tubes) <= 4 and all(t.guaranteed for t in tubes)


def test_fit_window_is_the_same_function_without_if_else():
    """The DE421 fit over 74 days has two pieces blended in time with if_else; restricted to a
    window on one side of (or inside) the blend it is the same polynomial, re-expanded on the
    window (equal up to rounding), with no if_else; a window across a blend boundary is one
    polynomial too, within its bound of the fit (it used to be refused)."""
    import casadi as ca

    from ocreach.ephemeris import SECONDS_PER_DAY, ephemeris_fit

    fit = ephemeris_fit(["earth", "moon", "sun"], "2026-01-01 00:00:00", 74.0)
    assert len(fit.coefficients) == 2
    e = fit.edges_days[1]
    t = ca.SX.sym("t")

    def fun(window=None):
        return ca.Function("r", [t], [fit.position_expr("moon", t, "earth", window=window)])

    def has_if_else(f):
        return any(f.instruction_id(k) == ca.OP_IF_ELSE_ZERO for k in range(f.n_instructions()))

    full = fun()
    assert has_if_else(full)
    for lo, hi in ((1.0, 8.0), (e - 0.5 * fit.blend_days, e + 0.5 * fit.blend_days),
                   (e + 2 * fit.blend_days, e + 9.0)):
        win = fun((lo * SECONDS_PER_DAY, hi * SECONDS_PER_DAY))
        assert not has_if_else(win)
        for d in np.linspace(lo, hi, 7):  # |r| ~ 4e5 km; the fit's own error is 4e-7 km
            np.testing.assert_allclose(np.asarray(win(d * SECONDS_PER_DAY)),
                                       np.asarray(full(d * SECONDS_PER_DAY)), rtol=0, atol=1e-8)
    W = ((e - 2 * fit.blend_days) * SECONDS_PER_DAY, e * SECONDS_PER_DAY)  # across e0
    win = fun(W)
    assert not has_if_else(win)
    bound = fit.window_error_bound("moon", "earth", *W)
    assert np.all(bound < 1e-7)
    for tk in np.linspace(*W, 7):
        np.testing.assert_array_less(np.abs(np.asarray(win(tk)) - np.asarray(full(tk))).ravel(),
                                     bound + 8 * np.spacing(4e5))
    with pytest.raises(ProblemError, match="window"):
        fun((2.0, 1.0))


def test_fit_window_interval_bound_encloses_the_fit_tightly():
    """The interval extension of the windowed fit over a sub-interval of the window contains the
    fit (:meth:`EphemerisFit.position`, the full two-piece expression's numeric twin) at 2001
    points of it, and is not much wider than its true variation, also near the start of a
    piece, where the degree-48 recurrence on the piece used to widen 2e4-7e4 times
    (docs/intervals.md "Ephemeris positions over a time interval")."""
    import casadi as ca

    from ocreach.ephemeris import SECONDS_PER_DAY, ephemeris_fit
    from ocreach.intervals import IntervalFunction

    fit = ephemeris_fit(["earth", "moon", "sun"], "2026-01-01 00:00:00", 74.0)
    e, d = fit.edges_days[1], fit.blend_days
    rng = np.random.default_rng(5)
    t = ca.SX.sym("t")
    # windows: at the start of piece 0, inside the blend, in piece 1 (days)
    for lo, hi in ((0.0, 6.6), (e - 0.5 * d, e + 0.5 * d), (e + 2 * d, e + 9.0)):
        for body, origin in (("earth", "moon"), ("sun", "moon")):
            expr = fit.position_expr(body, t, origin, window=(lo * SECONDS_PER_DAY,
                                                               hi * SECONDS_PER_DAY))
            f = IntervalFunction(ca.Function("r", [t], [expr]))
            for _ in range(4):
                width = rng.choice([0.01, 0.04])  # a 1-hour reference step is 0.042 d
                a = rng.uniform(lo, hi - width)
                (blo, bhi), = f([np.array([a * SECONDS_PER_DAY])],
                                [np.array([(a + width) * SECONDS_PER_DAY])])
                true = fit.position(body, np.linspace(a, a + width, 2001) * SECONDS_PER_DAY,
                                    origin)
                assert np.all(true >= blo.T) and np.all(true <= bhi.T), (body, lo, a)
                var = true.max(0) - true.min(0)
                # measured <= 6x near the window's ends (the piece's own basis: 2e4-7e4x)
                assert np.all(bhi.ravel() - blo.ravel() <= 10.0 * var + 1e-6), (body, lo, a)


def test_short_window_drops_the_noise_of_the_fit_values():
    """On windows of 7 hours the fit's values carry rounding noise of a few ulps of the
    position, absolute in every coordinate; the series keeps only the signal (it kept up to 57
    noise coefficients in its smallest row), so the interval bound over the window's first and
    last 0.01 d (where the recurrence widens most) contains 2001 samples of the fit and is at
    most 10 times their range (it was ~1e3-1e7 km wide), and the bound of the window's error
    stays at the rounding level."""
    import casadi as ca

    from ocreach.ephemeris import SECONDS_PER_DAY, ephemeris_fit
    from ocreach.intervals import IntervalFunction

    fit = ephemeris_fit(["earth", "moon", "sun"], "2026-01-01 00:00:00", 74.0)
    t = ca.SX.sym("t")
    for lo in (22.5, 35.5, 62.0):
        W = (lo * SECONDS_PER_DAY, (lo + 0.3) * SECONDS_PER_DAY)
        assert fit._window_matrix("earth", "moon", *W).shape[1] <= 12
        assert np.all(fit.window_error_bound("earth", "moon", *W) < 1e-8)
        f = IntervalFunction(ca.Function("r", [t], [fit.position_expr("earth", t, "moon",
                                                                       window=W)]))
        for a in (lo, lo + 0.29):
            (blo, bhi), = f([np.array([a * SECONDS_PER_DAY])],
                            [np.array([(a + 0.01) * SECONDS_PER_DAY])])
            true = fit.position("earth", np.linspace(a, a + 0.01, 2001) * SECONDS_PER_DAY, "moon")
            assert np.all(true >= blo.T) and np.all(true <= bhi.T), (lo, a)
            var = true.max(0) - true.min(0)
            assert np.all(bhi.ravel() - blo.ravel() <= 10.0 * var + 1e-6), (lo, a, bhi - blo)


def test_non_periodic_schedule_refreshes_at_its_starts(eph):
    ref, _ = eph

    def build(r):
        n = {0: 5, 5: 7, 12: 8}[r]
        return Tube(ref.X[r: r + n], np.full((n, 6, 1), 1e-3), k0=r)

    sched = TubeSchedule(build, ref, starts=[0, 5, 12], end=20)
    assert [sched.refresh_step(k) for k in (0, 4, 5, 11, 12, 19)] == [0, 0, 5, 5, 12, 12]
    assert [sched.next_refresh(r) for r in (0, 5, 12)] == [5, 12, 20]
    assert sched.refresh_steps(100) == [0, 5, 12] and sched.interval == 8
    c, G = sched.window(3, 4)  # steps 4..7 across the refresh at 5
    np.testing.assert_array_equal(c, ref.X[4:8])
    with pytest.raises(ProblemError, match="0..19"):
        sched.tube(20)


def test_bad_input(nrho, eph):
    ref, _ = eph
    G0 = paper_initial_set(nrho)
    for starts in ([1, 5], [0, 5, 5], [0, 30], [], [0, 2.5], [0, True], [0, float("nan")],
                   [0, "a"], [0, None]):  # the last three gave a bare ValueError / TypeError
        with pytest.raises(ProblemError, match="starts"):
            TubeSchedule(lambda r: None, ref, starts=starts, end=20)
    with pytest.raises(ProblemError, match="end"):
        TubeSchedule(lambda r: None, ref, starts=[0], end=ref.n_steps + 1)
    with pytest.raises(ProblemError, match="not both"):
        TubeSchedule(lambda r: None, ref, starts=[0], interval=4)
    with pytest.raises(ProblemError, match="tube source"):
        along_reference_schedule(nrho, ref, G0, PAPER_W, "ode")
    for end in (1, 2.5, "x"):  # 2.5 was truncated to 2 and "x" a bare ValueError
        with pytest.raises(ProblemError, match="end"):
            along_reference_schedule(nrho, ref, G0, PAPER_W, "linear", end=end)
    with pytest.raises(ProblemError, match="tube_interval"):
        run_station_keeping(nrho, controllers=("event-mpc",), revolutions=0.1,
                            plant="ephemeris", reference="ephemeris", tube_interval=20)
    with pytest.raises(ProblemError, match="phase"):
        run_station_keeping(nrho, controllers=("tube-mpc",), revolutions=0.1,
                            plant="ephemeris", reference="ephemeris", phase=3)


def _clenshaw_exact(c, x):
    """``sum_j c_j T_j(x)`` in exact rational arithmetic."""
    from fractions import Fraction

    b1 = b2 = Fraction(0)
    for ck in reversed(list(c)[1:]):
        b1, b2 = Fraction(float(ck)) + 2 * x * b1 - b2, b1
    return Fraction(float(c[0])) + x * b1 - b2


def _fit_exact(fit, body, origin, t):
    """The fit of ``position_expr`` (no window) at ``t`` seconds in exact arithmetic on its float
    constants, read off its definition (piece polynomials, smoothstep blend) independently of
    :mod:`ocreach.ephemeris.exact_chebyshev`."""
    from fractions import Fraction

    from ocreach.ephemeris.de421 import SECONDS_PER_DAY
    from ocreach.ephemeris.fit import _SMOOTHSTEP

    def piece(k):
        lo, hi = (v * SECONDS_PER_DAY for v in fit.piece_bounds_days[k])
        tau = (2 * t - Fraction(lo + hi)) / Fraction(hi - lo)
        return [_clenshaw_exact(row, tau) for row in fit._matrix(body, origin, k)]

    out = piece(0)
    for k in range(1, len(fit.coefficients)):
        e0, e1 = fit._blend_seconds(k)
        if t < Fraction(e0):
            continue
        nxt = piece(k)
        if t < Fraction(e1):
            u = (t - Fraction(e0)) / Fraction(e1 - e0)
            w = Fraction(0)
            for c in _SMOOTHSTEP.coef[::-1]:
                w = w * u + Fraction(float(c))
            out = [p + w * (q - p) for p, q in zip(out, nxt, strict=True)]
        else:
            out = nxt
    return out


def test_window_error_bound_covers_the_exact_difference():
    """:meth:`EphemerisFit.window_error_bound` >= the exact (rational arithmetic) difference
    between the fit and its re-expansion on a window at 161 points of the window (the ends
    included), for windows at a piece's start, inside the blend and after it; and it is tight
    (within 4x of the largest difference found).  The float differences of the two CasADi
    expressions are within the bound plus their own rounding (a few ulps of the position)."""
    from fractions import Fraction

    import casadi as ca

    from ocreach.ephemeris import SECONDS_PER_DAY, ephemeris_fit

    fit = ephemeris_fit(["earth", "moon", "sun"], "2026-01-01 00:00:00", 74.0)
    e, d = fit.edges_days[1], fit.blend_days
    t = ca.SX.sym("t")
    for lo, hi in ((0.0, 6.6), (e - 0.5 * d, e + 0.5 * d), (e + 2 * d, e + 9.0)):
        W = (lo * SECONDS_PER_DAY, hi * SECONDS_PER_DAY)
        ts = np.linspace(W[0], W[1], 161)
        for body in ("earth", "sun"):
            bound = fit.window_error_bound(body, "moon", *W)
            q = fit._window_matrix(body, "moon", *W)
            A, B = Fraction(W[0] + W[1]), Fraction(W[1] - W[0])
            worst = np.zeros(3)
            for tk in ts:
                tf = Fraction(float(tk))
                s = (2 * tf - A) / B
                diff = [p - _clenshaw_exact(row, s) for p, row in
                        zip(_fit_exact(fit, body, "moon", tf), q, strict=True)]
                worst = np.maximum(worst, [abs(float(v)) for v in diff])
            assert np.all(worst <= bound), (body, lo, worst, bound)
            assert np.all(bound <= 4.0 * worst + 1e-12), (body, lo, worst, bound)
            assert np.all(bound < 1e-6)  # km: the re-expansion is the fit up to ~1e-7 km
            win = ca.Function("q", [t], [fit.position_expr(body, t, "moon", window=W)])
            meas = np.abs(np.asarray(win(ts[None, :])).T - fit.position(body, ts, "moon"))
            ulp = np.spacing(np.abs(fit.position(body, ts, "moon")).max(0))
            assert np.all(meas.max(0) <= bound + 8 * ulp), (body, lo)


def test_window_error_bound_of_the_second_derivative():
    """The k = 2 bound covers the exact second derivative of the difference (rational Chebyshev
    differentiation of both series, the chain-rule factors exact) on a window inside one piece."""
    from fractions import Fraction

    from ocreach.ephemeris import SECONDS_PER_DAY, ephemeris_fit

    def der(c):  # Chebyshev derivative, exact
        c = [Fraction(float(v)) for v in c]
        n = len(c) - 1
        out = [Fraction(0)] * max(n, 1)
        for j in range(n, 0, -1):
            out[j - 1] = (out[j + 1] if j + 1 < n else 0) + 2 * j * c[j]
        out[0] /= 2
        return out

    fit = ephemeris_fit(["earth", "moon", "sun"], "2026-01-01 00:00:00", 74.0)
    W = (3.0 * SECONDS_PER_DAY, 7.5 * SECONDS_PER_DAY)
    bound = fit.window_error_bound("moon", "ssb", *W, derivative=2)
    lo, hi = (v * SECONDS_PER_DAY for v in fit.piece_bounds_days[0])
    Ap, Bp = Fraction(lo + hi), Fraction(hi - lo)
    Aw, Bw = Fraction(W[0] + W[1]), Fraction(W[1] - W[0])
    P = [der(der(r)) for r in fit._matrix("moon", "ssb", 0)]
    Q = [der(der(r)) for r in fit._window_matrix("moon", "ssb", *W)]
    worst = np.zeros(3)
    for tk in np.linspace(W[0], W[1], 61):
        tf = Fraction(float(tk))
        tau, s = (2 * tf - Ap) / Bp, (2 * tf - Aw) / Bw
        diff = [_clenshaw_exact(p, tau) * (2 / Bp) ** 2 - _clenshaw_exact(q, s) * (2 / Bw) ** 2
                for p, q in zip(P, Q, strict=True)]
        worst = np.maximum(worst, [abs(float(v)) for v in diff])
    assert np.all(worst <= bound) and np.all(worst > 0), (worst, bound)


def test_window_error_bound_across_blend_boundaries():
    """A window across the start (e0) or the end (e1) of the blend of two fit pieces, or over
    the whole blend, is one polynomial (no if_else) whose bound (the largest over the branches
    it meets, each on its own sub-window) covers the fit: against the exact (rational
    arithmetic) difference at points on both sides of each boundary, and against 4001 float
    samples of the value (plus the float evaluation's rounding, a few ulps) and of the first and
    second derivatives (the CasADi jacobians of the window expression against the fit's exact
    derivatives); and it is tight (within 8x of the largest sampled difference; measured
    1.1-5.8x).  The old code refused these windows."""
    from fractions import Fraction

    import casadi as ca

    from ocreach.ephemeris import SECONDS_PER_DAY, ephemeris_fit

    fit = ephemeris_fit(["earth", "moon", "sun"], "2026-01-01 00:00:00", 74.0)
    e0, e1 = fit._blend_seconds(1)
    day = SECONDS_PER_DAY
    t = ca.SX.sym("t")
    for W in ((e0 - 3 * day, e0 + 3 * day), (e1 - 3 * day, e1 + 3 * day),
              (e0 - day, e1 + 1.5 * day)):
        ts = np.linspace(W[0], W[1], 4001)
        A, B = Fraction(W[0] + W[1]), Fraction(W[1] - W[0])
        exact_ts = [tk for b in (e0, e1) for tk in (b - 600.0, b, b + 600.0)
                    if W[0] <= tk <= W[1]] + [W[0], W[1]]
        for body, origin in (("earth", "moon"), ("sun", "moon"), ("moon", "ssb")):
            expr = fit.position_expr(body, t, origin, window=W)
            q = fit._window_matrix(body, origin, *W)
            bounds = [fit.window_error_bound(body, origin, *W, derivative=k) for k in range(3)]
            worst = np.zeros(3)
            for tk in exact_ts:
                tf = Fraction(float(tk))
                s = (2 * tf - A) / B
                diff = [p - _clenshaw_exact(row, s) for p, row in
                        zip(_fit_exact(fit, body, origin, tf), q, strict=True)]
                worst = np.maximum(worst, [abs(float(v)) for v in diff])
            assert np.all(worst <= bounds[0]), (body, W, worst, bounds[0])
            for k in range(3):
                f = ca.Function("q", [t], [expr])
                meas = np.abs(np.asarray(f(ts[None, :])).T
                              - fit.position(body, ts, origin, derivative=k)).max(0)
                slack = 8 * np.spacing(np.abs(fit.position(body, ts, origin)).max(0)) if k == 0 \
                    else 0.0
                assert np.all(meas <= bounds[k] + slack), (body, W, k, meas, bounds[k])
                assert bounds[k].max() <= 8.0 * meas.max(), (body, W, k, meas, bounds[k])
                expr = ca.jacobian(expr, t)
            assert np.all(bounds[0] < 1e-6)  # km: the window is the fit up to ~1e-7 km


def test_interval_tubes_across_a_blend_are_guaranteed(nrho, eph):
    """On a plant whose DE421 fit has two pieces (74 days), the corrected reference's first
    8 steps moved in time so that the interval's window reaches across the start, then the end,
    of the blend: the ``taylor`` tubes are guaranteed (the old code raised for ``taylor`` and
    fell back to the linearised tube for ``taylor-or-linear``), carry the window's model error,
    and contain zero-thrust drift from the corners and the inside of the initial set integrated
    with SciPy on the plant's own right-hand side (the full fit, with its if_else)."""
    import dataclasses

    from ocreach.control.stationkeeping.ephemeris_plant import EphemerisPlant

    ref, _ = eph
    plant = EphemerisPlant(ref, "ball", nrho.velocity_dims, span_days=74.0)
    assert len(plant.ephemeris.coefficients) == 2
    G0, end = paper_initial_set(nrho), 9
    for boundary in plant.ephemeris._blend_seconds(1):
        t0 = boundary / plant.units.time - 3.5 * ref.dt  # steps 3 and 4 straddle the boundary
        moved = dataclasses.replace(ref, t0=t0, model=plant.frame_model(), A=None, B=None,
                                    cache={})
        sched = along_reference_schedule(nrho, moved, G0, PAPER_W, "taylor-or-linear", end=end,
                                         model_on=plant.frame_model_on)
        tubes = [sched.tube(int(r)) for r in sched.refresh_steps(end)]
        assert all(t.guaranteed and "taylor" in t.source for t in tubes), \
            [(t.source, t.meta.get("fallback_reason")) for t in tubes]
        assert all(0 < t.meta["model_error"]["acceleration"] < 1e-12 for t in tubes)
        g = _plant_drift_gauges(plant, moved, sched, G0, end, seed=11)
        assert g.max() <= 1.0 + 1e-9, g.max()
        assert g.max(axis=1).min() > 0.05


def test_window_model_acceleration_error_is_bounded(nrho, eph):
    """The frame model restricted to a window differs from the plant's full frame model by at
    most its ``window_error["acceleration"]`` at states within ``radius`` of the Moon (the
    reference's states and random ones up to the radius) and times across the window; and the
    sound tubes carry the widened disturbance (``meta["model_error"]``)."""
    ref, orbit = eph
    plant = orbit.plant
    full = plant.frame_model()
    p = np.array(ref.params, float)
    rng = np.random.default_rng(3)
    # 40 steps (1.7 d), and the whole reference (314 steps, 13 d: the radius must not shrink
    # with the window, as it did with one interval box over the Earth's whole arc: 0 DU here)
    for last in (40, ref.n_steps):
        t_lo, t_hi = float(ref.time(0)), float(ref.time(last))
        win = plant.frame_model_on(t_lo, t_hi)
        err = win.cache["window_error"]
        assert 0 < err["acceleration"] < 1e-12 and 0.4 < err["radius"] < 0.6, err
        centre = np.array(err["centre"])
        worst = 0.0
        for t in np.linspace(t_lo, t_hi, 41):
            xs = [ref.state(int(np.argmin(np.abs(ref.time(np.arange(last + 1)) - t))))]
            for _ in range(4):
                d = rng.normal(size=3)
                r = centre + d / np.linalg.norm(d) * rng.uniform(0.05, 1.0) * err["radius"]
                xs.append(np.concatenate([r, rng.normal(size=3)]))
            for x in xs:
                a = np.asarray(full.f_fun(x, np.zeros(3), t, p)).ravel()
                b = np.asarray(win.f_fun(x, np.zeros(3), t, p)).ravel()
                worst = max(worst, float(np.linalg.norm(a - b)))
        assert worst <= err["acceleration"], (worst, err)
        assert worst > 0  # the two models do differ (the test measures something)
    tubes = interval_tubes(nrho, ref, 0, 5, paper_initial_set(nrho), PAPER_W, "taylor",
                           {"max_tubes": 4}, plant.frame_model_on)
    for t in tubes:
        me = t.meta["model_error"]
        assert me["acceleration"] > 0 and me["max_distance"] < me["radius"]


def test_finite_horizon_terminal_set_is_the_one_at_the_horizon_end(nrho, eph):
    """Along the non-periodic corrected reference the tube MPC's terminal set of the solve at
    step ``k`` is ``P_(k+N) / alpha``, ``P`` the finite-horizon Riccati solution from ``P_M = Q``
    computed here independently (the textbook form ``Q + A'PA - A'PB (R + B'PB)^-1 B'PA``); the
    neighbouring steps' matrices differ by far more than the tolerance, so an index off by one
    is detected.  The LQR's cost-to-go refuses steps past the reference's end."""
    from ocreach.control.report import PAPER_Q, paper_pattern
    from ocreach.control.stationkeeping.tube_mpc import TubeMPC

    ref, _ = eph
    N = 15
    sched = along_reference_schedule(nrho, ref, paper_initial_set(nrho), PAPER_W, "linear")
    ctl = TubeMPC(paper_pattern(nrho, PAPER_Q[0], PAPER_Q[3]), np.ones(3), sched,
                  disturbance=PAPER_W, velocity_dims=nrho.velocity_dims, n_p=N)
    ctl.setup(ref, nrho.control_set.kind)
    tl = ctl.mpc.terminal_lqr
    M = ref.n_steps
    A, B, Q, R = ref.A, ref.B, tl.Q, tl.R
    P = [None] * (M + 1)
    P[M] = Q
    for k in range(M - 1, -1, -1):
        Pn = P[k + 1]
        S = R + B[k].T @ Pn @ B[k]
        P[k] = Q + A[k].T @ Pn @ A[k] - A[k].T @ Pn @ B[k] @ np.linalg.solve(S, B[k].T @ Pn @ A[k])
    S_last = ctl.n_starts - 1
    for k in (0, S_last // 2, S_last):
        Pf = ctl.terminal_matrix(k) * ctl.terminal_alpha
        scale = np.abs(P[k + N]).max()
        assert np.abs(Pf - P[k + N]).max() <= 1e-7 * scale, k
        for off in (-1, 1):
            assert np.abs(P[k + N + off] - P[k + N]).max() > 1e-4 * scale, (k, off)
        np.testing.assert_allclose(ctl.mpc.terminal_weight(k), Pf, rtol=0, atol=1e-12 * scale)
    np.testing.assert_array_equal(tl.cost_to_go(M), Q)
    for bad in (M + 1, -1, 2.5):
        with pytest.raises(ProblemError, match="cost_to_go"):
            tl.cost_to_go(bad)


def test_window_model_error_with_the_ephemeris_frame_acceleration(nrho, eph):
    """With ``frame_acceleration="ephemeris"`` the origin's term is the second derivative of the
    Moon's re-expanded position, which the window changes far more than the positions (measured
    7e-9 DU/TU^2, 7 % of the paper's W): the bound (the k = 2 bound of the fit) covers the
    difference of the two frame models at sampled states and times, and is tight (within 2x)."""
    from ocreach.control.stationkeeping.ephemeris_plant import EphemerisPlant

    ref, _ = eph
    plant = EphemerisPlant(ref, "ball", nrho.velocity_dims, span_days=14.0,
                           frame_acceleration="ephemeris")
    t_lo, t_hi = float(ref.time(0)), float(ref.time(100))
    win = plant.frame_model_on(t_lo, t_hi)
    err = win.cache["window_error"]
    full = plant.frame_model()
    p = np.array(ref.params, float)
    rng = np.random.default_rng(1)
    worst = 0.0
    for t in np.linspace(t_lo, t_hi, 41):
        for _ in range(5):
            d = rng.normal(size=3)
            r = np.array(err["centre"]) + d / np.linalg.norm(d) * rng.uniform(0.05, 1.0) \
                * err["radius"]
            x = np.concatenate([r, rng.normal(size=3)])
            a = np.asarray(full.f_fun(x, np.zeros(3), t, p)).ravel()
            b = np.asarray(win.f_fun(x, np.zeros(3), t, p)).ravel()
            worst = max(worst, float(np.linalg.norm(a - b)))
    assert 0.5 * err["acceleration"] <= worst <= err["acceleration"], (worst, err)


def test_window_error_bound_bad_input():
    """A reversed, empty or non-finite window and a derivative order that is not an integer >= 0
    raise a ProblemError naming the parameter (a reversed window used to return numbers, the
    empty one a ZeroDivisionError, derivative=-1 or 1.5 a silently meaningless "bound")."""
    from ocreach.ephemeris import SECONDS_PER_DAY, ephemeris_fit

    fit = ephemeris_fit(["earth", "moon", "sun"], "2026-01-01 00:00:00", 74.0)
    W = (1.0 * SECONDS_PER_DAY, 2.0 * SECONDS_PER_DAY)
    for lo, hi in ((W[1], W[0]), (W[0], W[0]), (np.nan, W[1]), (W[0], np.inf)):
        with pytest.raises(ProblemError, match="window must be"):
            fit.window_error_bound("earth", "moon", lo, hi)
    for k in (-1, 1.5, True, "2"):
        with pytest.raises(ProblemError, match="derivative"):
            fit.window_error_bound("earth", "moon", *W, derivative=k)
    assert np.all(fit.window_error_bound("earth", "moon", *W, derivative=2.0) > 0)


def test_window_error_bound_of_derivatives_inside_the_blend():
    """The k = 1, 2 bounds on a window inside the blend of two pieces (the smoothstep product's
    derivatives) cover the exact derivatives of the difference, from central differences of the
    difference evaluated in rational arithmetic (step 1e-3 s: the difference's higher
    derivatives make the truncation ~1e-25 of the values) at 13 points, and (largest
    coordinate) within 3x of them."""
    from fractions import Fraction

    from ocreach.ephemeris import SECONDS_PER_DAY, ephemeris_fit

    fit = ephemeris_fit(["earth", "moon", "sun"], "2026-01-01 00:00:00", 74.0)
    e, d = fit.edges_days[1], fit.blend_days
    W = ((e - 0.9 * d) * SECONDS_PER_DAY, (e + 0.9 * d) * SECONDS_PER_DAY)
    A, B = Fraction(W[0] + W[1]), Fraction(W[1] - W[0])
    h = Fraction(1, 1000)
    for body, origin in (("sun", "moon"), ("moon", "ssb")):
        q = fit._window_matrix(body, origin, *W)

        def diff(t, body=body, origin=origin, q=q):
            s = (2 * t - A) / B
            return [p - _clenshaw_exact(row, s) for p, row in
                    zip(_fit_exact(fit, body, origin, t), q, strict=True)]

        worst = np.zeros((2, 3))
        for tk in np.linspace(W[0] + 1.0, W[1] - 1.0, 13):
            t = Fraction(float(tk))
            a, m, b = diff(t + h), diff(t), diff(t - h)
            d1 = [(x - z) / (2 * h) for x, z in zip(a, b, strict=True)]
            d2 = [(x - 2 * y + z) / h**2 for x, y, z in zip(a, m, b, strict=True)]
            worst = np.maximum(worst, [[abs(float(v)) for v in d1], [abs(float(v)) for v in d2]])
        for k in (1, 2):
            bound = fit.window_error_bound(body, origin, *W, derivative=k)
            assert np.all(worst[k - 1] <= bound), (body, k, worst[k - 1], bound)
            assert bound.max() <= 3.0 * worst[k - 1].max(), (body, k, worst[k - 1], bound)


def test_model_error_widens_w_and_is_checked_against_the_flowpipe(nrho):
    """``with_model_error`` adds the acceleration bound to every velocity rate, whatever form W
    has (number, radii, zonotope, None), and leaves W alone without an error;
    ``checked_model_error`` raises when the flowpipe's box reaches the radius (a corner, not a
    face, being the farthest point) or is missing, and records the distance otherwise."""
    from ocreach.control.stationkeeping.ephemeris_tubes import checked_model_error, with_model_error
    from ocreach.errors import SolverError
    from ocreach.reach.taylor import disturbance_zonotope
    from ocreach.sets import Zonotope

    vd = list(nrho.velocity_dims)
    pos = [i for i in range(6) if i not in vd]
    err = {"acceleration": 2e-9, "radius": 0.5, "centre": [0.98, 0.0, 0.0],
           "position_km": {"earth": 1e-9}}
    assert with_model_error(nrho, 1e-7, None) == 1e-7
    assert with_model_error(nrho, 1e-7, {**err, "acceleration": 0.0}) == 1e-7
    assert with_model_error(nrho, 1e-7, err) == 1e-7 + 2e-9
    radii = np.arange(1.0, 7.0) * 1e-8
    for W in (None, radii, Zonotope(np.zeros(6), np.diag(radii))):
        got = disturbance_zonotope(nrho, with_model_error(nrho, W, err))
        base = np.zeros(6) if W is None else np.abs(disturbance_zonotope(nrho, W).G).sum(axis=1)
        extra = np.abs(got.G).sum(axis=1) - base
        np.testing.assert_allclose(extra[vd], 2e-9, rtol=1e-12)
        np.testing.assert_array_equal(extra[pos], 0.0)

    def tube(lo, hi):
        c = np.array([[0.98, 0.0, 0.0, 0.0, 0.0, 0.0]] * 2)
        return Tube(c, np.zeros((2, 6, 1)), k0=3, guaranteed=True, source="taylor",
                    meta={"flowpipe_hull": [lo + [0.0] * 3, hi + [0.0] * 3]})

    ok = checked_model_error(tube([0.98 - 0.28, -0.28, -0.28], [0.98 + 0.1, 0.1, 0.1]), err)
    assert ok.meta["model_error"]["max_distance"] == pytest.approx(0.28 * 3**0.5)
    assert ok.guaranteed and ok.k0 == 3 and ok.meta["flowpipe_hull"]
    # every face within 0.3 of the centre, the corner 0.52 away: refused
    with pytest.raises(SolverError, match="from step 3 reaches"):
        checked_model_error(tube([0.98 - 0.3, -0.3, -0.3], [0.98 + 0.3, 0.3, 0.3]), err)
    with pytest.raises(SolverError, match="no flowpipe"):
        checked_model_error(Tube(np.zeros((1, 6)), np.zeros((1, 6, 1)), k0=3), err)
    assert checked_model_error(ok, None) is ok
