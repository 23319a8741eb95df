"""A chaser near a target on a circular orbit (Clohessy-Wiltshire), with bounded low thrust."""
import casadi as ca
import numpy as np

import ocreach


def cw_chaser(t_final: float = 1.0, dt: float = 0.1, a_max: float = 1e-3) -> ocreach.Problem:
    """In-plane CW equations (lengths in orbit radii, time in 1 / mean motion), x radial."""
    x = ca.SX.sym("x", 4)  # x, y, vx, vy
    u = ca.SX.sym("u", 2)  # thrust vector, ||u|| <= 1
    a = ca.SX.sym("a_max")  # thrust acceleration at ||u|| = 1
    f = ca.vertcat(x[2], x[3], 3 * x[0] + 2 * x[3] + a * u[0], -2 * x[2] + a * u[1])
    model = ocreach.Model.build("cw", x, u, f, p=a, p_default=[a_max], param_names=["a_max"],
                                state_names=["x", "y", "vx", "vy"], control_set="ball",
                                thrust_param="a_max")
    return ocreach.Problem(id="cw-chaser", model=model, x0=np.array([0.0, -0.01, 0.0, 0.0]),
                           grid=np.linspace(0.0, t_final, round(t_final / dt) + 1),
                           position_dims=(0, 1), velocity_dims=(2, 3),
                           description="chaser 1 % of the orbit radius behind its target")


PROBLEMS = {"cw-chaser": cw_chaser}
