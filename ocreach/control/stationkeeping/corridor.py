"""Reachable-set corridor control: impulsive orbit maintenance that burns only when the
reachable set of the true state would leave a corridor around the reference without the burn,
and then burns the least Delta-V that keeps the reachable sets of the coming opportunities in
the corridor.

**Opportunities and the corridor.**  One burn opportunity per revolution, where the reference
passes the true anomaly ``burn_anomaly_deg`` (apolune by default), with an OD fix there: the
same opportunities, fixes and random draws as x-axis control and the target-point method.  The
corridor is a box ``C`` of half-widths ``corridor_position_km`` / ``corridor_velocity_mps`` per
axis on the deviation from the reference at the opportunities (default Patel & Subbarao's
initial deviation set, 1e-4 DU and 5e-4 DU/TU: 38.4 km and 0.512 m/s, :data:`PAPER_CORRIDOR`),
and between two opportunities the drift tube of that box, ``|Phi(j, r_a)| C`` (every deviation
a drifting state that starts in ``C`` reaches, to first order).  So a state whose deviation at
an opportunity lies in ``C`` stays in the corridor until the next one, and the sets need only
be checked at the opportunities.  The loop checks the *true* state against the corridor at
every step (``corridor_max_ratio``, ``corridor_exit_steps`` in the run record).

**The sets.**  At opportunity ``a`` (step ``r_a``) the estimate's deviation is ``d = xhat -
x_ref``; the true deviation lies in ``d - N``, ``N`` the navigation ellipsoid ``{e : e^T
Sigma^-1 e <= k^2}`` (``k^2`` the chi-square(6) quantile 0.999, :data:`~ocreach.control.
stationkeeping.navigation.ENCLOSURE_SIGMA`).  With ``Phi_a`` the STM from ``r_a`` to
``r_{a+1}`` (the exact products of the reference's step STMs) and a burn ``dv``, the set at the
next opportunity lies in the box (per axis ``i``)

    |(Phi_a (d + [0; dv]))_i| + k |Sigma^1/2 Phi_a,i^T| + c_e |dv| |Phi_a,i,v| + w_a,i:

the predicted deviation, the support of the mapped navigation ellipsoid, the execution error
(a ball of radius ``c_e |dv|`` around the command that holds the executed burn with
probability 0.999, :func:`execution_bound`; ``execution_in_tube=False`` leaves it out) and the drift tube of the
SRP dispersion box ``w`` (the part of SRP no controller knows, :func:`~ocreach.control.
stationkeeping.impulsive_tube.srp_disturbance`), ``w_a = sum_q |Phi(r_{a+1}, q + 1) B_q| w /
a_max``.  At the opportunity itself: ``|d_i| + k sigma_i``, and ``c_e |dv|`` more on the
velocity rows after a burn.  First order in the deviation (no remainder bound): the loop's
check of the true state is the evidence that this is enough at the corridor's size.

**The plan** (a second-order cone program, cvxpy + Clarabel): one burn per opportunity over
``horizon_revolutions`` ``H`` opportunities, ``dv_0 .. dv_{H-1}``, minimising

    sum_l |dv_l| + |ell . (z_{H-1} + [0; dv_{H-1}])|

subject to the sets staying in ``C``: the velocity rows at the opportunity, and at opportunity
``a + m`` (``m = 1 .. H``) the predicted deviation ``z_m = Phi(r_{a+m}, r_a) d + sum_{l<m}
Phi(r_{a+m}, r_{a+l}) [0; dv_l]`` widened by the tube of one revolution, ``|z_m| + k
|Sigma^1/2 Phi_{a+m-1}^T| + c_e |dv_{m-1}| |Phi_{a+m-1, v}| + w_{a+m-1} <= C``.  The
navigation tube spans one revolution because each later burn is computed again from the
fresh fix at its opportunity (the plan is re-solved there, only ``dv_0`` is executed).  The
second term is the cost to go: ``ell`` the left eigenvector of the growing mode of the
revolution after the last planned burn (``Phi_{a+H-1}``, eigenvalue 1.8-2.7 along the 9:2
NRHO), scaled so that ``|ell . z|`` is the Delta-V of the one impulse that nulls the mode
there (``null_unstable=False`` drops it).  Without it a fuel-minimal plan leaves the growing
mode at the corridor's edge at the end of its horizon and pays for its growth every
revolution; with it, removing the mode early (cheaper by the growth factor) is preferred, and
the other modes (the phase along the orbit, the neutral pair) are corrected only when the
corridor needs it.

**Trigger.**  No burn when the plan's first burn is zero, or below the minimum burn and the plan
without it (``dv_0 = 0``) still keeps every set in ``C``: the skip is certified by the
reachable set (its gauge at the next opportunity is below 1 whatever the navigation error in
``N``; recorded as ``gauge``).  A first burn below the minimum that cannot be deferred becomes
the smallest executable one (the plan solved again with ``a . dv_0 >= min_burn``, ``a`` its
direction).  When no plan keeps the sets in ``C`` (a deviation already outside, a tube wider
than the corridor) the plan minimising the worst ratio ``t`` (rows ``<= C (1 + t)``) is solved
first and the least Delta-V within it is burnt; the burn record says ``corridor_met: false``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from ocreach.control.stationkeeping.impulsive_tube import srp_disturbance
from ocreach.control.stationkeeping.navigation import ENCLOSURE_SIGMA
from ocreach.control.stationkeeping.scenario import Scenario
from ocreach.errors import ProblemError, SolverError, check_count, check_positive

#: Patel & Subbarao's initial deviation set, 1e-4 DU and 5e-4 DU/TU per axis (km, m/s).
PAPER_CORRIDOR = (38.44, 0.5123)
#: A planned first burn below this (cm/s, the solver's resolution) is no burn.
ZERO_BURN_CMPS = 1e-6
#: Probability that the executed burn lies in the execution ball of the sets.
EXECUTION_QUANTILE = 0.999


def execution_bound(execution) -> float:
    """``c_e``: the executed burn of a command ``dv`` lies within ``c_e |dv|`` of it with
    probability 0.999 (:data:`EXECUTION_QUANTILE`).  The execution
    (:class:`~ocreach.control.stationkeeping.execution.ExecutionErrors`) is ``(1 + eps) |dv| u``,
    ``u`` the direction tilted by the vector ``tau`` of two independent angles, so the chord
    ``|u - dv/|dv||`` is at most ``|tau|`` and ``|executed - dv| / |dv| = sqrt(eps^2 + (1 + eps)
    chord^2) <= sqrt(1 + |eps|) sqrt(eps^2 + |tau|^2)``; the three Gaussians ``(eps, tau)`` lie in
    ``eps^2 / s_m^2 + |tau|^2 / s_p^2 <= z^2`` (``z^2`` the chi-square(3) quantile) with that
    probability, where ``sqrt(eps^2 + |tau|^2) <= z max(s_m, s_p)``."""
    z = float(np.sqrt(chi2.ppf(EXECUTION_QUANTILE, 3)))
    s_m = execution.magnitude_sigma
    s = max(s_m, float(np.deg2rad(execution.pointing_sigma_deg)))
    return z * s * float(np.sqrt(1.0 + z * s_m))


@dataclass
class CorridorControl:
    """Reachable-set corridor control (module doc): ``corridor_position_km`` /
    ``corridor_velocity_mps`` (half-widths of the corridor box per axis at the opportunities,
    > 0), ``horizon_revolutions`` (burn opportunities in the plan, >= 1), ``execution_in_tube``
    (the execution-error ball in the sets), ``null_unstable`` (the plan's cost to go on the
    growing mode)."""

    corridor_position_km: float = PAPER_CORRIDOR[0]
    corridor_velocity_mps: float = PAPER_CORRIDOR[1]
    horizon_revolutions: int = 3
    execution_in_tube: bool = True
    null_unstable: bool = True
    name = "corridor"
    placement = "anomaly"

    def __post_init__(self) -> None:
        for nm in ("corridor_position_km", "corridor_velocity_mps"):
            setattr(self, nm, check_positive(nm, getattr(self, nm)))
        self.horizon_revolutions = check_count("horizon_revolutions (opportunities planned)",
                                               self.horizon_revolutions, 1)
        for nm in ("execution_in_tube", "null_unstable"):
            if not isinstance(getattr(self, nm), (bool, np.bool_)):
                raise ProblemError(f"{nm} must be True or False; got {getattr(self, nm)!r}")

    def lookahead(self) -> int:
        return self.horizon_revolutions + 1

    # ------------------------------------------------------------------ setup
    def prepare(self, sc: Scenario, settings) -> None:
        """Per process: the opportunities over the whole reference, the one-revolution STMs
        between them and the tube terms of each (module doc)."""
        units = sc.units
        self._C = np.r_[np.full(3, self.corridor_position_km * 1e3 / units.length),
                        np.full(3, self.corridor_velocity_mps / units.velocity)]
        self._min_burn = settings.execution.min_burn_mps / units.velocity
        self._ce = execution_bound(settings.execution) if self.execution_in_tube else 0.0
        sigma = settings.navigation.sigma(units)
        self._nav0 = ENCLOSURE_SIGMA * sigma
        opp = sc.anomaly_steps(settings.burn_anomaly_deg, last=sc.X.shape[0] - 1)
        A, B = sc.jacobians
        a_max = float(sc.params[list(sc.model.param_names).index("a_max")])
        w_u = srp_disturbance(sc) / a_max  # the SRP dispersion box as a thrust box
        n = opp.size - 1
        self._opp = opp
        self._index = {int(k): i for i, k in enumerate(opp)}
        self._Phi = np.empty((n, 6, 6))
        self._nav = np.empty((n, 6))
        self._exe = np.empty((n, 6))
        self._srp = np.empty((n, 6))
        self._ell = np.empty((n, 6))
        for i in range(n):
            P, srp = np.eye(6), np.zeros(6)
            for q in range(int(opp[i + 1]) - 1, int(opp[i]) - 1, -1):  # backwards: Phi(r_b, q+1)
                srp += np.abs(P @ B[q]) @ np.full(3, w_u)
                P = P @ A[q]
            self._Phi[i] = P
            self._nav[i] = ENCLOSURE_SIGMA * np.linalg.norm(P * sigma[None, :], axis=1)
            self._exe[i] = self._ce * np.linalg.norm(P[:, 3:], axis=1)
            self._srp[i] = srp
            # the growing mode: left eigenvector of the largest eigenvalue, per unit of the
            # Delta-V that nulls it with one impulse (ell . [0; dv] = 1 for |dv| = 1)
            w, V = np.linalg.eig(P.T)
            ell = np.real(V[:, int(np.argmax(np.abs(w)))])
            self._ell[i] = ell / np.linalg.norm(ell[3:])
        self.corridor_half_widths = self._corridor_tube(sc, opp)
        self._solver = None

    def _corridor_tube(self, sc: Scenario, opp: np.ndarray) -> np.ndarray:
        """Half-widths (N + 1, 6) of the corridor along the reference: the box ``C`` at every
        opportunity (and at step 0) and its drift tube ``|Phi(j, r_a)| C`` after it."""
        A = sc.jacobians[0]
        N = A.shape[0]
        h = np.empty((N + 1, 6))
        starts = sorted({0, *(int(k) for k in opp)})
        for s, e in zip(starts, starts[1:] + [N + 1], strict=True):
            P = np.eye(6)
            for j in range(s, e):
                h[j] = np.abs(P) @ self._C
                if j < N:
                    P = A[j] @ P
        return h

    # ------------------------------------------------------------------ the gauge
    def _opportunity(self, sc: Scenario, k: int) -> int:
        a = self._index.get(int(k))
        if a is None:
            raise SolverError(f"corridor control: step {k} is not a burn opportunity")
        if a + self.horizon_revolutions >= len(self._opp):
            raise SolverError(f"corridor control at step {k}: the reference has "
                              f"{len(self._opp) - 1 - a} opportunities after it; "
                              f"{self.horizon_revolutions} needed (raise lookahead)")
        return a

    def gauge(self, sc: Scenario, k: int, xhat: np.ndarray) -> float:
        """The reachable-set gauge of the estimate at opportunity step ``k`` without a burn: the
        largest ratio of the set box to the corridor, at ``k`` and at the next opportunity."""
        a = self._opportunity(sc, k)
        d = np.asarray(xhat, float) - sc.X[k]
        now = (np.abs(d) + self._nav0) / self._C
        nxt = (np.abs(self._Phi[a] @ d) + self._nav[a] + self._srp[a]) / self._C
        return float(max(now.max(), nxt.max()))

    def triggered(self, sc: Scenario, k: int, xhat: np.ndarray) -> bool:
        """Solve the plan at opportunity ``k``; a burn when its first burn is needed now
        (module doc), none when a plan without it keeps every set in the corridor."""
        self._plan_dv = self._plan(sc, k, xhat)
        return self._plan_dv is not None

    def burn(self, sc: Scenario, k: int, xhat: np.ndarray) -> np.ndarray:
        """Commanded burn (model units, (3,)): the first burn of the plan of :meth:`triggered`
        (solved here when the loop did not ask)."""
        dv = getattr(self, "_plan_dv", None)
        self._plan_dv = None
        if dv is None:
            dv = self._plan(sc, k, xhat)
        return np.zeros(3) if dv is None else dv

    # ------------------------------------------------------------------ the plan
    def _rows(self, sc: Scenario, a: int, d: np.ndarray):
        """The plan's rows divided by the corridor, with the burns in units of 1 cm/s: ``|M x +
        b| + E norms(x) <= c (+ t)``; ``x`` the stacked burns (3 H)."""
        H = self.horizon_revolutions
        scale = 0.01 / sc.units.velocity
        C = self._C
        M = np.zeros((3 + 6 * H, 3 * H))
        b = np.zeros(3 + 6 * H)
        c = np.zeros(3 + 6 * H)
        E = np.zeros((3 + 6 * H, H))
        M[:3, :3] = np.eye(3) * scale / C[3:, None]
        b[:3] = d[3:] / C[3:]
        c[:3] = 1.0 - self._nav0[3:] / C[3:]
        E[:3, 0] = self._ce * scale / C[3:]
        # z_m = Phi(r_{a+m}, r_a) d + sum_{l<m} Phi(r_{a+m}, r_{a+l})[:, 3:] dv_l
        prop = [np.eye(6)]  # prop[l] = Phi(r_{a+m}, r_{a+l}) for the current m
        for m in range(1, H + 1):
            P = self._Phi[a + m - 1]
            prop = [P @ Q for Q in prop] + [np.eye(6)]
            rows = slice(3 + 6 * (m - 1), 3 + 6 * m)
            for lag in range(m):
                M[rows, 3 * lag:3 * lag + 3] = prop[lag][:, 3:] * scale / C[:, None]
            b[rows] = prop[0] @ d / C
            i = a + m - 1
            c[rows] = 1.0 - (self._nav[i] + self._srp[i]) / C
            E[rows, m - 1] = self._exe[i] * scale / C
        # the cost to go: the Delta-V that nulls the growing mode left after the last burn
        ell = self._ell[a + H - 1]
        g = np.zeros(3 * H)
        if self.null_unstable:
            back = [np.eye(6)]  # back[l] = Phi(r_{a+H-1}, r_{a+l})
            for m in range(1, H):
                back = [self._Phi[a + m - 1] @ Q for Q in back] + [np.eye(6)]
            for lag in range(H):
                g[3 * lag:3 * lag + 3] = ell @ back[lag][:, 3:]
            g0 = float(ell @ back[0] @ d) / scale
        else:
            g0 = 0.0
        return M, b, c, E, g, g0, scale

    def _problems(self):
        import cvxpy as cp

        H = self.horizon_revolutions
        R = 3 + 6 * H
        x = cp.Variable(3 * H)
        t = cp.Variable(nonneg=True)
        M, b, c = cp.Parameter((R, 3 * H)), cp.Parameter(R), cp.Parameter(R)
        E = cp.Parameter((R, H), nonneg=True)
        t_max = cp.Parameter(nonneg=True)      # the allowed excess of the fuel plan
        a_dir, lo = cp.Parameter(3), cp.Parameter(nonneg=True)  # a . dv_0 >= lo (minimum burn)
        first = cp.Parameter(nonneg=True)      # |dv_0| <= first (0: the plan without it)
        g, g0 = cp.Parameter(3 * H), cp.Parameter()  # the cost to go |g . x + g0|
        norms = cp.hstack([cp.norm(x[3 * i:3 * i + 3], 2) for i in range(H)])
        rows = cp.abs(M @ x + b) + E @ norms
        fuel = cp.Problem(cp.Minimize(cp.sum(norms) + cp.abs(g @ x + g0)),
                          [rows <= c + t_max, a_dir @ x[:3] >= lo, norms[0] <= first])
        worst = cp.Problem(cp.Minimize(t), [rows <= c + t])
        return {"fuel": fuel, "worst": worst, "x": x, "t": t, "M": M, "b": b, "c": c, "E": E,
                "g": g, "g0": g0, "t_max": t_max, "a": a_dir, "lo": lo, "first": first}

    def _solve(self, S: dict, name: str, k: int, **values) -> str:
        for key, v in values.items():
            S[key].value = v
        try:
            S[name].solve(solver="CLARABEL", max_iter=200)
        except Exception as exc:  # cvxpy raises SolverError subclasses and others
            raise SolverError(f"corridor control at step {k}: the {name} SOCP failed: "
                              f"{exc}") from exc
        return S[name].status

    def _plan(self, sc: Scenario, k: int, xhat: np.ndarray) -> np.ndarray | None:
        """The first burn of the least-Delta-V plan (model units), or None when the plan does
        not need it (module doc)."""
        a = self._opportunity(sc, k)
        if self._solver is None:
            self._solver = self._problems()
        S = self._solver
        d = np.asarray(xhat, float) - sc.X[k]
        M, b, c, E, g, g0, scale = self._rows(sc, a, d)
        free = {"a": np.zeros(3), "lo": 0.0, "first": 1e6}
        ok = ("optimal", "optimal_inaccurate")
        status = self._solve(S, "fuel", k, M=M, b=b, c=c, E=E, g=g, g0=g0, t_max=0.0, **free)
        excess = 0.0
        if status not in ok:
            # no plan keeps the sets in the corridor: the least worst ratio first, then its
            # least Delta-V
            status = self._solve(S, "worst", k)
            if status not in ok or S["t"].value is None:
                raise SolverError(f"corridor control at step {k}: the worst-ratio SOCP "
                                  f"returned {status}")
            excess = float(S["t"].value)
            status = self._solve(S, "fuel", k, t_max=excess * (1.0 + 1e-6) + 1e-9)
        dv = self._checked(S, k, status)
        self.last_info = {"gauge": self.gauge(sc, k, xhat), "corridor_met": excess == 0.0,
                          "plan_excess": excess}
        min_burn = self._min_burn / scale
        size = float(np.linalg.norm(dv))
        if size < ZERO_BURN_CMPS:  # the plan needs no burn now
            return None
        if size < min_burn:
            # too small to be executed: none if the plan holds without it, else the smallest
            # executable burn
            if self._solve(S, "fuel", k, first=0.0) in ok:
                return None
            status = self._solve(S, "fuel", k, a=dv / size, lo=min_burn, first=1e6)
            dv = (self._checked(S, k, status) if status in ok else dv * (min_burn / size))
        self.last_converged = True
        return dv * scale

    @staticmethod
    def _checked(S: dict, k: int, status: str) -> np.ndarray:
        x = S["x"].value
        if status not in ("optimal", "optimal_inaccurate") or x is None or not np.all(
                np.isfinite(x)):
            raise SolverError(f"corridor control at step {k}: the fuel SOCP returned {status}")
        return np.asarray(x[:3], float)

    def describe(self) -> dict:
        return {"controller": self.name, "placement": self.placement,
                "corridor_position_km": self.corridor_position_km,
                "corridor_velocity_mps": self.corridor_velocity_mps,
                "horizon_revolutions": self.horizon_revolutions,
                "execution_in_tube": self.execution_in_tube,
                "null_unstable": self.null_unstable,
                "method": "reachable-set corridor control: one opportunity per revolution; the "
                          "least-Delta-V plan (SOCP) over the coming opportunities keeping the "
                          "reachable sets of the true state (navigation ellipsoid, execution "
                          "error, SRP dispersion) in the corridor, with the growing mode's cost "
                          "to go; a burn only when the plan cannot do without it"}


__all__ = ["EXECUTION_QUANTILE", "PAPER_CORRIDOR", "CorridorControl", "execution_bound"]
