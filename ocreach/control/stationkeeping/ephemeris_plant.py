"""DE421 ephemeris plant for closed loops whose controllers predict with the CR3BP.

The controllers (LQR, MPC, tubes) keep the CR3BP reference and its coordinates; only the plant
changes.  It integrates the Moon-centred point-mass ephemeris model (Patel & Scheeres Eq. 11
plus the indirect term of the Moon-centred frame; :func:`ocreach.models.ephemeris.ephemeris_inertial`,
ICRF axes, DE421 refit; default bodies Moon, Earth, Sun, third-body form of the frame acceleration) in the problem's units ``l*``, ``t*``, and
maps states through the CR3BP rotating frame *fixed at the epoch*:

* at the epoch (reference time ``t_0``) the frame's axes ``C_0`` are the true Earth-Moon synodic
  axes (x along Earth -> Moon, z along their orbital angular momentum, DE421);
* it rotates uniformly about ``C_0 z`` at the CR3BP rate (1 rad per TU): ``C(t) = C_0 R_z(t - t_0)``;
* it is centred on the Moon, so a CR3BP state ``x = [r, v]`` is the inertial Moon-relative state
  ``rho = C(t) (r - (1 - mu) e_x) l*``, ``drho/dt = C(t) (v + e_z x (r - (1 - mu) e_x)) l*/t*``.

This transform keeps the Moon's gravity and the frame's Coriolis and centrifugal terms exactly
those of the CR3BP; what differs is the Earth's (eccentric, inclined, Sun-perturbed) and the
Sun's pull.  (Two other maps were measured along the 9:2 NRHO at the default epoch: the
barycentric pulsating frame without a time scaling needs 889 m/s per revolution to track the
reference -- the Moon's gravity rescales with the Earth-Moon distance -- and the Moon-centred
translation into the true synodic frame 46 m/s with 1e-3 m/s^2 peaks at perilune from the varying
rotation rate; this map 40 m/s with peaks of 1.1e-4 m/s^2.)

Thrust ``a_max u`` and the disturbance ``w`` are physical accelerations along the CR3BP axes,
rotated by ``C(t)``: the controller's command means the same thrust in both plants.  The mass is
not depleted (as in the CR3BP plant).  With :class:`ocreach.ephemeris.CircularEarthMoon`
(``circular=True``) the plant is the CR3BP with ``mu = GM_M/(GM_E + GM_M)`` and
``t* = sqrt(l*^3/(GM_E + GM_M))`` (the test of the transform).

:meth:`EphemerisPlant.frame_model` is the same dynamics as a CasADi model in the CR3BP
coordinates: the model of the ephemeris-corrected reference
(:mod:`ocreach.control.stationkeeping.ephemeris_reference`) and of the controllers that track it.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.integrate import solve_ivp

from ocreach.control.common import saturate
from ocreach.control.stationkeeping.srp import AU_KM, SolarRadiationPressure
from ocreach.errors import ProblemError, SolverError

#: Bodies of the default ephemeris plant (point masses; the Moon is the origin).
DEFAULT_BODIES = ("moon", "earth", "sun")
#: Default epoch (TDB) of reference time ``t_0``.
DEFAULT_EPOCH = "2026-01-01 00:00:00"
PLANTS = ("cr3bp", "ephemeris")


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class EphemerisPlant:
    """The DE421 point-mass model as the plant of a CR3BP-coordinate closed loop (module doc).

    ``reference``: the CR3BP :class:`~ocreach.control.reference.TrackingReference` (spatial, with
    units and the parameters ``[mu, a_max]``); ``span_days``: days after the epoch the plant must
    cover (the ephemeris is refitted over it plus one day); ``bodies``: point masses, the Moon
    included; ``frame_acceleration``: as in :func:`~ocreach.models.ephemeris.ephemeris_inertial`;
    ``circular``: the circular Earth-Moon stand-in.  ``srp``: a
    :class:`~ocreach.control.stationkeeping.srp.SolarRadiationPressure` (cannonball solar radiation
    pressure; the Sun must be among the ``bodies``), or None (default: no SRP).  With SRP the
    frame model has a third parameter ``srp_scale`` (default 1: the nominal ``C_r A / m``; a run's
    true value over the nominal).  ``step(x, u, w, t0, dt)`` has the interface of
    :class:`ocreach.control.simulate.Plant`.
    """

    name = "ephemeris"

    def __init__(self, reference, control_set_kind: str, velocity_dims: tuple[int, ...], *,
                 span_days: float, epoch=DEFAULT_EPOCH, bodies: Sequence[str] = DEFAULT_BODIES,
                 frame_acceleration: str = "modelled", rtol: float = 1e-10, atol: float = 1e-12,
                 circular: bool = False, srp=None) -> None:
        from ocreach.ephemeris import CircularEarthMoon
        from ocreach.models.ephemeris import ephemeris_inertial

        cr = reference.model
        units = cr.units
        if units is None:
            raise ProblemError(f"ephemeris plant needs a model with units (l*, t*); model "
                               f"{cr.name!r} has none")
        if cr.n_x != 6 or list(cr.param_names[:2]) != ["mu", "a_max"]:
            raise ProblemError(f"ephemeris plant needs the spatial CR3BP (6 states, parameters "
                               f"[mu, a_max]); got model {cr.name!r} with {cr.n_x} states and "
                               f"parameters {list(cr.param_names)}")
        if isinstance(span_days, bool) or not np.isfinite(span_days) or span_days <= 0:
            raise ProblemError(f"span_days (plant coverage after the epoch) must be > 0; got "
                               f"{span_days!r}")
        bodies = tuple(bodies)
        if "moon" not in bodies:
            raise ProblemError(f"bodies of the ephemeris plant must include 'moon' (its origin); "
                               f"got {list(bodies)}")
        if circular and set(bodies) != {"earth", "moon"}:
            bodies = ("moon", "earth")
        if srp is not None:
            if not isinstance(srp, SolarRadiationPressure):
                raise ProblemError(f"srp must be a SolarRadiationPressure or None; got "
                                   f"{type(srp).__name__}")
            if "sun" not in bodies:
                raise ProblemError(f"solar radiation pressure needs the Sun among the ephemeris "
                                   f"bodies; got {list(bodies)}")
        self.srp = srp
        self.mu, self.a_max = float(reference.params[0]), float(reference.params[1])
        self.t0 = float(reference.time(0))
        self.units = units
        self.kind = control_set_kind
        self.rtol, self.atol = rtol, atol
        self.E = np.zeros((6, len(velocity_dims)))
        self.E[list(velocity_dims), np.arange(len(velocity_dims))] = 1.0
        eph = CircularEarthMoon(units.length / 1e3) if circular else None
        # u = 0 in the model (thrust added along C(t) below): T_max, Isp only fill the parameters
        self.model = ephemeris_inertial(bodies, "moon", epoch, float(span_days) + 1.0, 1.0, 1.0,
                                        1.0, units=units, frame_acceleration=frame_acceleration,
                                        ephemeris=eph)
        self.ephemeris = self.model.cache["ephemeris"]
        r = np.asarray(self.ephemeris.position("moon", 0.0, "earth"), float).ravel()
        v = np.asarray(self.ephemeris.position("moon", 0.0, "earth", derivative=1), float).ravel()
        x = r / np.linalg.norm(r)
        z = np.cross(r, v)
        z /= np.linalg.norm(z)
        self.C0 = np.column_stack([x, np.cross(z, x), z])
        self.epoch, self.bodies, self.circular = epoch, bodies, bool(circular)
        self.frame_acceleration = frame_acceleration
        self.span_days = float(span_days)
        self._p = np.asarray(self.model.p_default, float)
        self._u0 = np.zeros(3)

    # ------------------------------------------------------------------ frame at the epoch
    def axes(self, t: float) -> np.ndarray:
        """``C(t)``: the CR3BP axes (columns, ICRF) at reference time ``t``."""
        return self.C0 @ _rz(float(t) - self.t0)

    def to_inertial(self, t: float, x) -> np.ndarray:
        """CR3BP state at reference time ``t`` -> Moon-centred ICRF state of the plant (DU, DU/TU,
        plus the inverse mass 1)."""
        x = np.asarray(x, float)
        C = self.axes(t)
        rho = x[:3] - np.array([1.0 - self.mu, 0.0, 0.0])
        om = np.array([-rho[1], rho[0], 0.0])  # e_z x rho
        return np.concatenate([C @ rho, C @ (x[3:6] + om), [1.0]])

    def from_inertial(self, t: float, y) -> np.ndarray:
        """Inverse of :meth:`to_inertial` (the inverse mass is dropped)."""
        y = np.asarray(y, float)
        C = self.axes(t)
        rho = C.T @ y[:3]
        om = np.array([-rho[1], rho[0], 0.0])
        return np.concatenate([rho + np.array([1.0 - self.mu, 0.0, 0.0]), C.T @ y[3:6] - om])

    def frame_model(self):
        """The plant's dynamics in the CR3BP coordinates of the frame fixed at the epoch: a
        :class:`~ocreach.model.Model` with the CR3BP's interface (states ``[r, v]``, control ``u``
        in ``||u|| <= 1`` along the CR3BP axes, parameters ``[mu, a_max]``, time = reference time).

        With ``s = r - (1 - mu) e_x`` (Moon-relative, rotating axes) and the frame's uniform rate
        ``omega = e_z`` (1 rad/TU): ``ds/dt = v``,
        ``dv/dt = C(t)^T a(C(t) s, C(t)(v + omega x s), t - t_0) - 2 omega x v - omega x (omega x s)
        + a_max u``, with ``a`` the acceleration of the Moon-centred ICRF model (Patel & Scheeres
        Eq. 11 plus the Moon-centred frame's indirect term), called symbolically, so every derivative (STM, MPC) comes from the one CasADi
        model.  It is the plant of :meth:`step` expressed in the controllers' coordinates (the
        dynamics of :mod:`ocreach.control.stationkeeping.ephemeris_reference`).  Cached on the plant's model.
        """
        return self.model.cached(("cr3bp_frame_model", self.t0, self.mu, self._srp_key()),
                                 self._build_frame_model)

    def _srp_key(self) -> tuple | None:
        return None if self.srp is None else tuple(sorted(self.srp.as_dict().items()))

    def frame_model_on(self, t_lo: float, t_hi: float):
        """:meth:`frame_model` for reference times ``t_lo <= t <= t_hi`` only, without the
        ``if_else`` between DE421 fit pieces (``window`` of
        :func:`~ocreach.models.ephemeris.ephemeris_inertial`: the fit as one polynomial on the
        window, also across a blend of two pieces), for sound reachability; the same function
        there up to the acceleration difference that ``model.cache["window_error"]`` bounds
        (:meth:`_window_error`)."""
        from ocreach.models.ephemeris import ephemeris_inertial

        if self.circular:  # the circular stand-in is one smooth expression already
            return self.frame_model()
        window = (float(t_lo) - self.t0, float(t_hi) - self.t0)

        def build():
            inertial = ephemeris_inertial(
                self.bodies, "moon", self.epoch, self.span_days + 1.0, 1.0, 1.0, 1.0,
                units=self.units, frame_acceleration=self.frame_acceleration,
                ephemeris=self.ephemeris, window=window)
            model = self._build_frame_model(inertial, f"-window-{t_lo:.17g}-{t_hi:.17g}")
            model.cache["window_error"] = self._window_error(inertial.cache["window_seconds"])
            return model

        return self.model.cached(("cr3bp_frame_model", self.t0, self.mu, window, self._srp_key()),
                                 build)

    def _window_error(self, win: tuple[float, float]) -> dict:
        """Rigorous bound on ``|f_full - f_window|`` (acceleration, DU/TU^2, 2-norm) of
        :meth:`frame_model_on` over the window ``win`` (seconds after the epoch, as the inertial
        model's ``position_expr`` got it), for CR3BP states with ``|r - (1 - mu) e_x| <= radius``
        (returned with it; the caller checks its sets stay there).

        Only the body positions change with the window (the frame ``C(t)`` is not from the
        ephemeris).  Per body ``b``: ``delta_b`` = 2-norm of
        :meth:`~ocreach.ephemeris.EphemerisFit.window_error_bound` (exact, km); ``n_b`` = a lower
        bound of ``|r_b(t)|`` on the window (interval evaluation of the windowed position on
        sub-intervals of at most an hour, :class:`~ocreach.intervals.IntervalFunction`).  The acceleration ``g(d) = d / |d|^3`` has
        the Jacobian ``(I - 3 d d^T / |d|^2) / |d|^3`` of spectral norm ``2 / |d|^3``, so by the
        mean value theorem on the segment between the two positions
        ``|Delta a_b| <= mu_b 2 delta_b (1 / m1^3 + 1 / m2^3)`` with ``m1 = n_b - delta_b -
        radius`` (``|r - r_b|``) and ``m2 = n_b - delta_b`` (the origin's term ``r_b / |r_b|^3``
        of ``frame_acceleration="modelled"``); with ``"ephemeris"`` the origin's term is the
        second derivative of the Moon's position, bounded by ``window_error_bound(derivative=2)``.
        ``radius = n_min / 2`` (half the nearest perturbing body's distance).  ``C(t)^T`` keeps the
        2-norm; the float arithmetic of this bound and ``C_0``'s orthogonality are covered by a
        factor ``1 + 1e-9``."""
        import casadi as ca

        from ocreach.intervals import IntervalFunction

        eph = self.ephemeris
        du_km, tu = self.units.length / 1e3, self.units.time
        t = ca.SX.sym("t")
        others = [b for b in self.bodies if b != "moon"]
        delta, near = {}, {}
        for b in others:
            delta[b] = float(np.linalg.norm(eph.window_error_bound(b, "moon", *win))) / du_km
            f = IntervalFunction(ca.Function("r", [t], [eph.position_expr(b, t, "moon",
                                                                          window=win)]))
            # boxes over sub-intervals of at most an hour: one box over days of an orbit arc
            # would reach towards the Moon (a quarter revolution's box nearly touches it)
            cuts = np.linspace(win[0], win[1], max(2, int(np.ceil((win[1] - win[0]) / 3600.0))
                                                   + 1))
            cuts[-1] = win[1]
            (lo, hi), = f([cuts[None, :-1]], [cuts[None, 1:]])
            gap = np.maximum(0.0, np.maximum(lo, -hi))  # (3, boxes)
            near[b] = float(np.linalg.norm(gap, axis=0).min()) * (1 - 1e-12) / du_km
        radius = 0.5 * min(near.values()) if others else np.inf
        total = 0.0
        for b in others:
            mu_b = eph.gm(b) * tu**2 / du_km**3
            m1 = near[b] - delta[b] - radius
            m2 = near[b] - delta[b]
            if not (m1 > 0 and m2 > 0):
                raise SolverError(f"window model error bound: body {b!r} comes within "
                                  f"{near[b]:.3g} DU of the Moon on the window; no bound")
            total += 2.0 * mu_b * delta[b] * (1.0 / m1**3
                                              + (1.0 / m2**3 if self.frame_acceleration
                                                 == "modelled" else 0.0))
        if self.frame_acceleration == "ephemeris":
            dd = float(np.linalg.norm(eph.window_error_bound("moon", "ssb", *win, derivative=2)))
            total += dd * tu**2 / du_km
        if self.srp is not None:  # the same d/|d|^3 form as the Sun's pull, at the largest scale
            m1 = near["sun"] - delta["sun"] - radius
            k = self._srp_unit_coefficient() * (1.0 + self.srp.uncertainty)
            total += 2.0 * k * delta["sun"] / m1**3
        return {"acceleration": total * (1 + 1e-9), "radius": float(radius),
                "centre": [1.0 - self.mu, 0.0, 0.0],
                "position_km": {b: delta[b] * du_km for b in others}}

    def _build_frame_model(self, inertial=None, suffix: str = ""):
        import casadi as ca

        from ocreach.model import Model

        x = ca.SX.sym("x", 6)
        u = ca.SX.sym("u", 3)
        t = ca.SX.sym("t")
        mu, a_max = ca.SX.sym("mu"), ca.SX.sym("a_max")
        params, names, p_default = [mu, a_max], ["mu", "a_max"], [self.mu, self.a_max]
        s = x[:3] - ca.vertcat(1 - mu, 0, 0)
        v = x[3:6]
        c, sn = ca.cos(t - self.t0), ca.sin(t - self.t0)
        Rz = ca.vertcat(ca.horzcat(c, -sn, 0), ca.horzcat(sn, c, 0), ca.horzcat(0, 0, 1))
        C = ca.mtimes(ca.DM(self.C0), Rz)
        om_s = ca.vertcat(-s[1], s[0], 0)  # e_z x s
        y = ca.vertcat(ca.mtimes(C, s), ca.mtimes(C, v + om_s), 1)
        inertial = self.model if inertial is None else inertial
        a_in = inertial.f_fun(y, ca.DM.zeros(3), t - self.t0, ca.DM(self._p))[3:6]
        acc = (ca.mtimes(C.T, a_in) + ca.vertcat(2 * v[1] + s[0], -2 * v[0] + s[1], 0)
               + a_max * u)
        if self.srp is not None:
            scale = ca.SX.sym("srp_scale")
            params.append(scale)
            names.append("srp_scale")
            p_default.append(1.0)
            win = inertial.cache.get("window_seconds")
            du_km = self.units.length / 1e3
            r_sun = self.ephemeris.position_expr("sun", self.units.time * (t - self.t0), "moon",
                                                 window=win) / du_km
            a_srp = self.srp.expression(ca.mtimes(C, s) - r_sun, du_km, self.units.acceleration,
                                        scale)
            acc = acc + ca.mtimes(C.T, a_srp)
        f = ca.cse(ca.vertcat(v, acc))
        units = self.units
        return Model.build(
            "ephemeris-cr3bp-frame" + ("" if self.srp is None else "-srp") + suffix, x, u, f, t=t,
            p=ca.vertcat(*params), p_default=p_default,
            state_names=["x", "y", "z", "vx", "vy", "vz"],
            control_names=["ux", "uy", "uz"], param_names=names, thrust_param="a_max",
            control_set=self.kind if self.kind in ("ball", "box") else "ball", units=units,
            state_units=units.state_labels(3),
            description=(f"DE421 point masses {list(self.bodies)} (Moon-centred: Patel & Scheeres "
                         f"Eq. 11 plus the frame's indirect term) in the CR3BP rotating frame fixed at epoch {self.epoch} TDB"
                         + ("" if self.srp is None else
                            f", cannonball SRP C_r = {self.srp.cr:g}, A/m = "
                            f"{self.srp.area_to_mass:g} m^2/kg times srp_scale")))

    def _srp_unit_coefficient(self) -> float:
        """``C_r A/m P_1AU (1 AU)^2`` in model units (DU^3/TU^2): the SRP acceleration is this
        times ``d / |d|^3``, ``d`` the Sun-to-spacecraft vector in DU."""
        au = AU_KM / (self.units.length / 1e3)
        return self.srp.coefficient / self.units.acceleration * au**2

    def step(self, x: np.ndarray, u: np.ndarray, w: np.ndarray, t0: float, dt: float) -> np.ndarray:
        f = self.model.f_fun
        acc_c = self.a_max * saturate(u, self.kind) + (self.E @ w)[3:6]
        p, u0, off, C0 = self._p, self._u0, self.t0, self.C0
        k_srp = None if self.srp is None else self._srp_unit_coefficient()
        du_km, tu = self.units.length / 1e3, self.units.time

        def rhs(t, y):
            d = np.asarray(f(y, u0, t - off, p)).ravel()
            d[3:6] += C0 @ (_rz(t - off) @ acc_c)
            if k_srp is not None:  # nominal SRP (srp_scale 1)
                rel = y[:3] - self.ephemeris.position("sun", tu * (t - off), "moon") / du_km
                d[3:6] += k_srp * rel / np.linalg.norm(rel) ** 3
            d[6] = 0.0
            return d

        sol = solve_ivp(rhs, (t0, t0 + dt), self.to_inertial(t0, x), method="DOP853",
                        rtol=self.rtol, atol=self.atol)
        if not sol.success:
            raise SolverError(f"ephemeris plant integration failed at t = {t0:g}: {sol.message}")
        return self.from_inertial(t0 + dt, sol.y[:, -1])

    def describe(self) -> dict:
        """Settings for metrics.json."""
        gm_e, gm_m = self.ephemeris.gm("earth"), self.ephemeris.gm("moon")
        out = {"plant": "ephemeris", "epoch": str(self.epoch), "bodies": list(self.bodies),
               "circular": self.circular, "frame_acceleration": self.frame_acceleration,
               "span_days": self.span_days,
               "frame": "Moon-centred ICRF point masses (Patel & Scheeres Eq. 11 plus the Moon-centred frame's indirect term, DE421 refit); "
                        "CR3BP states through the rotating frame fixed at the epoch (true "
                        "Earth-Moon synodic axes at t0, uniform rotation 1 rad/TU)",
               "mu_de421": float(gm_m / (gm_e + gm_m))}
        if self.srp is not None:
            out["srp"] = self.srp.as_dict()
        return out


__all__ = ["DEFAULT_BODIES", "DEFAULT_EPOCH", "PLANTS", "EphemerisPlant"]
