"""Lagrange points and periodic orbits of the CR3BP by differential correction.

* :func:`lagrange_points` -- the five equilibria of the rotating frame.
* :func:`correct_symmetric` -- single-shooting differential correction of orbits symmetric about
  the ``xz``-plane (spatial halo / NRHO) or the ``x``-axis (planar Lyapunov / DRO), using the
  state-transition matrix to the half-period crossing ``y = 0`` (event-located on the dense output).
* :func:`continue_family` -- natural-parameter continuation in one coordinate of the initial state.
* :func:`nrho_9_2` -- the 9:2 synodic-resonant southern L2 NRHO (Patel & Subbarao, Sec.
  "L2 9:2 Near Rectilinear Halo Orbit"; Zimovan, Howell & Davis 2017).

The variational equations ``Phi' = A(x) Phi`` are built from the model's CasADi Jacobian
(:attr:`ocreach.model.Model.jac_fun`) once per model and integrated with SciPy's DOP853 at
``rtol = atol = 1e-12``.  The routines accept the planar (4 states) and spatial (6 states)
constant-mass CR3BP models of :func:`ocreach.models.cr3bp`; the thrust is held at zero.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from ocreach.errors import ProblemError, SolverError
from ocreach.model import Model
from ocreach.problem import Reference
from ocreach.units import EARTH_MOON_PATEL, Units

RTOL = 1e-12
ATOL = 1e-12
#: Mean synodic month (days); the 9:2 NRHO completes 9 revolutions in 2 synodic months.
SYNODIC_MONTH_DAYS = 29.530589
#: Earth-Moon mass ratio used for the 9:2 NRHO by default.
MU_EARTH_MOON = 0.012150585609624


# ====================================================================== Lagrange points
def _dUdx_axis(x: float, mu: float) -> float:
    """``dOmega/dx`` on the x-axis (``y = z = 0``), Omega = (x^2+y^2)/2 + (1-mu)/r1 + mu/r2."""
    d1 = x + mu
    d2 = x - 1 + mu
    return x - (1 - mu) * d1 / abs(d1) ** 3 - mu * d2 / abs(d2) ** 3


def lagrange_points(mu: float) -> np.ndarray:
    """Positions of L1..L5 (rows, ``[x, y, z]``) in the rotating barycentric frame.

    The collinear points are the roots of ``dOmega/dx = 0`` on the three x-axis intervals cut by the
    primaries (at ``-mu`` and ``1 - mu``), found by Brent's bracketing method (always converges)
    and polished by two Newton steps; L4/L5 are the equilateral points ``(1/2 - mu, +-sqrt(3)/2)``.
    """
    mu = float(mu)
    if not 0 < mu < 0.5:
        raise ProblemError(f"mu must be in (0, 0.5); got {mu!r}")
    eps = 1e-9
    p1, p2 = -mu, 1 - mu
    brackets = [(p1 + eps, p2 - eps), (p2 + eps, 2.0 + mu), (-2.0, p1 - eps)]
    out = np.zeros((5, 3))
    for i, (a, b) in enumerate(brackets):
        x = brentq(_dUdx_axis, a, b, args=(mu,), xtol=1e-15, rtol=4 * np.finfo(float).eps,
                   maxiter=500)
        for _ in range(2):  # Newton polish with the exact second derivative
            d1, d2 = abs(x + mu), abs(x - 1 + mu)
            dd = 1 + 2 * (1 - mu) / d1**3 + 2 * mu / d2**3
            x -= _dUdx_axis(x, mu) / dd
        out[i, 0] = x
    out[3] = [0.5 - mu, np.sqrt(3) / 2, 0.0]
    out[4] = [0.5 - mu, -np.sqrt(3) / 2, 0.0]
    return out


# ====================================================================== integration
def _check_model(model: Model) -> int:
    if model.n_x not in (4, 6) or not model.name.startswith("cr3bp") or "mu" not in model.param_names:
        raise ProblemError(f"periodic-orbit routines need a constant-mass CR3BP model (4 or 6 "
                           f"states, parameter 'mu'); got {model.name!r} with n_x = {model.n_x}")
    return model.n_x


def _variational_fun(model: Model) -> ca.Function:
    """CasADi ``(z, p) -> dz/dt`` for ``z = [x; vec(Phi)]`` (column-major), ``u = 0``; cached on the model."""
    def build() -> ca.Function:
        n = model.n_x
        x = ca.SX.sym("x", n)
        phi = ca.SX.sym("phi", n, n)
        p = ca.SX.sym("p", model.n_p)
        f, A, _ = model.jac_fun(x, ca.SX.zeros(model.n_u), 0, p)
        rhs = ca.vertcat(f, ca.reshape(ca.mtimes(A, phi), n * n, 1))
        return ca.Function("cr3bp_variational", [ca.vertcat(x, ca.reshape(phi, n * n, 1)), p],
                           [rhs], ["z", "p"], ["zdot"])

    return model.cached("orbits.variational", build)


def _params(model: Model, params) -> np.ndarray:
    p = model.p_default.copy() if params is None else np.asarray(params, dtype=float).copy()
    if p.shape != (model.n_p,):
        raise ProblemError(f"params must have {model.n_p} entries {list(model.param_names)}; "
                           f"got shape {p.shape}")
    if "a_max" in model.param_names:
        p[model.param_names.index("a_max")] = 0.0  # natural (unthrusted) motion
    return p


def propagate_stm(model: Model, x0, t_final: float, params=None, *, rtol: float = RTOL,
                  atol: float = ATOL, event_direction: float | None = None,
                  dense: bool = False):
    """Integrate the state and STM from ``t = 0`` (DOP853).

    With ``event_direction`` (``+1``/``-1``) the integration stops at the first crossing of
    ``y = 0`` in that direction, located on DOP853's dense output; ``t_final`` is then an upper
    bound.  Returns ``(t_end, x_end, Phi_end, sol)``.
    """
    n = _check_model(model)
    fun = _variational_fun(model)
    p = _params(model, params)
    z0 = np.concatenate([np.asarray(x0, dtype=float), np.eye(n).ravel(order="F")])

    def rhs(_t, z):
        return fun(z, p).full().ravel()

    events = None
    if event_direction is not None:
        def cross(_t, z):
            return z[1]
        cross.terminal = True
        cross.direction = float(event_direction)
        events = cross
    sol = solve_ivp(rhs, (0.0, float(t_final)), z0, method="DOP853", rtol=rtol, atol=atol,
                    events=events, dense_output=dense)
    if sol.status < 0:
        raise SolverError(f"DOP853 failed while propagating the STM from x0 = {x0!r}: {sol.message}")
    if event_direction is not None:
        if sol.t_events[0].size == 0:
            raise SolverError(f"no y = 0 crossing (direction {event_direction:+g}) within "
                              f"t <= {t_final:g} from x0 = {np.asarray(x0)!r}")
        t_end, z_end = float(sol.t_events[0][0]), sol.y_events[0][0]
    else:
        t_end, z_end = float(sol.t[-1]), sol.y[:, -1]
    if not np.all(np.isfinite(z_end)):
        raise SolverError(f"non-finite state/STM after propagation from x0 = {x0!r}")
    return t_end, z_end[:n].copy(), z_end[n:].reshape((n, n), order="F"), sol


# ====================================================================== periodic orbits
@dataclass(frozen=True, eq=False)
class PeriodicOrbit:
    """A corrected periodic orbit of the CR3BP.

    ``stability_indices`` are ``nu = (lambda + 1/lambda) / 2`` of the monodromy's reciprocal
    eigenvalue pairs, the trivial pair (``lambda = 1``) excluded, largest ``|nu|`` first
    (``|nu| > 1``: unstable; real ``|nu| <= 1``: centre).  ``closure`` is ``|x(T) - x0|_2``
    from the full-period integration that produced the monodromy; ``trivial_pair`` the two
    eigenvalues closest to 1.
    """

    x0: np.ndarray
    period: float
    monodromy: np.ndarray
    stability_indices: tuple
    mu: float
    family: str
    closure: float = float("nan")
    trivial_pair: tuple = field(default=())

    def __post_init__(self) -> None:
        # read-only copies: orbits are cached and shared between problems
        for name in ("x0", "monodromy"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    def to_reference(self, name: str | None = None) -> Reference:
        """This orbit as an :class:`ocreach.problem.Reference` (what a ``Problem`` stores)."""
        return Reference(x0=np.array(self.x0, dtype=float), period=float(self.period),
                         monodromy=np.array(self.monodromy), stability=tuple(self.stability_indices),
                         name=name or self.family)

    def period_in(self, units: Units, unit: str = "h") -> float:
        """Period in hours (``"h"``) or days (``"d"``) for the given units."""
        scale = {"h": 3600.0, "d": 86400.0, "s": 1.0}
        if unit not in scale:
            raise ProblemError(f"unit must be one of {sorted(scale)}; got {unit!r}")
        return self.period * units.time / scale[unit]


def stability_indices(monodromy: np.ndarray) -> tuple[tuple, tuple]:
    """``(indices, trivial_pair)`` of a symplectic monodromy matrix.

    The two eigenvalues closest to 1 form the trivial pair; the rest are paired greedily by
    ``nu = (lambda + 1/lambda)/2`` (reciprocal eigenvalues share the same ``nu``).  Real ``nu`` are
    returned as floats, complex ones (complex quadruplets) as complex numbers.
    """
    lam = np.linalg.eigvals(np.asarray(monodromy, dtype=float))
    order = np.argsort(np.abs(lam - 1.0))
    trivial = tuple(complex(v) for v in lam[order[:2]])
    rest = list(lam[order[2:]])
    nus = [0.5 * (v + 1.0 / v) for v in rest]
    out = []
    used = [False] * len(nus)
    for i in range(len(nus)):
        if used[i]:
            continue
        used[i] = True
        cand = [j for j in range(len(nus)) if not used[j]]
        if cand:
            j = min(cand, key=lambda k: abs(nus[k] - nus[i]))
            used[j] = True
            nu = 0.5 * (nus[i] + nus[j])
        else:
            nu = nus[i]
        out.append(float(nu.real) if abs(nu.imag) <= 1e-8 * max(1.0, abs(nu)) else complex(nu))
    out.sort(key=lambda v: -abs(v))
    return tuple(out), trivial


def _layout(n: int) -> dict[str, int]:
    if n == 6:
        return {"x": 0, "y": 1, "z": 2, "vx": 3, "vy": 4, "vz": 5}
    return {"x": 0, "y": 1, "vx": 2, "vy": 3}


def correct_symmetric(
    model: Model,
    x_guess: Sequence[float],
    *,
    fix: str = "x",
    period: float | None = None,
    params=None,
    family: str = "",
    tol: float = 1e-12,
    max_iter: int = 40,
    t_max: float = 20.0,
) -> PeriodicOrbit:
    """Differential correction of a symmetric periodic orbit (single shooting to the half period).

    The initial state is on the symmetry plane with velocity normal to it: planar
    ``[x0, 0, 0, vy0]`` (x-axis symmetry, Lyapunov / DRO) or spatial ``[x0, 0, z0, 0, vy0, 0]``
    (xz-plane symmetry, halo / NRHO).  Integrating to the next crossing ``y = 0`` at ``t_c``, the
    orbit is periodic with ``T = 2 t_c`` iff ``vx(t_c) = 0`` (and ``vz(t_c) = 0``).  Newton's
    method on the free coordinates ``q`` uses the STM with the crossing-time correction
    ``d(target)/dq = Phi[target, q] - f_target / vy * Phi[y, q]`` (Howell 1984).

    ``fix`` names the coordinate kept at its guess: planar ``"x"`` or ``"vy"``; spatial ``"x"``,
    ``"z"`` or ``"vy"``.  With ``period=T`` all coordinates are free and the half-period
    ``t_c = T/2`` is an extra target (``fix`` is ignored).
    Converges when the target residual is below ``tol``; raises :class:`SolverError` otherwise.
    The final orbit is integrated over one full period for the monodromy and closure error.
    """
    n = _check_model(model)
    L = _layout(n)
    x = np.asarray(x_guess, dtype=float).copy()
    if x.shape != (n,) or not np.all(np.isfinite(x)):
        raise ProblemError(f"x_guess must be a finite state of length {n}; got {x_guess!r}")
    zero_idx = [L["y"], L["vx"]] + ([L["vz"]] if n == 6 else [])
    if np.any(np.abs(x[zero_idx]) > 1e-2):
        raise ProblemError(f"x_guess must lie on the symmetry plane with perpendicular velocity "
                           f"(y, vx{', vz' if n == 6 else ''} ~ 0); got {x_guess!r}")
    x[zero_idx] = 0.0
    if x[L["vy"]] == 0:
        raise ProblemError("x_guess must have vy != 0 (velocity normal to the symmetry plane)")
    coords = ["x", "z", "vy"] if n == 6 else ["x", "vy"]
    if period is None:
        if fix not in coords:
            raise ProblemError(f"fix must be one of {coords} for a {n}-state model; got {fix!r}")
        free = [L[c] for c in coords if c != fix]
    else:
        if not np.isfinite(period) or period <= 0:
            raise ProblemError(f"period must be a finite number > 0; got {period!r}")
        free = [L[c] for c in coords]
    targets = [L["vx"]] + ([L["vz"]] if n == 6 else [])
    p = _params(model, params)
    fun = _variational_fun(model)

    resid_norm = np.inf
    for it in range(max_iter + 1):
        direction = -np.sign(x[L["vy"]])
        t_c, xc, phi, _ = propagate_stm(model, x, t_max, p, event_direction=direction)
        fc = fun(np.concatenate([xc, np.eye(n).ravel()]), p).full().ravel()[:n]
        vy_c = fc[L["y"]]
        D = phi[np.ix_(targets, free)] - np.outer(fc[targets], phi[L["y"], free]) / vy_c
        r = xc[targets]
        if period is not None:
            D = np.vstack([D, -phi[L["y"], free] / vy_c])
            r = np.concatenate([r, [t_c - 0.5 * period]])
        resid_norm = float(np.linalg.norm(r))
        if resid_norm < tol:
            break
        if it == max_iter:
            break
        step = np.linalg.solve(D, -r) if D.shape[0] == D.shape[1] else np.linalg.lstsq(D, -r, rcond=None)[0]
        # damp very large steps (keeps Newton inside the basin for poor seeds)
        scale = min(1.0, 0.05 / max(np.max(np.abs(step)), 1e-300))
        x[free] += scale * step
    if resid_norm >= tol:
        raise SolverError(f"differential correction did not converge in {max_iter} iterations "
                          f"(residual {resid_norm:.3e} >= tol {tol:g}) from x_guess = {x_guess!r}")
    T = 2.0 * t_c
    _, xT, M, _ = propagate_stm(model, x, T, p)
    nus, trivial = stability_indices(M)
    mu = model.param("mu", p)
    return PeriodicOrbit(x0=x, period=T, monodromy=M, stability_indices=nus, mu=mu,
                         family=family or ("spatial symmetric" if n == 6 else "planar symmetric"),
                         closure=float(np.linalg.norm(xT - x)), trivial_pair=trivial)


def continue_family(
    model: Model,
    orbit: PeriodicOrbit,
    coordinate: str,
    values: Iterable[float],
    *,
    fix: str | None = None,
    params=None,
) -> list[PeriodicOrbit]:
    """Natural-parameter continuation: step ``coordinate`` of ``x0`` through ``values``.

    Each member is corrected with ``coordinate`` fixed (``fix`` defaults to it), starting from the
    previous member linearly extrapolated in the free coordinates.
    """
    n = _check_model(model)
    L = _layout(n)
    if coordinate not in L or coordinate in ("y", "vx", "vz"):
        raise ProblemError(f"coordinate must be one of x, z, vy; got {coordinate!r}")
    fix = fix or coordinate
    out: list[PeriodicOrbit] = []
    prev, prev2 = orbit, None
    for v in values:
        guess = np.array(prev.x0, dtype=float)
        if prev2 is not None:
            dv = prev.x0[L[coordinate]] - prev2.x0[L[coordinate]]
            if dv != 0:
                guess = prev.x0 + (prev.x0 - prev2.x0) * (v - prev.x0[L[coordinate]]) / dv
        guess[L[coordinate]] = v
        orb = correct_symmetric(model, guess, fix=fix, params=params, family=orbit.family)
        out.append(orb)
        prev2, prev = prev, orb
    return out


def nrho_9_2(mu: float = MU_EARTH_MOON, units: Units = EARTH_MOON_PATEL,
             seed: Sequence[float] = (1.0220, 0.0, -0.1821, 0.0, -0.1033, 0.0)) -> PeriodicOrbit:
    """The southern L2 9:2 NRHO: 9 revolutions per 2 synodic months (T = 6.562 d), x0 at apolune.

    The target period is ``2/9 * 29.530589 d`` converted with ``units.time`` (1.5112 TU for
    t* = 375200 s).  The seed (approximate apolune state of the 9:2 NRHO, cf. Zimovan, Howell &
    Davis 2017) is first corrected with ``z0`` fixed, i.e. onto the L2 halo family
    member through that apolune height; the family is then followed in ``z0`` by secant steps on
    the period until it matches the target, and a final correction with the period as a
    constraint pins the member down.
    """
    from ocreach.models import cr3bp

    model = cr3bp(mu, planar=False)
    target = 2.0 / 9.0 * SYNODIC_MONTH_DAYS * 86400.0 / units.time
    orb = correct_symmetric(model, seed, fix="z", family="L2 southern halo (NRHO)")
    # secant continuation in z0 along the halo family until the period is within 0.5 % of the
    # target (the seed usually already is), then the period-constrained correction finishes
    z_prev, T_prev = orb.x0[2], orb.period
    z_cur = z_prev - 1e-3
    cur = orb
    for _ in range(30):
        if abs(cur.period - target) < 5e-3 * target:
            break
        guess = cur.x0.copy()
        guess[2] = z_cur
        cur = correct_symmetric(model, guess, fix="z", family=orb.family)
        dT = cur.period - T_prev
        if dT == 0:
            raise SolverError("NRHO continuation stalled: equal periods on two family members")
        z_next = z_cur + (target - cur.period) * (z_cur - z_prev) / dT
        z_prev, T_prev = z_cur, cur.period
        z_cur = z_cur + float(np.clip(z_next - z_cur, -0.01, 0.01))
    else:
        raise SolverError(f"NRHO continuation did not reach the target period {target:.6f} TU "
                          f"(last member {cur.period:.6f} TU)")
    final = correct_symmetric(model, cur.x0, period=target,
                              family="L2 southern 9:2 NRHO (apolune)")
    return final
