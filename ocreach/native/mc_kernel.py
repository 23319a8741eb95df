"""Fused C kernel of the stochastic Monte Carlo (Jain et al. Eq. 1): the Euler step of every
sample and the per-step sample mean and std over a block of steps, one C call per block.

The step is the CasADi-generated ``SplitStepMap.step`` of :mod:`ocreach.dynamics.stochastic_mc`, which
is also the per-step fallback without a C compiler (same numbers).
"""
from __future__ import annotations

import ctypes
import warnings

import casadi as ca
import numpy as np

from ocreach.errors import SolverError
from ocreach.native.codegen import C_WORK, generate_c
from ocreach.native.compile import COMPILE_ERRORS, compile_source, jit_enabled, load_library

__all__ = ["MCKernel", "mc_kernel"]


_MC_C = """
#include <math.h>
#include <stdlib.h>
#include <string.h>
/* Steps k0..k1-1 of the Monte Carlo for N samples X (N x n, updated in place) with controls
   u = unom[k] + Lu z, z from Z ((k1-k0) x N x m standard normals); after every step the sample mean and std (ddof 1, two-pass) go to row k+1
   of gmean/gstd.  Returns 0, 1 (non-finite sample at step fail[0]) or -1/2 (memory/evaluation). */
CASADI_SYMBOL_EXPORT int ocr_mc_run(long N, long n, long m, long k0, long k1, const double* grid,
                                    const double* Z, const double* unom, const double* Lu,
                                    const double* p, double* X, double* gmean, double* gstd,
                                    long* fail) {
  OCR_WORK_ALLOC(7, 2)
  double* xn = (double*)malloc(sizeof(double) * n);
  double* u = (double*)malloc(sizeof(double) * (m + 1));
  int flag = 0;
  if (!arg || !res || !iw || !wk || !xn || !u) flag = -1;
  for (long k = k0; k < k1 && !flag; ++k) {
    double t = grid[k], dt = grid[k + 1] - grid[k];
    const double* Zk = Z + (k - k0) * N * m;
    for (long s = 0; s < N; ++s) {
      double* x = X + s * n;
      const double* z = Zk + s * m;
      for (long i = 0; i < m; ++i) {
        double v = unom[k * m + i];
        for (long j = 0; j < m; ++j) v += Lu[i * m + j] * z[j];
        u[i] = v;
      }
      arg[0] = x; arg[1] = u; arg[2] = &t; arg[3] = &dt; arg[4] = p; arg[5] = p;
      res[0] = xn;
      if (OCR_FUN(arg, res, iw, wk, 0)) { flag = 2; fail[0] = k + 1; break; }
      int ok = 1;
      for (long a = 0; a < n; ++a) { x[a] = xn[a]; ok &= isfinite(xn[a]) ? 1 : 0; }
      if (!ok) { flag = 1; fail[0] = k + 1; }
    }
    if (flag) break;
    double* mu = gmean + (k + 1) * n;
    double* sd = gstd + (k + 1) * n;
    for (long a = 0; a < n; ++a) { mu[a] = 0.0; sd[a] = 0.0; }
    for (long s = 0; s < N; ++s)
      for (long a = 0; a < n; ++a) mu[a] += X[s * n + a];
    for (long a = 0; a < n; ++a) mu[a] /= (double)N;
    for (long s = 0; s < N; ++s)
      for (long a = 0; a < n; ++a) { double d = X[s * n + a] - mu[a]; sd[a] += d * d; }
    for (long a = 0; a < n; ++a) sd[a] = sqrt(sd[a] / (double)(N - 1));
  }
  OCR_WORK_FREE free(xn); free(u);
  return flag;
}
"""


class MCKernel:
    """Compiled Monte Carlo run over a block of steps: the Euler step of every sample (the same
    CasADi-generated step as :meth:`SplitStepMap.step`) and the per-step sample mean and std, with
    no Python work per step (the peer of the ``cut`` kernel, so the benchmark ratio is fair)."""

    def __init__(self, fun: ca.Function):
        main = (f"#define OCR_FUN {fun.name()}\n#define OCR_FUN_work {fun.name()}_work\n"
                "#include \"gen.c\"\n#include \"work.h\"\n#include \"mc.c\"\n").encode()
        sources = {"gen.c": generate_c([fun]), "work.h": C_WORK.encode(), "mc.c": _MC_C.encode(),
                   "main.c": main}
        lib = compile_source(f"ocr_mc_{fun.name()}", sources, "main.c", ("-O2",))
        self._dll = load_library(lib)
        self._fn = self._dll.ocr_mc_run
        self._fn.restype = ctypes.c_int

    def run(self, k0: int, k1: int, grid: np.ndarray, Z: np.ndarray, u_nom: np.ndarray,
            Lu: np.ndarray, p: np.ndarray, X: np.ndarray, gmean: np.ndarray, gstd: np.ndarray) -> int:
        """Advance ``X`` (C-contiguous, in place) over steps ``k0..k1-1`` with controls
        ``u_nom[k] + Lu z`` (``Z`` the block's standard normals); returns the step at which a
        sample became non-finite, or -1."""
        N, n = X.shape
        fail = np.zeros(1, dtype=np.int64)
        grid = np.ascontiguousarray(grid, dtype=float)
        p = np.ascontiguousarray(p, dtype=float)
        u_nom = np.ascontiguousarray(u_nom, dtype=float)
        Lu = np.ascontiguousarray(Lu, dtype=float)
        L = ctypes.c_long
        ptr = [a.ctypes.data_as(ctypes.c_void_p) for a in (grid, Z, u_nom, Lu, p, X, gmean, gstd, fail)]
        flag = self._fn(L(N), L(n), L(Z.shape[-1]), L(k0), L(k1), *ptr)
        if flag == 1:
            return int(fail[0])
        if flag != 0:
            raise SolverError(f"stochastic_monte_carlo: the compiled step failed (flag {flag}, "
                              f"step {int(fail[0])})")
        return -1


def mc_kernel(sm) -> MCKernel | None:
    def build() -> MCKernel | None:
        if not jit_enabled():
            return None
        try:
            return MCKernel(sm._step().fun)
        except COMPILE_ERRORS as exc:  # no compiler: the per-step batched path, same numbers
            warnings.warn(f"ocreach.native: compiling the Monte Carlo kernel failed "
                          f"({exc}); using the per-step path (slower)", RuntimeWarning, stacklevel=4)
            return None

    return sm.cached("mc_kernel", build)
