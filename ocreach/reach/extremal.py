"""Extremal trajectories from the state-costate ODE (Foss et al. Eq. 4, after Lew, Bonalli & Pavone).

For a control-affine model ``f = f0(x, t) + G(x, t) u`` every solution of ::

    dx/dt   =  f(x, u*, t),
    dlam/dt = -(df/dx)^T lam,          u* = argmin_{u in U} lam^T f(x, u, t)

with an arbitrary initial costate ``lam_0`` satisfies Pontryagin's maximum principle for the
problem "maximise ``-lam(t_f)^T x(t_f)``", so its endpoint lies on the boundary of the convex hull
of the reachable set with outward normal ``-lam(t_f)``.  Sampling ``lam_0`` uniformly on the unit
sphere and integrating the ODE gives boundary points without solving any boundary-value problem.

The control is the closed-form minimiser (``-G^T lam / ||G^T lam||`` on the unit ball,
``-sign(G^T lam)`` on the box), generated symbolically from the model.  The control is therefore
continuous in time, not piecewise constant: ``controls`` stores its value at the start of each
segment (for inspection) and ``meta["costate0"]`` the initial costates, from which every
trajectory is reproduced exactly with :func:`extremal_rhs`.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError
from ocreach.model import Model
from ocreach.problem import Problem
from ocreach.reach.base import Method, SamplingOptions, Timer, requirements
from ocreach.reach.result import ReachResult


def extremal_rhs(model: Model, kind: str | None = None) -> ca.Function:
    """``(y = [x; lam], t, p) -> dy/dt`` of Foss et al. Eq. 4, cached on the model.

    ``kind``: admissible control set ``"ball"`` or ``"box"`` (default: the model's).
    """
    kind = model.control_set if kind is None else kind

    def build():
        lam = ca.SX.sym("lam", model.n_x)
        u_star = model.optimal_control_expression(lam, kind=kind)
        fx, lam_dot = model.costate_dynamics(lam, u_star)
        y = ca.vertcat(model.x, lam)
        return ca.Function(f"extremal_rhs_{kind}", [y, model.t, model.p],
                           [ca.vertcat(fx, lam_dot)], ["y", "t", "a"], ["ydot"])

    key = "extremal_rhs" if kind == model.control_set else ("extremal_rhs", kind)
    return model.cached(key, build)


def optimal_control_fun(model: Model, kind: str | None = None) -> ca.Function:
    """``(x, lam, t, p) -> u*`` (the Hamiltonian minimiser over ``kind``), cached on the model."""
    kind = model.control_set if kind is None else kind

    def build():
        lam = ca.SX.sym("lam", model.n_x)
        return ca.Function("u_star", [model.x, lam, model.t, model.p],
                           [model.optimal_control_expression(lam, kind=kind)])

    key = "u_star_fun" if kind == model.control_set else ("u_star_fun", kind)
    return model.cached(key, build)


def support_point(initial_set, d: np.ndarray) -> np.ndarray:
    """Row-wise ``argmax_{x in X0} d^T x`` for an ellipsoid, zonotope or interval initial set.

    PMP transversality for a free initial state on ``X0`` (Holzinger & Scheeres; Patel & Scheeres
    Eq. 21-23 for the ellipsoid): the extremal starts where ``X0`` has outward normal ``d``.
    """
    from ocreach.sets import Ellipsoid, Interval, Zonotope

    d = np.atleast_2d(d)
    if isinstance(initial_set, Ellipsoid):
        Qd = d @ np.asarray(initial_set.Q).T
        norm = np.sqrt(np.maximum(np.einsum("ij,ij->i", d, Qd), 1e-300))
        return np.asarray(initial_set.q) + Qd / norm[:, None]
    if isinstance(initial_set, Zonotope):
        G = np.asarray(initial_set.G)
        return np.asarray(initial_set.c) + np.sign(d @ G) @ G.T
    if isinstance(initial_set, Interval):
        return np.where(d >= 0, np.asarray(initial_set.hi), np.asarray(initial_set.lo))
    raise ProblemError("method 'ode' needs an Ellipsoid, Zonotope or Interval initial_set "
                       f"(to place each extremal's start by transversality); got "
                       f"{type(initial_set).__name__}")


def unit_sphere(rng: np.random.Generator, samples: int, dim: int) -> np.ndarray:
    """Uniform samples on the unit sphere in ``R^dim``."""
    g = rng.standard_normal((samples, dim))
    return g / np.linalg.norm(g, axis=1, keepdims=True)


class ExtremalODE(Method):
    """Extremal trajectories from random initial costates (Foss Eq. 4, Lew et al.)."""

    name = "ode"
    description = "extremal state-costate ODE with random initial costates (Foss Eq. 4, Lew et al.)"

    @dataclass
    class Options(SamplingOptions):
        """:class:`~ocreach.reach.base.SamplingOptions`: ``samples`` is the number of extremals
        (one per random initial costate)."""

    @classmethod
    def applicable(cls, problem: Problem) -> tuple[bool, str]:
        return requirements(problem, bounded=True, control_affine=True,
                            initial_sets=("Ellipsoid", "Zonotope", "Interval"))

    def solve(self, problem: Problem) -> ReachResult:
        from ocreach.dynamics.flow import integrate_batch

        model = problem.model
        kind = problem.control_set.kind
        if kind not in ("ball", "box"):
            raise ProblemError(f"method 'ode' needs a bounded control set ('ball' or 'box'); "
                               f"problem {problem.id} has {kind!r} controls")
        opt = self.options
        rng = np.random.default_rng(opt.seed)
        timer = Timer()
        with timer("setup"):
            rhs = extremal_rhs(model, kind)
            ufun = optimal_control_fun(model, kind).map(opt.samples)
            lam0 = unit_sphere(rng, opt.samples, model.n_x)
            if problem.initial_set is None:
                x0 = np.tile(problem.x0, (opt.samples, 1))
            else:
                # extremal start on the initial set: outward normal -lam0 forward, +lam0 backward
                x0 = support_point(problem.initial_set, lam0 if problem.backward else -lam0)
        grid = problem.grid
        K = grid.size - 1
        traj = np.empty((opt.samples, K + 1, model.n_x))
        costates = np.empty_like(traj)
        controls = np.empty((opt.samples, K, model.n_u))
        y = np.hstack([x0, lam0])
        traj[:, 0], costates[:, 0] = x0, lam0
        with timer("propagation"):
            for k in range(K):
                controls[:, k] = np.asarray(
                    ufun(y[:, :model.n_x].T, y[:, model.n_x:].T, grid[k], problem.params)).T
                y = integrate_batch(rhs, y, grid[k], grid[k + 1], problem.params,
                                    rtol=opt.rtol, atol=opt.atol)
                traj[:, k + 1], costates[:, k + 1] = y[:, :model.n_x], y[:, model.n_x:]
        meta = self.base_meta(problem, timer.times)
        meta["control_set"] = kind
        meta["costate0"] = lam0
        meta["costate_final"] = costates[:, -1]
        # outward normal of the endpoint: -lam(t_f) forward; in backward time (t_f < t_0) the
        # same equations describe the extremals with costate -lam, so the normal is +lam(t_f)
        lam_f = costates[:, -1]
        normal = lam_f if problem.backward else -lam_f
        meta["outward_normal"] = normal / np.linalg.norm(normal, axis=1, keepdims=True)
        meta["controls_note"] = ("continuous optimal control u*(lambda(t)); controls holds its "
                                 "value at each segment start; re-simulate with extremal_rhs")
        return ReachResult.from_trajectories(grid, traj, controls=controls, meta=meta)
