"""Van der Pol oscillator with an input (Foss et al. Sec. 3.1, Eq. 20)."""
from __future__ import annotations

import casadi as ca

from ocreach.model import Model


def vanderpol(*, gain: float = 0.05, mu: float = 1.0) -> Model:
    """``x1' = x2``, ``x2' = mu (1 - x1^2) x2 - x1 + gain * u`` with ``u in [-1, 1]``."""
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    g = ca.SX.sym("gain")
    m = ca.SX.sym("mu")
    f = ca.vertcat(x[1], m * (1 - x[0] ** 2) * x[1] - x[0] + g * u[0])
    return Model.build(
        "vanderpol", x, u, f, p=ca.vertcat(m, g), p_default=[mu, gain],
        state_names=["x1", "x2"], control_names=["u"], param_names=["mu", "gain"],
        thrust_param="gain", control_set="box", description="Van der Pol oscillator with input gain * u, |u| <= 1")
