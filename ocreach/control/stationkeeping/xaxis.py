"""x-axis crossing control: the industry baseline of NRHO orbit maintenance (Guzzetti, Zimovan,
Howell & Davis, "Stationkeeping analysis for spacecraft in lunar near rectilinear halo orbits",
AAS 17-395, 2017; Davis et al., AAS 17-269, 2017; flown by CAPSTONE, the strategy planned for
Gateway).

Once per revolution (at apolune by default) an impulsive burn ``dv`` is computed from the
estimated state so that the trajectory crosses the Earth-Moon x-z plane (``y_syn = 0`` in the
true rotating frame, x from the Earth to the Moon, :meth:`Scenario.synodic_map`, in which the
NRHO is nearly symmetric) near the ``target_revolutions``-th perilune passage downstream with
the baseline's x-velocity there:

    g(dv) = v_x(t_c(dv)) - v_x,ref(t_c,ref) = 0,

``t_c(dv)`` the crossing time of the perturbed trajectory.  In the CR3BP the baseline crosses
perpendicularly (``v_x = 0``); along the DE421 reference the target is its own crossing velocity
(as Davis et al. target the ephemeris baseline).  One scalar condition for three unknowns: the
minimum-norm Newton step ``dv <- dv - J^+ g``.  The crossing is found by Newton on
``y_syn(t) = 0``; the STM ``Phi`` is taken to it, and with ``q = T x + c`` the synodic state,

    J = T Phi[:, v] + q' dt/d(dv),     dt/d(dv) = -(T Phi[:, v])_y / v_y,syn

(``q'`` the synodic state's rate along the trajectory, a central difference).  Iterated until
``|g| <= tolerance``; if ``max_iter`` iterations do not reach it the best iterate is burnt and the
burn record says ``targeting_converged: false``.  ``components`` adds ``v_z`` and the crossing
time ``t`` (the phase-constrained variant of Gateway's later algorithm: Davis et al. 2022 and
Shimane et al. 2025, through a secondary summary); several targets (``target_revolutions`` a
tuple) are met in the least-squares sense (up to three conditions exactly).  Without ``t`` the
burn leaves the phase along the orbit free, so it drifts (Shimane et al. 2025 report about 2 h
over 5 years).  The published budgets of Guzzetti et al. and Davis et al. were not available
here (only their abstracts): docs/validation/orbit-maintenance.md compares with the CAPSTONE
flight and with Zhang et al. 2022 at the same error levels.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.control.stationkeeping.scenario import ATOL, RTOL, Scenario
from ocreach.errors import ProblemError, SolverError, check_count

#: What can be matched at a crossing: x- and z-velocity, crossing time.
COMPONENTS = ("vx", "vz", "t")
#: Newton tolerance on the crossing x-velocity (m/s).
DEFAULT_TOLERANCE_MPS = 1e-3


@dataclass
class XAxisControl:
    """x-axis crossing control (module doc): ``target_revolutions`` (an integer >= 1, or a
    tuple of them: which perilune passages downstream are targeted; 1 = the next one),
    ``components`` (what is matched at each crossing: ``"vx"``, and optionally ``"vz"`` and
    ``"t"``, the crossing time: the phase-constrained variant), ``tolerance_mps`` (Newton
    tolerance on the crossing velocities; a crossing-time error counts as its product with
    1 m/s per minute), ``max_iter``."""

    target_revolutions: int | tuple[int, ...] = 1
    components: tuple[str, ...] = ("vx",)
    tolerance_mps: float = DEFAULT_TOLERANCE_MPS
    max_iter: int = 12
    name = "xaxis"
    placement = "anomaly"

    def __post_init__(self) -> None:
        t = self.target_revolutions
        targets = (t,) if np.ndim(t) == 0 else tuple(t)
        if not targets:
            raise ProblemError("target_revolutions must name at least one perilune passage")
        self.targets = tuple(sorted({check_count("target_revolutions entry", n, 1)
                                     for n in targets}))
        comps = (self.components,) if isinstance(self.components, str) else tuple(self.components)
        if not comps or any(c not in COMPONENTS for c in comps) or len(set(comps)) != len(comps):
            raise ProblemError(f"components must be distinct names from {list(COMPONENTS)}; got "
                               f"{self.components!r}")
        if len(comps) * len(self.targets) > 3:
            raise ProblemError(f"{len(comps)} components at {len(self.targets)} crossings is "
                               f"more than the 3 components of one burn")
        self.components = comps
        if not (np.isfinite(self.tolerance_mps) and self.tolerance_mps > 0):
            raise ProblemError(f"tolerance_mps must be a finite number > 0; got "
                               f"{self.tolerance_mps!r}")
        self.max_iter = check_count("max_iter", self.max_iter, 1)

    def prepare(self, sc: Scenario, settings) -> None:
        sc.perilune_crossings  # noqa: B018 - computed once, shared by the runs of the process

    def lookahead(self) -> int:
        return max(self.targets) + 1

    def burn(self, sc: Scenario, k: int, xhat: np.ndarray) -> np.ndarray:
        """Commanded burn (model units, (3,)) from the estimate ``xhat`` at step ``k``."""
        from ocreach.dynamics.flow import stm_batch

        cross = sc.perilune_crossings
        t_b = sc.times[k]
        later = np.flatnonzero(cross["time"] > t_b)
        if later.size < max(self.targets):
            raise SolverError(f"x-axis control at step {k}: the reference has {later.size} "
                              f"perilune crossings after it; {max(self.targets)} needed")
        idx = later[np.asarray(self.targets) - 1]
        ref_syn, ref_times = cross["synodic"][idx], cross["time"][idx]
        tol = self.tolerance_mps / sc.units.velocity
        t_scale = 60.0 / sc.units.time * sc.units.velocity  # 1 min of crossing time ~ 1 m/s
        col = {"vx": 3, "vz": 5}
        dv = np.zeros(3)
        best = (np.inf, dv)
        for _ in range(self.max_iter):
            x0 = xhat.copy()
            x0[3:] += dv
            g, J = [], []
            for i, tc_ref in enumerate(ref_times):
                tc, _ = sc.synodic_crossing(x0, t_b, tc_ref)
                X1, Phi = stm_batch(sc.model, x0[None], t_b, tc, p=sc.params, rtol=RTOL,
                                    atol=ATOL)
                T, c = sc.synodic_map(tc)
                q = T @ X1[0] + c
                dq = T @ Phi[0][:, 3:6]          # d q / d dv at fixed time
                rate = self._rate(sc, X1[0], tc)  # d q / dt along the trajectory
                dt = -dq[1] / q[4]                # d t_c / d dv (y_syn stays 0)
                for comp in self.components:
                    if comp == "t":
                        g.append((tc - tc_ref) / t_scale)
                        J.append(dt / t_scale)
                    else:
                        m = col[comp]
                        g.append(q[m] - ref_syn[i, m])
                        J.append(dq[m] + rate[m] * dt)
            g, J = np.asarray(g), np.asarray(J)
            err = float(np.max(np.abs(g)))
            if err < best[0]:
                best = (err, dv.copy())
            if err <= tol:
                self.last_converged = True
                return dv
            dv = dv - np.linalg.lstsq(J, g, rcond=None)[0]
        # not converged: burn the best iterate (as operations would) and say so in the record
        self.last_converged = False
        return best[1]

    @staticmethod
    def _rate(sc: Scenario, x: np.ndarray, t: float, h: float = 1e-4) -> np.ndarray:
        """``d/dt`` of the synodic state along the trajectory through ``x`` at ``t`` (central
        difference over +-h TU, about 38 s)."""
        from ocreach.dynamics.flow import propagate

        xs = propagate(sc.model, x, np.zeros((1, 3)), [t, t + h], p=sc.params, rtol=RTOL,
                       atol=ATOL)[-1]
        xm = propagate(sc.model, x, np.zeros((1, 3)), [t, t - h], p=sc.params, rtol=RTOL,
                       atol=ATOL)[-1]
        return (sc.synodic(t + h, xs) - sc.synodic(t - h, xm)) / (2.0 * h)

    def describe(self) -> dict:
        return {"controller": self.name, "placement": self.placement,
                "target_revolutions": list(self.targets), "components": list(self.components),
                "tolerance_mps": self.tolerance_mps,
                "method": "x-axis crossing control (Guzzetti et al. AAS 17-395; Davis et al. "
                          "AAS 17-269): minimum-norm Newton on the baseline x-velocity at the "
                          "targeted perilune y = 0 crossings"}


__all__ = ["XAxisControl"]
