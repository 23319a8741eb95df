"""Indirect reachability: FFOE and OLE on the multi-stage formulation (Patel & Scheeres Sec. 2-5).

A trajectory is ``K`` segments with piecewise-constant control ``u^i`` (Eq. 2-3).  For the
linear terminal cost ``J = -z-hat . x^N`` (Eq. 12) the costate recursion (Eq. 14) and the control
law (Eq. 16-18) need only the per-segment partials

* ``F_x^i = d x^{i+1} / d x^i``  (the segment STM, Eq. 15) and
* ``F_u^i = d x^{i+1} / d u^i``  (the impulse-response matrix Omega, Eq. 17),

which are the two column blocks of the first-order STT of the augmented state ``z = [x; u]``
(:func:`ocreach.dynamics.flow.stt`, Foss et al. Eq. 11-13).  Everything here is vectorised over
directions (and, for OLE, over the per-direction trajectories): the backward recursion is a loop
over segments of batched matrix products; the control law of all directions is one ``einsum``.

The normalised control ``u`` of the models carries both the thrust direction and the throttle
``T_mag / T_max = ||u||``; Eq. 18 (``T_mag = T_max``, ``T = -T_max F_T^T lam / |F_T^T lam|``) is the
minimiser of ``lam^{i+1 T} F_u^i u`` over the unit ball, i.e. :meth:`ControlSet.argmin`, which also
covers a box control set (sign law).

Initial-state manifolds (:class:`InitialManifold`): an ellipsoidal uncertainty of the initial state
(Patel & Scheeres Eq. 21-23, Holzinger & Scheeres) and an initial impulsive Delta-V of bounded
magnitude (Eq. 24-26) both turn the initial costate ``lam^0`` into an initial-state offset.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ocreach.errors import ProblemError, check_count, check_real
from ocreach.geometry.directions import resolve_dims, sample_directions
from ocreach.model import Model
from ocreach.problem import Problem
from ocreach.reach.base import Method, SamplingOptions, Timer, requirements
from ocreach.reach.result import ReachResult


def thrust_param(model: Model) -> str:
    """Name of the model parameter that scales the thrust: the model's declared
    ``thrust_param`` (e.g. ``a_max``, ``T_max``, Van der Pol's ``gain``), see
    :func:`ocreach.model.find_thrust_param`."""
    from ocreach.model import find_thrust_param

    name = find_thrust_param(model)
    if not name:
        raise ProblemError(f"model {model.name} declares no thrust parameter (Model.build(..., "
                           f"thrust_param=NAME)); its parameters are {list(model.param_names)}")
    return name


def with_thrust(model: Model, params: np.ndarray, level: float) -> np.ndarray:
    """``params`` with the thrust parameter set to ``level`` (model units, must be > 0)."""
    level = float(level)
    if not np.isfinite(level) or level <= 0:
        raise ProblemError(f"thrust level (T_max) must be a finite number > 0; got {level!r}")
    out = np.array(params, dtype=float, copy=True)
    out[model.param_names.index(thrust_param(model))] = level
    return out


# ------------------------------------------------------------------------------ partials
def segment_partials(model: Model, states: np.ndarray, controls: np.ndarray, grid: np.ndarray,
                     p: np.ndarray, *, rtol: float = 1e-10, atol: float = 1e-12
                     ) -> tuple[np.ndarray, np.ndarray]:
    """``F_x`` and ``F_u`` of every segment of a batch of trajectories (Eq. 15 and 17).

    ``states`` ``(N, K+1, n_x)`` and ``controls`` ``(N, K, n_u)`` are trajectories on ``grid``;
    ``p`` is ``(n_p,)`` or ``(N, n_p)``.  The ``N*K`` segments are integrated as one batch of the
    first-order STT equations (:func:`ocreach.dynamics.flow.stt_rhs`, each restarted from the identity).
    Returns ``F_x`` ``(N, K, n_x, n_x)`` and ``F_u`` ``(N, K, n_x, n_u)``.
    """
    from ocreach.dynamics.flow import integrate_batch, stt_rhs

    N, K1, nx = states.shape
    K = K1 - 1
    nz = model.n_z
    P = np.broadcast_to(np.asarray(p, dtype=float), (N, model.n_p))
    x = states[:, :-1].reshape(N * K, nx)
    Y0 = np.concatenate([x, np.tile(np.eye(nx, nz).ravel(), (N * K, 1))], axis=1)
    args = np.concatenate([controls.reshape(N * K, model.n_u), np.repeat(P, K, axis=0)], axis=1)
    t0 = np.tile(grid[:-1], N)
    t1 = np.tile(grid[1:], N)
    Y1 = integrate_batch(stt_rhs(model, 1), Y0, t0, t1, args, rtol=rtol, atol=atol)
    phi = Y1[:, nx:nx + nx * nz].reshape(N, K, nx, nz)
    return phi[..., :nx], phi[..., nx:]


def backward_sensitivities(Fx: np.ndarray, Fu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sensitivities of the final state to each segment's control and to the initial state.

    ``B_k = F_x^{K-1} ... F_x^{k+1} F_u^k`` and ``M = F_x^{K-1} ... F_x^0``, so that the costate
    recursion of Eq. 14 (``lam^k = F_x^{k T} lam^{k+1}``) gives ``F_u^{k T} lam^{k+1} = B_k^T lam^N``
    and ``lam^0 = M^T lam^N``.  Leading batch axes of ``Fx`` ``(..., K, n_x, n_x)`` and ``Fu``
    ``(..., K, n_x, n_u)`` are kept; the loop runs over segments only.
    """
    K = Fx.shape[-3]
    nx = Fx.shape[-1]
    B = np.empty_like(Fu)
    M = np.broadcast_to(np.eye(nx), Fx.shape[:-3] + (nx, nx)).copy()
    for k in range(K - 1, -1, -1):
        B[..., k, :, :] = M @ Fu[..., k, :, :]
        M = M @ Fx[..., k, :, :]
    return B, M


def control_gradient(B: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """``F_u^{k T} lam^{k+1} = B_k^T lam^N`` with ``lam^N = -z-hat`` (Eq. 12, 14): the gradient of
    the cost ``-z-hat . x^N`` w.r.t. each segment's control, ``(N, K, n_u)``."""
    if B.ndim == 3:
        return np.einsum("kiu,ni->nku", B, -directions, optimize=True)
    return np.einsum("nkiu,ni->nku", B, -directions, optimize=True)


def control_law(B: np.ndarray, lam_final: np.ndarray, control_set) -> np.ndarray:
    """Patel & Scheeres Eq. 18 for all directions and segments at once.

    ``B`` ``(K, n_x, n_u)`` (shared reference, FFOE) or ``(N, K, n_x, n_u)`` (one per direction,
    OLE); ``lam_final`` ``(N, n_x)`` the terminal costates ``lam^N = -z-hat``.  The switching
    vector ``F_u^{k T} lam^{k+1} = B_k^T lam^N`` is minimised over the control set (full thrust
    along ``-F_T^T lam``).  Returns normalised controls ``(N, K, n_u)``.
    """
    return control_set.argmin(control_gradient(B, -lam_final))


# ------------------------------------------------------------------------------ initial manifolds
@dataclass(frozen=True)
class InitialManifold:
    """Initial-state offsets from the initial costate (Patel & Scheeres Eq. 21-26).

    ``unc_dims``/``E_inv``/``d``: the uncertain components lie on ``dx^T E dx = d^2`` (Eq. 21);
    the transversality condition gives ``dx = -d E^-1 lam / sqrt(lam^T E^-1 lam)`` (Eq. 23).
    ``dv_dims``/``dv_max``: an initial impulse ``dv = -dV_max lam_v / |lam_v|`` (Eq. 26); when the
    model carries the inverse mass ``n`` (state ``mass_index``) it is set to the post-burn value
    ``n exp(dV_max / c)`` (rocket equation, exhaust speed ``c_ex``).
    """

    unc_dims: tuple[int, ...] = ()
    E_inv: np.ndarray | None = None
    d: float = 0.0
    dv_dims: tuple[int, ...] = ()
    dv_max: float = 0.0
    mass_index: int | None = None
    c_ex: float | None = None

    @property
    def active(self) -> bool:
        return (bool(self.unc_dims) and self.d > 0) or (bool(self.dv_dims) and self.dv_max > 0)

    def apply(self, x0: np.ndarray, lam0: np.ndarray) -> np.ndarray:
        """Initial states ``(N, n_x)`` on the manifold for initial costates ``lam0`` ``(N, n_x)``."""
        X = np.array(np.broadcast_to(x0, lam0.shape), dtype=float)
        if self.unc_dims and self.d > 0:
            lam = lam0[:, list(self.unc_dims)]
            w = lam @ self.E_inv.T
            nrm = np.sqrt(np.maximum(np.einsum("ni,ni->n", lam, w), 1e-300))
            X[:, list(self.unc_dims)] -= self.d * w / nrm[:, None]
        if self.dv_dims and self.dv_max > 0:
            lv = lam0[:, list(self.dv_dims)]
            nrm = np.maximum(np.linalg.norm(lv, axis=1), 1e-300)
            X[:, list(self.dv_dims)] -= self.dv_max * lv / nrm[:, None]
            if self.mass_index is not None and self.c_ex:
                X[:, self.mass_index] *= np.exp(self.dv_max / self.c_ex)
        return X

    def jacobian(self, lam0: np.ndarray) -> np.ndarray:
        """``d x0 / d lam0`` ``(n_x, n_x)`` at one costate (used by the BVP shooting)."""
        n = lam0.size
        J = np.zeros((n, n))
        if self.unc_dims and self.d > 0:
            idx = list(self.unc_dims)
            lam = lam0[idx]
            w = self.E_inv @ lam
            s = float(np.sqrt(lam @ w))
            J[np.ix_(idx, idx)] = -self.d * (self.E_inv / s - np.outer(w, w) / s**3)
        if self.dv_dims and self.dv_max > 0:
            idx = list(self.dv_dims)
            lv = lam0[idx]
            s = float(np.linalg.norm(lv))
            J[np.ix_(idx, idx)] += -self.dv_max * (np.eye(len(idx)) / s - np.outer(lv, lv) / s**3)
        return J


def _index_list(value, problem, what: str) -> tuple[int, ...]:
    from ocreach.geometry.directions import resolve_dims

    try:
        return resolve_dims(value, problem)
    except ProblemError as exc:
        raise ProblemError(f"{what}: {exc}") from None


def build_manifold(problem, opt) -> InitialManifold:
    """The :class:`InitialManifold` of a problem and method options.

    Options ``uncertainty_radius`` (d > 0 switches Eq. 21-23 on), ``uncertainty_dims`` (default the
    position dims) and ``uncertainty_matrix`` (E, symmetric positive definite, default identity).
    Without those options an :class:`~ocreach.sets.ellipsoid.Ellipsoid` ``problem.initial_set``
    is used (its non-degenerate dims, ``E = Q^-1``, ``d = 1``).  ``dv_max > 0`` switches the
    initial Delta-V (Eq. 24-26) on, along ``dv_dims`` (default the velocity dims).
    """
    model = problem.model
    unc_dims: tuple[int, ...] = ()
    E_inv = None
    d = float(opt.uncertainty_radius)
    if not np.isfinite(d) or d < 0:
        raise ProblemError(f"uncertainty_radius must be a finite number >= 0; got {opt.uncertainty_radius!r}")
    if d > 0:
        unc_dims = _index_list(opt.uncertainty_dims or "position", problem, "uncertainty_dims")
        m = len(unc_dims)
        E = np.eye(m) if opt.uncertainty_matrix is None else np.asarray(opt.uncertainty_matrix, float)
        E_inv = _spd_inverse(E, m, "uncertainty_matrix")
    elif problem.initial_set is not None:
        from ocreach.sets.ellipsoid import Ellipsoid

        if not isinstance(problem.initial_set, Ellipsoid):
            raise ProblemError("ffoe/ole/bvp handle an ellipsoidal initial set only (Patel & Scheeres "
                               f"Eq. 21-23); problem {problem.id} has {type(problem.initial_set).__name__}")
        Q = np.asarray(problem.initial_set.Q)
        unc_dims = tuple(int(i) for i in np.flatnonzero(np.abs(np.diag(Q)) > 0))
        if unc_dims:
            E_inv = np.array(Q[np.ix_(unc_dims, unc_dims)])
            _spd_inverse(E_inv, len(unc_dims), "initial_set shape matrix Q")
            d = 1.0
    dv = float(opt.dv_max)
    if not np.isfinite(dv) or dv < 0:
        raise ProblemError(f"dv_max must be a finite number >= 0; got {opt.dv_max!r}")
    dv_dims = _index_list(opt.dv_dims or "velocity", problem, "dv_dims") if dv > 0 else ()
    mass_index = model.state_names.index("n") if "n" in model.state_names else None
    c_ex = model.param("c_ex", problem.params) if "c_ex" in model.param_names else None
    return InitialManifold(unc_dims=unc_dims, E_inv=E_inv, d=d, dv_dims=dv_dims, dv_max=dv,
                           mass_index=mass_index, c_ex=c_ex)


def _spd_inverse(E: np.ndarray, m: int, name: str) -> np.ndarray:
    if E.shape != (m, m) or not np.all(np.isfinite(E)):
        raise ProblemError(f"{name} must be a finite ({m}, {m}) matrix; got shape {E.shape}")
    if not np.allclose(E, E.T, rtol=1e-10, atol=1e-14 * max(1.0, np.abs(E).max())):
        raise ProblemError(f"{name} must be symmetric; got {E!r}")
    w = np.linalg.eigvalsh(0.5 * (E + E.T))
    if w.min() <= 0:
        raise ProblemError(f"{name} must be positive definite (Patel & Scheeres Eq. 21 needs a full-rank "
                           f"ellipsoid); its smallest eigenvalue is {w.min():.3g}")
    return np.linalg.inv(0.5 * (E + E.T))


# ------------------------------------------------------------------------------ methods
def _costs(directions: np.ndarray, final_states: np.ndarray) -> np.ndarray:
    return np.einsum("ni,ni->n", directions, final_states)


class FFOE(Method):
    """Fast First-Order Estimate (Patel & Scheeres Algorithm 1)."""

    name = "ffoe"
    description = "fast first-order estimate: one unpowered STM pass, control laws by matrix products (Patel & Scheeres Alg. 1)"

    @dataclass
    class Options(SamplingOptions):
        """Options shared by ffoe, ole and bvp (Patel & Scheeres); ``samples`` is the number of
        directions z-hat."""

        #: the subspace of the directions z-hat: "position", "velocity", "all" or state indices
        dims: Any = "position"
        #: random directions (seeded by seed) instead of an even spread; always random above
        #: 3 dimensions
        random: bool = False
        #: thrust level in model units, overriding the problem's a_max / T_max (None: the problem's)
        thrust: float | None = None
        #: radius d of the initial uncertainty ellipsoid, model units (Eq. 21-23; 0: none, or the
        #: problem's ellipsoidal initial set)
        uncertainty_radius: float = 0.0
        #: states the uncertainty ellipsoid spans (None: the position states)
        uncertainty_dims: Any = None
        #: shape matrix E of the ellipsoid, symmetric positive definite (None: the identity)
        uncertainty_matrix: Any = None
        #: an initial impulsive Delta-V of at most this size, model velocity units (Eq. 24-26)
        dv_max: float = 0.0
        #: the velocity states the initial Delta-V acts on (None: all of them)
        dv_dims: Any = None

        def __post_init__(self) -> None:
            super().__post_init__()  # samples, seed, rtol, atol
            if self.thrust is not None and not check_real("thrust (T_max)", self.thrust) > 0:
                raise ProblemError(f"thrust (T_max) must be a finite number > 0; got {self.thrust!r}")
            self.random = bool(self.random)

    @classmethod
    def applicable(cls, problem: Problem) -> tuple[bool, str]:
        """A bounded control set, an ellipsoidal initial set (or none), and a declared thrust
        parameter or a control-affine model (the laws only need ``F_u``; ``thrust=`` then needs
        the parameter)."""
        ok, why = requirements(problem, bounded=True, initial_sets=("Ellipsoid",))
        if ok and not problem.model.control_affine:
            return requirements(problem, thrust=True)
        return ok, why

    # -------------------------------------------------------------- shared set-up
    def _setup(self, problem: Problem) -> tuple[np.ndarray, np.ndarray, InitialManifold]:
        opt = self.options
        model = problem.model
        if problem.control_set.kind == "free":
            raise ProblemError(f"method {self.name!r} needs a bounded control set ('ball' or 'box'); "
                               f"problem {problem.id} has 'free' controls")
        p = problem.params if opt.thrust is None else with_thrust(model, problem.params, opt.thrust)
        dims = resolve_dims(opt.dims, problem)
        dirs = sample_directions(model.n_x, dims, opt.samples, opt.seed, opt.random)
        return p, dirs, build_manifold(problem, opt)

    def reference(self, problem: Problem, p: np.ndarray):
        """Unpowered trajectory and its partials ``F_x``, ``F_u`` (Alg. 1, first loop)."""
        from ocreach.dynamics.flow import stt

        zeros = np.zeros((problem.n_segments, problem.model.n_u))
        ref = stt(problem.model, problem.x0, zeros, problem.grid, 1, p=p,
                  rtol=self.options.rtol, atol=self.options.atol)
        nx = problem.model.n_x
        return ref, ref.Phi1[..., :nx], ref.Phi1[..., nx:]

    def laws(self, problem: Problem, B: np.ndarray, M: np.ndarray, dirs: np.ndarray,
             manifold: InitialManifold) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Controls ``(N, K, n_u)``, initial costates and initial states of all directions
        (Alg. 1, second loop; Eq. 14, 18, 23, 26) by matrix products only."""
        lam_f = -dirs
        U = control_law(B, lam_f, problem.control_set)
        lam0 = lam_f @ M if M.ndim == 2 else np.einsum("ni,nij->nj", lam_f, M)
        X0 = manifold.apply(problem.x0, lam0) if manifold.active else np.tile(problem.x0, (len(dirs), 1))
        return U, lam0, X0

    def first_pass(self, problem: Problem, timer: Timer):
        """Algorithm 1: set-up, unpowered partials, control laws, one powered batch.

        Returns ``(p, dirs, manifold, ref, U, lam0, traj)``; OLE starts from it.
        """
        from ocreach.dynamics.flow import propagate

        opt = self.options
        with timer("setup"):
            p, dirs, manifold = self._setup(problem)
        with timer("unpowered_partials"):
            ref, Fx, Fu = self.reference(problem, p)
        with timer("control_laws"):
            B, M = backward_sensitivities(Fx, Fu)
            U, lam0, X0 = self.laws(problem, B, M, dirs, manifold)
        with timer("powered_propagation"):
            traj = propagate(problem.model, X0, U, problem.grid, p=p, rtol=opt.rtol, atol=opt.atol)
        return p, dirs, manifold, ref, U, lam0, traj

    def solve(self, problem: Problem) -> ReachResult:
        timer = Timer()
        p, dirs, _manifold, ref, U, lam0, traj = self.first_pass(problem, timer)
        meta = self.base_meta(problem, timer.times)
        meta.update(directions=dirs, costate0=lam0, cost=_costs(dirs, traj[:, -1]),
                    params=p, reference_final=ref.states[-1],
                    controls_note="piecewise-constant normalised controls; trajectories[:, 0] is the "
                                  "initial state (shifted on the uncertainty/Delta-V manifold if any); "
                                  "re-simulate with flow.propagate(model, traj[:, 0], controls, grid, p=meta['params'])")
        return ReachResult.from_trajectories(problem.grid, traj, controls=U, meta=meta)

    def sweep(self, problem: Problem, thrust_levels) -> list[ReachResult]:
        """FFOE for several thrust levels re-using one set of unpowered partials.

        Patel & Scheeres Sec. 3: ``T_max`` scales ``F_u`` but not the thrust direction of Eq. 18,
        so the control laws are computed once; only the powered propagations (one batch for all
        levels and directions) depend on the level.  ``thrust_levels`` are in model units (the
        unit of the problem's ``a_max`` / ``T_max``); each must be > 0.
        """
        from ocreach.dynamics.flow import propagate

        levels = np.atleast_1d(np.asarray(thrust_levels, dtype=float))
        if levels.ndim != 1 or levels.size == 0:
            raise ProblemError(f"thrust_levels must be a non-empty 1-D list; got {thrust_levels!r}")
        opt = self.options
        timer = Timer()
        with timer("setup"):
            p, dirs, manifold = self._setup(problem)
            P = np.stack([with_thrust(problem.model, p, lv) for lv in levels])
        with timer("unpowered_partials"):
            _ref, Fx, Fu = self.reference(problem, p)
        with timer("control_laws"):
            B, M = backward_sensitivities(Fx, Fu)
            U, lam0, X0 = self.laws(problem, B, M, dirs, manifold)
        L, N = levels.size, dirs.shape[0]
        with timer("powered_propagation"):
            traj = propagate(problem.model, np.tile(X0, (L, 1)), np.tile(U, (L, 1, 1)), problem.grid,
                             p=np.repeat(P, N, axis=0), rtol=opt.rtol, atol=opt.atol)
        traj = traj.reshape(L, N, -1, problem.model.n_x)
        out = []
        for i in range(L):
            meta = self.base_meta(problem, {k: v / L for k, v in timer.times.items()})
            meta.update(directions=dirs, costate0=lam0, cost=_costs(dirs, traj[i, :, -1]), params=P[i],
                        thrust_level=float(levels[i]), sweep_runtime=dict(timer.times))
            out.append(ReachResult.from_trajectories(problem.grid, traj[i], controls=U, meta=meta))
        return out


class OLE(FFOE):
    """Open-Loop Exact solution (Patel & Scheeres Sec. 5): FFOE, then re-linearise until converged."""

    name = "ole"
    description = "open-loop exact: FFOE law re-linearised about each powered trajectory until the cost settles (Patel & Scheeres Sec. 5)"

    @dataclass
    class Options(FFOE.Options):
        """FFOE options plus the iteration's.  ``meta["first_order_gap"]`` is the gain the last
        plain update predicted on its linearisation (zero at a multi-stage PMP extremal)."""

        #: change of the cost under the plain, undamped update at which a direction counts as
        #: converged (model units; the paper's criterion), > 0
        tol: float = 1e-9
        #: most iterations per direction, >= 1
        max_iter: int = 50
        #: halvings of a blended control step when an update lowers the cost (0: the paper's
        #: plain iteration)
        backtrack: int = 6

        def __post_init__(self) -> None:
            super().__post_init__()
            self.tol = check_real("tol", self.tol)
            if not self.tol > 0:
                raise ProblemError(f"tol must be > 0; got {self.tol!r}")
            self.max_iter = check_count("max_iter", self.max_iter, 1)
            self.backtrack = check_count("backtrack", self.backtrack, 0)

    def solve(self, problem: Problem) -> ReachResult:
        from ocreach.dynamics.flow import propagate

        opt = self.options
        model = problem.model
        grid = problem.grid
        timer = Timer()
        p, dirs, manifold, ref, U, lam0, traj = self.first_pass(problem, timer)
        N = dirs.shape[0]
        J = _costs(dirs, traj[:, -1])
        J_ffoe = J.copy()
        iters = np.zeros(N, dtype=int)
        active = np.ones(N, dtype=bool)
        stalled = np.zeros(N, dtype=bool)
        gap = np.full(N, np.nan)
        history = [J.copy()]
        for _ in range(opt.max_iter):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            with timer("partials"):
                Fx_a, Fu_a = segment_partials(model, traj[idx], U[idx], grid, p,
                                              rtol=opt.rtol, atol=opt.atol)
            with timer("control_laws"):
                B_a, M_a = backward_sensitivities(Fx_a, Fu_a)
                U_new, lam_new, X_new = self.laws(problem, B_a, M_a, dirs[idx], manifold)
            with timer("powered_propagation"):
                traj_new = propagate(model, X_new, U_new, grid, p=p, rtol=opt.rtol, atol=opt.atol)
            J_new = _costs(dirs[idx], traj_new[:, -1])
            # first-order gain the plain update predicts on the current linearisation (>= 0; zero
            # exactly at a fixed point of Eq. 18 / 23 / 26, i.e. a multi-stage PMP extremal)
            gap[idx] = (np.einsum("nku,nku->n", control_gradient(B_a, dirs[idx]), U[idx] - U_new)
                        + np.einsum("ni,ni->n", lam_new, traj[idx, 0] - X_new))
            # convergence is judged on the plain (undamped) update, the paper's criterion: a tiny
            # damped step from the backtracking below must not count as convergence
            change = np.abs(J_new - J[idx])
            if opt.backtrack > 0:
                with timer("backtracking"):
                    U_new, traj_new, J_new, lam_new = self._backtrack(
                        problem, p, manifold, dirs[idx], U[idx], traj[idx], J[idx], lam0[idx],
                        U_new, traj_new, J_new, lam_new)
            keep = J_new >= J[idx] - opt.tol if opt.backtrack > 0 else np.ones(idx.size, bool)
            upd = idx[keep]
            U[upd], traj[upd], lam0[upd], J[upd] = U_new[keep], traj_new[keep], lam_new[keep], J_new[keep]
            iters[idx] += 1
            stalled[idx[~keep]] = True
            active[idx[(change < opt.tol) | ~keep]] = False
            history.append(J.copy())
        meta = self.base_meta(problem, timer.times)
        meta.update(directions=dirs, costate0=lam0, cost=J, cost_ffoe=J_ffoe, iterations=iters,
                    converged=~active & ~stalled, stalled=stalled, cost_history=np.array(history), params=p,
                    first_order_gap=gap,
                    reference_final=ref.states[-1],
                    controls_note="piecewise-constant normalised controls; re-simulate with "
                                  "flow.propagate(model, traj[:, 0], controls, grid, p=meta['params'])")
        return ReachResult.from_trajectories(grid, traj, controls=U, meta=meta)


    def _backtrack(self, problem, p, manifold, dirs, U, traj, J, lam0, U_new, traj_new, J_new, lam_new):
        """Where an update lowered the cost, try blended laws ``normalise((1-a) U + a U_new)``
        with ``a = 1/2, 1/4, ...`` (a line search on the control sphere; not in the paper).  The
        initial state of a blended step comes from the blended initial costate through the
        manifold (Eq. 23 / 26), so it stays on the ellipsoid / Delta-V sphere."""
        from ocreach.dynamics.flow import propagate

        opt = self.options
        worse = np.flatnonzero(J_new < J - opt.tol)
        alpha = 1.0
        for _ in range(opt.backtrack):
            if worse.size == 0:
                break
            alpha *= 0.5
            Ub = problem.control_set.argmin(-((1 - alpha) * U[worse] + alpha * U_new[worse]))
            lb = (1 - alpha) * lam0[worse] + alpha * lam_new[worse]
            x0b = manifold.apply(problem.x0, lb) if manifold.active else traj[worse, 0]
            tb = propagate(problem.model, x0b, Ub, problem.grid, p=p, rtol=opt.rtol, atol=opt.atol)
            Jb = _costs(dirs[worse], tb[:, -1])
            better = Jb > J_new[worse]
            w = worse[better]
            U_new[w], traj_new[w], J_new[w], lam_new[w] = Ub[better], tb[better], Jb[better], lb[better]
            worse = worse[Jb < J[worse] - opt.tol]
        return U_new, traj_new, J_new, lam_new
