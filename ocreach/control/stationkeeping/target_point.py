"""Target-point stationkeeping with state-transition tensors (Howell & Pernicka, "Stationkeeping
method for libration point trajectories", JGCD 16(1), 1993; the high-order version of Fu,
Baresi & Armellin, "A high-order target point approach to the stationkeeping of near rectilinear
halo orbits", 2021, which expands the flow with differential algebra; here with the project's
STTs, :func:`ocreach.dynamics.flow.stt`).  Both cited from memory: only the 2021 paper's title was
available here.

At a burn (once per revolution, apolune by default) the deviation of the estimate from the
reference, ``dx0 = xhat - x_ref(t_b)``, plus the burn, ``dz = dx0 + [0; dv]``, is mapped to
``n_targets`` target points ``t_j = t_b + j s T`` (``s`` = ``spacing_revolutions``, ``T`` the
revolution) by the second-order expansion of the reference flow,

    dx_j = x_ref,flow(t_j) - x_ref(t_j) + Phi1_j dz + 1/2 Phi2_j [dz, dz]

(Foss et al. Eq. 13, composed from the per-step tensors of one :func:`ocreach.dynamics.flow.stt` call:
``Phi1_02 = Phi1_12 Phi1_01``, ``Phi2_02 = Phi1_12 Phi2_01 + Phi2_12 [Phi1_01, Phi1_01]``), and
the burn minimises Howell & Pernicka's cost

    J(dv) = |dv|^2 / s_dv^2 + sum_j ( |dr_j|^2 / s_r^2 + |dv_j|^2 / s_v^2 )

by Gauss-Newton on the three components of ``dv`` (the residual's Jacobian is ``(Phi1_j +
Phi2_j dz)[:, 3:6]``), started from the first-order (linear least-squares) burn.  ``order=1`` is
the classical linear target-point method.  The tensors depend only on the reference and the
burn step, so they are computed once per process for every burn step and shared by all runs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.control.stationkeeping.scenario import ATOL, RTOL, Scenario
from ocreach.errors import ProblemError, check_count, check_positive


@dataclass
class TargetPointControl:
    """Target-point method with STTs (module doc).  ``n_targets`` target points every
    ``spacing_revolutions`` of a revolution after the burn; ``position_scale_km``,
    ``velocity_scale_mps``, ``dv_scale_mps``: the deviations at the targets and the burn that
    cost the same (the weights ``1 / s^2``); ``order`` 1 or 2 (STT order); ``iterations`` of
    Gauss-Newton."""

    n_targets: int = 4
    spacing_revolutions: float = 0.5
    position_scale_km: float = 50.0
    velocity_scale_mps: float = 0.5
    dv_scale_mps: float = 0.05
    order: int = 2
    iterations: int = 8
    name = "target-point"
    placement = "anomaly"

    def __post_init__(self) -> None:
        self.n_targets = check_count("n_targets", self.n_targets, 1)
        self.iterations = check_count("iterations", self.iterations, 1)
        for nm in ("spacing_revolutions", "position_scale_km", "velocity_scale_mps",
                   "dv_scale_mps"):
            setattr(self, nm, check_positive(nm, getattr(self, nm)))
        if self.order not in (1, 2):
            raise ProblemError(f"order (STT order) must be 1 or 2; got {self.order!r}")

    def lookahead(self) -> int:
        return int(np.ceil(self.n_targets * self.spacing_revolutions)) + 1

    def prepare(self, sc: Scenario, settings) -> None:
        self._steps = [int(round(j * self.spacing_revolutions * sc.M))
                       for j in range(1, self.n_targets + 1)]
        if len(set(self._steps)) != len(self._steps) or self._steps[0] < 1:
            raise ProblemError(f"target points {self._steps} steps after the burn must be "
                               f"distinct and after it; raise spacing_revolutions")
        s = np.r_[np.full(3, sc.units.length / 1e3 / self.position_scale_km),
                  np.full(3, sc.units.velocity / self.velocity_scale_mps)]
        self._w_state = s  # residual scale per target component (1 / s in model units)
        self._w_dv = sc.units.velocity / self.dv_scale_mps

    def tensors(self, sc: Scenario, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(offsets (n, 6), Phi1 (n, 6, 6), Phi2 (n, 6, 6, 6))`` from step ``k`` to each
        target (cached on the scenario)."""
        key = ("target-point", k, tuple(self._steps), self.order)
        if key not in sc.cache:
            from ocreach.dynamics.flow import stt

            ks = [k] + [k + d for d in self._steps]
            res = stt(sc.model, sc.X[k], np.zeros((len(ks) - 1, 3)), sc.times[ks], self.order,
                      p=sc.params, rtol=RTOL, atol=ATOL)
            nx = 6
            P1 = np.eye(nx)
            P2 = np.zeros((nx, nx, nx))
            out1, out2 = [], []
            for j in range(len(ks) - 1):
                a = res.phi[0][j][:, :nx]
                b = res.phi[1][j][:, :nx, :nx] if self.order == 2 else np.zeros((nx, nx, nx))
                P2 = (np.einsum("ia,abc->ibc", a, P2)
                      + np.einsum("iab,bc,ad->idc", b, P1, P1))
                P1 = a @ P1
                out1.append(P1)
                out2.append(P2)
            offsets = res.states[1:] - sc.X[ks[1:]]
            sc.cache[key] = (offsets, np.stack(out1), np.stack(out2))
        return sc.cache[key]

    def burn(self, sc: Scenario, k: int, xhat: np.ndarray) -> np.ndarray:
        """Commanded burn (model units, (3,)) from the estimate ``xhat`` at step ``k``."""
        c, P1, P2 = self.tensors(sc, k)
        dx0 = np.asarray(xhat, float) - sc.X[k]
        w = self._w_state

        def residual(dv):
            dz = dx0.copy()
            dz[3:] += dv
            dx = c + np.einsum("nia,a->ni", P1, dz) + 0.5 * np.einsum("niab,a,b->ni", P2, dz, dz)
            Jx = P1[:, :, 3:] + np.einsum("niab,a->nib", P2, dz)[:, :, 3:]
            r = np.concatenate([self._w_dv * dv, (w * dx).ravel()])
            J = np.concatenate([self._w_dv * np.eye(3), (w[None, :, None] * Jx).reshape(-1, 3)])
            return r, J

        dv = np.zeros(3)
        for _ in range(self.iterations):
            r, J = residual(dv)
            step = np.linalg.lstsq(J, -r, rcond=None)[0]
            dv = dv + step
            if np.linalg.norm(step) <= 1e-12:
                break
        return dv

    def describe(self) -> dict:
        return {"controller": self.name, "placement": self.placement, "order": self.order,
                "n_targets": self.n_targets, "spacing_revolutions": self.spacing_revolutions,
                "position_scale_km": self.position_scale_km,
                "velocity_scale_mps": self.velocity_scale_mps, "dv_scale_mps": self.dv_scale_mps,
                "method": "target-point method (Howell & Pernicka 1993) on the second-order "
                          "STT expansion of the reference flow (after Fu, Baresi & Armellin "
                          "2021), Gauss-Newton on the burn"}


__all__ = ["TargetPointControl"]
