"""Trajectories, batches of trajectories, state-transition matrices and tensors.

Integrator
----------
:func:`integrate_batch` (:mod:`ocreach.native.integrator`, re-exported here) is an explicit
adaptive Runge-Kutta integrator for batches: the Dormand-Prince 8(5,3) pair (Hairer, Norsett &
Wanner, *Solving ODEs I*, Sec. II.10) with SciPy's ``DOP853`` tableau, error norm, step-size
controller and initial-step rule, and one step size per sample, generated as C from the
right-hand side and cached on disk (see :mod:`ocreach.native`).  Without a compiler (or with
``OCREACH_JIT=0``) the same algorithm runs as a NumPy loop over steps; results agree to
round-off, only slower.

Why not CVODES: its default BDF/Newton is a poor fit for non-stiff orbits.  CVODES Adams with
functional iteration (reltol 1e-10, interpreted right-hand side) took ~49 ms for the order-2 STT
over one NRHO period against ~14 ms here at rtol 1e-12 (similar final-state error, ~1e-11; same
loaded machine), and it needs one integrator call per sample.  CVODES with a compiled
right-hand side was not compared.  The defaults ``rtol = 1e-10``, ``atol = 1e-12`` agree with
SciPy ``DOP853`` at ``rtol = 1e-12`` to ~1e-10 on the DRO test case.

State-transition tensors
------------------------
:func:`stt` integrates the STT equations of Foss et al. Eq. 11 for the augmented dynamics
``z = [x; u]``, ``dz/dt = [f; 0]`` (Eq. 12) on every segment ``[t_k, t_{k+1}]`` of a grid, restarted
from the identity at each ``t_k``, which gives the discrete map of Eq. 13::

    delta x(t_{k+1}) = sum_j 1/j! Phi_k^(j) [delta z(t_k)]^j.

Only the x-rows of the tensors are integrated (the u-rows are ``[0 I]`` and zero).  Phi2 and Phi3
are symmetric in their lower indices, so only the index tuples ``a <= b (<= c)`` are integrated
(for the spatial CR3BP with ``n_z = 9`` this is 45 instead of 81 and 165 instead of 729 columns).
The right-hand side is built symbolically from :meth:`Model.derivative_expressions`; the tensor
contractions of Eq. 11 are written as products of ``f``-derivative matrices with Kronecker
products of Phi columns, so CasADi's sparse SX algebra drops the structural zeros.
The reference trajectory is propagated first (sequential), then the K segments are integrated in
one :func:`integrate_batch` call as K independent samples.
"""
from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from ocreach.errors import ProblemError
from ocreach.model import Model

# the compiled-code machinery lives in ocreach.native; these names stay importable from here
from ocreach.native import (  # noqa: F401
    COMPILE_ERRORS,
    c_identifier,
    cache_dir,
    compile_function,
    compile_source,
    generate_c,
    jit_enabled,
)
from ocreach.native.integrator import integrate_batch

__all__ = ["STTResult", "flow_rhs", "integrate_batch", "propagate", "stm", "stt", "stt_rhs"]

# --------------------------------------------------------------------------- model helpers
def flow_rhs(model: Model) -> ca.Function:
    """``(x, t, a = [u; p]) -> f(x, u, t; p)`` for :func:`integrate_batch`, cached on the model."""
    def build():
        a = ca.vertcat(model.u, model.p)
        return ca.Function(f"flow_{c_identifier(model.name)}", [model.x, model.t, a], [model.f],
                           ["y", "t", "a"], ["ydot"])

    return model.cached("flow_rhs", build)


def check_grid(grid, name: str = "grid") -> np.ndarray:
    """``grid`` as a finite, strictly monotone 1-D float array of >= 2 times, or a clear
    :class:`ProblemError` (decreasing grids mean backward time)."""
    g = np.asarray(grid, dtype=float)
    if g.ndim != 1 or g.size < 2:
        raise ProblemError(f"{name} must be a 1-D array of at least 2 times; got shape {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ProblemError(f"{name} must be finite; got {g!r}")
    d = np.diff(g)
    if not (np.all(d > 0) or np.all(d < 0)):
        raise ProblemError(f"{name} must be strictly increasing (or strictly decreasing for "
                           f"backward time); got {g!r}")
    return g


def _params(model: Model, p, n: int | None) -> np.ndarray:
    """Parameters as ``(n_p,)`` or ``(N, n_p)``."""
    if p is None:
        return model.p_default.astype(float)
    arr = np.asarray(p, dtype=float)
    if arr.shape == (model.n_p,) or (n is not None and arr.shape == (n, model.n_p)):
        if not np.all(np.isfinite(arr)):
            raise ProblemError(f"p must be finite; got {arr!r}")
        return arr
    allowed = f"({model.n_p},)" + (f" or ({n}, {model.n_p})" if n is not None else "")
    raise ProblemError(f"p must have shape {allowed} for model {model.name} "
                       f"(parameters {list(model.param_names)}); got {arr.shape}")


def _controls(model: Model, controls, k: int, n: int | None) -> np.ndarray:
    arr = np.asarray(controls, dtype=float)
    if model.n_u == 0 and arr.size == 0:
        return np.zeros((k, 0)) if n is None else np.zeros((n, k, 0))
    ok = arr.shape == (k, model.n_u) or (arr.ndim == 3 and arr.shape[1:] == (k, model.n_u)
                                         and (n is None or arr.shape[0] == n))
    if not ok:
        raise ProblemError(f"controls must have shape (K, n_u) = ({k}, {model.n_u}) or "
                           f"(N, {k}, {model.n_u}) for a grid of {k + 1} times; got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ProblemError("controls must be finite")
    return arr


def propagate(model: Model, x0: ArrayLike, controls: ArrayLike, grid: ArrayLike, *,
              p: ArrayLike | None = None, rtol: float = 1e-10, atol: float = 1e-12,
              substeps: int = 0, max_steps: int = 100000
              ) -> np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Propagate one state or a batch under piecewise-constant controls on ``grid``.

    Parameters
    ----------
    model : the dynamics.
    x0 : ``(n_x,)`` or ``(N, n_x)`` initial states at ``grid[0]``.
    controls : ``(K, n_u)`` (shared) or ``(N, K, n_u)``: control ``u_k`` held on ``[t_k, t_{k+1}]``.
    grid : ``(K+1,)`` strictly monotone times (decreasing = backward time).
    p : parameter vector ``(n_p,)`` (default ``model.p_default``) or ``(N, n_p)`` per sample.
    substeps : if > 0 also return ``substeps`` equally spaced points per segment (for plotting).

    Returns ``states`` of shape ``(N, K+1, n_x)``, or ``(K+1, n_x)`` for a single ``x0`` with 2-D
    controls; with ``substeps > 0`` returns ``(states, dense_times (K*substeps+1,),
    dense_states (N, K*substeps+1, n_x))`` (leading ``N`` dropped likewise).
    """
    g = check_grid(grid)
    k = g.size - 1
    x0a = model.validate_state(x0, "x0")
    single = x0a.ndim == 1
    if x0a.ndim not in (1, 2):
        raise ProblemError(f"x0 must have shape ({model.n_x},) or (N, {model.n_x}); got {x0a.shape}")
    X0 = x0a[None, :] if single else x0a
    n = X0.shape[0]
    U = _controls(model, controls, k, None)
    if U.ndim == 3:
        if single and U.shape[0] >= 1:
            X0 = np.repeat(X0, U.shape[0], axis=0)
            n = X0.shape[0]
        elif U.shape[0] != n:
            raise ProblemError(f"controls of shape {U.shape} need N = {U.shape[0]} initial states; "
                               f"got x0 of shape {x0a.shape}")
        single = False
    else:
        U = np.broadcast_to(U, (n, k, model.n_u))
    P = _params(model, p, n)
    P = np.broadcast_to(P, (n, model.n_p))
    substeps = int(substeps)
    if substeps < 0:
        raise ProblemError(f"substeps must be >= 0; got {substeps}")
    m = max(substeps, 1)
    if m == 1:
        times = g.copy()
    else:
        times = np.concatenate([np.linspace(g[i], g[i + 1], m + 1)[:-1] for i in range(k)] + [g[-1:]])
    out = _propagate_segments(model, X0, U, P, times, m, rtol, atol, max_steps)
    states = out[:, ::m]
    if single:
        states, out = states[0], out[0]
    if substeps > 0:
        return states, times, out
    return states


def _propagate_segments(model: Model, X0: np.ndarray, U: np.ndarray, P: np.ndarray,
                        times: np.ndarray, m: int, rtol: float, atol: float,
                        max_steps: int) -> np.ndarray:
    """States ``(N, len(times), n_x)`` from ``X0`` under ``U[:, j // m]`` on ``[times[j], times[j+1]]``
    (inputs checked once here, not per segment; see
    :func:`ocreach.native.integrator.propagate_segments`)."""
    from ocreach import parallel
    from ocreach.errors import check_count
    from ocreach.native.integrator import propagate_segments, stepper, tol_vector

    return propagate_segments(stepper(flow_rhs(model)), X0, U, P, times, m,
                              tol_vector(rtol, model.n_x, "rtol"), tol_vector(atol, model.n_x, "atol"),
                              int(check_count("max_steps", max_steps, 1)), parallel.threads())


# --------------------------------------------------------------------------- STT
@dataclass(frozen=True)
class STTResult:
    """Reference and per-segment state-transition tensors (Foss et al. Eq. 13).

    ``states[k]`` is the reference at ``times[k]``; ``phi[j-1][k]`` is ``Phi_k^(j)`` with shape
    ``(n_x,) + (n_z,) * j`` (x-rows of the augmented STT from ``t_k`` to ``t_{k+1}``), so that
    ``delta x(t_{k+1}) = sum_j 1/j! Phi_k^(j) [delta z(t_k)]^j`` with ``z = [x; u]``.
    """

    times: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    phi: tuple[np.ndarray, ...]

    @property
    def order(self) -> int:
        return len(self.phi)

    @property
    def Phi1(self) -> np.ndarray:
        return self.phi[0]

    @property
    def Phi2(self) -> np.ndarray:
        if self.order < 2:
            raise ProblemError(f"Phi2 needs an STT of order >= 2; this one has order {self.order}")
        return self.phi[1]

    @property
    def Phi3(self) -> np.ndarray:
        if self.order < 3:
            raise ProblemError(f"Phi3 needs an STT of order 3; this one has order {self.order}")
        return self.phi[2]

    def predict(self, k: int, dz: np.ndarray) -> np.ndarray:
        """``delta x(t_{k+1})`` from ``delta z(t_k)`` (shape ``(..., n_z)``) by Eq. 13."""
        dz = np.asarray(dz, dtype=float)
        out = np.einsum("ia,...a->...i", self.phi[0][k], dz)
        if self.order >= 2:
            out = out + 0.5 * np.einsum("iab,...a,...b->...i", self.phi[1][k], dz, dz)
        if self.order >= 3:
            out = out + np.einsum("iabc,...a,...b,...c->...i", self.phi[2][k], dz, dz, dz) / 6.0
        return out


def _sym_index(n_z: int, order: int) -> tuple[list[tuple[int, ...]], np.ndarray]:
    """Sorted index tuples ``a <= b (<= c)`` and the map from full to packed positions."""
    tuples = list(itertools.combinations_with_replacement(range(n_z), order))
    pos = {tup: i for i, tup in enumerate(tuples)}
    full = np.empty((n_z,) * order, dtype=np.int64)
    for idx in itertools.product(range(n_z), repeat=order):
        full[idx] = pos[tuple(sorted(idx))]
    return tuples, full


def stt_rhs(model: Model, order: int) -> ca.Function:
    """Right-hand side of the reference + STT equations (Foss et al. Eq. 11, augmented Eq. 12).

    ``y = [x; vec(Phi1_x); packed Phi2_x; packed Phi3_x]`` with ``Phi1_x`` (n_x, n_z) row-major and
    the packed tensors holding, per row ``i``, the entries with sorted lower indices
    (``itertools.combinations_with_replacement`` order).  ``a = [u; p]``.  Cached on the model.
    """
    if order not in (1, 2, 3):
        raise ProblemError(f"order must be 1, 2 or 3; got {order!r}")

    def build():
        nx, nz = model.n_x, model.n_z
        D = model.derivative_expressions(order)
        # f-derivative matrices with rows i and row-major multi-index columns
        F1 = D[0]                                            # (nx, nz)
        F2 = _rowmajor_reshape(D[1], nx, nz * nz) if order >= 2 else None
        F3 = _rowmajor_reshape(D[2], nx, nz ** 3) if order >= 3 else None
        p1 = ca.SX.sym("phi1", nx * nz)
        P1x = _rowmajor_reshape(p1, nx, nz)
        P = ca.vertcat(P1x, ca.horzcat(ca.SX.zeros(model.n_u, nx), ca.SX.eye(model.n_u)))  # (nz, nz)
        syms = [model.x, p1]
        dots = [model.f, _rowmajor_flat(ca.mtimes(F1, P))]
        if order >= 2:
            t2, full2 = _sym_index(nz, 2)
            p2 = ca.SX.sym("phi2", nx * len(t2))
            Q2x = _rowmajor_reshape(p2, nx, len(t2))             # packed (nx, n2)
            Qfull = ca.vertcat(Q2x, ca.SX.zeros(model.n_u, len(t2)))  # rows alpha over z

            def Q(a, b):
                return Qfull[:, int(full2[a, b])]

            cols = [ca.kron(P[:, a], P[:, b]) for a, b in t2]
            d2 = ca.mtimes(F1, Qfull) + ca.mtimes(F2, ca.horzcat(*cols))
            syms.append(p2)
            dots.append(_rowmajor_flat(d2))
        if order >= 3:
            t3, _ = _sym_index(nz, 3)
            p3 = ca.SX.sym("phi3", nx * len(t3))
            R3x = _rowmajor_reshape(p3, nx, len(t3))
            cols2 = [ca.kron(P[:, a], Q(b, c)) + ca.kron(P[:, c], Q(a, b)) + ca.kron(P[:, b], Q(a, c))
                     for a, b, c in t3]
            cols3 = [ca.kron(P[:, a], ca.kron(P[:, b], P[:, c])) for a, b, c in t3]
            d3 = (ca.mtimes(F1[:, :nx], R3x) + ca.mtimes(F2, ca.horzcat(*cols2))
                  + ca.mtimes(F3, ca.horzcat(*cols3)))
            syms.append(p3)
            dots.append(_rowmajor_flat(d3))
        y = ca.vertcat(*syms)
        a = ca.vertcat(model.u, model.p)
        return ca.Function(f"stt{order}_{c_identifier(model.name)}", [y, model.t, a], [ca.vertcat(*dots)],
                           ["y", "t", "a"], ["ydot"], {"cse": True})

    return model.cached(("stt_rhs", order), build)


def _rowmajor_reshape(v: ca.SX, rows: int, cols: int) -> ca.SX:
    """Row-major reshape (NumPy C order) of an SX to ``(rows, cols)``."""
    return ca.reshape(ca.reshape(v.T, -1, 1) if v.size2() > 1 else v, cols, rows).T


def _rowmajor_flat(m: ca.SX) -> ca.SX:
    return ca.reshape(m.T, -1, 1)


def _stt_initial(model: Model, order: int, X: np.ndarray) -> np.ndarray:
    nx, nz = model.n_x, model.n_z
    parts = [X, np.tile(np.eye(nx, nz).ravel(), (X.shape[0], 1))]
    for j in range(2, order + 1):
        nt = len(list(itertools.combinations_with_replacement(range(nz), j)))
        parts.append(np.zeros((X.shape[0], nx * nt)))
    return np.concatenate(parts, axis=1)


def _stt_unpack(model: Model, order: int, Y: np.ndarray) -> list[np.ndarray]:
    nx, nz = model.n_x, model.n_z
    k = Y.shape[0]
    off = nx
    out = [Y[:, off:off + nx * nz].reshape(k, nx, nz)]
    off += nx * nz
    for j in range(2, order + 1):
        tuples, full = _sym_index(nz, j)
        nt = len(tuples)
        packed = Y[:, off:off + nx * nt].reshape(k, nx, nt)
        out.append(packed[:, :, full])  # (k, nx, nz, ..., nz)
        off += nx * nt
    return out


def stt(model: Model, x0: ArrayLike, controls: ArrayLike, grid: ArrayLike, order: int, *,
        p: ArrayLike | None = None, rtol: float = 1e-10,
        atol: float = 1e-12, max_steps: int = 100000) -> STTResult:
    """Reference trajectory and per-segment STTs of orders 1..``order`` (Foss et al. Eq. 11-13).

    ``x0`` (n_x,), ``controls`` (K, n_u), ``grid`` (K+1,).  The reference is propagated first;
    then the K segments (each restarted from the identity at ``t_k``) are integrated as one batch.
    """
    if order not in (1, 2, 3):
        raise ProblemError(f"order must be 1, 2 or 3; got {order!r}")
    g = check_grid(grid)
    x0a = model.validate_state(x0, "x0")
    if x0a.ndim != 1:
        raise ProblemError(f"stt takes one reference state x0 of shape ({model.n_x},); got {x0a.shape}")
    U = _controls(model, controls, g.size - 1, None)
    if U.ndim != 2:
        raise ProblemError(f"stt takes controls of shape (K, n_u); got {U.shape}")
    P = _params(model, p, None)
    states = propagate(model, x0a, U, g, p=P, rtol=rtol, atol=atol, max_steps=max_steps)
    k = g.size - 1
    Y0 = _stt_initial(model, order, states[:-1])
    args = np.concatenate([U, np.broadcast_to(P, (k, model.n_p))], axis=1)
    Y1 = integrate_batch(stt_rhs(model, order), Y0, g[:-1], g[1:], args, rtol=rtol, atol=atol,
                         max_steps=max_steps)
    phi = _stt_unpack(model, order, Y1)
    return STTResult(times=g, states=states, controls=U, phi=tuple(phi))


def stt_polynomial(phi: Sequence[np.ndarray], dz: np.ndarray) -> list[np.ndarray]:
    """Terms ``1/j! Phi^(j)[dz]^j`` (j = 1..n) for samples ``dz`` (N, n_z) (Foss Eq. 13): the
    STT expansion of the flow, ``phi`` as returned by :func:`stt` for one step."""
    out = [dz @ phi[0].T]
    if len(phi) >= 2:
        out.append(0.5 * np.einsum("iab,na,nb->ni", phi[1], dz, dz, optimize=True))
    if len(phi) >= 3:
        out.append(np.einsum("iabc,na,nb,nc->ni", phi[2], dz, dz, dz, optimize=True) / 6.0)
    return out


def _batch_values(name: str, value: ArrayLike, n: int, size: int | None = None) -> np.ndarray:
    """``value`` (a number or ``n`` numbers; exactly ``size`` if given) as a float array of length
    ``n``; a clear :class:`ProblemError` naming ``name`` otherwise."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ProblemError(f"{name} must be numbers; got {value!r}") from None
    allowed = (size,) if size is not None else (1, n)
    if arr.ndim > 1 or arr.size not in allowed:
        what = f"{size} numbers" if size is not None else f"a number or {n} numbers (one per arc)"
        raise ProblemError(f"{name} must be {what}; got shape {arr.shape}")
    return np.broadcast_to(arr.reshape(-1), (n,)).copy()


def stm_batch(model: Model, X0: ArrayLike, t0: ArrayLike, t1: ArrayLike, u: ArrayLike | None = None,
              *, p: ArrayLike | None = None, rtol: float = 1e-10, atol: float = 1e-12,
              max_steps: int = 100000) -> tuple[np.ndarray, np.ndarray]:
    """States and state-transition matrices of ``N`` independent arcs, integrated as one batch.

    Arc ``i`` starts from ``X0[i]`` at ``t0[i]`` and ends at ``t1[i]`` (scalars broadcast) under a
    constant control ``u`` (default 0).  The STM comes from the model's variational equation
    ``dPhi/dt = f_x Phi`` (:func:`stt_rhs` order 1).  Returns ``(X1 (N, n_x), Phi (N, n_x, n_x))``.
    The arcs of a multiple-shooting correction, for instance.
    """
    X = model.validate_state(X0, "X0")
    if X.ndim != 2:
        raise ProblemError(f"X0 must have shape (N, {model.n_x}); got {X.shape}")
    n = X.shape[0]
    u = np.zeros(model.n_u) if u is None else _batch_values("u", u, model.n_u, model.n_u)
    P = np.broadcast_to(_params(model, p, None), (n, model.n_p))
    args = np.concatenate([np.broadcast_to(u, (n, model.n_u)), P], axis=1)
    Y1 = integrate_batch(stt_rhs(model, 1), _stt_initial(model, 1, X),
                         _batch_values("t0", t0, n), _batch_values("t1", t1, n), args,
                         rtol=rtol, atol=atol, max_steps=max_steps)
    return Y1[:, :model.n_x], _stt_unpack(model, 1, Y1)[0][:, :, :model.n_x]


def stm(model: Model, x0: ArrayLike, t0: float, t1: float, u: ArrayLike | None = None, *,
        p: ArrayLike | None = None, rtol: float = 1e-10,
        atol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """State and state-transition matrix ``(x(t1), dx(t1)/dx(t0))`` under a constant control."""
    u = np.zeros(model.n_u) if u is None else np.asarray(u, dtype=float).reshape(model.n_u)
    res = stt(model, x0, u[None, :], [t0, t1], 1, p=p, rtol=rtol, atol=atol)
    return res.states[-1], res.phi[0][0][:, :model.n_x]
