"""Independent truth for the zonotope methods: trajectories integrated with SciPy's DOP853 on
right-hand sides written here in numpy (not the project's CasADi models), and the gauge check.

Used by ``tests/test_taylor_sdc.py`` and ``examples/patel_subbarao_sets.py``.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

#: a point is inside a set when its scaled gauge is at most this
GAUGE_TOL = 1 + 1e-9


def cr3bp_rhs(mu: float, a_max: float):
    def rhs(X: np.ndarray, U: np.ndarray) -> np.ndarray:  # X (N, 6), U (N, 3) acceleration incl. w
        x, y, z, vx, vy, vz = X.T
        r1 = np.sqrt((x + mu) ** 2 + y**2 + z**2)
        r2 = np.sqrt((x - 1 + mu) ** 2 + y**2 + z**2)
        ax = x + 2 * vy - (1 - mu) * (x + mu) / r1**3 - mu * (x - 1 + mu) / r2**3
        ay = y - 2 * vx - (1 - mu) * y / r1**3 - mu * y / r2**3
        az = -(1 - mu) * z / r1**3 - mu * z / r2**3
        return np.column_stack([vx, vy, vz, ax + a_max * U[:, 0], ay + a_max * U[:, 1],
                                az + a_max * U[:, 2]])
    return rhs


def twobody_rhs(mu: float, a_max: float):
    def rhs(X: np.ndarray, U: np.ndarray) -> np.ndarray:
        r = X[:, :3]
        rn = np.linalg.norm(r, axis=1, keepdims=True)
        return np.hstack([X[:, 3:], -mu * r / rn**3 + a_max * U])
    return rhs


def rhs_for(problem):
    m = problem.model
    mu, a = problem.param("mu"), problem.param("a_max")
    if m.name.startswith("cr3bp-spatial"):
        return cr3bp_rhs(mu, a)
    if m.name == "twobody":
        return twobody_rhs(mu, a)
    raise ValueError(f"no numpy truth for model {m.name}")


def ball_controls(rng, N: int, K: int, law: str) -> np.ndarray:
    """(N, K, 3) admissible controls: 'constant' (one unit direction held), 'bang' (fresh unit
    direction every segment), 'random' (uniform in the ball every segment)."""
    g = rng.standard_normal((N, 1 if law == "constant" else K, 3))
    g /= np.linalg.norm(g, axis=-1, keepdims=True)
    if law == "random":
        g *= rng.uniform(size=g.shape[:-1] + (1,)) ** (1 / 3)
    return np.broadcast_to(g, (N, K, 3)).copy()


def initial_samples(rng, Z, N: int) -> np.ndarray:
    """Half at vertices of the initial zonotope (factors +-1), half uniform inside."""
    if Z.n_generators == 0:
        return np.tile(Z.c, (N, 1))
    nv = N // 2
    return np.vstack([Z.sample(nv, rng, mode="extreme"), Z.sample(N - nv, rng, mode="uniform")])


def simulate(problem, X0: np.ndarray, U: np.ndarray, W: np.ndarray | None = None,
             rtol: float = 1e-12, atol: float = 1e-14, inner: int = 1):
    """States at every grid time (N, K+1, 6) and at ``inner`` interior times of each segment
    (N, K, inner, 6); ``U`` (N, K, 3) normalised controls, ``W`` (N, K, 3) velocity-row
    disturbance accelerations (constant per segment)."""
    rhs = rhs_for(problem)
    grid = problem.grid
    N, n = X0.shape
    K = grid.size - 1
    out = np.empty((N, K + 1, n))
    mid = np.empty((N, K, inner, n))
    out[:, 0] = X0
    X = X0.copy()
    a = problem.param("a_max")
    for k in range(K):
        acc = U[:, k].copy()
        if W is not None:
            acc = acc + W[:, k] / a

        def f(t, y, acc=acc):
            return rhs(y.reshape(N, n), acc).ravel()

        t_in = grid[k] + (grid[k + 1] - grid[k]) * (np.arange(1, inner + 1) / (inner + 1))
        sol = solve_ivp(f, (grid[k], grid[k + 1]), X.ravel(), method="DOP853", rtol=rtol, atol=atol,
                        t_eval=np.r_[t_in, grid[k + 1]])
        assert sol.success, sol.message
        Y = sol.y.T.reshape(-1, N, n)
        mid[:, k] = Y[:-1].transpose(1, 0, 2)
        X = Y[-1]
        out[:, k + 1] = X
    return out, mid


def assert_contained(res, traj: np.ndarray, mid: np.ndarray) -> None:
    """Every state of ``traj`` (N, K+1, n) in the set at its grid time, every interior state of
    ``mid`` (N, K, inner, n) in its step's tube (scaled gauge <= :data:`GAUGE_TOL`)."""
    from ocreach.sets.union import union_gauge

    for k in range(res.times.size):
        g = union_gauge(res.sets[k], traj[:, k])
        assert g.max() <= GAUGE_TOL, f"time index {k}: gauge {g.max()!r} > 1"
    for k in range(res.times.size - 1):
        for j in range(mid.shape[2]):
            g = union_gauge(res.tubes[k], mid[:, k, j])
            assert g.max() <= GAUGE_TOL, f"tube {k}, interior time {j}: gauge {g.max()!r} > 1"
