"""Fused C kernel of the ``cut`` moment recursion (Jain et al. Eq. 6, 9-15), whole horizon per call.

One generated C function runs all ``K`` steps of the mean/covariance recursion of
:func:`ocreach.reach.cut.propagate_moments` (which is the reference implementation and the
fallback without a C compiler; both give the same numbers to round-off):

per step ``k``: square root ``L`` of ``P_k`` (semidefinite Cholesky, dependency states first),
state points ``x_i = m_k + L[:, :n_y] xi_i``, one call of the CasADi-generated point function
``(x, t, dt, p, E[h], C_h) -> (mu(x) = x + dt f0 + dt G E[h], q(x) = G_d C_h G_d^T)`` per point
(``G_d = dt G``), and the weighted
sums ``m_{k+1} = sum w_i mu_i``, ``P_{k+1} = sum w_i (y_i y_i^T + q_i) + R`` with
``y_i = mu_i - m_{k+1}`` and ``R`` the covariance of the states the step does not depend on, given
the ones it does (see ``reduce`` in :mod:`ocreach.reach.cut`).  The control moments ``E[h]``,
``C_h`` of every step are computed beforehand in one batched call.  No Python work per step.
"""
from __future__ import annotations

import ctypes
import warnings

import casadi as ca
import numpy as np

from ocreach.errors import SolverError
from ocreach.native.codegen import C_WORK, c_identifier, generate_c
from ocreach.native.compile import COMPILE_ERRORS, compile_source, jit_enabled, load_library

__all__ = ["CUTKernel", "cut_kernel", "point_function"]

_KERNEL_C = r"""
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Semidefinite Cholesky P = L L^T (lower, row-major n x n): a pivot whose remaining variance is
   <= 1e-12 of the state's own variance gets a zero column (the state is, to that precision, an
   affine function of the earlier ones).  Returns the failing row + 1 if P is indefinite/not finite. */
static long ocr_psd_chol(const double* P, double* L, long n) {
  memset(L, 0, sizeof(double) * n * n);
  for (long j = 0; j < n; ++j) {
    double pjj = P[j * n + j];
    double d = pjj;
    for (long m = 0; m < j; ++m) d -= L[j * n + m] * L[j * n + m];
    if (!(pjj >= 0.0) || !isfinite(d)) return j + 1;
    if (d <= 1e-12 * pjj) {
      if (d < -1e-8 * pjj) return j + 1;
      continue;
    }
    double ljj = sqrt(d);
    L[j * n + j] = ljj;
    for (long i = j + 1; i < n; ++i) {
      double s = P[i * n + j];
      for (long m = 0; m < j; ++m) s -= L[i * n + m] * L[j * n + m];
      L[i * n + j] = s / ljj;
    }
  }
  return 0;
}

/* Returns 0, or: 1 = covariance indefinite at step fail[0], 2 = non-finite moments at step
   fail[0], 3 = point function failed, -1 = out of memory. */
CASADI_SYMBOL_EXPORT int ocr_cut_run(long K, long n, long r, long M, long ny, const long* perm,
                                     const double* grid, const double* xi, const double* w,
                                     const double* Eh, const double* Ch, const double* p,
                                     double* mean, double* cov, long* fail) {
  OCR_WORK_ALLOC(7, 3)
  double* Pp = (double*)malloc(sizeof(double) * n * n);
  double* L = (double*)malloc(sizeof(double) * n * n);
  double* X = (double*)malloc(sizeof(double) * n);
  long nq = n * (n + 1) / 2;
  double* MU = (double*)malloc(sizeof(double) * M * n);
  double* QQ = (double*)malloc(sizeof(double) * M * nq);
  double* Y = (double*)malloc(sizeof(double) * n);
  int flag = 0;
  if (!arg || !res || !iw || !wk || !Pp || !L || !X || !MU || !QQ || !Y) { flag = -1; goto done; }
  for (long k = 0; k < K && !flag; ++k) {
    const double* m = mean + k * n;
    const double* P = cov + k * n * n;
    for (long a = 0; a < n; ++a)
      for (long b = 0; b < n; ++b) Pp[a * n + b] = P[perm[a] * n + perm[b]];
    if (ocr_psd_chol(Pp, L, n)) { flag = 1; fail[0] = k; break; }
    double t = grid[k], dt = grid[k + 1] - grid[k];
    const double* eh = Eh + k * r;
    const double* ch = Ch + k * r * r;
    for (long i = 0; i < M; ++i) {
      const double* z = xi + i * ny;
      for (long a = 0; a < n; ++a) {
        double s = m[perm[a]];
        long top = a < ny ? a + 1 : ny;
        for (long j = 0; j < top; ++j) s += L[a * n + j] * z[j];
        X[perm[a]] = s;
      }
      arg[0] = X; arg[1] = &t; arg[2] = &dt; arg[3] = p; arg[4] = eh; arg[5] = ch;
      res[0] = MU + i * n; res[1] = QQ + i * nq;
      if (OCR_FUN(arg, res, iw, wk, 0)) { flag = 3; fail[0] = k; break; }
    }
    if (flag) break;
    double* mn = mean + (k + 1) * n;
    double* Pn = cov + (k + 1) * n * n;
    memset(mn, 0, sizeof(double) * n);
    memset(Pn, 0, sizeof(double) * n * n);
    for (long i = 0; i < M; ++i)
      for (long a = 0; a < n; ++a) mn[a] += w[i] * MU[i * n + a];
    for (long i = 0; i < M; ++i) {
      const double* mu = MU + i * n;
      const double* qq = QQ + i * nq;
      double wi = w[i];
      for (long a = 0; a < n; ++a) Y[a] = mu[a] - mn[a];
      for (long a = 0, e = 0; a < n; ++a)
        for (long b = 0; b <= a; ++b, ++e) Pn[a * n + b] += wi * (Y[a] * Y[b] + qq[e]);
    }
    /* covariance of the states the step does not depend on, given those it does (identity map) */
    for (long a = ny; a < n; ++a)
      for (long b = ny; b <= a; ++b) {
        double s = 0.0;
        for (long j = ny; j <= b; ++j) s += L[a * n + j] * L[b * n + j];
        long A = perm[a], B = perm[b];
        if (A >= B) Pn[A * n + B] += s; else Pn[B * n + A] += s;
      }
    for (long a = 0; a < n; ++a)
      for (long b = 0; b < a; ++b) Pn[b * n + a] = Pn[a * n + b];
    for (long a = 0; a < n * n && !flag; ++a)
      if (!isfinite(Pn[a]) || (a < n && !isfinite(mn[a]))) { flag = 2; fail[0] = k + 1; }
  }
done:
  OCR_WORK_FREE free(Pp); free(L); free(X); free(MU); free(QQ);
  free(Y);
  return flag;
}
"""


def point_function(sm) -> ca.Function:
    """``(x, t, dt, p, E[h], C_h) -> (mu, q)``: the conditional mean ``x + dt f0 + dt G E[h]`` of
    the Euler step (Jain et al. Eq. 1, 6) and the lower triangle (row by row) of the conditional
    covariance ``G_d C_h G_d^T`` with ``G_d = dt G`` (Eq. 9, 14-15), for a SplitStepMap ``sm``.
    Built symbolically, so the structural zeros of ``G`` cost nothing."""
    n, r = sm.n_x, sm.n_h
    x = ca.SX.sym("x", n)
    t, dt = ca.SX.sym("t"), ca.SX.sym("dt")
    p = ca.SX.sym("p", sm.f0.size1_in(2))
    eh = ca.SX.sym("eh", r)
    ch = ca.SX.sym("ch", r, r)
    G = sm.G(x, t, p)
    mu = x + dt * (sm.f0(x, t, p) + ca.mtimes(G, eh))
    Gd = dt * G
    Q = ca.mtimes(ca.mtimes(Gd, ch.T), Gd.T)  # ch is row-major in the kernel: pass its transpose
    q = ca.vertcat(*[Q[a, b] for a in range(n) for b in range(a + 1)])
    return ca.Function(f"cut_pt_{c_identifier(sm.name)}", [x, t, dt, p, eh, ch],
                       [ca.densify(mu), ca.densify(q)])


class CUTKernel:
    """Compiled whole-horizon mean/covariance recursion for one SplitStepMap (built once, cached
    with ``sm`` (:meth:`SplitStepMap.cached`); the shared library is cached on disk by :mod:`ocreach.native.compile`)."""

    def __init__(self, sm):
        fun = point_function(sm)
        main = (f"#define OCR_FUN {fun.name()}\n#define OCR_FUN_work {fun.name()}_work\n"
                "#include \"gen.c\"\n#include \"work.h\"\n#include \"kernel.c\"\n").encode()
        sources = {"gen.c": generate_c([fun]), "work.h": C_WORK.encode(),
                   "kernel.c": _KERNEL_C.encode(), "main.c": main}
        lib = compile_source(f"ocr_cut_{fun.name()}", sources, "main.c", ("-O2",))
        self._dll = load_library(lib)
        self._fn = self._dll.ocr_cut_run
        self._fn.restype = ctypes.c_int
        self.sm = sm

    def run(self, grid: np.ndarray, mean0: np.ndarray, cov0: np.ndarray, xi: np.ndarray,
            w: np.ndarray, perm: np.ndarray, Eh: np.ndarray, Ch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Means ``(K+1, n)`` and covariances ``(K+1, n, n)`` on ``grid`` (see module docstring).

        ``xi (M, n_y)``, ``w (M,)`` the standard-normal rule of the dependency states ``perm[:n_y]``;
        ``Eh (K, r)``, ``Ch (K, r, r)`` the control moments per step.
        """
        sm = self.sm
        K, n, r = grid.size - 1, sm.n_x, sm.n_h
        M, ny = xi.shape
        mean = np.zeros((K + 1, n))
        cov = np.zeros((K + 1, n, n))
        mean[0], cov[0] = mean0, cov0
        c = np.ascontiguousarray
        arrs = [c(perm, dtype=np.int64), c(grid, dtype=float), c(xi, dtype=float), c(w, dtype=float),
                c(Eh, dtype=float), c(Ch, dtype=float), c(sm.p, dtype=float)]
        fail = np.zeros(1, dtype=np.int64)
        L = ctypes.c_long
        ptr = [a.ctypes.data_as(ctypes.c_void_p) for a in arrs + [mean, cov, fail]]
        flag = self._fn(L(K), L(n), L(r), L(M), L(ny), *ptr)
        k = int(fail[0])
        if flag == 1:
            raise SolverError(f"cut: the propagated covariance at step {k} (t = {grid[k]:g}) is "
                              "indefinite or not finite; the rule has negative weights or the "
                              "dynamics produced non-finite values")
        if flag == 2:
            raise SolverError(f"cut: non-finite moments at t = {grid[k]:g} (step {k})")
        if flag != 0:
            raise SolverError(f"cut: the compiled moment kernel failed (flag {flag}, step {k})")
        return mean, cov


def cut_kernel(sm) -> CUTKernel | None:
    """The cached :class:`CUTKernel` of ``sm``, or ``None`` if C compilation is disabled or fails
    (then :func:`ocreach.reach.cut.propagate_moments` in NumPy gives the same numbers)."""
    def build() -> CUTKernel | None:
        if not jit_enabled():
            return None
        try:
            return CUTKernel(sm)
        except COMPILE_ERRORS as exc:  # no compiler: NumPy path, same numbers
            warnings.warn(f"ocreach.reach.cut: compiling the moment kernel failed ({exc}); "
                          "using NumPy (slower)", RuntimeWarning, stacklevel=4)
            return None

    return sm.cached("cut_kernel", build)
