"""Two-body dynamics with low thrust (Patel & Subbarao Eq. 6)."""
from __future__ import annotations

import casadi as ca

from ocreach.model import Model
from ocreach.units import Units


def twobody(*, mu: float = 1.0, a_max: float = 1e-3, control_set: str = "ball",
            units: Units | None = None) -> Model:
    """Keplerian motion ``r'' = -mu r / |r|^3 + a_max u`` in 3-D; parameters ``[mu, a_max]``.

    ``a_max`` defaults to 1e-3 (0.1 % of the central gravity at unit radius, a typical low-thrust
    level; a problem needs a thrust > 0).
    """
    r = ca.SX.sym("r", 3)
    v = ca.SX.sym("v", 3)
    u = ca.SX.sym("u", 3)
    mu_s = ca.SX.sym("mu")
    a_s = ca.SX.sym("a_max")
    f = ca.vertcat(v, -mu_s * r / ca.norm_2(r) ** 3 + a_s * u)
    return Model.build(
        "twobody", ca.vertcat(r, v), u, f, p=ca.vertcat(mu_s, a_s), p_default=[mu, a_max],
        state_names=["x", "y", "z", "vx", "vy", "vz"], control_names=["ux", "uy", "uz"],
        param_names=["mu", "a_max"], thrust_param="a_max", control_set=control_set, units=units,
        description="two-body problem with thrust acceleration a_max * u",
        state_units=(units or Units(length=1.0, time=1.0)).state_labels(3))
