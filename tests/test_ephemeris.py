"""Ephemeris data layer and ephemeris dynamics (Patel & Scheeres Eq. 11, Foss et al. Eq. 6).

Truth used here: direct jplephem evaluation of DE421 (``jplephem.Ephemeris(de421)``), central finite
differences, the CR3BP model, an SSB-inertial propagation (no frame terms) against the synodic one,
two-body energy and the closed-form inverse-mass solution ``n(t) = n0 / (1 - k n0 t)``.
"""
from __future__ import annotations

import casadi as ca
import de421
import jplephem
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ocreach.ephemeris import (
    ECLIPJ2000_FROM_ICRF,
    EphemerisFit,
    ephemeris_fit,
    epoch_from_et,
    gm,
    parse_epoch,
)
from ocreach.errors import ProblemError
from ocreach.models.cr3bp import cr3bp
from ocreach.models.ephemeris import (
    ephemeris_inertial,
    ephemeris_synodic,
    inertial_state_from_si,
    inertial_to_synodic,
    synodic_to_inertial,
)
from ocreach.units import EARTH_MOON_FOSS, Units

FOSS_EPOCH = "2024-05-01 12:00:00"
FOSS_X0 = np.array([0.91, -0.01, 0.16, 0.03, -0.08, 0.01])  # Foss Sec. 4.2
DAY = 86400.0


@pytest.fixture(scope="module")
def jpl():
    return jplephem.Ephemeris(de421)


def _jpl_ssb(jpl, body, jd_day, days):
    """Direct DE421 position (km) and velocity (km/s) of ``body`` w.r.t. the SSB."""
    es = 1.0 / (1.0 + jpl.EMRAT)
    if body in ("earth", "moon"):
        pe, ve = jpl.position_and_velocity("earthmoon", jd_day, days)
        pm, vm = jpl.position_and_velocity("moon", jd_day, days)
        w = -es if body == "earth" else 1.0 - es
        p, v = pe + w * pm, ve + w * vm
    else:
        p, v = jpl.position_and_velocity(body, jd_day, days)
    return p.T, v.T / DAY


def _integrate(model, x0, t1, u=None, p=None, rtol=1e-12, atol=1e-12):
    u = np.zeros(model.n_u) if u is None else u
    p = model.p_default if p is None else p
    f = model.f_fun
    sol = solve_ivp(lambda t, x: np.asarray(f(x, u, t, p)).ravel(), (0.0, t1), x0,
                    method="DOP853", rtol=rtol, atol=atol)
    assert sol.success, sol.message
    return sol.y[:, -1]


# ------------------------------------------------------------------------------- data layer
@pytest.mark.parametrize("epoch, span", [
    (FOSS_EPOCH, 4.4),                           # Foss Sec. 4.2: t in [0, 1] TU ~ 4.3 d
    (epoch_from_et(1072864.169), 16.7),          # Patel & Scheeres case 2: 200 x 7200 s
    (epoch_from_et(2512864.169), -16.7),         # case 3, backwards in time
    ("2030-02-10 03:00", (-10.0, 80.0)),         # long span -> several pieces
])
def test_fit_matches_jplephem(jpl, epoch, span):
    fit = EphemerisFit(["sun", "earth", "moon", "venus"], epoch, span)
    jd_day, frac = fit.epoch
    days = np.linspace(*fit.fit_days, 1501)
    t = days * DAY
    for body in ("sun", "earth", "moon", "venus"):
        p_true, v_true = _jpl_ssb(jpl, body, jd_day, frac + days)
        assert np.abs(fit.position(body, t) - p_true).max() < 1e-3  # < 1 m
        assert np.abs(fit.velocity(body, t) - v_true).max() < 1e-7  # < 0.1 mm/s
    pm, vm = jpl.position_and_velocity("moon", jd_day, frac + days)  # geocentric Moon
    assert np.abs(fit.position("moon", t, "earth") - pm.T).max() < 1e-3
    assert np.abs(fit.velocity("moon", t, "earth") - vm.T / DAY).max() < 1e-7
    # ecliptic axes are a fixed rotation of ICRF
    np.testing.assert_allclose(fit.position("moon", t[:5], "earth", frame="eclipj2000"),
                               pm.T[:5] @ ECLIPJ2000_FROM_ICRF.T, atol=1e-3)


def test_expression_and_its_derivatives():
    fit = EphemerisFit(["earth", "moon", "sun"], "2030-02-10 03:00", (-10.0, 80.0))
    assert len(fit.coefficients) > 1  # exercise the if_else piece selection
    t = ca.SX.sym("t")
    r = fit.position_expr("moon", t, "earth")
    d1 = ca.jacobian(r, t)
    d2 = ca.jacobian(d1, t)
    d3 = ca.jacobian(d2, t)
    F = ca.Function("F", [t], [r, d1, d2, d3])
    ts = np.linspace(-9.5, 79.5, 23) * DAY
    h = 5.0  # s; FD truncation ~ h^2/6 |r'| ~ 1e-10 km/s, rounding ~ 1e-16 |r| / h
    for tk in ts:
        r0, v0, a0, j0 = (np.asarray(x).ravel() for x in F(tk))
        np.testing.assert_allclose(r0, fit.position("moon", tk, "earth"), atol=1e-8, rtol=0)
        rp, vp, ap, _ = (np.asarray(x).ravel() for x in F(tk + h))
        rm, vm, am, _ = (np.asarray(x).ravel() for x in F(tk - h))
        for exact, fd in ((v0, (rp - rm) / (2 * h)), (a0, (vp - vm) / (2 * h)),
                          (j0, (ap - am) / (2 * h))):
            assert np.linalg.norm(exact - fd) < 1e-7 * np.linalg.norm(exact)
        # Moon's geocentric acceleration is Kepler + solar tide: within 1 % of GM/r^2
        g = (gm("earth") + gm("moon")) / np.linalg.norm(r0) ** 2
        assert abs(np.linalg.norm(a0) / g - 1) < 0.02


def test_epochs_and_cache():
    assert sum(parse_epoch("2000-01-01 12:00:00")) == 2451545.0
    assert sum(parse_epoch("2000-01-01T12:00:00 TDB")) == 2451545.0
    assert sum(epoch_from_et(0.0)) == 2451545.0
    assert sum(parse_epoch(2460432.0)) == 2460432.0
    a = ephemeris_fit(["moon", "earth"], FOSS_EPOCH, 4.4)
    assert ephemeris_fit(["earth", "moon"], FOSS_EPOCH, 4.4) is a
    m = ephemeris_synodic(["earth", "moon"], FOSS_EPOCH, 4.4)
    assert m.cache["ephemeris"] is a


def test_bad_inputs():
    with pytest.raises(ProblemError, match=r"1850-01-01.*1899-07-29.*2053-10-09"):
        EphemerisFit(["moon"], "1850-01-01", 10)
    with pytest.raises(ProblemError, match=r"2053-10-01.*30.*2053-10-09"):
        ephemeris_synodic(["earth", "moon"], "2053-10-01", 30, 0.1)
    with pytest.raises(ProblemError, match="epoch"):
        EphemerisFit(["moon"], "2024-13-01", 10)
    with pytest.raises(ProblemError, match="vulcan"):
        EphemerisFit(["vulcan"], FOSS_EPOCH, 10)
    with pytest.raises(ProblemError, match="span_days"):
        EphemerisFit(["moon"], FOSS_EPOCH, 0.0)
    for T in (0.0, -0.01):
        with pytest.raises(ProblemError, match="thrust"):
            ephemeris_inertial(["earth"], "earth", FOSS_EPOCH, 1, thrust=T, isp=3000, mass0=1000)
    with pytest.raises(ProblemError, match="isp"):
        ephemeris_inertial(["earth"], "earth", FOSS_EPOCH, 1, thrust=0.01, isp=0, mass0=1000)
    with pytest.raises(ProblemError, match="moon"):
        ephemeris_synodic(["earth", "sun"], FOSS_EPOCH, 1)
    fit = ephemeris_fit(["earth", "moon"], FOSS_EPOCH, 4.4)
    with pytest.raises(ProblemError, match="fitted interval"):
        fit.position("moon", 30 * DAY)
    with pytest.raises(ProblemError, match="not in this fit"):
        fit.position("sun", 0.0)


# ------------------------------------------------------------------------------ frame (b)
def test_synodic_circular_is_cr3bp():
    """Circular Earth-Moon stand-in: Foss Eq. 6 reduces to the CR3BP (Foss Eq. 5).

    With TU = sqrt(DU^3 / GM_EM) the two vector fields are identical (checked to 1e-12, i.e.
    rounding).  With Foss's rounded units (DU = 3.825e8 m, TU = 3.724e5 s),
    eps = 1 - GM_EM TU^2/DU^3 = 6.4e-5: gravity and centrifugal terms scale by (1 - eps), the
    Coriolis term by sqrt(1 - eps), so |f - f_cr3bp| <= eps (|g| + |x_xy| + |2 v|).
    """
    gem = gm("earth") + gm("moon")
    mu = gm("moon") / gem
    du = EARTH_MOON_FOSS.length / 1e3
    exact = Units(du * 1e3, float(np.sqrt(du**3 / gem)))
    m_exact = ephemeris_synodic(["earth", "moon"], FOSS_EPOCH, 1, circular=True, units=exact)
    m_foss = ephemeris_synodic(["earth", "moon"], FOSS_EPOCH, 1, circular=True)
    c = cr3bp(mu)
    eps = 1 - gem * EARTH_MOON_FOSS.time**2 / du**3
    assert 5e-5 < eps < 8e-5
    rng = np.random.default_rng(0)
    for _ in range(50):
        x = rng.uniform([-1.5, -1.5, -0.5, -1, -1, -1], [1.5, 1.5, 0.5, 1, 1, 1])
        t = rng.uniform(-3, 3)
        fc = c(x)
        np.testing.assert_allclose(m_exact(x, t=t), fc, rtol=0, atol=1e-12 * (1 + np.abs(fc).max()))
        coriolis = 2 * np.linalg.norm(x[3:5])
        grav = np.linalg.norm(fc[3:] - np.r_[x[0] + 2 * x[4], x[1] - 2 * x[3], 0.0])
        bound = eps * (grav + np.linalg.norm(x[:2]) + coriolis)
        assert np.linalg.norm(m_foss(x, t=t) - fc) <= 1.01 * bound
    # a trajectory (Foss's NRHO flyby state) over 1 TU agrees with the CR3BP flow
    xe = _integrate(m_exact, FOSS_X0, 1.0)
    xc = _integrate(c, FOSS_X0, 1.0)
    np.testing.assert_allclose(xe, xc, atol=1e-8)


FOSS_BODIES = ["sun", "earth", "moon", "venus"]
FOSS_SPAN = 1.1 * EARTH_MOON_FOSS.time / DAY  # days; Foss propagates 1 TU


@pytest.fixture(scope="module")
def foss_models():
    return {mode: ephemeris_synodic(FOSS_BODIES, FOSS_EPOCH, FOSS_SPAN, frame_acceleration=mode)
            for mode in ("ephemeris", "modelled")}


def test_synodic_matches_inertial_propagation(foss_models):
    """Foss Eq. 6 (rotating frame, EMB origin) against Newton in ICRF axes.

    The synodic model adds frame terms built from M, M', M'' and R_J'' by automatic
    differentiation; the SSB-centred inertial model has none.  With R_J'' from the ephemeris both
    describe the same motion: the propagated states must agree to integration accuracy (< 1 m,
    < 1 um/s after 1 TU = 4.3 d).  So must the Earth-centred model with the ephemeris frame
    acceleration.  With "modelled" frame accelerations the synodic and Earth-centred models both
    add the unmodelled bodies' pull on their origin (~20 km effect); they then agree to the
    difference of that pull on Earth and on the EMB (a tide, ~1e-11 m/s^2, ~1 m): bound 10 m.
    """
    units = Units(EARTH_MOON_FOSS.length, EARTH_MOON_FOSS.time)
    du, vu, T = units.length / 1e3, units.velocity / 1e3, units.time

    def inertial(central, mode):  # SSB-centred km, km/s after 1 TU, from the same initial state
        syn = foss_models["ephemeris"]
        fit = syn.cache["ephemeris"]
        s0 = synodic_to_inertial(syn, 0.0, FOSS_X0)
        o0 = np.zeros(6) if central == "ssb" else np.r_[fit.position(central, 0.0),
                                                        fit.velocity(central, 0.0)]
        m = ephemeris_inertial(FOSS_BODIES, central, FOSS_EPOCH, FOSS_SPAN, thrust=1e-3, isp=3000,
                               mass0=14, units=units, frame_acceleration=mode)
        x1 = _integrate(m, np.r_[(s0[:3] - o0[:3]) / du, (s0[3:] - o0[3:]) / vu, 1.0], 1.0)
        o1 = np.zeros(6) if central == "ssb" else np.r_[fit.position(central, T),
                                                        fit.velocity(central, T)]
        return np.r_[x1[:3] * du, x1[3:6] * vu] + o1

    def synodic(mode):
        syn = foss_models[mode]
        return synodic_to_inertial(syn, 1.0, _integrate(syn, FOSS_X0, 1.0))

    syn0 = foss_models["ephemeris"]
    s0 = synodic_to_inertial(syn0, 0.0, FOSS_X0)
    np.testing.assert_allclose(inertial_to_synodic(syn0, 0.0, s0[:3], s0[3:]), FOSS_X0,
                               atol=1e-12)
    ref = inertial("ssb", "ephemeris")
    for other in (synodic("ephemeris"), inertial("earth", "ephemeris")):
        assert np.abs(other[:3] - ref[:3]).max() < 1e-3
        assert np.abs(other[3:] - ref[3:]).max() < 1e-9
    a, b = synodic("modelled"), inertial("earth", "modelled")
    assert np.abs(a[:3] - b[:3]).max() < 1e-2
    assert 1.0 < np.abs(a[:3] - ref[:3]).max() < 100.0  # the unmodelled bodies' effect, km


def test_synodic_time_derivatives_and_tensors(foss_models):
    """f is smooth in t and in z: CasADi derivatives vs central differences."""
    syn = foss_models["ephemeris"]
    t = syn.t
    dfdt = ca.Function("dfdt", [syn.x, syn.u, t, syn.p], [ca.jacobian(syn.f, t)])
    x, u, p = FOSS_X0, np.array([0.2, -0.1, 0.3]), np.array([0.05])
    for tk in (0.1, 0.55, 0.95):
        h = 1e-4
        fd = (syn(x, u, tk + h, p) - syn(x, u, tk - h, p)) / (2 * h)
        np.testing.assert_allclose(np.asarray(dfdt(x, u, tk, p)).ravel(), fd, atol=1e-6)
    F = syn.tensors(x, u, 0.4, p, order=3)
    h = 1e-4
    for a in (0, 2, 4):
        e = np.zeros(syn.n_z)
        e[a] = h
        zp, zm = np.r_[x, u] + e, np.r_[x, u] - e
        F2p = syn.tensors(zp[:6], zp[6:], 0.4, p, order=2)[2]
        F2m = syn.tensors(zm[:6], zm[6:], 0.4, p, order=2)[2]
        np.testing.assert_allclose(F[3][:, :, :, a], (F2p - F2m) / (2 * h), rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------------------ frame (a)
def test_inertial_two_body_energy_and_mass():
    m = ephemeris_inertial(["earth"], "earth", FOSS_EPOCH, 10, thrust=0.01, isp=3000, mass0=1000)
    assert abs(m.units.time - np.sqrt(384400.0**3 / gm("earth"))) < 1e-6
    x0 = inertial_state_from_si(m, [0, 210820, 0], [0.753136347, 0, 0], 1000)  # Patel Fig. 1
    assert x0[-1] == 1.0
    t1 = 8 * DAY / m.units.time
    x1 = _integrate(m, x0, t1)

    def energy(x):
        return 0.5 * x[3:6] @ x[3:6] - 1.0 / np.linalg.norm(x[:3])

    assert abs(energy(x1) - energy(x0)) < 1e-10 * abs(energy(x0))
    assert x1[-1] == pytest.approx(1.0, abs=1e-14)  # no thrust, no mass flow
    # full thrust along a fixed direction: n(t) = n0 / (1 - k n0 t), k = T_max / c
    u = np.array([0.6, 0.0, 0.8])
    T, c = m.p_default
    x1 = _integrate(m, x0, t1, u=u)
    assert x1[-1] == pytest.approx(1.0 / (1.0 - T / c * t1), rel=1e-10)
    # physical check: Isp 3000 s, 0.01 N for 8 days burns m_dot t = 0.01/(g0 3000) 8 d = 2.35 kg
    mass1 = m.units.mass / x1[-1]
    assert mass1 == pytest.approx(1000 - 0.01 / (9.80665 * 3000) * 8 * DAY, rel=1e-9)


def test_inertial_acceleration_vs_jplephem(jpl):
    """Patel Eq. 11 with Sun and Moon, Earth origin, ecliptic axes: against numpy + jplephem."""
    epoch = epoch_from_et(1072864.169)
    m = ephemeris_inertial(["earth", "moon", "sun"], "earth", epoch, 16.7, thrust=0.02,
                           isp=3000, mass0=1000, frame="eclipj2000")
    du, tu = m.units.length / 1e3, m.units.time
    x = inertial_state_from_si(m, [-379476, 0, 0], [0, -0.561354689, 0], 1000)  # Patel Fig. 2
    u = np.array([0.0, 0.6, -0.8])
    for t_days in (0.0, 7.3, 16.0):
        f = m(x, u, t_days * DAY / tu)
        pe, _ = _jpl_ssb(jpl, "earth", epoch[0], epoch[1] + t_days)
        r = x[:3] * du  # km, ecliptic
        acc = -gm("earth") * r / np.linalg.norm(r) ** 3
        for b in ("moon", "sun"):
            pb, _ = _jpl_ssb(jpl, b, epoch[0], epoch[1] + t_days)
            rb = ECLIPJ2000_FROM_ICRF @ (pb - pe).ravel()
            acc += -gm(b) * ((r - rb) / np.linalg.norm(r - rb) ** 3 + rb / np.linalg.norm(rb) ** 3)
        acc += 0.02 / 1000 * u / 1e3  # thrust acceleration, km/s^2
        acc_model = f[3:6] * m.units.acceleration / 1e3
        np.testing.assert_allclose(acc_model, acc, rtol=1e-9, atol=1e-16)
        assert f[6] == pytest.approx(m.p_default[0] / m.p_default[1], rel=1e-12)


def test_inertial_takes_gms_from_the_ephemeris_it_is_given():
    """A stand-in with its own GMs: the accelerations (and the default TU) use them, not DE421's."""
    from ocreach.ephemeris import CircularEarthMoon

    gme, gmm = 1.1 * gm("earth"), 0.7 * gm("moon")
    eph = CircularEarthMoon(384400.0, gm_earth=gme, gm_moon=gmm)
    m = ephemeris_inertial(["earth", "moon"], "earth", FOSS_EPOCH, 1.0, 1.0, 1.0, 1.0,
                           ephemeris=eph)
    du, tu = m.units.length / 1e3, m.units.time
    assert tu == pytest.approx(np.sqrt(du**3 / gme), rel=1e-14)  # mu_earth = 1 with its own GM
    x = np.array([0.3, -0.8, 0.2, 0.1, 0.4, -0.2, 1.0])
    t = 0.37
    rm = np.asarray(eph.position("moon", t * tu, "earth"), float).ravel() / du
    r = x[:3]
    mu_e, mu_m = gme * tu**2 / du**3, gmm * tu**2 / du**3
    acc = (-mu_e * r / np.linalg.norm(r) ** 3
           - mu_m * ((r - rm) / np.linalg.norm(r - rm) ** 3 + rm / np.linalg.norm(rm) ** 3))
    np.testing.assert_allclose(m(x, np.zeros(3), t)[3:6], acc, rtol=1e-12, atol=1e-15)
