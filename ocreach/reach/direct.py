"""Support function by direct transcription (CasADi + IPOPT): a reference for the indirect methods.

``max z-hat . x(t_f)`` over piecewise-constant controls on the problem grid (the multi-stage problem
of Patel & Scheeres Eq. 2-4 and 12 solved directly instead of through Eq. 14-18): multiple shooting
with one RK4 step function of the model's ``f`` (``n_sub`` substeps per segment, optionally
``refine`` sub-segments per grid segment), ``||u|| <= 1`` (ball) or ``|u_i| <= 1`` (box), and
optionally the initial position on the ball of radius ``x0_radius`` about ``x0`` in ``x0_dims``
(Eq. 21 with ``E = I``).  The initial guess is the unpowered trajectory and the FFOE law of
Patel & Scheeres Alg. 1 (its controls scaled by 1/2, inside the control set).  One NLP per direction; meant for validation tables, not for speed.
"""
from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError, SolverError, check_count
from ocreach.problem import Problem


def _rk4_step(model, n_sub: int) -> ca.Function:
    """``(x, u, t, h, p) -> x(t + h)`` by ``n_sub`` RK4 substeps with ``u`` held (the same
    expression as the MPC prediction model); built once per ``n_sub`` and cached on the model."""
    from ocreach.dynamics.discretize import rk4_expression

    def build() -> ca.Function:
        h = ca.SX.sym("h")
        y = rk4_expression(model, model.x, model.u, model.t, model.p, h, n_sub)
        return ca.Function("rk4_step", [model.x, model.u, model.t, h, model.p], [y])

    return model.cached(("rk4_step", int(n_sub)), build)


def _ffoe_guess(problem: Problem, zhat: np.ndarray, g: np.ndarray, p: np.ndarray) -> np.ndarray:
    """FFOE controls (Patel & Scheeres Eq. 14, 18 along the unpowered trajectory) on grid ``g``."""
    from ocreach.dynamics.flow import stt
    from ocreach.reach.indirect import backward_sensitivities, control_law

    model = problem.model
    ref = stt(model, problem.x0, np.zeros((g.size - 1, model.n_u)), g, 1, p=p)
    B, _ = backward_sensitivities(ref.Phi1[..., :model.n_x], ref.Phi1[..., model.n_x:])
    return control_law(B, -zhat[None], problem.control_set)[0]


def transcription_support(problem: Problem, zhat, *, refine: int = 1, n_sub: int = 20,
                          x0_radius: float = 0.0, x0_dims: Sequence[int] | None = None,
                          p=None, tol: float = 1e-11, max_iter: int = 2000) -> float:
    """``max z-hat . x(t_f)`` by direct multiple shooting (see the module docstring).

    Raises :class:`SolverError` when IPOPT does not reach its tolerance.
    """
    from ocreach.dynamics.flow import propagate

    model = problem.model
    zhat = np.asarray(zhat, float)
    if zhat.shape != (model.n_x,):
        raise ProblemError(f"zhat must have length n_x = {model.n_x}; got shape {zhat.shape}")
    refine, n_sub = check_count("refine", refine, 1), check_count("n_sub", n_sub, 1)
    kind = problem.control_set.kind
    if kind not in ("ball", "box"):
        raise ProblemError(f"transcription_support needs a 'ball' or 'box' control set; got {kind!r}")
    if not np.isfinite(x0_radius) or x0_radius < 0:
        raise ProblemError(f"x0_radius must be a finite number >= 0; got {x0_radius!r}")
    p = problem.params if p is None else np.asarray(p, float)
    grid = problem.grid
    g = np.concatenate([np.linspace(grid[i], grid[i + 1], int(refine) + 1)[:-1]
                        for i in range(len(grid) - 1)] + [grid[-1:]])
    K, nx, nu = g.size - 1, model.n_x, model.n_u
    step = _rk4_step(model, int(n_sub)).map(K)
    guess = propagate(model, problem.x0, np.zeros((K, nu)), g, p=p)
    u_guess = 0.5 * _ffoe_guess(problem, zhat, g, p)
    opti = ca.Opti()
    X, U = opti.variable(nx, K + 1), opti.variable(nu, K)
    if x0_radius > 0:
        dims = list(problem.position_dims if x0_dims is None else x0_dims)
        rest = [i for i in range(nx) if i not in dims]
        d = opti.variable(len(dims))
        opti.subject_to(ca.sumsqr(d) <= x0_radius**2)
        opti.subject_to(X[dims, 0] == problem.x0[dims] + d)
        if rest:
            opti.subject_to(X[rest, 0] == problem.x0[rest])
        opti.set_initial(d, 0.5 * x0_radius * zhat[dims] / max(np.linalg.norm(zhat[dims]), 1e-300))
    else:
        opti.subject_to(X[:, 0] == problem.x0)
    opti.subject_to(X[:, 1:] == step(X[:, :-1], U, g[None, :-1], np.diff(g)[None, :],
                                     ca.repmat(ca.DM(p), 1, K)))
    if kind == "ball":
        opti.subject_to(ca.sum1(U**2) <= 1)
    else:
        opti.subject_to(opti.bounded(-1, ca.vec(U), 1))
    opti.minimize(-ca.dot(zhat, X[:, -1]))
    opti.set_initial(X, guess.T)
    opti.set_initial(U, u_guess.T)
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "tol": tol, "max_iter": max_iter,
                                                  "sb": "yes"})
    try:
        sol = opti.solve()
    except RuntimeError as exc:
        raise SolverError(f"transcription_support: IPOPT failed for z-hat = {zhat.tolist()}: {exc}") from None
    return float(zhat @ sol.value(X[:, -1]))
