"""Independent truth for the soundness harness: admissible trajectories integrated by SciPy.

The trajectories are integrated by SciPy's DOP853 (``solve_ivp``, ``rtol = 1e-12``,
``atol = 1e-14``), not by the project's compiled kernels (:mod:`ocreach.native`).  The
right-hand side is, for a generated system, its own numpy coding of the coefficients
(:meth:`ocreach.testing.strategies.GeneratedSystem.rhs`), and for a bundled problem the model's
symbolic ``f`` evaluated by a plain ``casadi.Function`` (:func:`model_rhs`): the model defines the
problem, the method under test only ever sees its own derived functions.

The samples (:func:`samples`) are the ones that find the edge of a reachable set:

* initial states at vertices of the initial set (``argmax_x d^T x`` over the set for random
  directions ``d``: ``c + G sign(G^T d)`` on a zonotope or box, the boundary of an ellipsoid),
  at its centre and uniform inside it;
* inputs piecewise constant on ``pieces`` equal parts of every grid step: a vertex of the input
  set held for the whole horizon (corner of the box, point of the unit sphere), bang-bang (a new
  vertex on every piece) and uniform random in the input set on every piece;
* directed samples (:func:`directed`): the extremal bang-bang input and initial vertex of the
  linearised dynamics for a direction and a grid time, so that some trajectories reach the edge
  of the set in that direction -- random inputs almost never push every state outward at once.

:func:`integrate` returns the states at every grid time and at the interior times ``inner``
(fractions of each step; the step midpoint by default), where the time-interval tubes are checked.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

#: DOP853 tolerances of the truth (tight: the global error is ~1e-11 on the harness's horizons,
#: far below the containment tolerance of :mod:`ocreach.testing.containment`)
RTOL, ATOL = 1e-12, 1e-14
#: input laws of :func:`samples`, cycled over the initial states
LAWS = ("constant", "bang-bang", "random")

Rhs = Callable[[float, np.ndarray, np.ndarray], np.ndarray]   # (t, X (N, n), U (N, m)) -> (N, n)


@dataclass(frozen=True)
class Samples:
    """``X0`` (N, n) initial states, ``U`` (N, K, pieces, m) normalised inputs, a label each."""

    X0: np.ndarray
    U: np.ndarray
    labels: tuple[str, ...]


@dataclass(frozen=True)
class Truth:
    """States at the grid times ``states`` (N, K+1, n) and at the interior times ``inner``
    (fractions of each step) ``interior`` (N, K, len(inner), n).  ``steps`` grid steps were
    integrated (fewer than K if the integrator failed, e.g. a finite escape time; ``failure``
    says why); the arrays are NaN after that."""

    grid: np.ndarray
    states: np.ndarray
    inner: tuple[float, ...]
    interior: np.ndarray
    labels: tuple[str, ...]
    steps: int
    failure: str = ""


def model_rhs(problem) -> Rhs:
    """``f`` of ``problem.model`` as a numpy right-hand side, through a plain ``casadi.Function``
    (CasADi's virtual machine; no generated or compiled code of :mod:`ocreach.native`)."""
    import casadi as ca

    m = problem.model
    f = ca.Function("truth_f", [m.x, m.u, m.t, m.p], [m.f])
    p = np.asarray(problem.params, dtype=float)
    mapped: dict[int, ca.Function] = {}

    def rhs(t: float, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        N = X.shape[0]
        if N not in mapped:
            mapped[N] = f.map(N)
        out = mapped[N](X.T, U.T, t, np.tile(p[:, None], (1, N)))
        return np.asarray(out).T

    return rhs


def support_points(S, W: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Points of the initial set ``S`` maximising ``w^T x`` for each row ``w`` of ``W``: the
    vertex ``c + G sign(G^T w)`` of a zonotope or box, ``q + Q w / sqrt(w^T Q w)`` on an
    ellipsoid; boundary samples (``mode="extreme"``) for other sets."""
    from ocreach.sets.ellipsoid import Ellipsoid
    from ocreach.sets.interval import Interval
    from ocreach.sets.zonotope import Zonotope

    if isinstance(S, Interval):
        S = S.to_zonotope()
    if isinstance(S, Zonotope):
        sign = np.sign(W @ S.G)
        sign[sign == 0] = 1.0
        return S.c + sign @ S.G.T
    if isinstance(S, Ellipsoid):
        QW = W @ S.Q
        return S.q + QW / np.sqrt(np.maximum(np.einsum("ij,ij->i", QW, W), 1e-300))[:, None]
    return S.sample(W.shape[0], rng, mode="extreme")


def jacobians(rhs: Rhs, x: np.ndarray, m: int, t: float) -> tuple[np.ndarray, np.ndarray]:
    """``df/dx`` and ``df/du`` at ``(x, u = 0, t)`` by central differences of ``rhs``."""
    n = x.size
    Z = np.zeros((2 * (n + m), n + m))
    step = 1e-6 * np.maximum(1.0, np.abs(np.r_[x, np.zeros(m)]))
    for i in range(n + m):
        Z[2 * i, i], Z[2 * i + 1, i] = step[i], -step[i]
    F = rhs(t, x + Z[:, :n], Z[:, n:])
    J = (F[0::2] - F[1::2]) / (2 * step[:, None])
    return J[:n].T, J[n:].T


def directed(problem, rhs: Rhs, N: int, pieces: int, rng: np.random.Generator
             ) -> tuple[np.ndarray, np.ndarray]:
    """``N`` samples aimed at the edge of the reachable set in a direction ``d`` at a grid time
    ``t_k`` (axes and random directions, random ``k``): the extremal inputs of the dynamics
    linearised at the initial centre (Pontryagin: ``lambda(t) = exp(A^T (t_k - t)) d``, ``u``
    maximising ``lambda^T B u`` over the input set on every piece, bang-bang on a box) from the
    vertex of the initial set that maximises ``lambda(0)^T x0``."""
    from scipy.linalg import expm

    S = problem.initial_set
    grid = problem.grid
    K, n, cs = problem.n_segments, problem.model.n_x, problem.control_set
    centre = problem.x0 if S is None else np.asarray(getattr(S, "c", getattr(S, "q", problem.x0)))
    A, B = jacobians(rhs, np.asarray(centre, dtype=float), cs.dim, float(grid[0]))
    axes = np.vstack([np.eye(n), -np.eye(n)])
    D = np.vstack([axes, rng.standard_normal((max(N - len(axes), 0), n))])[:N]
    D = D[rng.permutation(len(D))]
    X0 = np.tile(centre, (N, 1)).astype(float)
    U = np.zeros((N, K, pieces, cs.dim))
    for i, d in enumerate(D):
        k = int(rng.integers(1, K + 1))
        T = grid[k]
        lam0 = expm(A.T * (T - grid[0])) @ d
        if S is not None:
            X0[i] = support_points(S, lam0[None], rng)[0]
        for j in range(K):
            for s in range(pieces):
                t = grid[j] + (s + 0.5) / pieces * (grid[j + 1] - grid[j])
                lam = expm(A.T * max(T - t, 0.0)) @ d
                U[i, j, s] = cs.argmin(-(B.T @ lam))
    return X0, U


def initial_points(problem, n_vertex: int, n_inside: int, rng: np.random.Generator
                   ) -> tuple[np.ndarray, list[str]]:
    """Initial states: ``n_vertex`` vertices (random directions), the centre and
    ``n_inside - 1`` uniform points."""
    S = problem.initial_set
    if S is None:
        N = n_vertex + n_inside
        return np.tile(problem.x0, (N, 1)), ["x0"] * N
    V = support_points(S, rng.standard_normal((n_vertex, S.dim)), rng)
    inside = S.sample(max(n_inside - 1, 0), rng, mode="uniform")
    centre = np.asarray(getattr(S, "c", getattr(S, "q", problem.x0)), dtype=float)
    X0 = np.vstack([V, centre[None], inside])
    return X0, ["vertex"] * len(V) + ["centre"] + ["inside"] * len(inside)


def input_schedules(control_set, N: int, K: int, pieces: int, rng: np.random.Generator
                    ) -> tuple[np.ndarray, list[str]]:
    """``(N, K, pieces, m)`` admissible inputs, the laws of :data:`LAWS` in turn."""
    U = np.empty((N, K, pieces, control_set.dim))
    laws = [LAWS[i % len(LAWS)] for i in range(N)]
    for i, law in enumerate(laws):
        if law == "constant":
            U[i] = control_set.sample_boundary(rng, (1, 1))
        elif law == "bang-bang":
            U[i] = control_set.sample_boundary(rng, (K, pieces))
        else:
            U[i] = control_set.sample(rng, (K, pieces))
    return U, laws


def samples(problem, n: int, seed: int = 0, pieces: int = 2, rhs: Rhs | None = None) -> Samples:
    """About ``n`` samples: with ``rhs``, a third :func:`directed`; of the rest half at vertices,
    half at the centre and inside, each with an input law of :data:`LAWS`."""
    rng = np.random.default_rng(seed)
    n_dir = n // 3 if rhs is not None else 0
    n_vertex = max(1, (n - n_dir) // 2)
    X0, where = initial_points(problem, n_vertex, max(1, n - n_dir - n_vertex), rng)
    U, laws = input_schedules(problem.control_set, X0.shape[0], problem.n_segments, pieces, rng)
    labels = [f"{w}/{law}" for w, law in zip(where, laws)]
    if n_dir:
        Xd, Ud = directed(problem, rhs, n_dir, pieces, rng)
        X0, U = np.vstack([X0, Xd]), np.concatenate([U, Ud])
        labels += ["directed"] * n_dir
    return Samples(X0=X0, U=U, labels=tuple(labels))


def integrate(rhs: Rhs, grid: np.ndarray, smp: Samples, inner: Sequence[float] = (0.5,),
              rtol: float = RTOL, atol: float = ATOL) -> Truth:
    """Integrate every sample over ``grid`` (module docstring); all samples in one DOP853 system
    per input piece."""
    X = np.asarray(smp.X0, dtype=float).copy()
    N, n = X.shape
    K, pieces = smp.U.shape[1], smp.U.shape[2]
    inner = tuple(float(s) for s in inner)
    states = np.full((N, K + 1, n), np.nan)
    interior = np.full((N, K, len(inner), n), np.nan)
    states[:, 0] = X
    for k in range(K):
        t0, t1 = float(grid[k]), float(grid[k + 1])
        for s in range(pieces):
            a, b = s / pieces, (s + 1) / pieces
            want = [(j, t0 + f * (t1 - t0)) for j, f in enumerate(inner) if a < f <= b]
            Us = smp.U[:, k, s]
            ta, tb = t0 + a * (t1 - t0), t0 + b * (t1 - t0)
            t_eval = [t for _, t in want if t != tb] + [tb]
            try:
                sol = solve_ivp(lambda t, y, Us=Us: rhs(t, y.reshape(N, n), Us).ravel(), (ta, tb),
                                X.ravel(), method="DOP853", rtol=rtol, atol=atol, t_eval=t_eval)
                ok = sol.success and np.all(np.isfinite(sol.y))
                reason = sol.message
            except (FloatingPointError, OverflowError, ValueError) as exc:
                ok, reason = False, f"{type(exc).__name__}: {exc}"
            if not ok:
                return Truth(grid, states, inner, interior, smp.labels, k,
                             f"DOP853 failed on step {k} [{t0:.6g}, {t1:.6g}]: {reason}")
            Y = sol.y.T.reshape(-1, N, n)
            for idx, (j, t) in enumerate(w for w in want if w[1] != tb):
                interior[:, k, j] = Y[idx]
            X = Y[-1]
            for j, t in want:
                if t == tb:
                    interior[:, k, j] = X
        states[:, k + 1] = X
    return Truth(grid, states, inner, interior, smp.labels, K)
