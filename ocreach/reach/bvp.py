"""Continuous-time PMP boundary-value problem solved by shooting and continuation ("BVP").

Holzinger & Scheeres' formulation as used by Foss et al. Sec. 2.1 and Tucker et al. Sec. 2.2:
the extremal ``dx/dt = f(x, u*, t)``, ``dlam/dt = -(df/dx)^T lam`` with ``u* = argmin_u lam^T f``
(Foss Eq. 4, the model's :meth:`~ocreach.model.Model.optimal_control_expression`) and the
terminal condition of the support problem

* ``cost="linear"``: ``lam(t_f) = -z-hat`` (maximise ``z-hat . x(t_f)``, Foss Sec. 2.1), or
* ``cost="quadratic"``: ``lam(t_f) = -G (x(t_f) - x_ref(t_f))`` with ``G = z-hat z-hat^T`` on the
  direction subspace (Tucker Eq. 4-5, ``G = R(theta) D R(theta)^T``, ``D = e1 e1^T``), measured
  from the unpowered final state.

The unknown is the initial costate ``lam_0``; the initial state is the nominal one or, with an
ellipsoidal initial manifold (Tucker Eq. 6, Patel & Scheeres Eq. 21-23) or an initial Delta-V
(Eq. 24-26), the transversality point ``x_0(lam_0)`` of :class:`InitialManifold`.  The root
``F(lam_0, s) = lam(t_f; lam_0) - lam_f(s) = 0`` (Tucker Eq. 7-9) is found by Newton's method with
the Jacobian from the state-costate STM (``dF/dlam_0 = Phi_lx dx_0/dlam_0 + Phi_ll`` plus the
terms of ``lam_f``'s dependence on ``x(t_f)`` for the quadratic cost), first for one direction from
the FFOE guess ``lam_0 = M^T lam_f`` (Patel & Scheeres Eq. 14 along the unpowered trajectory), then
continued along the direction parameter ``s`` with the Euler predictor of the continuation ODE
``dz/ds = -[dF/dz]^-1 dF/ds`` (Tucker Eq. 12) and a Newton corrector, halving the step when the
corrector fails.  In a 2-D direction subspace ``s`` is the angle ``theta`` of
``z-hat = (cos theta, sin theta)``; otherwise the directions are chained nearest-neighbour and
``s`` is the great-circle angle between consecutive ones.

Box control sets (three independent thrusters, Tucker Sec. 4) use the smoothed law
``u* = -tanh(G^T lam / smooth)``; a smoothing continuation (``smooth_start`` down to ``smooth`` by
``smooth_factor``, each level warm-started from the last costate) reaches the nearly bang-bang
solution, and is repeated for a direction whose continuation step fails.  The smoothing value is a
runtime input (the last entry of ``a = [p; smooth]``) of one compiled state-costate(-STM) kernel.
``costate_guess`` warm-starts every direction from given costates (a nearby horizon or thrust
level).

The control is continuous in time (not piecewise constant).  ``controls`` holds ``u*`` at the start
of each segment (for inspection), ``meta["costate0"]`` the initial costates and
``trajectories[:, 0]`` the initial states: :func:`ocreach.reach.extremal.extremal_rhs`
integrated from ``[x_0, lam_0]`` reproduces every trajectory.  Needs a control-affine model or an
inverse-mass model of Patel & Scheeres Eq. 11 (:func:`thrust_law_expression`).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError, SolverError, check_count, check_real
from ocreach.geometry.directions import continuation_order
from ocreach.model import Model
from ocreach.problem import Problem
from ocreach.reach.base import Timer
from ocreach.reach.indirect import FFOE, InitialManifold, backward_sensitivities
from ocreach.reach.result import ReachResult

COSTS = ("linear", "quadratic")


def thrust_law_expression(model: Model, lam: ca.SX, smooth: float | ca.SX = 0.0) -> ca.SX:
    """``u*(x, lam)``: the Hamiltonian minimiser of Foss Eq. 4 / Patel & Scheeres Eq. 18.

    Control-affine models: ``s = G^T lam`` with ``G = df/du``; ball ``u* = -s / sqrt(|s|^2 +
    smooth^2)``, box ``u* = -tanh(s / smooth)`` (``-sign(s)`` for ``smooth = 0``; three
    independent thrusters, Tucker Sec. 4).  ``smooth`` may be a number or a CasADi symbol (the
    runtime smoothing parameter of :func:`costate_stm_rhs`).  Variable-mass models whose
    ``f = f0 + G(x) u + h(x) ||u||`` (the inverse-mass equation of Patel & Scheeres Eq. 11) with a
    ball control set: full thrust along ``-G^T lam`` (Eq. 18, ``T_mag = T_max``); ``G = df/du`` at
    ``u = 0``, where the smoothed ``||u||`` has zero gradient, so the mass rate does not enter the
    direction (the paper's ``F_T`` columns).  Full thrust is the exact minimiser over the ball when
    ``h^T lam <= |G^T lam|``, i.e. whenever thrusting pays for its fuel, as in reachability.
    """
    numeric = not isinstance(smooth, (ca.SX, ca.MX))
    if model.control_affine:
        if numeric and (smooth == 0 or model.control_set == "ball"):
            return model.optimal_control_expression(lam, smooth=smooth)
        sw = ca.mtimes(ca.jacobian(model.f, model.u).T, lam)
        if model.control_set == "box":
            return -ca.tanh(sw / smooth)
        return -sw / ca.fmax(ca.sqrt(ca.sumsqr(sw) + smooth**2), 1e-300)
    if model.control_set != "ball" or "n" not in model.state_names:
        raise ProblemError(f"method 'bvp' needs a control-affine model or an inverse-mass model "
                           f"(Patel & Scheeres Eq. 11) with a ball control set; {model.name} is neither")
    zero = ca.DM.zeros(model.n_u)
    G = ca.substitute(ca.jacobian(model.f, model.u), model.u, zero)
    rest = model.f - ca.substitute(model.f, model.u, zero) - ca.mtimes(G, model.u)
    i_n = model.state_names.index("n")
    if ca.depends_on(ca.vertcat(*[rest[i] for i in range(model.n_x) if i != i_n]), model.u):
        raise ProblemError(f"method 'bvp': model {model.name} is not control-affine outside its mass "
                           "equation; the closed-form law of Patel & Scheeres Eq. 18 does not apply")
    sw = ca.mtimes(G.T, lam)
    return -sw / ca.fmax(ca.sqrt(ca.sumsqr(sw) + smooth**2), 1e-300)


def thrust_law_fun(model: Model) -> ca.Function:
    """``(x, lam, t, p, smooth) -> u*`` of :func:`thrust_law_expression`, cached on the model
    (``smooth = 0``: the exact law; the box law needs ``smooth > 0``)."""

    def build():
        lam = ca.SX.sym("lam", model.n_x)
        sm = ca.SX.sym("smooth")
        return ca.Function("u_star_bvp", [model.x, lam, model.t, model.p, sm],
                           [thrust_law_expression(model, lam, sm)])

    return model.cached("u_star_bvp_fun_rt", build)


def rhs_args(params: np.ndarray, smooth: float) -> np.ndarray:
    """The argument vector ``[p; smooth]`` of :func:`costate_rhs` / :func:`costate_stm_rhs`."""
    return np.concatenate([np.asarray(params, dtype=float).ravel(), [float(smooth)]])


def costate_stm_rhs(model: Model) -> ca.Function:
    """``(y = [x; lam; vec Phi], t, a = [p; smooth]) -> dy/dt``: Foss Eq. 4 with its ``2n x 2n``
    STM (row-major).  The smoothing of the control law is the last argument, a runtime input: one
    compiled kernel serves every value of the smoothing continuation.

    The STM includes the dependence of ``u*`` on ``lam`` (and ``x``).  Cached on the model.
    """

    def build():
        from ocreach.dynamics.flow import c_identifier

        n = model.n_x
        lam = ca.SX.sym("lam", n)
        sm = ca.SX.sym("smooth")
        u_star = thrust_law_expression(model, lam, sm)
        xdot, ldot = model.costate_dynamics(lam, u_star)
        w = ca.vertcat(model.x, lam)
        g = ca.vertcat(xdot, ldot)
        A = ca.jacobian(g, w)
        phi = ca.SX.sym("phi", 4 * n * n)
        Phi = ca.reshape(phi, 2 * n, 2 * n).T  # row-major
        dPhi = ca.reshape(ca.mtimes(A, Phi).T, -1, 1)
        y = ca.vertcat(w, phi)
        return ca.Function(f"costate_stm_{c_identifier(model.name)}_{model.control_set}",
                           [y, model.t, ca.vertcat(model.p, sm)],
                           [ca.vertcat(g, dPhi)], ["y", "t", "a"], ["ydot"], {"cse": True})

    return model.cached("costate_stm_rhs_rt", build)


def costate_rhs(model: Model) -> ca.Function:
    """``(y = [x; lam], t, a = [p; smooth]) -> dy/dt`` (Foss Eq. 4), cached on the model."""

    def build():
        from ocreach.dynamics.flow import c_identifier

        lam = ca.SX.sym("lam", model.n_x)
        sm = ca.SX.sym("smooth")
        u_star = thrust_law_expression(model, lam, sm)
        xdot, ldot = model.costate_dynamics(lam, u_star)
        return ca.Function(f"costate_{c_identifier(model.name)}_{model.control_set}",
                           [ca.vertcat(model.x, lam), model.t, ca.vertcat(model.p, sm)],
                           [ca.vertcat(xdot, ldot)], ["y", "t", "a"], ["ydot"])

    return model.cached("costate_rhs_rt", build)


def _slerp(a: np.ndarray, b: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Point and derivative of the great circle from ``a`` (s=0) to ``b`` (s=1), and its angle."""
    cos = float(np.clip(a @ b, -1.0, 1.0))
    ang = float(np.arccos(cos))
    if ang < 1e-12:
        return b.copy(), np.zeros_like(b), 0.0
    perp = b - cos * a
    perp /= np.linalg.norm(perp)
    th = s * ang
    return np.cos(th) * a + np.sin(th) * perp, ang * (-np.sin(th) * a + np.cos(th) * perp), ang


class BVPContinuation(FFOE):
    """PMP boundary-value problem by shooting on lam_0 and continuation in the direction
    (Holzinger & Scheeres; Foss Sec. 2.1 "BVP"; Tucker Eq. 4-12)."""

    name = "bvp"
    description = "PMP boundary-value problem: Newton shooting on lam_0 from the FFOE guess, continued along the direction (Holzinger; Tucker Eq. 12)"

    @dataclass
    class Options(FFOE.Options):
        """FFOE options plus the boundary-value solver's (Tucker et al.)."""

        #: terminal cost: "linear" (lam_f = -z-hat) or "quadratic" (Tucker Eq. 4)
        cost: str = "linear"
        #: regularisation of the control law, sqrt(|G^T lam|^2 + smooth^2) for a ball, tanh(s /
        #: smooth) for a box; position directions give lam_v(t_f) = 0, where the exact law's
        #: Jacobian blows up like 1/(t_f - t); 1e-8 changes the cost by far less than the
        #: integration tolerance; >= 0
        smooth: float = 1e-8
        #: first value of the smoothing continuation, large to small with warm-started costates
        #: (None: automatic for a box control set, max |G^T lam_0| of the first guess; no
        #: continuation for a ball)
        smooth_start: float | None = None
        #: ratio of consecutive smoothing values, in (0, 1)
        smooth_factor: float = 0.1
        #: initial costates (samples, n_x) to start every direction from, e.g. a result at a
        #: nearby horizon or thrust level (as ocreach.custody.reach_balls.ReachableBalls does)
        costate_guess: Any = None
        #: Newton residual at which a direction is solved: max-norm of lam(t_f) - lam_f, > 0
        tol: float = 1e-10
        #: Newton iterations per corrector, >= 1
        max_newton: int = 12
        #: continuation step halvings before a direction is given up, >= 0
        max_halvings: int = 12

        def __post_init__(self) -> None:
            super().__post_init__()
            if self.cost not in COSTS:
                raise ProblemError(f"cost must be one of {COSTS}; got {self.cost!r}")
            self.smooth, self.tol = check_real("smooth", self.smooth), check_real("tol", self.tol)
            if not self.smooth >= 0:
                raise ProblemError(f"smooth must be >= 0; got {self.smooth!r}")
            if self.smooth_start is not None:
                self.smooth_start = check_real("smooth_start", self.smooth_start)
                if not self.smooth_start > 0:
                    raise ProblemError(f"smooth_start must be > 0 (or None); got {self.smooth_start!r}")
            self.smooth_factor = check_real("smooth_factor", self.smooth_factor)
            if not 0 < self.smooth_factor < 1:
                raise ProblemError(f"smooth_factor must be in (0, 1); got {self.smooth_factor!r}")
            if self.costate_guess is not None:
                g = np.asarray(self.costate_guess, dtype=float)
                if g.shape != (self.samples, g.shape[-1]) or not np.all(np.isfinite(g)):
                    raise ProblemError(f"costate_guess must be a finite (samples = {self.samples}, n_x) "
                                       f"array; got shape {g.shape}")
                self.costate_guess = g
            if not self.tol > 0:
                raise ProblemError(f"tol must be > 0; got {self.tol!r}")
            self.max_newton = check_count("max_newton", self.max_newton, 1)
            self.max_halvings = check_count("max_halvings", self.max_halvings, 0)

    # -------------------------------------------------------------- shooting
    def _shoot(self, problem: Problem, p, manifold: InitialManifold, lam0: np.ndarray):
        """``x0, x(t_f), lam(t_f)`` and the STM blocks ``(Phi_xx, Phi_xl, Phi_lx, Phi_ll)`` at the
        current smoothing value (``self._args = [p; smooth]``)."""
        from ocreach.dynamics.flow import integrate_batch

        n = problem.model.n_x
        x0 = manifold.apply(problem.x0, lam0[None])[0] if manifold.active else problem.x0
        y0 = np.concatenate([x0, lam0, np.eye(2 * n).ravel()])
        g = problem.grid
        y1 = integrate_batch(self._rhs, y0[None], g[0], g[-1], self._args, rtol=self.options.rtol,
                             atol=self.options.atol)[0]
        Phi = y1[2 * n:].reshape(2 * n, 2 * n)
        self._n_shots += 1
        return x0, y1[:n], y1[n:2 * n], (Phi[:n, :n], Phi[:n, n:], Phi[n:, :n], Phi[n:, n:])

    def _residual(self, problem, p, manifold, lam0, zhat, dims, x_ref):
        """``F``, ``dF/dlam0`` and ``dF/dz-hat`` (a matrix acting on d z-hat) at ``lam0``."""
        n = problem.model.n_x
        _x0, xf, lf, (Pxx, Pxl, Plx, Pll) = self._shoot(problem, p, manifold, lam0)
        dx0 = manifold.jacobian(lam0) if manifold.active else np.zeros((n, n))
        dxf = Pxx @ dx0 + Pxl
        dlf = Plx @ dx0 + Pll
        if self._cost == "linear":
            return lf + zhat, dlf, np.eye(n)
        G = np.outer(zhat, zhat)
        e = xf - x_ref
        F = lf + G @ e
        dF_dz = (zhat @ e) * np.eye(n) + np.outer(zhat, e)  # d(G e)/dz-hat with G = z z^T
        return F, dlf + G @ dxf, dF_dz

    def _newton(self, problem, p, manifold, lam0, zhat, dims, x_ref):
        """Newton corrector; returns ``(lam0, converged, residual norm, dF/dlam0, dF/dz-hat)``."""
        opt = self.options
        F, J, Dz = self._residual(problem, p, manifold, lam0, zhat, dims, x_ref)
        err = float(np.max(np.abs(F)))
        for _ in range(opt.max_newton):
            if err < opt.tol:
                return lam0, True, err, J, Dz
            try:
                step = np.linalg.solve(J, F)
            except np.linalg.LinAlgError:
                return lam0, False, err, J, Dz
            t = 1.0
            for _ls in range(8):  # damped Newton: accept the first step that lowers the residual
                cand = lam0 - t * step
                Fc, Jc, Dc = self._residual(problem, p, manifold, cand, zhat, dims, x_ref)
                ec = float(np.max(np.abs(Fc)))
                if np.isfinite(ec) and ec < err:
                    break
                t *= 0.5
            else:
                return lam0, False, err, J, Dz
            lam0, F, J, Dz, err = cand, Fc, Jc, Dc, ec
        return lam0, err < opt.tol, err, J, Dz

    @classmethod
    def applicable(cls, problem: Problem) -> tuple[bool, str]:
        ok, why = super().applicable(problem)
        m = problem.model
        if ok and not m.control_affine and not (problem.control_set.kind == "ball" and "n" in m.state_names):
            return False, ("needs a control-affine model, or an inverse-mass model (Patel & Scheeres "
                           "Eq. 11) with a ball control set")
        return ok, why

    def _smoothing_schedule(self, problem: Problem, p, lam0: np.ndarray) -> list[float]:
        """Smoothing values from ``smooth_start`` (default ``max |G^T lam_0|`` at ``x_0``, where
        ``tanh`` is nearly linear) down to ``smooth`` by the factor ``smooth_factor``."""
        opt = self.options
        if opt.smooth_start is not None:
            start = opt.smooth_start
        else:
            model = problem.model
            B = np.asarray(model.jac_fun(problem.x0, np.zeros(model.n_u), problem.grid[0], p)[2])
            start = float(np.max(np.abs(B.T @ lam0)))
        out = []
        sig = start
        while sig > opt.smooth * (1 + 1e-12):
            out.append(sig)
            sig *= opt.smooth_factor
        return out + [opt.smooth]

    def _smoothed(self, problem, p, manifold, lam, zhat, dims, x_ref):
        """Newton solutions along the smoothing continuation (large to small, each level warm-started
        from the previous costate; a failed level is split geometrically up to ``max_halvings``
        times).  Leaves ``self._args`` at the final smoothing; returns ``(lam, J, Dz, levels)``."""
        opt = self.options
        todo = self._smoothing_schedule(problem, p, lam)
        done_sig, levels, splits = None, 0, 0
        err = np.inf
        while todo:
            sig = todo[0]
            self._args = rhs_args(p, sig)
            cand, ok, err, J, Dz = self._newton(problem, p, manifold, lam, zhat, dims, x_ref)
            if ok:
                lam, done_sig = cand, sig
                todo.pop(0)
                levels += 1
                continue
            splits += 1
            if done_sig is None or splits > opt.max_halvings:
                self._args = rhs_args(p, opt.smooth)
                raise SolverError(f"bvp: smoothing continuation failed for direction {zhat.tolist()} at "
                                  f"smooth = {sig:.3g} (residual {err:.3g} > tol {opt.tol:g}; last "
                                  f"converged smooth = {done_sig})")
            todo.insert(0, float(np.sqrt(sig * done_sig)))
        return lam, J, Dz, levels

    def _first(self, problem, p, manifold, guess, zhat, dims, x_ref, smoothing: bool,
               scale_from_linear: bool = False):
        """Solution for one direction from a guess: plain Newton, or the smoothing continuation.

        ``scale_from_linear`` (quadratic cost from the FFOE guess): the quadratic cost has the
        trivial root ``lam = 0`` (``x_f = x_ref``); the extremal of Tucker Eq. 4 is the linear-cost
        extremal with ``lam`` scaled by ``z-hat . (x_f - x_ref)``, so the linear problem is solved
        first and its costate, scaled, starts the quadratic one.
        """
        lin_levels = 0
        if scale_from_linear:
            self._cost = "linear"
            try:
                lam, _J, _Dz, lin_levels = self._first(problem, p, manifold, guess, zhat, dims, x_ref, smoothing)
            finally:
                self._cost = self.options.cost
            xf = self._shoot(problem, p, manifold, lam)[1]
            guess = lam * float(zhat @ (xf - x_ref))
            # with a heavily smoothed (nearly linear) law the quadratic problem has only the trivial
            # root, so it is solved at the final smoothing directly from the scaled costate
            smoothing = False
            self._args = rhs_args(p, self.options.smooth)
        if smoothing:
            lam, J, Dz, levels = self._smoothed(problem, p, manifold, guess, zhat, dims, x_ref)
            return lam, J, Dz, levels
        lam, ok, err, J, Dz = self._newton(problem, p, manifold, guess, zhat, dims, x_ref)
        if not ok:
            raise SolverError(f"bvp: Newton shooting did not converge for direction {zhat.tolist()} "
                              f"(residual {err:.3g} > tol {self.options.tol:g})")
        return lam, J, Dz, lin_levels

    def solve(self, problem: Problem) -> ReachResult:
        from ocreach.dynamics.flow import integrate_batch

        opt = self.options
        model = problem.model.with_control_set(problem.control_set.kind)  # laws follow the problem's set
        thrust_law_expression(model, ca.SX.sym("lam", model.n_x))  # ProblemError if no closed-form law
        if model.control_set == "box" and opt.smooth <= 0:
            raise ProblemError("method 'bvp' with a box control set needs smooth > 0 (the exact law "
                               "-sign(G^T lam) has no shooting Jacobian); got smooth = 0")
        timer = Timer()
        self._n_shots = 0
        with timer("setup"):
            p, dirs, manifold = self._setup(problem)
            from ocreach.geometry.directions import resolve_dims

            dims = resolve_dims(opt.dims, problem)
            self._rhs = costate_stm_rhs(model)
            self._args = rhs_args(p, opt.smooth)
            N, n = dirs.shape[0], model.n_x
            order = np.arange(N) if len(dims) == 2 and not opt.random else continuation_order(dirs)
            guesses = opt.costate_guess
            if guesses is not None and guesses.shape != (N, n):
                raise ProblemError(f"costate_guess must have shape ({N}, {n}); got {guesses.shape}")
            smoothing = model.control_set == "box" or opt.smooth_start is not None
        with timer("ffoe_guess"):
            ref, Fx, Fu = self.reference(problem, p)
            _, M = backward_sensitivities(Fx, Fu)
            x_ref = ref.states[-1]
        lam_sol = np.zeros((N, n))
        steps = np.zeros(N, dtype=int)
        levels = np.zeros(N, dtype=int)
        warm = np.zeros(N, dtype=bool)
        with timer("continuation"):
            first = order[0]
            guess = -dirs[first] @ M if guesses is None else guesses[first]
            self._cost = opt.cost
            try:
                lam, J, Dz, levels[first] = self._first(problem, p, manifold, guess, dirs[first], dims,
                                                        x_ref, smoothing,
                                                        opt.cost == "quadratic" and guesses is None)
            except SolverError as exc:
                raise SolverError(f"bvp: the first direction {dirs[first].tolist()} did not converge from "
                                  f"the {'FFOE' if guesses is None else 'given'} guess: {exc}") from None
            lam_sol[first] = lam
            for a, b in itertools.pairwise(order):
                if guesses is not None:  # warm start: Newton from the given costate first
                    cand, ok, _err, Jb, Db = self._newton(problem, p, manifold, guesses[b], dirs[b], dims,
                                                          x_ref)
                    if ok:
                        lam, J, Dz, warm[b] = cand, Jb, Db, True
                        lam_sol[b] = lam
                        continue
                try:
                    lam, J, Dz, nsteps = self._continue(problem, p, manifold, lam, J, Dz, dirs[a], dirs[b],
                                                        dims, x_ref)
                except SolverError:
                    if not smoothing:
                        raise
                    # box thrust: the switching structure changed; redo the smoothing continuation
                    # for this direction from the neighbour's costate (quadratic cost: from the
                    # FFOE guess through the linear problem, see _first)
                    if opt.cost == "quadratic":
                        lam, J, Dz, levels[b] = self._first(problem, p, manifold, -dirs[b] @ M, dirs[b],
                                                            dims, x_ref, smoothing, True)
                    else:
                        lam, J, Dz, levels[b] = self._smoothed(problem, p, manifold, lam, dirs[b], dims,
                                                               x_ref)
                    nsteps = 0
                lam_sol[b], steps[b] = lam, nsteps
        with timer("trajectories"):
            x0 = manifold.apply(problem.x0, lam_sol) if manifold.active else np.tile(problem.x0, (N, 1))
            g = problem.grid
            K = g.size - 1
            traj = np.empty((N, K + 1, n))
            lams = np.empty((N, K + 1, n))
            controls = np.empty((N, K, model.n_u))
            ufun = thrust_law_fun(model).map(N)
            rhs = costate_rhs(model)
            args = rhs_args(p, opt.smooth)
            y = np.hstack([x0, lam_sol])
            traj[:, 0], lams[:, 0] = x0, lam_sol
            for k in range(K):
                controls[:, k] = np.asarray(ufun(y[:, :n].T, y[:, n:].T, g[k], p, opt.smooth)).T
                y = integrate_batch(rhs, y, g[k], g[k + 1], args, rtol=opt.rtol, atol=opt.atol)
                traj[:, k + 1], lams[:, k + 1] = y[:, :n], y[:, n:]
        meta = self.base_meta(problem, timer.times)
        meta["options"].pop("costate_guess", None)
        meta.update(directions=dirs, costate0=lam_sol, costate_final=lams[:, -1],
                    cost=np.einsum("ni,ni->n", dirs, traj[:, -1]), continuation_steps=steps,
                    continuation_order=order, shots=self._n_shots, params=p,
                    smoothing_levels=levels, warm_started=warm, warm_start=guesses is not None,
                    reference_final=x_ref,
                    controls_note="continuous optimal control u*(lambda(t)); controls holds its value "
                                  "at each segment start; re-simulate [x0, costate0] with "
                                  "bvp.costate_rhs(model) and args bvp.rhs_args(params, smooth)")
        return ReachResult.from_trajectories(g, traj, controls=controls, meta=meta)

    def _continue(self, problem, p, manifold, lam, J, Dz, za, zb, dims, x_ref):
        """Continue the solution from direction ``za`` to ``zb``: Euler predictor of Tucker Eq. 12
        ``d lam0/ds = -[dF/dlam0]^-1 dF/ds`` and a Newton corrector; the step halves on failure."""
        opt = self.options
        s, ds = 0.0, 1.0
        halvings = nsteps = 0
        while s < 1.0 - 1e-14:
            ds = min(ds, 1.0 - s)
            dz_s = _slerp(za, zb, s)[1]
            try:
                dlam = -np.linalg.solve(J, Dz @ dz_s)
            except np.linalg.LinAlgError:
                raise SolverError("bvp: singular shooting Jacobian dF/dlam0 during continuation "
                                  f"from {za.tolist()} to {zb.tolist()} at s = {s:.4g}") from None
            z_new = _slerp(za, zb, s + ds)[0]
            cand, ok, err, Jn, Dn = self._newton(problem, p, manifold, lam + ds * dlam, z_new, dims, x_ref)
            if ok:
                lam, J, Dz, s = cand, Jn, Dn, s + ds
                nsteps += 1
                ds = min(2 * ds, 1.0)
            else:
                halvings += 1
                ds *= 0.5
                if halvings > opt.max_halvings:
                    raise SolverError(f"bvp: continuation from {za.tolist()} to {zb.tolist()} failed at "
                                      f"s = {s:.4g} after {halvings} step halvings (last residual {err:.3g})")
        return lam, J, Dz, nsteps
