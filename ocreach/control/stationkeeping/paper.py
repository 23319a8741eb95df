"""Patel & Subbarao, "Station-keeping in the near rectilinear halo orbit": the paper's settings
(non-dimensional: horizon ``N``, initial deviation set ``G_pos``/``G_vel``, disturbance ``W``) and
its result (``Delta V = 0.0061 m/s`` over 157 h), and the initial deviation set they define."""
from __future__ import annotations

import numpy as np

#: Patel & Subbarao's NRHO station-keeping settings (non-dimensional).
PAPER_N = 15
PAPER_G_POS, PAPER_G_VEL = 1e-4, 5e-4
PAPER_W = 1e-7
PAPER_DELTA_V_MPS = 0.0061
PAPER_TF_HOURS = 157.0


def paper_initial_set(problem, g_pos: float = PAPER_G_POS, g_vel: float = PAPER_G_VEL) -> np.ndarray:
    """Diagonal of the initial deviation set: ``g_pos`` on positions, ``g_vel`` on velocities."""
    d = np.zeros(problem.model.n_x)
    d[list(problem.position_dims)] = g_pos
    d[list(problem.velocity_dims)] = g_vel
    return d


__all__ = ["PAPER_DELTA_V_MPS", "PAPER_G_POS", "PAPER_G_VEL", "PAPER_N", "PAPER_TF_HOURS",
           "PAPER_W", "paper_initial_set"]
