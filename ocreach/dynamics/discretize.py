"""Discrete-time prediction model ``x_{k+1} = f_d(x_k, u_k, t_k)`` (Patel & Subbarao Eq. 26).

The continuous model ``dx/dt = f(x, u, t; p)`` is integrated over one control step ``dt`` with the
control held constant, by ``n_sub`` classical Runge-Kutta 4 substeps.  The map is one symbolic SX
expression, so CasADi differentiates it exactly:

* ``A_k = d x_{k+1} / d x_k`` is the RK4 discretisation of the variational equation
  ``dPhi/dt = f_x Phi``, ``Phi(t_k) = I`` (differentiation commutes with an explicit Runge-Kutta
  scheme), i.e. the state-transition matrix ``Phi(t_{k+1}, t_k)``;
* ``B_k = d x_{k+1} / d u_k`` is the RK4 discretisation of ``dPsi/dt = f_x Psi + f_u``,
  ``Psi(t_k) = 0``, i.e. ``int_{t_k}^{t_{k+1}} Phi(t_{k+1}, s) f_u(s) ds`` for the held control.

Both converge with order 4 in ``dt / n_sub``; ``tests/test_control.py`` checks the map and both
matrices against SciPy's ``solve_ivp`` (DOP853, rtol 1e-12) on the L2 halo.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError, check_positive
from ocreach.model import Model


def rk4_expression(model: Model, x: ca.SX, u: ca.SX, t: ca.SX, p: ca.SX, dt: float | ca.SX,
                   n_sub: int) -> ca.SX:
    """Symbolic state after ``n_sub`` RK4 substeps of length ``dt / n_sub`` with ``u`` held
    (``dt`` a number, or a symbol as in :mod:`ocreach.reach.direct`)."""
    f = model.f_fun
    h = dt / n_sub
    xk = x
    for i in range(n_sub):
        ti = t + i * h
        k1 = f(xk, u, ti, p)
        k2 = f(xk + 0.5 * h * k1, u, ti + 0.5 * h, p)
        k3 = f(xk + 0.5 * h * k2, u, ti + 0.5 * h, p)
        k4 = f(xk + h * k3, u, ti + h, p)
        xk = xk + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return xk


@dataclass(frozen=True, eq=False)
class Discretization:
    """RK4 zero-order-hold discretisation of ``model`` with step ``dt`` and ``n_sub`` substeps.

    ``F(x, u, t, p) -> x_next`` and ``F_jac(x, u, t, p) -> (x_next, A, B)`` are built once (SX)
    and cached on the model (keyed by ``dt`` and ``n_sub``), so every controller, plant and
    report built on the same discretisation shares them.
    """

    model: Model
    dt: float
    n_sub: int = 4

    def __post_init__(self) -> None:
        check_positive("dt", self.dt)
        if int(self.n_sub) != self.n_sub or self.n_sub < 1:
            raise ProblemError(f"n_sub (RK4 substeps per step) must be an integer >= 1; "
                               f"got {self.n_sub!r}")

    def _cached(self, key, builder):
        return self.model.cached(("rk4_discretization", float(self.dt), int(self.n_sub), key), builder)

    @property
    def F(self) -> ca.Function:
        """``(x, u, t, p) -> x_next`` (Patel & Subbarao Eq. 26)."""
        m = self.model

        def build():
            x_next = rk4_expression(m, m.x, m.u, m.t, m.p, self.dt, self.n_sub)
            return ca.Function("f_d", [m.x, m.u, m.t, m.p], [x_next],
                               ["x", "u", "t", "p"], ["x_next"])

        return self._cached("F", build)

    @property
    def F_jac(self) -> ca.Function:
        """``(x, u, t, p) -> (x_next, A, B)`` with ``A = Phi(t+dt, t)``, ``B = int Phi f_u``."""
        m = self.model

        def build():
            x_next = rk4_expression(m, m.x, m.u, m.t, m.p, self.dt, self.n_sub)
            return ca.Function("f_d_jac", [m.x, m.u, m.t, m.p],
                               [x_next, ca.jacobian(x_next, m.x), ca.jacobian(x_next, m.u)],
                               ["x", "u", "t", "p"], ["x_next", "A", "B"])

        return self._cached("F_jac", build)

    def step(self, x, u, t: float, p) -> np.ndarray:
        """One numeric step."""
        return np.asarray(self.F(x, u, t, p)).ravel()

    def linearize(self, X: np.ndarray, U: np.ndarray, T: np.ndarray,
                  p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Discrete linearisation along ``(X_k, U_k, T_k)``, ``k = 0..K-1``, in one mapped call.

        Returns ``(X_next (K, n_x), A (K, n_x, n_x), B (K, n_x, n_u))``.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        U = np.atleast_2d(np.asarray(U, dtype=float))
        T = np.asarray(T, dtype=float).ravel()
        K = X.shape[0]
        if U.shape[0] != K or T.size != K:
            raise ProblemError(f"linearize needs as many controls and times as states ({K}); "
                               f"got U {U.shape}, T {T.shape}")
        nx, nu = self.model.n_x, self.model.n_u
        fm = self._cached(("map", K), lambda: self.F_jac.map(K))
        xn, A, B = fm(X.T, U.T, T.reshape(1, -1), np.repeat(np.asarray(p, float).reshape(-1, 1), K, 1))
        A = np.asarray(A).reshape(nx, K, nx).transpose(1, 0, 2)
        B = np.asarray(B).reshape(nx, K, nu).transpose(1, 0, 2)
        return np.asarray(xn).T, A, B
