"""Modified equinoctial elements (Walker, Ireland & Owens, Celest. Mech. 36, 1985) of a two-body model.

``z = (p, f, g, h, k, L)``: semi-latus rectum ``p = |r x v|^2 / mu``, the eccentricity vector in the
equinoctial frame ``(f, g)``, the node vector ``(h, k) = tan(i/2) (cos Omega, sin Omega)`` and the
true longitude ``L``.  Keplerian motion leaves ``p, f, g, h, k`` constant and moves ``L`` only,
``dL/dt = sqrt(mu p) (w / p)^2``, ``w = 1 + f cos L + g sin L``: the thrust is then the only thing
that changes the first five, which is why sets stay nearly linear over many revolutions.

The elements are singular for ``i = 180 deg`` (retrograde equatorial orbits: ``1 + cos i = 0``) and
for rectilinear motion (``r x v = 0``); zero eccentricity and zero inclination are regular.  ``L``
is continuous along a trajectory (not reduced modulo 2 pi); ``phi`` measures it from a reference
angle ``L_ref`` (the initial state's, so that the initial set does not straddle the branch cut of
``atan2``).

Two charts:

* ``mee``: time stays the independent variable (Walker et al. Eq. 9 are what the chain rule of the
  model gives);
* ``mee-longitude``: the true longitude is the independent variable, ``dt/dL = 1 / (dL/dt)``; then
  Keplerian motion is the identity on ``(p, f, g, h, k)`` and the time is a state.

For a thrust ball the control is taken in the orbit's radial / transverse / normal frame (the
ball is the same ball in any frame), and the chart declares the simplified forms of its chain rule
(Keplerian motion, Walker et al.'s perturbation equations), checked against the model before use
(:mod:`ocreach.models.coordinates.chart`, "Simplified forms").
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError
from ocreach.model import Model
from ocreach.models.coordinates.chart import Chart

CITATION = ("M. J. H. Walker, B. Ireland & J. Owens, \"A set of modified equinoctial orbit "
            "elements\", Celestial Mechanics 36, 409-419 (1985)")
NAMES = ("p", "f", "g", "h", "k", "L")


def two_body_fit(model: Model) -> tuple[bool, str]:
    """``(True, "")`` if ``model`` is a two-body model the elements fit: Cartesian state
    ``(x, y, z, vx, vy, vz)`` about a central body at the origin with parameter ``mu``."""
    if not model.name.startswith("twobody") or model.n_x != 6 or "mu" not in model.param_names:
        return False, (f"the modified equinoctial elements need a two-body model (central body at "
                       f"the origin, state x, y, z, vx, vy, vz, parameter mu); model "
                       f"{model.name!r} has states {list(model.state_names)}")
    return True, ""


def _cross(a: ca.SX, b: ca.SX) -> ca.SX:
    return ca.vertcat(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                      a[0] * b[1] - a[1] * b[0])


def elements(x: ca.SX, mu: ca.SX, L_ref: float) -> tuple[ca.SX, ca.SX]:
    """``(z, valid)``: the elements of the Cartesian state ``x`` (Walker et al. Eq. 1-4 inverted)
    and the expressions that must be > 0 (``|r|``, ``|r x v|``, ``1 + cos i``)."""
    r, v = x[:3], x[3:]
    hv = _cross(r, v)
    hm = ca.norm_2(hv)
    rm = ca.norm_2(r)
    p = hm**2 / mu
    one_cos_i = 1 + hv[2] / hm
    h = -hv[1] / (hm + hv[2])
    k = hv[0] / (hm + hv[2])
    s2 = 1 + h**2 + k**2
    a2 = h**2 - k**2
    fhat = ca.vertcat(1 + a2, 2 * h * k, -2 * k) / s2
    ghat = ca.vertcat(2 * h * k, 1 - a2, 2 * h) / s2
    e = _cross(v, hv) / mu - r / rm
    X, Y = ca.dot(r, fhat), ca.dot(r, ghat)
    c, s = np.cos(L_ref), np.sin(L_ref)
    L = L_ref + ca.atan2(c * Y - s * X, c * X + s * Y)
    return ca.vertcat(p, ca.dot(e, fhat), ca.dot(e, ghat), h, k, L), ca.vertcat(rm, hm, one_cos_i)


def cartesian(z: ca.SX, mu: ca.SX) -> tuple[ca.SX, ca.SX]:
    """``(x, valid)``: position and velocity of the elements ``z`` (Walker et al. Eq. 3-4) and the
    expressions that must be > 0 (``p``, ``w = p / r``)."""
    p, f, g, h, k, L = (z[i] for i in range(6))
    cL, sL = ca.cos(L), ca.sin(L)
    w = 1 + f * cL + g * sL
    s2 = 1 + h**2 + k**2
    a2 = h**2 - k**2
    rr = p / w
    r = rr / s2 * ca.vertcat(cL + a2 * cL + 2 * h * k * sL, sL - a2 * sL + 2 * h * k * cL,
                             2 * (h * sL - k * cL))
    q = ca.sqrt(mu / p) / s2
    v = -q * ca.vertcat(sL + a2 * sL - 2 * h * k * cL + g - 2 * f * h * k + a2 * g,
                        -cL + a2 * cL + 2 * h * k * sL - f + 2 * g * h * k + a2 * f,
                        -2 * (h * cL + k * sL + f * h + g * k))
    return ca.vertcat(r, v), ca.vertcat(p, w)


def reference_longitude(x0: np.ndarray) -> float:
    """The true longitude of ``x0`` in (-pi, pi] (float), used as ``L_ref``."""
    r, v = np.asarray(x0[:3], float), np.asarray(x0[3:6], float)
    hv = np.cross(r, v)
    den = np.linalg.norm(hv) + hv[2]
    if not den > 0:
        raise ProblemError("the modified equinoctial elements are singular for this state: its "
                           "orbit is retrograde equatorial (inclination 180 deg) or rectilinear "
                           f"(r x v = {hv.tolist()}); use coordinates='cartesian'")
    h, k = -hv[1] / den, hv[0] / den
    s2 = 1 + h * h + k * k
    a2 = h * h - k * k
    fhat = np.array([1 + a2, 2 * h * k, -2 * k]) / s2
    ghat = np.array([2 * h * k, 1 - a2, 2 * h]) / s2
    return float(np.arctan2(r @ ghat, r @ fhat))


def perturbation_matrix(z: ca.SX, mu: ca.SX) -> ca.SX:
    """``dz/dt`` per unit acceleration in the radial / transverse / normal frame (Walker et al.
    1985, the perturbation equations of the modified equinoctial elements), ``6 x 3``."""
    p, f, g, h, k, L = (z[i] for i in range(6))
    cL, sL = ca.cos(L), ca.sin(L)
    w = 1 + f * cL + g * sL
    s2 = 1 + h**2 + k**2
    q = ca.sqrt(p / mu)
    hk = h * sL - k * cL
    zero = ca.SX(0)
    rows = [(zero, 2 * p / w * q, zero),
            (q * sL, q * ((w + 1) * cL + f) / w, -q * g * hk / w),
            (-q * cL, q * ((w + 1) * sL + g) / w, q * f * hk / w),
            (zero, zero, q * s2 * cL / (2 * w)),
            (zero, zero, q * s2 * sL / (2 * w)),
            (zero, zero, q * hk / w)]
    return ca.vertcat(*[ca.horzcat(*r) for r in rows])


def rtn_frame(x: ca.SX) -> ca.SX:
    """The orbit's radial / transverse / normal axes as the columns of a 3 x 3 matrix."""
    r, v = x[:3], x[3:6]
    rh = r / ca.norm_2(r)
    hv = _cross(r, v)
    nh = hv / ca.norm_2(hv)
    return ca.horzcat(rh, _cross(nh, rh), nh)


def mee_chart(model: Model, x0: np.ndarray, *, longitude: bool = False, rtn: bool = True,
              simplified: bool = True) -> Chart:
    """The modified equinoctial elements of a two-body ``model`` (module docstring); with
    ``longitude=True`` the true longitude is the independent variable; with ``rtn=True`` the
    control is given in the orbit's radial / transverse / normal frame (ball control sets); with
    ``simplified=True`` the chart declares Keplerian motion and (in that frame) Walker et al.'s
    perturbation equations as the simplified forms of its chain rule, verified against the model
    (:class:`~ocreach.models.coordinates.chart.Chart`); ``False``: the chain rule alone."""
    ok, why = two_body_fit(model)
    if not ok:
        raise ProblemError(why)
    mu = model.p[model.param_names.index("mu")]
    L_ref = reference_longitude(x0)
    z = ca.SX.sym("mee", 6)
    phi, valid_x = elements(model.x, mu, L_ref)
    psi, valid_z = cartesian(z, mu)
    P, f, g, L = z[0], z[1], z[2], z[5]
    w = 1 + f * ca.cos(L) + g * ca.sin(L)
    kepler = ca.vertcat(0, 0, 0, 0, 0, ca.sqrt(mu * P) * (w / P) ** 2)   # Walker et al. Eq. 9
    length = model.units.length_label if model.units is not None else "DU"
    name = "mee-longitude" if longitude else "mee"
    desc = ("modified equinoctial elements (p, f, g, h, k, L)"
            + (" with the true longitude L as independent variable" if longitude else "")
            + (", control in the radial / transverse / normal frame" if rtn else "")
            + ("" if simplified else ", dynamics by the chain rule alone"))
    return Chart(
        name=name, model=model, z=z, phi=phi, psi=psi, names=NAMES,
        units=(length, "", "", "", "", "rad"), valid_x=valid_x, valid_z=valid_z,
        valid_why=("the elements are singular where |r| = 0, r x v = 0 (rectilinear) or the "
                   "inclination is 180 deg (retrograde equatorial), and their inverse where "
                   "p <= 0 or w = 1 + f cos L + g sin L <= 0"),
        drift=kepler if simplified else None,
        drift_name="Keplerian motion about a central body at the origin",
        input_matrix=perturbation_matrix(z, mu) if (simplified and rtn) else None,
        control_frame=rtn_frame(model.x) if rtn else None,
        independent=5 if longitude else None, s_name="L" if longitude else "t",
        s_unit="rad" if longitude else "TU", description=desc, citation=CITATION)
