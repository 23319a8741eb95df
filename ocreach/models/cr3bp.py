"""Circular restricted three-body problem with low thrust (Foss et al. Eq. 5, 7; Patel & Subbarao Eq. 7)."""
from __future__ import annotations

import casadi as ca

from ocreach.errors import ProblemError, check_positive
from ocreach.model import Model
from ocreach.units import G0, Units

_ND = Units(length=1.0, time=1.0, name="non-dimensional")  # labels DU, DU/TU without units


def cr3bp(
    mu: float,
    *,
    planar: bool = False,
    a_max: float = 0.0,
    control_set: str = "ball",
    variable_mass: bool = False,
    thrust: float | None = None,
    isp: float | None = None,
    units: Units | None = None,
) -> Model:
    """CR3BP in the rotating barycentric frame with thrust acceleration ``a_max * B u``.

    State ``[x, y, (z,) vx, vy, (vz)]``; control ``u`` normalised (``||u||_2 <= 1`` or a box).
    Parameters ``p = [mu, a_max]``: ``a_max = T_max / m`` in model units (Foss Eq. 7).

    With ``variable_mass=True`` the state gains the inverse mass ``n = 1/m`` (1/kg, Patel & Scheeres
    Eq. 11) and the parameters become ``[mu, T_max_nd, c_nd]`` where ``T_max_nd`` is the thrust in
    model units (kg DU / TU^2) and ``c_nd = g0 Isp`` in DU/TU; then ``dv/dt += T_max n u`` and
    ``dn/dt = T_max n^2 ||u|| / c``.
    """
    if not 0 < mu < 0.5:
        raise ProblemError(f"mu must be in (0, 0.5); got {mu!r}")
    d = 2 if planar else 3
    pos = ca.SX.sym("r", d)
    vel = ca.SX.sym("v", d)
    u = ca.SX.sym("u", d)
    mu_s = ca.SX.sym("mu")
    x3 = pos[0]
    y3 = pos[1]
    z3 = 0 if planar else pos[2]
    r1 = ca.sqrt((x3 + mu_s) ** 2 + y3**2 + z3**2)
    r2 = ca.sqrt((x3 - 1 + mu_s) ** 2 + y3**2 + z3**2)
    ax = x3 + 2 * vel[1] - (1 - mu_s) * (x3 + mu_s) / r1**3 - mu_s * (x3 - 1 + mu_s) / r2**3
    ay = y3 - 2 * vel[0] - (1 - mu_s) * y3 / r1**3 - mu_s * y3 / r2**3
    grav = [ax, ay] if planar else [ax, ay, -(1 - mu_s) * z3 / r1**3 - mu_s * z3 / r2**3]
    names = ["x", "y", "vx", "vy"] if planar else ["x", "y", "z", "vx", "vy", "vz"]
    cnames = ["ux", "uy"] if planar else ["ux", "uy", "uz"]
    kind = "planar" if planar else "spatial"
    if not variable_mass:
        a_s = ca.SX.sym("a_max")
        f = ca.vertcat(vel, ca.vertcat(*grav) + a_s * u)
        return Model.build(
            f"cr3bp-{kind}", ca.vertcat(pos, vel), u, f, p=ca.vertcat(mu_s, a_s),
            p_default=[mu, a_max], state_names=names, control_names=cnames,
            param_names=["mu", "a_max"], thrust_param="a_max", control_set=control_set, units=units,
            description=f"{kind} CR3BP, mu = {mu}, thrust acceleration a_max * u",
            state_units=(units or _ND).state_labels(d))
    if units is None or thrust is None or isp is None:
        raise ProblemError("variable_mass=True needs units, thrust (N) and isp (s)")
    check_positive("thrust", thrust)
    check_positive("isp", isp)
    n = ca.SX.sym("n")
    T_s = ca.SX.sym("T_max")
    c_s = ca.SX.sym("c_ex")
    unorm = ca.sqrt(ca.sumsqr(u) + 1e-30)
    sigma = ca.SX.sym("sigma")  # ||u|| (throttle), see Model.throttle
    f_sigma = ca.vertcat(vel, ca.vertcat(*grav) + T_s * n * u, T_s * n**2 * sigma / c_s)
    f = ca.substitute(f_sigma, sigma, unorm)
    T_nd = thrust / (units.length / units.time**2)  # kg * DU / TU^2 (mass kept in kg)
    c_nd = G0 * isp / units.velocity
    return Model.build(
        f"cr3bp-{kind}-mass", ca.vertcat(pos, vel, n), u, f, p=ca.vertcat(mu_s, T_s, c_s),
        p_default=[mu, T_nd, c_nd], state_names=names + ["n"], control_names=cnames,
        param_names=["mu", "T_max", "c_ex"], thrust_param="T_max", control_set=control_set, units=units,
        throttle=(sigma, f_sigma),
        description=f"{kind} CR3BP with inverse mass n = 1/m (1/kg), mu = {mu}",
        state_units=units.state_labels(d, ("1/kg",)))
