"""C code of an SX Function evaluated on ``W`` samples at once ("lanes", for SIMD).

CasADi's code generator writes one scalar evaluation.  Here the SX instruction list of a Function
(``Function.instruction_id`` / ``instruction_input`` / ``instruction_output``) is written out once
more with every work variable a GCC/Clang vector of ``W`` doubles (``vector_size``), so every
operation is one or two SIMD instructions on ``W`` samples, on inputs and outputs laid out
component-major (entry ``i`` of lane ``l`` at ``i * W + l``).  Straight-line vector code compiles
about as fast as CasADi's scalar code.  Every lane runs the same IEEE operations in the same
order (no ``-ffast-math``; ``fmax``/``fmin`` with C's NaN rules; products and sums may be fused
into FMAs, see :data:`LANE_FLAGS_BASE`), so a lane's result does not depend on which lane or
which other samples it ran with.  The lane code agrees with CasADi's scalar code to the last bits,
not bit for bit, because of FMAs and two rewrites that make it cheaper: integer and half-integer
powers with a constant exponent are products and square roots (CasADi's generated C calls
``pow``), and a divisor shared by several divisions is inverted once (``x / d`` and ``y / d``
become ``x * r`` and ``y * r`` with ``r = 1 / d``: at most one rounding more per quotient;
division and square root are the slow SIMD operations in the CR3BP's ``(x + mu) / r1^3`` and
``y / r1^3``).  Common subexpressions are merged first (``casadi.cse``, for Functions up to
:data:`CSE_MAX_INSTRUCTIONS`; same operations, same bits).

An SX Function has elementwise operations only; one without a lane form raises
:class:`LaneCodegenError` and the caller uses the scalar path.
"""
from __future__ import annotations

import os

import casadi as ca

__all__ = ["CSE_MAX_INSTRUCTIONS", "LANE_FLAGS", "LaneCodegenError", "lane_source", "lane_sources"]


class LaneCodegenError(ValueError):
    """The Function has an operation without a lane form (the caller falls back to scalar code)."""


_LIBM1 = {ca.OP_SQRT: "sqrt", ca.OP_EXP: "exp", ca.OP_LOG: "log", ca.OP_SIN: "sin",
          ca.OP_COS: "cos", ca.OP_TAN: "tan", ca.OP_ASIN: "asin", ca.OP_ACOS: "acos",
          ca.OP_ATAN: "atan", ca.OP_SINH: "sinh", ca.OP_COSH: "cosh", ca.OP_TANH: "tanh",
          ca.OP_ASINH: "asinh", ca.OP_ACOSH: "acosh", ca.OP_ATANH: "atanh", ca.OP_FLOOR: "floor",
          ca.OP_CEIL: "ceil", ca.OP_ERF: "erf", ca.OP_EXPM1: "expm1", ca.OP_LOG1P: "log1p",
          ca.OP_SIGN: "ocr_sign1"}
_LIBM2 = {ca.OP_POW: "pow", ca.OP_CONSTPOW: "pow", ca.OP_ATAN2: "atan2", ca.OP_FMOD: "fmod",
          ca.OP_COPYSIGN: "copysign", ca.OP_HYPOT: "hypot"}
_UNARY = {ca.OP_ASSIGN: "{x}", ca.OP_NEG: "(-{x})", ca.OP_SQ: "({x}*{x})",
          ca.OP_TWICE: "(2.0*{x})", ca.OP_INV: "(1.0/{x})",
          ca.OP_FABS: "((ocr_v)((ocr_m){x} & OCR_ABSMASK))",
          ca.OP_NOT: "ocr_b2d({x} == 0.0)"}
_BINARY = {ca.OP_ADD: "({x}+{y})", ca.OP_SUB: "({x}-{y})", ca.OP_MUL: "({x}*{y})",
           ca.OP_DIV: "({x}/{y})",
           ca.OP_FMAX: "ocr_sel(({x} > {y}) | ({y} != {y}), {x}, {y})",
           ca.OP_FMIN: "ocr_sel(({x} < {y}) | ({y} != {y}), {x}, {y})",
           ca.OP_LT: "ocr_b2d({x} < {y})", ca.OP_LE: "ocr_b2d({x} <= {y})",
           ca.OP_EQ: "ocr_b2d({x} == {y})", ca.OP_NE: "ocr_b2d({x} != {y})",
           ca.OP_AND: "ocr_b2d(({x} != 0.0) & ({y} != 0.0))",
           ca.OP_OR: "ocr_b2d(({x} != 0.0) | ({y} != 0.0))",
           ca.OP_IF_ELSE_ZERO: "((ocr_v)(((ocr_m)({x} != 0.0)) & (ocr_m){y}))"}

#: Compiler flags of lane code: IEEE arithmetic (no ``-ffast-math``: no reassociation, no
#: approximate reciprocals or square roots, NaN and infinity kept) with products and sums
#: contracted into fused multiply-adds where the CPU has them (``-ffp-contract=fast``; an FMA is
#: one IEEE operation rounded once instead of twice; ~8%
#: faster DOP853 steps on the DRO batch; every lane runs the same instructions, so results still
#: do not depend on the lane), and the vector extensions of this CPU named explicitly (never
#: -march=native, whose meaning differs between hosts that share one cache).
LANE_FLAGS_BASE = ("-O2", "-ffp-contract=fast", "-fno-math-errno", "-Wno-psabi")


def _cpu_flags() -> tuple[str, ...]:
    try:
        with open("/proc/cpuinfo") as fh:
            have = next((set(line.split(":", 1)[1].split()) for line in fh
                         if line.startswith("flags")), set())
    except OSError:
        return ()
    if {"avx512f", "avx512dq", "avx512vl"} <= have and os.environ.get("OCREACH_AVX512", "1") != "0":
        return ("-mavx2", "-mfma", "-mavx512f", "-mavx512dq", "-mavx512vl")
    if {"avx2", "fma"} <= have:
        return ("-mavx2", "-mfma")
    return ("-mavx",) if "avx" in have else ()


LANE_FLAGS = LANE_FLAGS_BASE + _cpu_flags()

_PRELUDE = r"""
#include <math.h>
#include <string.h>
typedef long long ocr_m __attribute__((vector_size(8 * OCR_LW)));
#define OCR_ABSMASK 0x7fffffffffffffffLL
static inline ocr_v ocr_sel(ocr_m m, ocr_v a, ocr_v b) {
  return (ocr_v)((m & (ocr_m)a) | (~m & (ocr_m)b));
}
static inline ocr_v ocr_b2d(ocr_m m) { ocr_v one = ocr_bc(1.0); return (ocr_v)(m & (ocr_m)one); }
static inline double ocr_sign1(double x) { return x < 0 ? -1.0 : (x > 0 ? 1.0 : x); }
static inline ocr_v ocr_ld(const double* p) { ocr_v v; memcpy(&v, p, sizeof v); return v; }
static inline void ocr_st(double* p, ocr_v v) { memcpy(p, &v, sizeof v); }
#define OCR_MAP1(f, x) ({ ocr_v _x = (x), _r; for (int _l = 0; _l < OCR_LW; ++_l) _r[_l] = f(_x[_l]); _r; })
#define OCR_MAP2(f, x, y) ({ ocr_v _x = (x), _y = (y), _r; \
  for (int _l = 0; _l < OCR_LW; ++_l) _r[_l] = f(_x[_l], _y[_l]); _r; })
"""


def _power(x: str, c: float) -> str | None:
    """``x ** c`` as products / square roots for small integer and half-integer ``c``."""
    if c == int(c) and 1 <= abs(c) <= 4:
        prod = "*".join([x] * int(abs(c)))
    elif 2 * c == int(2 * c) and 0.5 <= abs(c) <= 3.5:
        prod = "*".join([x] * int(abs(c) - 0.5) + [f"OCR_MAP1(sqrt, {x})"])
    else:
        return None
    return f"({prod})" if c > 0 else f"(1.0/({prod}))"


def _const(c: float) -> str:
    if c != c:
        return "ocr_bc(NAN)"
    if abs(c) == float("inf"):
        return f"ocr_bc({'' if c > 0 else '-'}INFINITY)"
    return f"ocr_bc({c!r})"


def lane_source(fun: ca.Function, name: str, width: int) -> str:
    """C source defining ``static void NAME(const double** in, double** out)``: the SX Function
    ``fun`` (expanded if it is not one) on ``width`` lanes; ``in[i]`` / ``out[j]`` point to
    component-major arrays ``(nnz_i, width)``.  Outputs are written for their structural
    non-zeros only (callers pass dense outputs)."""
    return lane_sources([(fun, name)], width)


def lane_sources(funs: list[tuple[ca.Function, str]], width: int) -> str:
    """One C source with the lane prelude once and a lane function per ``(fun, name)`` (see
    :func:`lane_source`)."""
    W = int(width)
    bc = ", ".join(["c"] * W)
    lines = [f"#define OCR_LW {W}", "typedef double ocr_v __attribute__((vector_size(8 * OCR_LW)));",
             f"static inline ocr_v ocr_bc(double c) {{ return (ocr_v){{{bc}}}; }}",  # broadcast
             _PRELUDE]
    for fun, name in funs:
        lines += _lane_body(_simplified(fun), name, W)
    return "\n".join(lines) + "\n"


#: common subexpressions are merged only in Functions up to this many instructions: on the
#: DRO step (1,265 instructions) ``casadi.cse`` takes milliseconds and makes the lane step ~12%
#: faster; on a first-order STT of a 7-state model (22,780) it takes ~0.4 s, paid by every
#: process that loads the kernel (the source is regenerated to find the cached library)
CSE_MAX_INSTRUCTIONS = 10000


def _simplified(fun: ca.Function) -> ca.Function:
    """``fun`` as an SX Function, with common subexpressions merged (``casadi.cse``) if it has
    at most :data:`CSE_MAX_INSTRUCTIONS` instructions."""
    if not fun.is_a("SXFunction"):
        fun = fun.expand()
    if fun.n_instructions() > CSE_MAX_INSTRUCTIONS:
        return fun
    ins = fun.sx_in()
    outs = ca.cse(fun.call(ins))
    return ca.Function(fun.name(), ins, outs, fun.name_in(), fun.name_out())


def _shared_divisors(fun: ca.Function) -> set[tuple[int, int]]:
    """Divisors used by two or more divisions, as (work variable, assignment count) values
    (work variables are re-used, so a value is a variable together with its version)."""
    version: dict[int, int] = {}
    uses: dict[tuple[int, int], int] = {}
    for k in range(fun.n_instructions()):
        op = fun.instruction_id(k)
        if op == ca.OP_DIV:
            d = fun.instruction_input(k)[1]
            key = (d, version.get(d, 0))
            uses[key] = uses.get(key, 0) + 1
        if op != ca.OP_OUTPUT:
            o = fun.instruction_output(k)[0]
            version[o] = version.get(o, 0) + 1
    return {key for key, n in uses.items() if n > 1}


def _lane_body(fun: ca.Function, name: str, W: int) -> list[str]:
    lines = [f"static void {name}(const double** in, double** out) {{"]
    if fun.sz_w():
        lines.append("  ocr_v " + ", ".join(f"w{i}" for i in range(fun.sz_w())) + ";")
    shared = _shared_divisors(fun)
    recip: dict[tuple[int, int], str] = {}  # shared divisor value -> its reciprocal variable
    version: dict[int, int] = {}
    const: dict[int, float] = {}
    for k in range(fun.n_instructions()):
        op = fun.instruction_id(k)
        ins = fun.instruction_input(k)
        outs = fun.instruction_output(k)
        if op == ca.OP_OUTPUT:
            lines.append(f"  ocr_st(out[{outs[0]}] + {outs[1] * W}, w{ins[0]});")
            continue
        o = outs[0]
        const.pop(o, None)
        if op == ca.OP_INPUT:
            expr = f"ocr_ld(in[{ins[0]}] + {ins[1] * W})"
        elif op == ca.OP_CONST:
            c = float(fun.instruction_constant(k))
            expr = _const(c)
            const[o] = c
        elif op == ca.OP_DIV and (ins[1], version.get(ins[1], 0)) in shared:
            key = (ins[1], version.get(ins[1], 0))
            if key not in recip:
                recip[key] = f"r{len(recip)}"
                lines.append(f"  const ocr_v {recip[key]} = 1.0 / w{ins[1]};")
            expr = f"(w{ins[0]}*{recip[key]})"
        elif op in _UNARY:
            expr = _UNARY[op].format(x=f"w{ins[0]}")
        elif op in _LIBM1:
            expr = f"OCR_MAP1({_LIBM1[op]}, w{ins[0]})"
        elif op in _BINARY:
            expr = _BINARY[op].format(x=f"w{ins[0]}", y=f"w{ins[1]}")
        elif op in _LIBM2:
            expr = None
            if op in (ca.OP_POW, ca.OP_CONSTPOW) and ins[1] in const:
                expr = _power(f"w{ins[0]}", const[ins[1]])
            expr = expr or f"OCR_MAP2({_LIBM2[op]}, w{ins[0]}, w{ins[1]})"
        else:
            raise LaneCodegenError(f"operation {op} of {fun.name()} has no lane form")
        lines.append(f"  w{o} = {expr};")
        version[o] = version.get(o, 0) + 1
    lines.append("}")
    return lines
