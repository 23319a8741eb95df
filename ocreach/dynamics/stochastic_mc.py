"""Stochastic discrete-time systems ``x_{k+1} = f(x_k) + G(x_k) h(u_k)`` and their Monte Carlo.

Jain et al. Eq. 1: the state ``x_k`` is a random vector (Gaussian at ``k = 0``, Eq. 24-27) and the
control ``u_k`` is drawn afresh from a Gaussian about a nominal profile at every step, independent
of ``x_k``.  This module holds

* :class:`SplitStepMap` - the split ``f(x, u) = f0(x, t) + G(x, t) hu(u)`` of a continuous model as
  CasADi Functions, and the forward-Euler step ``x + dt f0 + dt G hu`` that keeps it (the
  discretisation of Jain et al. Eq. 21-23);
* :func:`step_map_for` - the map of a problem (``problem.extra["step_map"]`` or, for a
  control-affine model, ``hu(u) = u`` and ``G = df/du``);
* :func:`psd_factor` - a checked square root of a covariance (raises :class:`ProblemError`);
* :func:`stochastic_monte_carlo` - the paper's ground truth: ``samples`` initial states and fresh
  control samples at every step, vectorised over samples (one batched map call per step).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError, SolverError, check_count
from ocreach.native.batch_eval import BatchFunction
from ocreach.native.codegen import c_identifier
from ocreach.native.mc_kernel import mc_kernel

STEPS = ("euler", "flow")


# =============================================================================== covariances
def psd_factor(name: str, P: Any, n: int) -> np.ndarray:
    """``L`` with ``L L^T = P`` for a symmetric positive semi-definite ``(n, n)`` covariance ``P``.

    Uses the eigen-decomposition, so singular covariances (Jain et al. Eq. 25 and 27 have zero
    variances) are allowed.  Raises :class:`ProblemError` naming ``name`` if ``P`` has the wrong
    shape, is not finite, not symmetric or has an eigenvalue below ``-1e-10 * max|eig|``.
    """
    arr = np.asarray(P, dtype=float)
    if arr.shape != (n, n):
        raise ProblemError(f"{name} must be a ({n}, {n}) covariance matrix; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ProblemError(f"{name} must be finite; got {arr!r}")
    scale = float(np.abs(arr).max(initial=0.0))
    if not np.allclose(arr, arr.T, rtol=1e-10, atol=1e-12 * max(scale, 1e-300)):
        raise ProblemError(f"{name} must be symmetric; max |P - P^T| = {np.abs(arr - arr.T).max():.3g}")
    w, V = np.linalg.eigh(0.5 * (arr + arr.T))
    if w.size and w.min() < -1e-10 * max(scale, 1e-300):
        raise ProblemError(f"{name} must be positive semidefinite; its smallest eigenvalue is "
                           f"{w.min():.6g} (largest {w.max():.6g})")
    return V * np.sqrt(np.clip(w, 0.0, None))[None, :]


# =============================================================================== step map
@dataclass(eq=False)
class SplitStepMap:
    """``f(x, u, t) = f0(x, t) + G(x, t) hu(u)`` and its Euler step (Jain et al. Eq. 1, 21-23).

    ``f0(x, t, p) -> (n,)``, ``G(x, t, p) -> (n, r)``, ``hu(u, p) -> (r,)`` are CasADi Functions;
    ``p`` the numeric parameters.  Batched evaluation maps them over columns (cached per size).
    """

    f0: ca.Function
    G: ca.Function
    hu: ca.Function
    p: np.ndarray
    name: str = ""
    _maps: dict = field(default_factory=dict, repr=False)

    @property
    def n_x(self) -> int:
        return self.f0.size1_in(0)

    @property
    def n_u(self) -> int:
        return self.hu.size1_in(0)

    @property
    def n_h(self) -> int:
        return self.hu.size1_out(0)

    def cached(self, key: Any, build: Callable[[], Any]) -> Any:
        """``build()`` computed once per ``key`` and kept with this map (compiled kernels of
        :mod:`ocreach.native` live as long as the map)."""
        if key not in self._maps:
            self._maps[key] = build()
        return self._maps[key]

    def _fx(self) -> BatchFunction:
        if "fx" not in self._maps:
            x = ca.SX.sym("x", self.n_x)
            t = ca.SX.sym("t")
            p = ca.SX.sym("p", self.f0.size1_in(2))
            G = self.G(x, t, p)
            fun = ca.Function(f"split_fx_{c_identifier(self.name)}", [x, t, p],
                              [ca.densify(self.f0(x, t, p)), ca.densify(ca.reshape(G.T, -1, 1))])
            self._maps["fx"] = BatchFunction(fun, batched=(True, False, False))
        return self._maps["fx"]

    def _hu(self) -> BatchFunction:
        if "hu" not in self._maps:
            u = ca.SX.sym("u", self.n_u)
            p = ca.SX.sym("p", self.hu.size1_in(1))
            fun = ca.Function(f"split_hu_{c_identifier(self.name)}", [u, p], [ca.densify(self.hu(u, p))])
            self._maps["hu"] = BatchFunction(fun, batched=(True, False))
        return self._maps["hu"]

    def drift_gain(self, X: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """``f0(X)`` of shape ``(N, n)`` and ``G(X)`` of shape ``(N, n, r)`` for states ``X (N, n)``."""
        X = np.asarray(X, dtype=float)
        F, G = self._fx()(X, np.array([t], dtype=float), self.p)
        return F, G.reshape(X.shape[0], self.n_x, self.n_h)

    def control(self, U: np.ndarray) -> np.ndarray:
        """``hu(U)`` of shape ``(M, r)`` for controls ``U (M, m)``."""
        (H,) = self._hu()(np.asarray(U, dtype=float), self.p)
        return H

    def _step(self) -> BatchFunction:
        if "step" not in self._maps:
            x = ca.SX.sym("x", self.n_x)
            u = ca.SX.sym("u", self.n_u)
            t = ca.SX.sym("t")
            dt = ca.SX.sym("dt")
            p = ca.SX.sym("p", self.f0.size1_in(2))
            pu = ca.SX.sym("pu", self.hu.size1_in(1))
            xn = x + dt * (self.f0(x, t, p) + ca.mtimes(self.G(x, t, p), self.hu(u, pu)))
            fun = ca.Function(f"split_step_{c_identifier(self.name)}", [x, u, t, dt, p, pu], [ca.densify(xn)])
            self._maps["step"] = BatchFunction(fun, batched=(True, True, False, False, False, False))
        return self._maps["step"]

    def step(self, X: np.ndarray, U: np.ndarray, dt: float, t: float = 0.0) -> np.ndarray:
        """Euler step ``X + dt (f0(X) + G(X) hu(U))`` for paired rows of ``X (N, n)``, ``U (N, m)``
        (Jain et al. Eq. 21-23, corrected; one compiled call for the whole batch)."""
        (Xn,) = self._step()(np.asarray(X, dtype=float), np.asarray(U, dtype=float),
                             np.array([t], dtype=float), np.array([dt], dtype=float), self.p, self.p)
        return Xn


def step_map_for(problem) -> SplitStepMap:
    """The split map of ``problem``: ``problem.extra["step_map"]`` if present (e.g. re-entry,
    whose controls enter through ``hu(u) = [c_D, c_L cos, c_L sin]``), else ``hu(u) = u``,
    ``G = df/du``, ``f0 = f(x, 0, t)`` for a control-affine model."""
    sm = problem.extra.get("step_map") if problem.extra else None
    if sm is not None:
        if not isinstance(sm, SplitStepMap):
            raise ProblemError(f"problem.extra['step_map'] must be a SplitStepMap; got {type(sm).__name__}")
        return sm
    model = problem.model
    if not model.control_affine:
        raise ProblemError(f"model {model.name} is not control-affine and problem {problem.id!r} has "
                           "no extra['step_map']; give a SplitStepMap f0, G, hu")

    def split() -> tuple[ca.Function, ca.Function, ca.Function]:
        u0 = ca.DM.zeros(model.n_u)
        f0 = ca.substitute(model.f, model.u, u0)
        G = ca.substitute(ca.jacobian(model.f, model.u), model.u, u0)
        return (ca.Function("affine_f0", [model.x, model.t, model.p], [f0]),
                ca.Function("affine_G", [model.x, model.t, model.p], [G]),
                ca.Function("affine_hu", [model.u, model.p], [model.u + 0 * ca.sum1(model.p)]))

    # one map per parameter vector, so its batched Functions and compiled kernels are built once
    params = np.asarray(problem.params, dtype=float)
    return model.cached(("split_affine_map", params.tobytes()), lambda: SplitStepMap(
        *model.cached(("split_affine",), split), params.copy(), name=model.name))


# =============================================================================== Monte Carlo
def stochastic_spec(problem):
    """``problem.stochastic`` validated: shapes, finiteness, PSD covariances (clear errors)."""
    spec = problem.stochastic
    if spec is None:
        raise ProblemError(f"problem {problem.id!r} has no stochastic specification "
                           "(problem.stochastic = StochasticSpec(...)) needed by this method")
    n, m, K = problem.model.n_x, problem.model.n_u, problem.n_segments
    mean = np.asarray(spec.x0_mean, dtype=float)
    if mean.shape != (n,) or not np.all(np.isfinite(mean)):
        raise ProblemError(f"stochastic.x0_mean must be a finite vector of length {n}; got {mean!r}")
    u_nom = np.asarray(spec.u_nominal, dtype=float)
    if u_nom.shape != (K, m) or not np.all(np.isfinite(u_nom)):
        raise ProblemError(f"stochastic.u_nominal must be finite with shape (K, n_u) = ({K}, {m}); "
                           f"got shape {u_nom.shape}")
    Lx = psd_factor("stochastic.x0_cov", spec.x0_cov, n)
    Lu = psd_factor("stochastic.u_cov", spec.u_cov, m)
    return mean, Lx, u_nom, Lu


def _raise_nonfinite(X: np.ndarray, samples: int, grid: np.ndarray, k: int) -> None:
    bad = np.flatnonzero(~np.all(np.isfinite(X), axis=1))
    raise SolverError(f"stochastic_monte_carlo: {bad.size} of {samples} samples became "
                      f"non-finite at t = {grid[k]:g} (step {k}); first {bad[:10].tolist()}")


def time_indices(grid: np.ndarray, times: Sequence[float] | str | None) -> np.ndarray:
    """Grid indices of ``times`` (each must be a grid time to 1e-9 relative); ``"all"``: every
    grid index; ``None``: the final one."""
    if isinstance(times, str):
        if times != "all":
            raise ProblemError(f"times must be grid times, None (the final time) or 'all'; got {times!r}")
        return np.arange(grid.size)
    if times is None:
        return np.array([grid.size - 1])
    t = np.atleast_1d(np.asarray(times, dtype=float))
    span = max(abs(grid[-1] - grid[0]), 1e-300)
    idx = np.abs(grid[None, :] - t[:, None]).argmin(axis=1)
    bad = np.abs(grid[idx] - t) > 1e-9 * span
    if bad.any():
        raise ProblemError(f"times must be times of the problem grid ({grid[0]:g} .. {grid[-1]:g}, "
                           f"{grid.size} points); not on it: {t[bad].tolist()}")
    return idx


#: bound on the standard normals drawn at once (doubles): the Monte Carlo's working memory is
#: O(samples * n) plus this, whatever the horizon
_DRAW_BLOCK = 1 << 21


def stochastic_monte_carlo(problem, samples: int = 10000, seed: int = 0,
                           times: Sequence[float] | str | None = None, *, step: str = "euler",
                           keep_controls: bool = False, rtol: float = 1e-8,
                           atol: float = 1e-10) -> dict[str, Any]:
    """Monte Carlo of Jain et al.'s stochastic system (their ground truth, 10,000 samples).

    ``samples`` initial states from ``N(x0_mean, x0_cov)``; at every step ``k`` fresh controls
    ``u_k ~ N(u_nominal[k], u_cov)`` per sample.  ``step="euler"`` uses the split Euler map of
    :func:`step_map_for` (the system the ``cut`` method propagates); ``step="flow"`` integrates the
    continuous model over each segment with :func:`ocreach.dynamics.flow.integrate_batch` (DOP853, ``rtol``,
    ``atol``) to measure the discretisation error.  Vectorised over samples.

    Only what is asked for is kept: the sample mean and std at every grid time (``grid_mean``,
    ``grid_std``, (K+1, n)), the samples at ``times`` (default ``None``: the final time only; a
    list of grid times; ``"all"`` for full state histories) and the sampled controls only with
    ``keep_controls``.  Memory is ``samples * (T n + [K m]) * 8`` bytes for what is kept plus
    O(samples * n) working memory (the normals are drawn in blocks of at most ~16 MB; the random
    stream is the same as one ``(samples, m)`` draw per step).

    Returns a dict: ``times`` (T,), ``index`` (grid indices), ``mean``, ``std`` (T, n) at
    ``times``, ``trajectories`` (samples, T, n), ``grid_mean``, ``grid_std``, ``samples``,
    ``seed``, ``step``, and ``controls`` (samples, K, n_u) if ``keep_controls``.
    Raises :class:`SolverError` if a sample becomes non-finite.
    """
    samples = check_count("samples", samples, 2)
    if step not in STEPS:
        raise ProblemError(f"step must be one of {STEPS}; got {step!r}")
    samples = int(samples)
    grid = problem.grid
    mean0, Lx, u_nom, Lu = stochastic_spec(problem)
    idx = time_indices(grid, times)
    rng = np.random.default_rng(seed)
    n, m, K = problem.model.n_x, problem.model.n_u, problem.n_segments

    X = mean0 + rng.standard_normal((samples, n)) @ Lx.T
    out_traj = np.empty((samples, idx.size, n))
    where = {int(k): j for j, k in enumerate(idx)}
    grid_mean = np.empty((K + 1, n))
    grid_std = np.empty((K + 1, n))
    controls = np.empty((samples, K, m)) if keep_controls else None

    if step == "euler":
        sm = step_map_for(problem)
    else:
        from ocreach.dynamics.flow import flow_rhs, integrate_batch

        rhs = flow_rhs(problem.model)
        P = np.broadcast_to(problem.params, (samples, problem.model.n_p))

    def record(k: int, X: np.ndarray) -> None:
        grid_mean[k] = X.mean(axis=0)
        grid_std[k] = X.std(axis=0, ddof=1)
        if k in where:
            out_traj[:, where[k]] = X

    record(0, X)
    kern = mc_kernel(sm) if step == "euler" else None
    if kern is not None:
        # blocks of <= 64 steps (fewer for large batches) ending at every recorded index: one C
        # call per block, controls drawn per block (the same random stream as one (samples, m)
        # draw per step)
        X = np.ascontiguousarray(X)
        block = int(max(1, min(64, _DRAW_BLOCK // max(1, samples * m))))
        stops = sorted(set(range(block, K, block)) | {int(k) for k in idx if 0 < k < K} | {K})
        k0 = 0
        for k1 in stops:
            Z = rng.standard_normal((k1 - k0, samples, m))
            if keep_controls:
                controls[:, k0:k1] = (u_nom[k0:k1, None, :] + Z @ Lu.T).transpose(1, 0, 2)
            bad_k = kern.run(k0, k1, grid, Z, u_nom, Lu, sm.p, X, grid_mean, grid_std)
            if bad_k >= 0:
                _raise_nonfinite(X, samples, grid, bad_k)
            if k1 in where:
                out_traj[:, where[k1]] = X
            k0 = k1
        K_done = K
    else:
        K_done = 0
    for k in range(K_done, K):
        U = u_nom[k] + rng.standard_normal((samples, m)) @ Lu.T
        if keep_controls:
            controls[:, k] = U
        dt = grid[k + 1] - grid[k]
        if step == "euler":
            X = sm.step(X, U, dt, grid[k])
        else:
            X = integrate_batch(rhs, X, grid[k], grid[k + 1], np.concatenate([U, P], axis=1),
                                rtol=rtol, atol=atol)
        if not np.all(np.isfinite(X)):
            _raise_nonfinite(X, samples, grid, k + 1)
        record(k + 1, X)

    out = {"times": grid[idx], "index": idx, "mean": grid_mean[idx], "std": grid_std[idx],
           "trajectories": out_traj, "grid_mean": grid_mean, "grid_std": grid_std,
           "samples": samples, "seed": seed, "step": step}
    if keep_controls:
        out["controls"] = controls
    return out
