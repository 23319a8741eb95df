"""Row-wise evaluation of a CasADi Function over a batch of samples, in one C call."""
from __future__ import annotations

import ctypes
import warnings

import casadi as ca
import numpy as np

from ocreach.errors import SolverError
from ocreach.native.codegen import C_WORK, generate_c
from ocreach.native.compile import COMPILE_ERRORS, compile_source, jit_enabled, load_library

__all__ = ["BatchFunction"]

_BATCH_C = """
#include <stdlib.h>
CASADI_SYMBOL_EXPORT int ocr_batch(long N, long n_in, const double** in, const long* in_stride,
                                   long n_out, double** out, const long* out_stride) {
  OCR_WORK_ALLOC(n_in + 1, n_out + 1)
  if (!arg || !res || !iw || !wk) { OCR_WORK_FREE return -1; }
  int flag = 0;
  for (long s = 0; s < N && !flag; ++s) {
    for (long i = 0; i < n_in; ++i) arg[i] = in[i] + s * in_stride[i];
    for (long j = 0; j < n_out; ++j) res[j] = out[j] + s * out_stride[j];
    flag = OCR_FUN(arg, res, iw, wk, 0);
  }
  OCR_WORK_FREE
  return flag;
}
"""


class BatchFunction:
    """Evaluate a CasADi Function (dense column inputs/outputs) row-wise over a batch.

    The Function is generated as C with a loop over samples (compiled once, cached on disk by
    :mod:`ocreach.native.compile`), so a batch of 10^4 samples costs one C call; inputs flagged ``batched``
    are ``(N, size)`` arrays, the others are shared.  Falls back to ``Function.map`` when no C
    compiler is available (same numbers, slower).
    """

    def __init__(self, fun: ca.Function, batched: tuple[bool, ...]):
        self.fun = fun
        self.batched = batched
        self.sizes_in = [fun.size1_in(i) for i in range(fun.n_in())]
        self.sizes_out = [fun.size1_out(j) for j in range(fun.n_out())]
        self.native = None
        self.maps: dict[int, ca.Function] = {}
        try:
            self.native = self._build()
        except COMPILE_ERRORS as exc:  # no compiler: CasADi's VM gives the same numbers
            warnings.warn(f"ocreach.native: compiling {fun.name()} failed ({exc}); using "
                          "CasADi's VM (slower)", RuntimeWarning, stacklevel=3)

    def _build(self):
        if not jit_enabled():
            return None
        main = (f"#define OCR_FUN {self.fun.name()}\n#define OCR_FUN_work {self.fun.name()}_work\n"
                "#include \"gen.c\"\n#include \"work.h\"\n#include \"batch.c\"\n").encode()
        lib = compile_source(f"ocr_batch_{self.fun.name()}",
                              {"gen.c": generate_c([self.fun]), "work.h": C_WORK.encode(),
                               "batch.c": _BATCH_C.encode(),
                               "main.c": main}, "main.c", ("-O2",))
        dll = load_library(lib)
        fn = dll.ocr_batch
        pp = ctypes.POINTER(ctypes.c_void_p)
        fn.argtypes = [ctypes.c_long, ctypes.c_long, pp, ctypes.POINTER(ctypes.c_long),
                       ctypes.c_long, pp, ctypes.POINTER(ctypes.c_long)]
        fn.restype = ctypes.c_int
        self._dll = dll
        return fn

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        arrs = []
        n = None
        for a, b, size in zip(args, self.batched, self.sizes_in):
            a = np.ascontiguousarray(a, dtype=float)
            if b:
                a = a.reshape(-1, size)
                n = a.shape[0]
            else:
                a = a.reshape(size)
            arrs.append(a)
        n = 1 if n is None else n
        if self.native is None:
            fun = self.maps.get(n)
            if fun is None:
                fun = self.maps[n] = self.fun.map(n, "serial") if n > 1 else self.fun
            res = fun(*[a.T if b else a for a, b in zip(arrs, self.batched)])
            res = res if isinstance(res, (list, tuple)) else [res]
            return [np.asarray(r.full()).T.reshape(n, s) for r, s in zip(res, self.sizes_out)]
        outs = [np.empty((n, s)) for s in self.sizes_out]
        in_ptr = (ctypes.c_void_p * len(arrs))(*[a.ctypes.data for a in arrs])
        in_str = (ctypes.c_long * len(arrs))(*[s if b else 0 for s, b in
                                               zip(self.sizes_in, self.batched)])
        out_ptr = (ctypes.c_void_p * len(outs))(*[o.ctypes.data for o in outs])
        out_str = (ctypes.c_long * len(outs))(*self.sizes_out)
        flag = self.native(n, len(arrs), in_ptr, in_str, len(outs), out_ptr, out_str)
        if flag != 0:
            raise SolverError(f"evaluating {self.fun.name()} over a batch of {n} failed (flag {flag})")
        return outs
