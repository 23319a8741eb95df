"""Discrete time-varying LQR along a reference (the baseline of Patel & Subbarao, "Remark").

About the reference the prediction model is linearised per step (``A_k = Phi(t_{k+1}, t_k)``,
``B_k = int Phi f_u``; see :mod:`ocreach.dynamics.discretize`) and the Riccati recursion

    K_k = (R + B_k^T P_{k+1} B_k)^{-1} B_k^T P_{k+1} A_k,
    P_k = Q + A_k^T P_{k+1} (A_k - B_k K_k)

gives the feedback ``u_k = u_ref_k - K_k (x_k - x_ref_k)``, saturated onto the plant's thrust set.

Modes (``riccati``):

* ``"periodic"`` (default for a periodic reference): the recursion is iterated backward over whole
  periods until ``P_0`` stops changing, giving the periodic solution ``P_{k+M} = P_k``;
* ``"finite"`` (default otherwise): one backward sweep from a terminal ``P_M`` (``P_terminal``,
  default ``Q``);
* ``"dare"``: frozen-time steady state, ``P_k`` from the discrete algebraic Riccati equation of
  ``(A_k, B_k)`` (SciPy's ``solve_discrete_are``), a new gain at every step;
* ``"constant"``: one gain for the whole run, ``K`` from the DARE of a single linearisation
  ``(A, B)``: at reference step ``linearize_at`` (an integer, default 0: the initial state) or at a
  given state (an array, e.g. the L2 point; ``u = 0``, ``t = t_0``).  This is the textbook
  "LQR about an operating point" (MATLAB ``dlqr(A, B, Q, R)`` once, applied everywhere); on a halo
  orbit it ignores how the linearisation changes along the orbit.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from ocreach.control.common import as_weight, check_thrust, control_scale, saturate
from ocreach.control.reference import TrackingReference
from ocreach.errors import ProblemError, SolverError

RICCATI_MODES = ("auto", "periodic", "finite", "dare", "constant")


def riccati_step(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray,
                 P_next: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One backward Riccati step: ``(K_k, P_k)`` from ``P_{k+1}``."""
    BtP = B.T @ P_next
    K = np.linalg.solve(R + BtP @ B, BtP @ A)
    P = Q + A.T @ P_next @ (A - B @ K)
    return K, 0.5 * (P + P.T)


def riccati_backward(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray,
                     P_terminal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Finite-horizon recursion over ``M`` steps: ``(K (M, m, n), P (M + 1, n, n))``."""
    M = A.shape[0]
    P = np.empty((M + 1,) + Q.shape)
    K = np.empty((M, B.shape[2], Q.shape[0]))
    P[M] = P_terminal
    for k in range(M - 1, -1, -1):
        K[k], P[k] = riccati_step(A[k], B[k], Q, R, P[k + 1])
    return K, P


def periodic_riccati(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, *,
                     rtol: float = 1e-11, max_periods: int = 500) -> tuple[np.ndarray, np.ndarray]:
    """Periodic solution ``P_{k+M} = P_k`` by backward iteration over whole periods."""
    P_end = Q.copy()
    for _ in range(max_periods):
        K, P = riccati_backward(A, B, Q, R, P_end)
        if not np.all(np.isfinite(P[0])):
            raise SolverError("periodic Riccati recursion diverged (non-finite P); the pair "
                              "(A_k, B_k) may not be stabilisable")
        if np.linalg.norm(P[0] - P_end) <= rtol * max(1.0, np.linalg.norm(P[0])):
            return K, P
        P_end = P[0]
    raise SolverError(f"periodic Riccati recursion did not converge in {max_periods} periods "
                      f"(rtol {rtol:g})")


def dare(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state gain and cost of a time-invariant pair: ``(K, P)`` (SciPy DARE)."""
    try:
        P = sla.solve_discrete_are(A, B, Q, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise SolverError(f"discrete algebraic Riccati equation failed: {exc}") from exc
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    return K, P


class LQR:
    """Time-varying discrete LQR tracking a :class:`TrackingReference` with thrust saturation.

    Parameters
    ----------
    Q : state weight (``n_x x n_x`` or its diagonal), symmetric positive semidefinite.
    R : control weight (``n_u x n_u`` or diagonal), symmetric positive definite, in the units of
        ``weights_in`` (see :mod:`ocreach.control.common`; default: thrust acceleration).
    riccati : ``"auto"``, ``"periodic"``, ``"finite"``, ``"dare"`` or ``"constant"`` (module
        docstring).
    P_terminal : terminal cost of the ``"finite"`` mode (default ``Q``).
    linearize_at : where the ``"constant"`` mode linearises: a reference step index (default 0) or
        a state of length ``n_x``.
    """

    name = "lqr"

    def __init__(self, Q, R, *, riccati: str = "auto", weights_in: str = "auto",
                 P_terminal=None, linearize_at=0) -> None:
        if riccati not in RICCATI_MODES:
            raise ProblemError(f"riccati must be one of {RICCATI_MODES}; got {riccati!r}")
        self.linearize_at = linearize_at
        self.Q_in, self.R_in = Q, R
        self.riccati = riccati
        self.weights_in = weights_in
        self.P_terminal_in = P_terminal
        self.fallbacks = 0
        self.events: list[dict] = []
        self.reference: TrackingReference | None = None

    # ------------------------------------------------------------------ setup
    def setup(self, reference: TrackingReference, control_set_kind: str) -> LQR:
        """Validate weights, linearise along ``reference`` and solve the Riccati equation."""
        model = reference.model
        check_thrust(model, reference.params)
        self.Q = as_weight("Q", self.Q_in, model.n_x, definite=False)
        R = as_weight("R", self.R_in, model.n_u, definite=True)
        self.u_scale = control_scale(model, reference.params, self.weights_in)
        self.R = self.u_scale**2 * R  # weight on the normalised control
        self.kind = control_set_kind
        self.reference = reference.linearize()
        A, B = reference.A, reference.B
        mode = self.riccati
        if mode == "auto":
            mode = "periodic" if reference.periodic else "finite"
        if mode == "periodic" and not reference.periodic:
            raise ProblemError("riccati='periodic' needs a periodic reference; got the "
                               f"non-periodic reference {reference.name!r}")
        if mode == "periodic":
            self.K, self.P = periodic_riccati(A, B, self.Q, self.R)
        elif mode == "constant":
            Ac, Bc = self.operating_point(reference)
            K, P = dare(Ac, Bc, self.Q, self.R)
            M = A.shape[0]
            self.K = np.repeat(K[None], M, axis=0)
            self.P = np.repeat(P[None], M + 1, axis=0)
            self.A_const, self.B_const = Ac, Bc
        elif mode == "finite":
            PT = self.Q if self.P_terminal_in is None else as_weight(
                "P_terminal", self.P_terminal_in, model.n_x, definite=False)
            self.K, self.P = riccati_backward(A, B, self.Q, self.R, PT)
        else:
            pairs = [dare(A[k], B[k], self.Q, self.R) for k in range(A.shape[0])]
            self.K = np.stack([p[0] for p in pairs])
            P = np.stack([p[1] for p in pairs])
            self.P = np.concatenate([P, P[-1:]])
        self.mode = mode
        return self

    def operating_point(self, reference: TrackingReference) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` of the ``"constant"`` mode: the discrete linearisation at ``linearize_at``."""
        at = self.linearize_at
        model = reference.model
        if isinstance(at, str) or np.ndim(at) == 0:
            if not isinstance(at, (int, np.integer)) or isinstance(at, bool) \
                    or not 0 <= int(at) < reference.n_steps:
                raise ProblemError(f"linearize_at must be a reference step 0..{reference.n_steps - 1} "
                                   f"or a state of length {model.n_x}; got {at!r}")
            k = int(at)
            return reference.A[k], reference.B[k]
        x = model.validate_state(at, "linearize_at")
        _, A, B = reference.discretization.linearize(
            x[None], np.zeros((1, model.n_u)), np.array([reference.t0]), reference.params)
        return A[0], B[0]

    def reset(self) -> None:
        self.fallbacks = 0
        self.events = []

    # ------------------------------------------------------------------ queries
    def gain(self, k: int) -> np.ndarray:
        """``K_k`` (normalised control per state error)."""
        return self.K[self.reference.gains_index(k)]

    def cost_to_go(self, k: int) -> np.ndarray:
        """``P_k`` (cost on the normalised control): modular in ``k`` along a periodic reference;
        along a non-periodic one ``k`` must be in ``0..M`` (``P_M`` the terminal cost of the
        reference's ``M`` steps), else :class:`ProblemError` (no cost-to-go beyond its end)."""
        ref = self.reference
        if ref.periodic:
            return self.P[k % ref.n_steps]
        last = self.P.shape[0] - 1
        if isinstance(k, bool) or int(k) != k or not 0 <= k <= last:
            raise ProblemError(f"cost_to_go: step k must be in 0..{last} along the non-periodic "
                               f"reference '{ref.name}' ({ref.n_steps} steps, P_0..P_{last}); "
                               f"got {k!r}")
        return self.P[int(k)]

    def unsaturated(self, k: int, x: np.ndarray) -> np.ndarray:
        ref = self.reference
        return ref.control(k) - self.gain(k) @ (np.asarray(x, float) - ref.state(k))

    def control(self, k: int, x: np.ndarray) -> np.ndarray:
        """Saturated feedback ``u_k`` (normalised)."""
        return saturate(self.unsaturated(k, x), self.kind)
