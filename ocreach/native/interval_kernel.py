"""A compiled (C) evaluation of an :class:`ocreach.intervals.IntervalFunction`, for the few boxes of
one reachability step (the interval Hessian of ``taylor``, the third derivatives of ``sdc``).

The numpy evaluator runs one group of like operations per numpy call; for two boxes its cost is
the ~20-30 groups' call overhead (~0.35 ms for the earth-mars Hessian), not the arithmetic.  This
module emits the same schedule as straight-line C, one box at a time, with the *same* bound of
every operation as the numpy kernels in their ``np.nextafter`` mode (:mod:`ocreach.intervals`:
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
"""
from __future__ import annotations

import ctypes
import warnings
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from ocreach.native.codegen import c_identifier
from ocreach.native.compile import COMPILE_ERRORS, compile_source, jit_enabled, load_library

if TYPE_CHECKING:
    from ocreach.intervals import IntervalFunction

__all__ = ["IntervalKernel", "build_interval_kernel"]

#: compiler flags: no FMA contraction and no value-changing optimisation (every operation is the
#: one IEEE operation whose rounding the bound covers); -O1 keeps the build of the largest
#: generated sources (the spatial CR3BP third derivatives, ~6,000 operations) to a few seconds
FLAGS = ("-O1", "-ffp-contract=off", "-fno-fast-math", "-fno-unsafe-math-optimizations")

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
"""


def _entry_code(kind: str, o: int, a: int, b: int | None) -> list[str]:
    """C statements bounding one operation: value ``o`` from values ``a`` (and ``b``); ``L``/``H``
    are the lower/upper bound arrays, ``bad`` collects the failures (module docstring)."""
    al, ah, ol, oh = f"L[{a}]", f"H[{a}]", f"L[{o}]", f"H[{o}]"
    bl, bh = (f"L[{b}]", f"H[{b}]") if b is not None else ("", "")
    if kind in ("add", "sub"):
        if kind == "add":
            return [f"{{ double s = {al} + {bl}; {ol} = ({al} == 0 || {bl} == 0 || s == 0) ? s : DN(s); "
                    f"double t = {ah} + {bh}; {oh} = ({ah} == 0 || {bh} == 0 || t == 0) ? t : UP(t); }}"]
        return [f"{{ double s = {al} - {bh}; {ol} = ({al} == 0 || {bh} == 0 || s == 0) ? s : DN(s); "
                f"double t = {ah} - {bl}; {oh} = ({ah} == 0 || {bl} == 0 || t == 0) ? t : UP(t); }}"]
    if kind in ("mul", "mulc_corner"):
        body = (f"double p0 = {al} * {bl}, p1 = {al} * {bh}, p2 = {ah} * {bl}, p3 = {ah} * {bh}; "
                f"{ol} = DN(FMIN4(p0, p1, p2, p3)); {oh} = UP(FMAX4(p0, p1, p2, p3));")
        if kind == "mul":
            body += (f" if (({al} == 0 && {ah} == 0) || ({bl} == 0 && {bh} == 0)) "
                     f"{{ {ol} = 0.0; {oh} = 0.0; }}")
        return ["{ " + body + " }"]
    if kind == "div":
        return [f"if ({bl} <= 0 && {bh} >= 0) bad = 1;",
                f"{{ double p0 = {al} / {bl}, p1 = {al} / {bh}, p2 = {ah} / {bl}, p3 = {ah} / {bh}; "
                f"{ol} = DN(FMIN4(p0, p1, p2, p3)); {oh} = UP(FMAX4(p0, p1, p2, p3)); }}"]
    if kind == "mulc_min":
        return [f"{{ double p = {al} * {bl}, q = {ah} * {bl}; {ol} = DN(NMIN(p, q)); "
                f"{oh} = UP(NMAX(p, q)); }}"]
    if kind == "neg":
        return [f"{ol} = -{ah}; {oh} = -{al};"]
    if kind == "twice":
        return [f"{ol} = NMIN(2.0 * {al}, FMAX_); {oh} = NMAX(2.0 * {ah}, -FMAX_);"]
    if kind == "inv":
        return [f"if ({al} <= 0 && {ah} >= 0) bad = 1;",
                f"{ol} = DN(1.0 / {ah}); {oh} = UP(1.0 / {al});"]
    if kind == "sq":
        return [f"{{ double fa = fabs({al}), fb = fabs({ah}); "
                f"double mig = ({al} <= 0 && {ah} >= 0) ? 0.0 : NMIN(fa, fb); double mag = NMAX(fa, fb); "
                f"{ol} = NMAX(DN(mig * mig), 0.0); {oh} = UP(mag * mag); }}"]
    if kind == "sqrt":
        return [f"if ({al} < 0) bad = 1;",
                f"{ol} = NMAX(DN(sqrt({al})), 0.0); {oh} = UP(sqrt({ah}));"]
    if kind == "assign":
        return [f"{ol} = {al}; {oh} = {ah};"]
    raise ValueError(kind)


def _entries(ivf: IntervalFunction) -> list[tuple[str, int, int, int | None]] | None:
    """``(kind, out, a, b)`` per operation in schedule order, or None if an op is not supported."""
    from ocreach import intervals as iv

    simple = {ca.OP_ADD: "add", ca.OP_SUB: "sub", ca.OP_MUL: "mul", ca.OP_DIV: "div",
              iv._OP_MULC: "mulc_min", ca.OP_NEG: "neg", ca.OP_TWICE: "twice", ca.OP_INV: "inv",
              ca.OP_SQ: "sq", ca.OP_SQRT: "sqrt", ca.OP_ASSIGN: "assign"}
    out = []
    for g, neg in zip(ivf._groups, ivf._group_neg):
        rows = range(g.start, g.stop)
        a = np.arange(ivf.n_values)[g.a] if g.a is not None else None
        b = np.arange(ivf.n_values)[g.b] if g.b is not None else None
        for j, r in enumerate(rows):
            if g.op == iv._OP_ADDSUB:
                kind = "sub" if bool(neg[j, 0]) else "add"
            elif g.op == iv._OP_MULDIV:
                isdiv, ismul = neg
                kind = "div" if bool(isdiv[j, 0]) else "mul" if bool(ismul[j, 0]) else "mulc_corner"
            elif g.op in simple:
                kind = simple[g.op]
            else:
                return None
            out.append((kind, r, int(a[j]), None if b is None else int(b[j])))
    return out


def kernel_source(ivf: IntervalFunction, entries: list, cname: str) -> str | None:
    """C source of ``int cname(long nb, const double *vin, double *out)`` (see
    :class:`IntervalKernel`), or None if a constant is not finite."""
    consts = ivf._const_vals.ravel()
    if not np.all(np.isfinite(consts)):
        return None
    n_in = int(ivf._const_rows.start)
    nv = ivf.n_values
    lines = [_PRELUDE, f"int {cname}(long nb, const double *vin, double *out) {{",
             f"  double L[{nv}], H[{nv}];", "  int bad = 0;",
             "  for (long b = 0; b < nb; ++b) {"]
    for i in range(n_in):
        lines.append(f"    L[{i}] = vin[{i} * nb + b]; H[{i}] = vin[({n_in} + {i}) * nb + b];")
    for k, v in enumerate(consts):
        r = n_in + k
        lines.append(f"    L[{r}] = {float(v).hex()}; H[{r}] = {float(v).hex()};")
    for kind, o, a, b in entries:
        lines.extend("    " + s for s in _entry_code(kind, o, a, b))
    op0 = ivf._op_start
    lines.append(f"    for (int k = {op0}; k < {nv}; ++k) if (isnan(L[k]) || isnan(H[k])) bad = 1;")
    off = 0
    for rows, dense, k in zip(ivf._out_rows, ivf._out_dense, ivf._out_numel):
        for r, d in zip(rows, dense):
            lines.append(f"    out[({off} + {int(d)}) * nb + b] = L[{int(r)}]; "
                         f"out[({off + k} + {int(d)}) * nb + b] = H[{int(r)}];")
        off += 2 * k
    lines += ["  }", "  return bad;", "}", ""]
    return "\n".join(lines)


class IntervalKernel:
    """The compiled evaluation of one :class:`~ocreach.intervals.IntervalFunction`.

    ``kernel(los, his, B)`` (the evaluator's input lists after its shape handling) returns the
    list of ``(lo, hi)`` outputs of shape ``(numel, B)``, or None when the kernel flags a failure
    (the caller then runs the numpy evaluator, which reports it)."""

    def __init__(self, ivf: IntervalFunction, fn):
        self._fn = fn
        self._in_gather = ivf._in_gather
        self._n_in = int(ivf._const_rows.start)
        self._numel = list(ivf._out_numel)
        self._size = 2 * sum(self._numel)

    def __call__(self, los, his, B: int):
        vin = np.empty((2, self._n_in, B))
        for i, (rows, idx) in enumerate(self._in_gather):
            if rows.size:
                vin[0, rows] = los[i][idx]
                vin[1, rows] = his[i][idx]
        out = np.zeros(self._size * B)
        if self._fn(B, vin.ctypes.data, out.ctypes.data) != 0:
            return None
        res, off = [], 0
        for k in self._numel:
            blk = out[off * B:(off + 2 * k) * B].reshape(2, k, B)
            res.append((blk[0], blk[1]))
            off += 2 * k
        return res


def build_interval_kernel(ivf: IntervalFunction) -> IntervalKernel | None:
    """Compile ``ivf`` (cached on disk); None if compilation is off, an op is not one of the
    correctly rounded ones (module docstring) or the compiler fails (with a warning)."""
    if not jit_enabled():
        return None
    entries = _entries(ivf)
    if entries is None:
        return None
    cname = "ocr_iv_" + c_identifier(ivf.name)
    src = kernel_source(ivf, entries, cname)
    if src is None:
        return None
    try:
        lib = compile_source(cname, {"iv.c": src.encode()}, "iv.c", FLAGS)
        dll = load_library(lib)
    except COMPILE_ERRORS as exc:
        warnings.warn(f"ocreach.native: compiling the interval kernel of {ivf.name} failed ({exc}); "
                      "using the numpy evaluator (same bounds, slower)", RuntimeWarning, stacklevel=3)
        return None
    fn = getattr(dll, cname)
    fn.argtypes = [ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p]
    fn.restype = ctypes.c_int
    kernel = IntervalKernel(ivf, fn)
    kernel._dll = dll  # keep the library loaded
    return kernel
