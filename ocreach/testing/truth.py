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
from types import SimpleNamespace

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


def with_disturbance(rhs: Rhs, smp: Samples, centre: np.ndarray, generators: np.ndarray,
                     seed: int = 0) -> tuple[Rhs, Samples]:
    """The samples with an additive disturbance ``w(t) = centre + generators omega(t)``,
    ``omega`` in ``[-1, 1]^q`` piecewise constant like the inputs (the laws of :data:`LAWS`,
    shifted by one against the inputs' so that a constant input meets a bang-bang disturbance):
    the right-hand side ``rhs(t, x, u) + w`` on the inputs ``[u, omega]``, and the samples with
    ``omega`` appended to ``U``."""
    from ocreach.problem import ControlSet

    wc = np.asarray(centre, dtype=float)
    WG = np.asarray(generators, dtype=float)
    N, K, pieces, m = smp.U.shape
    Om, laws = input_schedules(ControlSet("box", WG.shape[1]), N, K, pieces,
                               np.random.default_rng([seed, 1]))
    Om, laws = np.roll(Om, 1, axis=0), laws[-1:] + laws[:-1]

    def disturbed(t: float, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        return rhs(t, X, U[:, :m]) + wc + U[:, m:] @ WG.T

    labels = tuple(f"{lab}/w-{law}" for lab, law in zip(smp.labels, laws, strict=True))
    return disturbed, Samples(X0=smp.X0, U=np.concatenate([smp.U, Om], axis=-1), labels=labels)


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


# ------------------------------------------------------------------------------ hybrid automata
@dataclass(frozen=True)
class HybridTruth:
    """Truth states of a hybrid automaton: ``points`` (M, n) with their global times ``times``
    (M,), ``locations`` (M,) and the sample each came from (``labels``); the states at the grid
    times, at the interior times ``inner`` of every step, and just before and after every jump.
    ``blocked``: samples that reached an invariant's boundary with no enabled transition (their
    states up to there are kept); ``jumps``: transitions taken."""

    points: np.ndarray
    times: np.ndarray
    locations: tuple[str, ...]
    labels: tuple[str, ...]
    blocked: int = 0
    jumps: int = 0
    failure: str = ""


#: a guard or invariant constraint holds at a state when its value is <= this (times 1 + |bound|)
HYBRID_TOL = 1e-9
#: probability of each end of a permissive transition's time window (the rest uniform inside)
WINDOW_END = 0.15


def _clock_window(region, clock: str) -> tuple[float, float]:
    """The window ``[lo, hi]`` that the clock-only constraints of ``region`` allow."""
    lo, hi = -np.inf, np.inf
    for c in region:
        if getattr(c, "names", None) == (clock,):
            a = float(c.coeffs[0][1])
            lo, hi = (lo, min(hi, c.bound / a)) if a > 0 else (max(lo, c.bound / a), hi)
    return lo, hi


def _holds(region, x: np.ndarray, t: float, names, tol: float = HYBRID_TOL) -> bool:
    xa = np.r_[x, t][None, :]
    return all(float(c.value(xa, names)[0]) <= tol * (1 + abs(float(getattr(c, "bound", 0.0))))
               for c in region)


def hybrid_truth(problem, n: int, seed: int = 0, inner: Sequence[float] = (0.5,),
                 rtol: float = RTOL, atol: float = ATOL, max_jumps: int = 50) -> HybridTruth:
    """About ``n`` runs of ``problem.automaton`` from vertices, the centre and the inside of the
    initial set (inputs, if any, a constant vertex of the input set), each integrated alone by
    SciPy's DOP853 with each location's :func:`model_rhs`: the urgent guards' and the invariant's
    state constraints are event functions (a run jumps where an urgent guard starts to hold, or at
    the invariant's boundary through an enabled transition, else it is blocked); a permissive
    transition is taken at a time drawn in its window (each end with probability
    :data:`WINDOW_END`).  Not the project's sampler (:func:`ocreach.reach.hybrid.simulate_hybrid`)
    nor its compiled integrator."""
    from ocreach.hybrid import CLOCK as clock

    aut = problem.automaton
    names = (*aut.state_names, clock)
    grid = np.asarray(problem.grid, float)
    T = float(grid[-1])
    rng = np.random.default_rng(seed)
    n_vertex = max(1, n // 2)
    X0, where = initial_points(problem, n_vertex, max(1, n - n_vertex), rng)
    nu = aut.locations[0].model.n_u
    U0 = (problem.control_set.sample_boundary(rng, (X0.shape[0],)).reshape(X0.shape[0], nu)
          if nu else np.zeros((X0.shape[0], 0)))
    rhs = {loc.name: model_rhs(SimpleNamespace(model=loc.model, params=problem.params))
           for loc in aut.locations}
    rec_t = np.unique(np.r_[grid, [grid[k] + f * (grid[k + 1] - grid[k])
                                   for k in range(grid.size - 1) for f in inner]])
    pts, ts, locs, labels = [], [], [], []
    blocked = jumps = 0

    def record(x, t, loc, s):
        pts.append(np.asarray(x, float).copy())
        ts.append(float(t))
        locs.append(loc)
        labels.append(where[s])

    for s in range(X0.shape[0]):
        x, t, loc, u = X0[s].astype(float), float(grid[0]), problem.initial_location, U0[s]
        record(x, t, loc, s)
        for _ in range(max_jumps + 1):
            L = aut.location(loc)
            out = aut.outgoing(loc)
            # the permissive jump drawn on entering the location
            t_dec, tr_dec = np.inf, None
            for tr in out:
                if tr.urgent:
                    continue
                lo, hi = _clock_window(tr.guard, clock)
                lo, hi = max(lo, t), min(hi, T)
                if lo <= hi:
                    v = rng.uniform()
                    td = lo if v < WINDOW_END else hi if v < 2 * WINDOW_END else rng.uniform(lo, hi)
                    if td < t_dec:
                        t_dec, tr_dec = td, tr
            inv_hi = _clock_window(L.invariant, clock)[1]
            t_end = min(T, t_dec, inv_hi)
            watch = [(c, -1) for tr in out if tr.urgent for c in tr.guard
                     if getattr(c, "names", None) != (clock,)]
            watch += [(c, +1) for c in L.invariant if getattr(c, "names", None) != (clock,)]
            events = []
            for c, direction in watch:
                def ev(tt, y, c=c):
                    return float(c.value(np.r_[y, tt][None, :], names)[0])
                ev.terminal, ev.direction = True, direction
                events.append(ev)
            f = rhs[loc]
            hit = False
            if t_end > t:
                t_eval = np.r_[rec_t[(rec_t > t) & (rec_t < t_end)], t_end]
                sol = solve_ivp(lambda tt, y: f(tt, y[None, :], u[None, :])[0], (t, t_end), x,
                                method="DOP853", rtol=rtol, atol=atol, events=events or None,
                                t_eval=t_eval)
                if sol.status < 0:
                    return HybridTruth(np.array(pts), np.array(ts), tuple(locs), tuple(labels),
                                       blocked, jumps, f"DOP853 failed in {loc!r}: {sol.message}")
                for j in range(sol.t.size):
                    record(sol.y[:, j], sol.t[j], loc, s)
                hit = sol.status == 1
                if hit:  # the first event (a terminal event ends the integration there)
                    k = min((i for i, e in enumerate(sol.t_events) if e.size),
                            key=lambda i: sol.t_events[i][0])
                    x, t = sol.y_events[k][0].copy(), float(sol.t_events[k][0])
                else:
                    x, t = sol.y[:, -1].copy(), t_end
            if not hit and t >= T:
                break
            if hit:
                tr = next((tr for tr in out if tr.urgent and _holds(tr.guard, x, t, names)), None) \
                    or next((tr for tr in out if _holds(tr.guard, x, t, names)), None)
                if tr is None:
                    if _holds(L.invariant, x, t, names):
                        continue  # one constraint of a conjunctive guard: go on
                    blocked += 1
                    break
            elif t >= t_dec:
                tr = tr_dec if _holds(tr_dec.guard, x, t, names) else None
                if tr is None:
                    continue
            else:  # the invariant's time bound
                tr = next((tr for tr in out if _holds(tr.guard, x, t, names)), None)
                if tr is None:
                    blocked += 1
                    break
            record(x, t, loc, s)
            x, loc = tr.reset.apply(x), tr.target
            record(x, t, loc, s)
            jumps += 1
        else:
            return HybridTruth(np.array(pts), np.array(ts), tuple(locs), tuple(labels), blocked,
                               jumps, f"a run took more than max_jumps = {max_jumps} jumps")
    return HybridTruth(np.array(pts), np.array(ts), tuple(locs), tuple(labels), blocked, jumps)
