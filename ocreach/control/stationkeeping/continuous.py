"""Continuous-thrust reference controllers on the orbit-maintenance loop: the time-varying LQR
(finite-horizon Riccati along the DE421 + SRP reference, :class:`~ocreach.control.lqr.LQR`) and
the nonlinear MPC (:class:`~ocreach.control.mpc.MPC`), both with Patel & Subbarao's Table 3
weights (``Q = diag(1000 I, 100 I)``, ``R = I`` on the thrust acceleration) and the problem's
thrust bound (nrho-9-2: 0.1 N on 1000 kg).

They act on the same estimate as the impulsive controllers (Gaussian OD fixes every
``od_interval_h``, dead-reckoned in between, :mod:`ocreach.control.stationkeeping.navigation`)
at every control step (1.003 h on nrho-9-2), and their thrust is executed with the same
magnitude and pointing errors per step (:mod:`ocreach.control.stationkeeping.execution`; no
minimum burn and no skipped steps: continuous thrust).  The LQR's linearisation is the exact
one-step STM of the reference (:attr:`Scenario.jacobians`).  The MPC predicts with 8 RK4
substeps plus the reference's one-step defect (exact on the reference); a year of it is
about 9000 NLP solves per run, so the Monte Carlo runs the LQR by default.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.control.stationkeeping.scenario import Scenario


def _weights(sc: Scenario):
    from ocreach.control.report import PAPER_Q, paper_pattern

    return paper_pattern(sc.problem, PAPER_Q[0], PAPER_Q[3]), np.ones(3)


@dataclass
class ContinuousLQR:
    """Time-varying LQR with continuous thrust (module doc)."""

    name = "lqr"
    placement = "continuous"

    def lookahead(self) -> int:
        return 1

    def prepare(self, sc: Scenario, settings) -> None:
        from ocreach.control.lqr import LQR

        key = ("lqr", sc.steps)
        if key not in sc.cache:
            Q, R = _weights(sc)
            sc.cache[key] = LQR(Q, R).setup(sc.reference, sc.problem.control_set.kind)
        self._lqr = sc.cache[key]

    def control(self, sc: Scenario, k: int, xhat: np.ndarray) -> np.ndarray:
        return self._lqr.control(k, xhat)

    def describe(self) -> dict:
        return {"controller": self.name, "placement": self.placement,
                "method": "finite-horizon time-varying LQR (Riccati along the DE421 + SRP "
                          "reference), Patel & Subbarao Table 3 weights, continuous thrust"}


@dataclass
class ContinuousMPC:
    """Nonlinear MPC with continuous thrust (module doc); ``n_p`` the horizon (steps)."""

    n_p: int = 15
    max_cpu_time: float = 2.0
    name = "mpc"
    placement = "continuous"

    def lookahead(self) -> int:
        return 1

    def prepare(self, sc: Scenario, settings) -> None:
        from ocreach.control.mpc import MPC

        lqr = ContinuousLQR()
        lqr.prepare(sc, settings)
        Q, R = _weights(sc)
        self._mpc = MPC(Q, R, n_p=self.n_p, n_c=self.n_p, fallback=lqr._lqr,
                        max_cpu_time=self.max_cpu_time, prediction_substeps=8,
                        defect_correction=True)
        self._mpc.setup(sc.reference, sc.problem.control_set.kind)

    def control(self, sc: Scenario, k: int, xhat: np.ndarray) -> np.ndarray:
        return self._mpc.control(k, xhat)

    def describe(self) -> dict:
        return {"controller": self.name, "placement": self.placement, "n_p": self.n_p,
                "method": "nonlinear MPC (Patel & Subbarao Eq. 26-28 without the tube), "
                          "continuous thrust, Table 3 weights"}


__all__ = ["ContinuousLQR", "ContinuousMPC"]
