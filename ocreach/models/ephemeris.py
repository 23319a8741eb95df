"""Ephemeris (DE421) point-mass dynamics with low thrust in two frames.

* :func:`ephemeris_inertial` -- Patel & Scheeres Eq. 11: ICRF (or ECLIPJ2000) axes, any origin
  body, state ``[r, v, n]`` with the inverse mass ``n``.
* :func:`ephemeris_synodic` -- Foss et al. Sec. 2.2.2 Eq. 6 (+ Eq. 7 thrust): the Earth-Moon
  synodic frame built from the ephemeris, origin at the Earth-Moon barycentre, fixed DU/TU.

Body positions come from :class:`ocreach.ephemeris.EphemerisFit` (a Chebyshev refit of DE421), so
``f(x, u, t; p)`` is one smooth CasADi expression and every derivative the methods take (w.r.t.
``x``, ``u`` and ``t``) is exact for the fit.  Model time ``t`` is in TU from the epoch.

The fitted ephemeris and frame data are stored in ``model.cache["ephemeris"]`` and
``model.cache["frame"]`` (used by :func:`synodic_to_inertial` and by problem files).
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace
from typing import Any

import casadi as ca
import numpy as np

from ocreach.ephemeris import (
    AU_KM,
    BODIES,
    FRAMES,
    ORIGINS,
    CircularEarthMoon,
    EphemerisFit,
    check_body,
    ephemeris_fit,
    gm,
)
from ocreach.errors import ProblemError, check_positive, check_real
from ocreach.model import Model
from ocreach.units import EARTH_MOON_FOSS, G0, Units

FRAME_ACCELERATIONS = ("modelled", "ephemeris")
#: Default Earth-centred distance unit of :func:`ephemeris_inertial`, km.
DU_EARTH_MOON_KM = 384400.0


def _bodies(bodies: Iterable[str]) -> tuple[str, ...]:
    if isinstance(bodies, str):
        bodies = [bodies]
    out = tuple(dict.fromkeys(check_body(b, BODIES, "bodies entry") for b in bodies))
    if not out:
        raise ProblemError("bodies must name at least one gravitating body; got an empty list")
    return out


def default_inertial_units(central: str, mass0: float = 1.0, gm_of=gm) -> Units:
    """DU = 384400 km (Earth, Moon, EMB origin) or 1 AU (otherwise); TU makes ``mu_central = 1``.

    For the SSB and EMB origins the reference GM is the Sun's and Earth+Moon's.  The mass unit is
    ``mass0`` (so the inverse mass state starts at ``n = 1``).  ``gm_of(body)``: the GMs (km^3/s^2;
    default DE421's, :func:`ocreach.ephemeris.gm`).
    """
    central = check_body(central, ORIGINS, "central")
    du_km = DU_EARTH_MOON_KM if central in ("earth", "moon", "emb") else AU_KM
    if central == "ssb":
        ref = gm_of("sun")
    elif central == "emb":
        ref = gm_of("earth") + gm_of("moon")
    else:
        ref = gm_of(central)
    return Units(length=du_km * 1e3, time=float(np.sqrt(du_km**3 / ref)), mass=mass0,
                 name=f"{central}-centred (DU = {du_km:.10g} km, mu_{central} = 1)")


def _gm_of(eph):
    """``body -> GM`` of the ephemeris object ``eph``, DE421's for bodies it does not carry (the
    Sun of a circular Earth-Moon stand-in, say)."""
    def gm_of(body: str) -> float:
        try:
            return float(eph.gm(body))
        except ProblemError:
            return gm(body)
    return gm_of


def _second_derivative(expr: ca.SX, t: ca.SX) -> ca.SX:
    return ca.jacobian(ca.jacobian(expr, t), t)


def _check_window_tu(window: Any) -> tuple[float, float]:
    """``window = (lo, hi)`` in TU after the epoch as floats; :class:`ProblemError` unless it is
    a pair of finite numbers with ``lo < hi``."""
    try:
        lo, hi = window
    except (TypeError, ValueError):
        raise ProblemError(f"window must be a pair (lo, hi) of model times (TU after the epoch) "
                           f"with lo < hi; got {window!r}") from None
    lo, hi = check_real("window[0] (TU)", lo), check_real("window[1] (TU)", hi)
    if not lo < hi:
        raise ProblemError(f"window must be (lo, hi) with lo < hi (TU after the epoch); "
                           f"got {window!r}")
    return lo, hi


def ephemeris_inertial(
    bodies: Iterable[str],
    central: str,
    epoch,
    span_days,
    thrust: float,
    isp: float,
    mass0: float,
    *,
    frame: str = "icrf",
    units: Units | None = None,
    frame_acceleration: str = "modelled",
    control_set: str = "ball",
    ephemeris: EphemerisFit | None = None,
    tol_km: float = 1e-5,
    window: tuple[float, float] | None = None,
) -> Model:
    """Point-mass ephemeris dynamics with thrust and inverse mass (Patel & Scheeres Eq. 11).

    ``dr/dt = v``, ``dv/dt = sum_j -mu_j (r - r_j)/|r - r_j|^3 - a_origin(t) + T_max n u``,
    ``dn/dt = T_max n^2 ||u|| / c``; ``u`` normalised (``||u|| <= 1``, thrust vector
    ``T = T_max u``), ``c = g0 Isp``.

    Units (see :func:`default_inertial_units`): lengths in DU, time in TU from the epoch, mass in
    units of ``mass0`` (``n = mass0 / m``, so ``n(0) = 1`` for the initial mass).  Parameters
    ``p = [T_max, c_ex]`` in model units: ``T_max = thrust / (mass0 DU/TU^2)`` (the thrust
    acceleration at ``m = mass0``) and ``c_ex = g0 Isp / (DU/TU)``.

    ``central`` is the origin: a body in ``bodies`` or ``"ssb"`` (inertial, no frame term); its
    fitted DE421 trajectory defines the frame either way.  ``a_origin``:

    * ``frame_acceleration="modelled"`` (default): the pull of the other modelled bodies on the
      origin (the classic third-body form ``-mu_j (d_j/|d_j|^3 + r_j/|r_j|^3)``).  Relative to the
      ephemeris origin this adds the unmodelled bodies' (Jupiter, ...) pull on the origin to the
      spacecraft, which is what they do up to a tide: closest to the real N-body motion.
    * ``"ephemeris"``: the second derivative of the origin's fitted trajectory.  Exactly equivalent
      to propagating in SSB-centred axes with only the modelled bodies acting on the spacecraft
      (about 20 km apart from "modelled" after 4.3 days in cislunar space, Jupiter mostly).
      Any origin in :data:`ocreach.ephemeris.ORIGINS` is allowed then.

    ``frame="eclipj2000"`` uses ecliptic J2000 axes (Patel & Scheeres Sec. 6).
    ``span_days``: days from the epoch the model must be valid for (negative for backward
    propagation; see :class:`ocreach.ephemeris.EphemerisFit`).
    ``window = (lo, hi)`` (model time, TU after the epoch): the dynamics for ``lo <= t <= hi``
    only, without the ``if_else`` between fit pieces, the fit as one polynomial on the window
    (:meth:`~ocreach.ephemeris.EphemerisFit.position_expr`, also across a blend of two pieces):
    not the same function but within
    :meth:`~ocreach.ephemeris.EphemerisFit.window_error_bound` of it (positions; ``cache[
    "window_seconds"]`` is the window it takes), so a sound method run on it encloses the full
    model only with that difference added to its disturbance, as
    :meth:`~ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant.frame_model_on` does.
    """
    bodies = _bodies(bodies)
    central = check_body(central, ORIGINS, "central")
    frame = check_body(frame, FRAMES, "frame")
    frame_acceleration = check_body(frame_acceleration, FRAME_ACCELERATIONS, "frame_acceleration")
    thrust = check_positive("thrust (T_max, N)", thrust)
    isp = check_positive("isp (s)", isp)
    mass0 = check_positive("mass0 (kg)", mass0)
    if frame_acceleration == "modelled" and central != "ssb" and central not in bodies:
        raise ProblemError(f"central {central!r} must be 'ssb' or one of bodies {list(bodies)} with "
                           "frame_acceleration='modelled' (use 'ephemeris' for other origins)")
    fit_bodies = set(bodies) | ({central} if central in BODIES else set())
    if central == "emb":
        fit_bodies |= {"earth"}
    eph = ephemeris if ephemeris is not None else ephemeris_fit(sorted(fit_bodies), epoch,
                                                                span_days, tol_km=tol_km)
    if units is None:
        units = default_inertial_units(central, mass0, _gm_of(eph))
    else:
        units = replace(units, mass=mass0)
    du_km, tu = units.length / 1e3, units.time

    t = ca.SX.sym("t")
    ts = tu * t
    window = None if window is None else _check_window_tu(window)
    win = None if window is None else (tu * window[0], tu * window[1])
    r = ca.SX.sym("r", 3)
    v = ca.SX.sym("v", 3)
    n = ca.SX.sym("n")
    u = ca.SX.sym("u", 3)
    T_s = ca.SX.sym("T_max")
    c_s = ca.SX.sym("c_ex")
    # GMs from the ephemeris object in use (a stand-in may carry its own), like ephemeris_synodic
    mu = {b: eph.gm(b) * tu**2 / du_km**3 for b in bodies}

    acc = ca.SX.zeros(3)
    origin_acc = ca.SX.zeros(3)
    for b in bodies:
        if b == central:
            acc += -mu[b] * r / ca.norm_2(r) ** 3
            continue
        rb = eph.position_expr(b, ts, central, frame=frame, window=win) / du_km
        d = r - rb
        acc += -mu[b] * d / ca.norm_2(d) ** 3
        if frame_acceleration == "modelled" and central != "ssb":
            origin_acc += mu[b] * rb / ca.norm_2(rb) ** 3
    if frame_acceleration == "ephemeris" and central != "ssb":
        origin_acc = _second_derivative(
            eph.position_expr(central, ts, "ssb", frame=frame, window=win) / du_km, t)
    unorm = ca.sqrt(ca.sumsqr(u) + 1e-30)
    sigma = ca.SX.sym("sigma")  # ||u|| (throttle), see Model.throttle
    # cse: every position_expr builds its own Chebyshev basis; merge the common subexpressions
    f_sigma = ca.cse(ca.vertcat(v, acc - origin_acc + T_s * n * u, T_s * n**2 * sigma / c_s))
    f = ca.substitute(f_sigma, sigma, unorm)

    T_nd = thrust / mass0 / units.acceleration
    c_nd = G0 * isp / units.velocity
    model = Model.build(
        f"ephemeris-inertial-{central}"
        + ("" if window is None else f"-window-{window[0]:.17g}-{window[1]:.17g}"),
        ca.vertcat(r, v, n), u, f, t=t, p=ca.vertcat(T_s, c_s),
        p_default=[T_nd, c_nd], state_names=["x", "y", "z", "vx", "vy", "vz", "n"],
        control_names=["ux", "uy", "uz"], param_names=["T_max", "c_ex"], thrust_param="T_max",
        control_set=control_set, units=units, state_units=units.state_labels(3, ("1",)),
        throttle=(sigma, f_sigma),
        description=(f"DE421 point masses {list(bodies)}, origin {central}, {frame} axes, "
                     f"frame acceleration {frame_acceleration}, inverse mass n = mass0/m "
                     f"(Patel & Scheeres Eq. 11); mass0 = {mass0} kg, T_max = {thrust} N, "
                     f"Isp = {isp} s"))
    model.cache["ephemeris"] = eph
    if win is not None:  # the window in seconds, as position_expr got it (window_error_bound)
        model.cache["window_seconds"] = win
    model.cache["frame"] = {"kind": "inertial", "central": central, "axes": frame,
                            "bodies": bodies, "frame_acceleration": frame_acceleration}
    return model


def inertial_state_from_si(model: Model, r_km, v_km_s, mass_kg: float) -> np.ndarray:
    """Model state ``[r, v, n]`` of :func:`ephemeris_inertial` from km, km/s and kg."""
    u = model.units
    if u is None:
        raise ProblemError(f"model {model.name} has no units")
    r = np.asarray(r_km, float) * 1e3 / u.length
    v = np.asarray(v_km_s, float) * 1e3 / u.velocity
    return np.concatenate([r, v, [u.mass / check_positive("mass_kg", mass_kg)]])


# ----------------------------------------------------------------------------- synodic frame
def _synodic_frame(eph, t: ca.SX, du_km: float, tu: float):
    """Frame data of Foss Eq. 6 as SX of model time ``t``: ``R_J, M, dM/dt, d2M/dt2`` (ND).

    x along Earth->Moon, z along the Earth-Moon angular momentum, y = z x x; ``M`` has these unit
    vectors (ICRF components) as columns, so ``r_J = R_J + M r_R``.
    """
    ts = tu * t
    rel = eph.position_expr("moon", ts, "earth") / du_km
    vel = ca.jacobian(rel, t)
    xh = rel / ca.norm_2(rel)
    h = ca.cross(rel, vel)
    zh = h / ca.norm_2(h)
    yh = ca.cross(zh, xh)
    M = ca.horzcat(xh, yh, zh)
    Md = ca.reshape(ca.jacobian(ca.vec(M), t), 3, 3)
    Mdd = ca.reshape(ca.jacobian(ca.vec(Md), t), 3, 3)
    R = eph.position_expr("emb", ts, "ssb") / du_km
    return R, M, Md, Mdd


def ephemeris_synodic(
    bodies: Iterable[str],
    epoch,
    span_days,
    a_max: float = 0.0,
    *,
    units: Units = EARTH_MOON_FOSS,
    frame_acceleration: str = "ephemeris",
    circular: bool = False,
    control_set: str = "ball",
    ephemeris=None,
    tol_km: float = 1e-5,
) -> Model:
    """Ephemeris dynamics in the Earth-Moon synodic frame (Foss et al. Eq. 6 and 7).

    ``r'' = -sum_i mu_i d_i/|d_i|^3 - M^T M'' r - 2 M^T M' r' - M^T R_J'' + a_max u`` with
    ``d_i = r - M^T (r_i - R_J)``; origin the Earth-Moon barycentre ``R_J``; ``M``, ``M'``, ``M''``
    are exact time derivatives of the fitted Earth->Moon vector (the frame follows the Moon).

    Non-dimensionalised by a *fixed* DU and TU (``units``, default Foss Sec. 4: DU = 3.825e8 m,
    TU = 3.724e5 s), not the instantaneous Earth-Moon distance, so the Moon oscillates about
    ``x ~ 1 - mu``.  ``mu_i = GM_i TU^2 / DU^3`` from DE421.  Parameters ``[a_max]`` (thrust
    acceleration ``T_max/m`` in DU/TU^2, Foss Eq. 7); control ``||u|| <= 1``.

    ``frame_acceleration="ephemeris"`` (default, as Foss) takes ``R_J''`` from the fitted EMB
    trajectory: exactly the SSB-centred N-body motion under the modelled bodies, seen in the
    ephemeris frame.  ``"modelled"`` uses the pull of the modelled bodies on Earth and Moon instead,
    which adds the unmodelled bodies' (Jupiter, ...) pull on the EMB to the spacecraft, closer to
    the real N-body motion (the two differ by ~20 km after 1 TU with Sun, Earth, Moon, Venus).
    ``circular=True`` replaces DE421 by :class:`ocreach.ephemeris.CircularEarthMoon` at distance
    DU (bodies must be Earth and Moon): the CR3BP check case.
    """
    bodies = _bodies(bodies)
    if "earth" not in bodies or "moon" not in bodies:
        raise ProblemError(f"bodies must contain 'earth' and 'moon' for the synodic frame; got "
                           f"{list(bodies)}")
    frame_acceleration = check_body(frame_acceleration, FRAME_ACCELERATIONS, "frame_acceleration")
    if not np.isfinite(a_max) or a_max < 0:
        raise ProblemError(f"a_max must be a finite number >= 0; got {a_max!r}")
    du_km, tu = units.length / 1e3, units.time
    if circular:
        if set(bodies) != {"earth", "moon"}:
            raise ProblemError(f"circular=True supports bodies ['earth', 'moon'] only; got "
                               f"{list(bodies)}")
        eph = CircularEarthMoon(du_km) if ephemeris is None else ephemeris
    else:
        eph = ephemeris if ephemeris is not None else ephemeris_fit(bodies, epoch, span_days,
                                                                    tol_km=tol_km)

    t = ca.SX.sym("t")
    ts = tu * t
    r = ca.SX.sym("r", 3)
    v = ca.SX.sym("v", 3)
    u = ca.SX.sym("u", 3)
    a_s = ca.SX.sym("a_max")
    R, M, Md, Mdd = _synodic_frame(eph, t, du_km, tu)
    mu = {b: eph.gm(b) * tu**2 / du_km**3 for b in bodies}
    pos = {b: eph.position_expr(b, ts, "emb") / du_km for b in bodies}  # r_i - R_J, ICRF

    acc = ca.SX.zeros(3)
    for b in bodies:
        d = r - ca.mtimes(M.T, pos[b])
        acc += -mu[b] * d / ca.norm_2(d) ** 3
    if frame_acceleration == "ephemeris":
        Rdd = _second_derivative(R, t)
    else:  # pull of the other modelled bodies on Earth and Moon (their mutual pull cancels)
        Rdd = ca.SX.zeros(3)
        for b in ("earth", "moon"):
            ab = ca.SX.zeros(3)
            for o in bodies:
                if o in ("earth", "moon"):
                    continue
                d = pos[o] - pos[b]
                ab += mu[o] * d / ca.norm_2(d) ** 3
            Rdd += mu[b] / (mu["earth"] + mu["moon"]) * ab
    acc += -ca.mtimes(ca.mtimes(M.T, Mdd), r) - 2 * ca.mtimes(ca.mtimes(M.T, Md), v) \
        - ca.mtimes(M.T, Rdd)
    f = ca.cse(ca.vertcat(v, acc + a_s * u))
    kind = "circular Earth-Moon stand-in" if circular else f"DE421 point masses {list(bodies)}"
    model = Model.build(
        "ephemeris-synodic", ca.vertcat(r, v), u, f, t=t, p=a_s, p_default=[a_max],
        state_names=["x", "y", "z", "vx", "vy", "vz"], control_names=["ux", "uy", "uz"],
        param_names=["a_max"], thrust_param="a_max", control_set=control_set, units=units, state_units=units.state_labels(3),
        description=(f"Earth-Moon synodic frame (Foss Eq. 6), {kind}, frame acceleration "
                     f"{frame_acceleration}, DU = {du_km:g} km, TU = {tu:g} s"))
    model.cache["ephemeris"] = eph
    model.cache["frame"] = {"kind": "synodic", "bodies": bodies, "du_km": du_km, "tu": tu,
                            "frame_acceleration": frame_acceleration}
    return model


def synodic_frame_function(model: Model) -> ca.Function:
    """``t -> (R_J, dR_J/dt, M, dM/dt)`` (ND, ICRF) of a model from :func:`ephemeris_synodic`."""
    info = model.cache.get("frame", {})
    if info.get("kind") != "synodic":
        raise ProblemError(f"model {model.name} is not an ephemeris_synodic model")

    def build():
        t = ca.SX.sym("t")
        R, M, Md, _ = _synodic_frame(model.cache["ephemeris"], t, info["du_km"], info["tu"])
        return ca.Function("synodic_frame", [t], [R, ca.jacobian(R, t), M, Md],
                           ["t"], ["R", "Rd", "M", "Md"])

    return model.cached("synodic_frame", build)


def synodic_to_inertial(model: Model, t: float, x) -> np.ndarray:
    """Synodic state ``[r_R, v_R]`` at model time ``t`` -> SSB-centred ICRF state in km, km/s.

    ``r_J = R_J + M r_R``, ``v_J = R_J' + M' r_R + M v_R`` (Foss Sec. 2.2.2), scaled by DU, TU.
    """
    R, Rd, M, Md = (np.asarray(a) for a in synodic_frame_function(model)(t))
    x = np.asarray(x, float)
    du, tu = model.cache["frame"]["du_km"], model.cache["frame"]["tu"]
    r = R.ravel() + M @ x[:3]
    v = Rd.ravel() + Md @ x[:3] + M @ x[3:6]
    return np.concatenate([r * du, v * du / tu])


def inertial_to_synodic(model: Model, t: float, r_km, v_km_s) -> np.ndarray:
    """Inverse of :func:`synodic_to_inertial` (SSB-centred ICRF km, km/s -> synodic ND state)."""
    R, Rd, M, Md = (np.asarray(a) for a in synodic_frame_function(model)(t))
    du, tu = model.cache["frame"]["du_km"], model.cache["frame"]["tu"]
    rr = M.T @ (np.asarray(r_km, float) / du - R.ravel())
    vv = M.T @ (np.asarray(v_km_s, float) * tu / du - Rd.ravel() - Md @ rr)
    return np.concatenate([rr, vv])
