"""A compiled (C) evaluation of an interval :class:`~ocreach.intervals.walker.Schedule`, for the few
boxes of one reachability step (the interval Hessian of ``taylor``, the third derivatives of ``sdc``).

The numpy evaluator runs one group of like operations per numpy call; for two boxes its cost is
the ~20-30 groups' call overhead (~0.35 ms for the earth-mars Hessian), not the arithmetic.  This
module runs the same schedule, one operation and one box at a time, in a small C interpreter
(``ocr_iv_eval``: one library for every Function, compiled once and cached on disk; a Function is
a table of operation kinds and argument rows), with the *same* bound of every operation as the
numpy kernels in their ``np.nextafter`` mode (:mod:`ocreach.intervals.ops`:
``_add2``/``_sub2``/``_addsub2``, ``_mul2``/``_div2``/``_muldiv2``, ``_mulc``, ``_neg``,
``_twice``, ``_inv``, ``_sq``, ``_sqrt``, ``_assign``):

* ``+ - * /`` and ``sqrt`` are correctly rounded in IEEE 754, so each computed bound is moved to
  the neighbouring float outward (``nextafter``, inlined on the bit pattern: the same float as
  ``np.nextafter``, tested against it on zeros, subnormals, the largest floats and infinities), with
  the numpy kernels' exact cases kept (a sum with a zero addend or a zero result, a product with
  a factor exactly 0, the sign-free ``neg``/``twice``);
* products and quotients take the hull of the four corners with ``fmin``/``fmax`` (NaN-skipping,
  as ``np.fmin``/``np.fmax``), a product by a constant alone the NaN-propagating min/max of its two
  products (as ``np.minimum``/``np.maximum`` in ``_mulc``);
* the compiler may not contract ``a * b + c`` into an FMA or reassociate (``-ffp-contract=off``,
  no ``-ffast-math``), so every operation is the one IEEE operation the bound assumes.

So the bounds are bit for bit those of the numpy evaluator in ``nextafter`` mode (up to the sign
of a zero bound), which is what it uses for the few boxes of a step (``NEXTAFTER_MAX``); for many
boxes numpy's scaled-ulp rounding is at most one ulp wider.  Only Functions made of these
correctly rounded operations are compiled (libm functions need the evaluator's documented
margins and stay in numpy).  Every failure -- a divisor or an inverse containing 0, ``sqrt`` of
negative numbers, a NaN in any value -- makes the kernel return a flag, and the caller re-runs
the numpy evaluator, which raises the documented :class:`~ocreach.intervals.IntervalDomainError`
naming the op and the box (or, where the NaN rules differ, returns its own sound result).

Imports the schedule (:mod:`ocreach.intervals.walker`), the pseudo op codes of
:mod:`ocreach.intervals.ops` and the compiler (:mod:`ocreach.native.compile`); the evaluator
(:class:`~ocreach.intervals.IntervalFunction`) builds the kernel and calls it.
"""
from __future__ import annotations

import ctypes
import warnings
from typing import Any

import casadi as ca
import numpy as np

from ocreach.intervals.ops import _OP_ADDSUB, _OP_MULC, _OP_MULDIV
from ocreach.intervals.walker import Schedule
from ocreach.native.compile import COMPILE_ERRORS, compile_source, jit_enabled, load_library

__all__ = ["IntervalKernel", "build_interval_kernel"]

#: compiler flags: no FMA contraction and no value-changing optimisation (every operation is the
#: one IEEE operation whose rounding the bound covers)
FLAGS = ("-O2", "-ffp-contract=off", "-fno-fast-math", "-fno-unsafe-math-optimizations")

#: the C source of the interpreter
_PRELUDE = r"""
#include <math.h>
#include <stdint.h>
#include <string.h>
/* DN(x) = nextafter(x, -inf), UP(x) = nextafter(x, +inf), inlined on the bit pattern (the
   neighbouring float is the integer neighbour of the pattern, away from or towards zero) */
static inline double DN(double x) {
  if (isnan(x) || x == -INFINITY) return x;
  if (x == 0) return -4.9406564584124654e-324;
  int64_t i; memcpy(&i, &x, 8); i += (x > 0) ? -1 : 1; memcpy(&x, &i, 8); return x;
}
static inline double UP(double x) {
  if (isnan(x) || x == INFINITY) return x;
  if (x == 0) return 4.9406564584124654e-324;
  int64_t i; memcpy(&i, &x, 8); i += (x > 0) ? 1 : -1; memcpy(&x, &i, 8); return x;
}
/* NaN-propagating min/max (np.minimum / np.maximum) */
#define NMIN(a, b) ((isnan(a) || isnan(b)) ? NAN : ((a) < (b) ? (a) : (b)))
#define NMAX(a, b) ((isnan(a) || isnan(b)) ? NAN : ((a) > (b) ? (a) : (b)))
/* NaN-skipping min/max (C99 fmin/fmax, np.fmin/np.fmax), inlined */
static inline double FMIN(double a, double b) { return (a < b || isnan(b)) ? a : b; }
static inline double FMAX(double a, double b) { return (a > b || isnan(b)) ? a : b; }
#define FMIN4(p0, p1, p2, p3) FMIN(FMIN(FMIN(p0, p1), p2), p3)
#define FMAX4(p0, p1, p2, p3) FMAX(FMAX(FMAX(p0, p1), p2), p3)
static const double FMAX_ = 1.7976931348623157e308;

/* operation kinds (the order of KINDS in ocreach/intervals/kernel.py) */
enum { K_ADD, K_SUB, K_MUL, K_MULC_CORNER, K_DIV, K_MULC_MIN, K_NEG, K_TWICE, K_INV, K_SQ, K_SQRT,
       K_ASSIGN };

/* Bounds of every value of the schedule, box by box.  Values 0 .. n_in-1: inputs (vin, lower
   bounds then upper bounds, (2, n_in, nb)); n_in .. op0-1: constants; op0 + i: operation i,
   kind[i] of values oa[i] (and ob[i]).  Output entry j is value out_row[j]; its lower bound goes
   to out[out_lo[j] * nb + b], the upper to out[out_hi[j] * nb + b].  L, H: work arrays of
   op0 + n_ops values.  Returns 1 if any bound is undefined (a divisor or inverse containing 0,
   sqrt of negative numbers, a NaN), else 0. */
int ocr_iv_eval(int64_t nb, int64_t n_in, int64_t n_const, int64_t n_ops, int64_t n_out,
                const int32_t *kind, const int32_t *oa, const int32_t *ob, const double *consts,
                const double *vin, const int64_t *out_row, const int64_t *out_lo,
                const int64_t *out_hi, double *L, double *H, double *out) {
  int bad = 0;
  const int64_t op0 = n_in + n_const;
  for (int64_t b = 0; b < nb; ++b) {
    for (int64_t i = 0; i < n_in; ++i) { L[i] = vin[i * nb + b]; H[i] = vin[(n_in + i) * nb + b]; }
    for (int64_t i = 0; i < n_const; ++i) { L[n_in + i] = consts[i]; H[n_in + i] = consts[i]; }
    for (int64_t i = 0; i < n_ops; ++i) {
      const double al = L[oa[i]], ah = H[oa[i]];
      const double bl = ob[i] >= 0 ? L[ob[i]] : 0.0, bh = ob[i] >= 0 ? H[ob[i]] : 0.0;
      double lo, hi;
      switch (kind[i]) {
        case K_ADD: {  /* exact where an addend or the sum is 0 */
          double s = al + bl, t = ah + bh;
          lo = (al == 0 || bl == 0 || s == 0) ? s : DN(s);
          hi = (ah == 0 || bh == 0 || t == 0) ? t : UP(t);
          break;
        }
        case K_SUB: {
          double s = al - bh, t = ah - bl;
          lo = (al == 0 || bh == 0 || s == 0) ? s : DN(s);
          hi = (ah == 0 || bl == 0 || t == 0) ? t : UP(t);
          break;
        }
        case K_MUL: case K_MULC_CORNER: {
          double p0 = al * bl, p1 = al * bh, p2 = ah * bl, p3 = ah * bh;
          lo = DN(FMIN4(p0, p1, p2, p3));
          hi = UP(FMAX4(p0, p1, p2, p3));
          if (kind[i] == K_MUL && ((al == 0 && ah == 0) || (bl == 0 && bh == 0))) { lo = 0.0; hi = 0.0; }
          break;
        }
        case K_DIV: {
          if (bl <= 0 && bh >= 0) bad = 1;
          double p0 = al / bl, p1 = al / bh, p2 = ah / bl, p3 = ah / bh;
          lo = DN(FMIN4(p0, p1, p2, p3));
          hi = UP(FMAX4(p0, p1, p2, p3));
          break;
        }
        case K_MULC_MIN: {
          double p = al * bl, q = ah * bl;
          lo = DN(NMIN(p, q));
          hi = UP(NMAX(p, q));
          break;
        }
        case K_NEG: lo = -ah; hi = -al; break;
        case K_TWICE: lo = NMIN(2.0 * al, FMAX_); hi = NMAX(2.0 * ah, -FMAX_); break;
        case K_INV:
          if (al <= 0 && ah >= 0) bad = 1;
          lo = DN(1.0 / ah); hi = UP(1.0 / al);
          break;
        case K_SQ: {
          double fa = fabs(al), fb = fabs(ah);
          double mig = (al <= 0 && ah >= 0) ? 0.0 : NMIN(fa, fb), mag = NMAX(fa, fb);
          lo = NMAX(DN(mig * mig), 0.0); hi = UP(mag * mag);
          break;
        }
        case K_SQRT:
          if (al < 0) bad = 1;
          lo = NMAX(DN(sqrt(al)), 0.0); hi = UP(sqrt(ah));
          break;
        case K_ASSIGN: lo = al; hi = ah; break;
        default: return 2;
      }
      L[op0 + i] = lo;
      H[op0 + i] = hi;
      if (isnan(lo) || isnan(hi)) bad = 1;
    }
    for (int64_t j = 0; j < n_out; ++j) {
      out[out_lo[j] * nb + b] = L[out_row[j]];
      out[out_hi[j] * nb + b] = H[out_row[j]];
    }
  }
  return bad;
}
"""


def _entries(sch: Schedule) -> list[tuple[str, int, int, int | None]] | None:
    """``(kind, out, a, b)`` per operation in schedule order, or None if an op is not supported."""
    simple = {ca.OP_ADD: "add", ca.OP_SUB: "sub", ca.OP_MUL: "mul", ca.OP_DIV: "div",
              _OP_MULC: "mulc_min", ca.OP_NEG: "neg", ca.OP_TWICE: "twice", ca.OP_INV: "inv",
              ca.OP_SQ: "sq", ca.OP_SQRT: "sqrt", ca.OP_ASSIGN: "assign"}
    out = []
    for g in sch.groups:
        rows = range(g.start, g.stop)
        a = np.arange(sch.n_values)[g.a] if g.a is not None else None
        b = np.arange(sch.n_values)[g.b] if g.b is not None else None
        for j, r in enumerate(rows):
            if g.op == _OP_ADDSUB:
                kind = "sub" if bool(g.sub[j, 0]) else "add"
            elif g.op == _OP_MULDIV:
                kind = "div" if bool(g.div[j, 0]) else "mul" if bool(g.mul[j, 0]) else "mulc_corner"
            elif g.op in simple:
                kind = simple[g.op]
            else:
                return None
            out.append((kind, r, int(a[j]), None if b is None else int(b[j])))
    return out


#: the operation kinds, in the order of the C enum
KINDS = ("add", "sub", "mul", "mulc_corner", "div", "mulc_min", "neg", "twice", "inv", "sq", "sqrt",
         "assign")

_LIB: dict[str, Any] = {}


def _library():
    """The compiled interpreter (one small library for every Function, cached on disk)."""
    if "fn" not in _LIB:
        lib = compile_source("ocr_interval_eval", {"iv.c": _PRELUDE.encode()}, "iv.c", FLAGS)
        dll = load_library(lib)
        fn = dll.ocr_iv_eval
        fn.argtypes = [ctypes.c_int64] * 5 + [ctypes.c_void_p] * 11
        fn.restype = ctypes.c_int
        _LIB["dll"], _LIB["fn"] = dll, fn
    return _LIB["fn"]


class IntervalKernel:
    """The compiled evaluation of one :class:`~ocreach.intervals.walker.Schedule` (of an
    :class:`~ocreach.intervals.IntervalFunction`): its groups as tables (kind, argument rows) run
    by the C interpreter ``ocr_iv_eval``.

    ``kernel(los, his, B)`` (the evaluator's input lists after its shape handling) returns the
    list of ``(lo, hi)`` outputs of shape ``(numel, B)``, or None when the kernel flags a failure
    (the caller then runs the numpy evaluator, which reports it)."""

    def __init__(self, sch: Schedule, entries: list, fn):
        self._fn = fn
        self._in_gather = sch.in_gather
        self._n_in = int(sch.const_rows.start)
        self._consts = np.ascontiguousarray(sch.const_vals.ravel(), dtype=float)
        op0 = sch.op_start
        if [e[1] for e in entries] != list(range(op0, op0 + len(entries))):
            raise ValueError("interval kernel: the operations are not in row order")
        code = {k: i for i, k in enumerate(KINDS)}
        self._kind = np.asarray([code[e[0]] for e in entries], dtype=np.int32)
        self._oa = np.asarray([e[2] for e in entries], dtype=np.int32)
        self._ob = np.asarray([-1 if e[3] is None else e[3] for e in entries], dtype=np.int32)
        self._n_values = sch.n_values
        self._numel = list(sch.out_numel)
        self._size = 2 * sum(self._numel)
        rows, los, his, off = [], [], [], 0
        for r, d, k in zip(sch.out_rows, sch.out_dense, sch.out_numel):
            rows.append(r)
            los.append(off + d)
            his.append(off + k + d)
            off += 2 * k
        self._out_row, self._out_lo, self._out_hi = (
            np.ascontiguousarray(np.concatenate(a), dtype=np.int64) for a in (rows, los, his))
        self._sizes = (self._n_in, self._consts.size, self._kind.size, self._out_row.size)
        self._ptrs = tuple(a.ctypes.data for a in (self._kind, self._oa, self._ob, self._consts))
        self._out_ptrs = tuple(a.ctypes.data for a in (self._out_row, self._out_lo, self._out_hi))

    def __call__(self, los, his, B: int):
        vin = np.empty((2, self._n_in, B))
        for i, (rows, idx) in enumerate(self._in_gather):
            if rows.size:
                vin[0, rows] = los[i][idx]
                vin[1, rows] = his[i][idx]
        out = np.zeros(self._size * B)
        work = np.empty(2 * self._n_values)
        flag = self._fn(B, *self._sizes, *self._ptrs, vin.ctypes.data, *self._out_ptrs,
                        work.ctypes.data, work.ctypes.data + 8 * self._n_values, out.ctypes.data)
        if flag != 0:
            return None
        res, off = [], 0
        for k in self._numel:
            blk = out[off * B:(off + 2 * k) * B].reshape(2, k, B)
            res.append((blk[0], blk[1]))
            off += 2 * k
        return res


def build_interval_kernel(sch: Schedule) -> IntervalKernel | None:
    """The kernel of the schedule ``sch``; None if compilation is off, an op is not one of the
    correctly rounded ones (module docstring), a constant is not finite, or the compiler fails
    (with a warning)."""
    if not jit_enabled():
        return None
    entries = _entries(sch)
    if entries is None or not np.all(np.isfinite(sch.const_vals)):
        return None
    try:
        fn = _library()
    except COMPILE_ERRORS as exc:
        warnings.warn(f"ocreach.native: compiling the interval kernel failed ({exc}); using the "
                      "numpy evaluator (same bounds, slower)", RuntimeWarning, stacklevel=3)
        return None
    return IntervalKernel(sch, entries, fn)
