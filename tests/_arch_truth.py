"""Independent truth for the ARCH-COMP benchmarks: right-hand sides written here in numpy (not the
project's CasADi models), integrated by SciPy's DOP853 over the whole batch of samples, and the
hybrid automata's runs rebuilt phase by phase from dense output (crossing times by bisection on
the interpolant), not by the project's sampler.

Used by ``tests/test_arch.py``.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

RTOL, ATOL = 1e-11, 1e-13


def laub_loomis(X: np.ndarray) -> np.ndarray:
    x1, x2, x3, x4, x5, x6, x7 = X.T
    return np.column_stack([1.4 * x3 - 0.9 * x1, 2.5 * x5 - 1.5 * x2, 0.6 * x7 - 0.8 * x2 * x3,
                            2 - 1.3 * x3 * x4, 0.7 * x1 - x4 * x5, 0.3 * x1 - 3.1 * x6,
                            1.8 * x6 - 1.5 * x2 * x7])


def coupled_vanderpol(mu: float):
    """The coupled Van der Pol oscillators (b = 1) of CVDP20."""
    def f(X: np.ndarray) -> np.ndarray:
        x1, y1, x2, y2 = X.T
        return np.column_stack([y1, mu * (1 - x1**2) * y1 - x1 + (x2 - x1),
                                y2, mu * (1 - x2**2) * y2 - x2 - (x2 - x1)])
    return f


def lotka_volterra(X: np.ndarray) -> np.ndarray:
    x, y = X[:, 0], X[:, 1]
    return np.column_stack([3 * x - 3 * x * y, x * y - y])


SC_MU, SC_R, SC_MC = 3.986e14 * 3600.0, 42164e3, 500.0
SC_K1 = np.array([[-28.8287, 0.1005, -1449.9754, 0.0046], [-0.087, -33.2562, 0.00462, -1451.5013]])
SC_K2 = np.array([[-288.0288, 0.1312, -9614.9898, 0.0], [-0.1312, -288.0, 0.0, -9614.9883]])


def spacecraft(K: np.ndarray | None):
    n = np.sqrt(SC_MU / SC_R**3)

    def f(X: np.ndarray) -> np.ndarray:
        x, y, vx, vy = X.T
        rc3 = ((SC_R + x) ** 2 + y**2) ** 1.5
        ux, uy = (X @ K.T / SC_MC).T if K is not None else (0.0, 0.0)
        return np.column_stack([vx, vy, n * n * x + 2 * n * vy + SC_MU / SC_R**2 - SC_MU / rc3 * (SC_R + x) + ux,
                                n * n * y - 2 * n * vx - SC_MU / rc3 * y + uy])
    return f


def batch(rhs, X0: np.ndarray, t_end: float):
    """Dense solution of the batch from 0 to ``t_end``: a function of local time -> (N, n)."""
    N, n = X0.shape

    def f(t, y):
        return rhs(y.reshape(N, n)).ravel()

    sol = solve_ivp(f, (0.0, t_end), X0.ravel(), method="DOP853", rtol=RTOL, atol=ATOL,
                    dense_output=True)
    assert sol.success, sol.message

    def at(t: float) -> np.ndarray:
        return sol.sol(min(max(t, 0.0), t_end)).reshape(N, n)
    return at


def states_at(rhs, X0: np.ndarray, times: np.ndarray) -> np.ndarray:
    """States of the batch at ``times`` (from 0): (len(times), N, n)."""
    N, n = X0.shape

    def f(t, y):
        return rhs(y.reshape(N, n)).ravel()

    sol = solve_ivp(f, (0.0, float(times[-1])), X0.ravel(), method="DOP853", rtol=RTOL,
                    atol=ATOL, t_eval=times)
    assert sol.success, sol.message
    return sol.y.T.reshape(len(times), N, n)


def first_root(at, rhs, g, t_end: float, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, the first local time in (0, t_end] where ``g(state) <= 0`` and the state there
    (inf and NaN if never): a scan of the batch's dense output on ``steps`` points brackets it,
    then the sample alone is integrated from the bracket's start with a terminal event."""
    ts = np.linspace(0.0, t_end, steps + 1)
    vals = np.array([g(at(t)) for t in ts])  # (steps+1, N)
    N = vals.shape[1]
    t_ev = np.full(N, np.inf)
    x_ev = np.full((N, at(0.0).shape[1]), np.nan)
    for s in np.flatnonzero(np.any(vals[1:] <= 0, axis=0)):
        k = int(np.flatnonzero(vals[1:, s] <= 0)[0])
        x0 = at(ts[k])[s]

        def ev(t, y):
            return g(y[None, :])[0]
        ev.terminal, ev.direction = True, -1
        sol = solve_ivp(lambda t, y: rhs(y[None, :])[0], (ts[k], ts[k + 1] + 1e-9 * t_end), x0,
                        method="DOP853", rtol=RTOL, atol=ATOL, events=ev)
        if sol.t_events[0].size:
            t_ev[s], x_ev[s] = sol.t_events[0][0], sol.y_events[0][0]
    return t_ev, x_ev
