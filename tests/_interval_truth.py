"""Independent rigorous interval truth for tests/test_intervals.py and benchmarks/bench_intervals.py.

A plain sequential interpreter of a CasADi SX Function's instruction list over CasADi's own work
slots (no renaming, no grouping, one box at a time) with ``mpmath.iv`` interval arithmetic at 53
bits (directed rounding: the tightest float enclosure of each operation).  Functions that
``mpmath.iv`` lacks or bounds loosely (``tan`` = sin/cos there) are taken as monotone pieces whose
end values are computed with ``mpmath.mp`` at 120 bits and widened by a relative 2**-100.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
from mpmath import iv, mp
from mpmath.libmp import to_float

_HI_PREC = 120
_WIDEN = mp.mpf(2) ** -100


class RefDomainError(ArithmeticError):
    """The reference has no finite bound (division by an interval containing 0, ...)."""


def _contains0(a) -> bool:
    return a.a <= 0 <= a.b


def _lo_hi(v):
    """A rigorous interval around a 120-bit value ``v``."""
    d = abs(v) * _WIDEN + mp.mpf(2) ** -1100
    return v - d, v + d


def _mono(fn, a, inc=True):
    with mp.workprec(_HI_PREC):
        ya, yb = fn(mp.mpf(a.a)), fn(mp.mpf(a.b))
        lo_a, hi_a = _lo_hi(ya)
        lo_b, hi_b = _lo_hi(yb)
    return iv.mpf([lo_a, hi_b]) if inc else iv.mpf([lo_b, hi_a])


def _mig_mag(a):
    mig = 0 if _contains0(a) else min(abs(a.a), abs(a.b))
    return mig, max(abs(a.a), abs(a.b))


def _tan(a):
    if _contains0(iv.cos(a)):
        raise RefDomainError("tan pole")
    return _mono(mp.tan, a)


def _pow(a, b):
    if b.a == b.b and mp.floor(b.a) == b.a:
        n = int(b.a)
        if n < 0 and _contains0(a):
            raise RefDomainError("negative power of an interval containing 0")
        return a ** n
    if a.a < 0 or (a.a == 0 and b.a <= 0):
        raise RefDomainError("pow domain")
    with mp.workprec(_HI_PREC):
        c = [mp.power(mp.mpf(x), mp.mpf(y)) for x in (a.a, a.b) for y in (b.a, b.b)]
        lo, _ = _lo_hi(min(c))
        _, hi = _lo_hi(max(c))
    return iv.mpf([lo, hi])


def _div(a, b):
    if _contains0(b):
        raise RefDomainError("division by an interval containing 0")
    return a / b


def _inv(a):
    if _contains0(a):
        raise RefDomainError("1/x of an interval containing 0")
    return 1 / a


def _sqrt(a):
    if a.a < 0:
        raise RefDomainError("sqrt of negative numbers")
    return iv.sqrt(a)


def _log(a):
    if a.a <= 0:
        raise RefDomainError("log of numbers <= 0")
    return iv.log(a)


def _cosh(a):
    mig, mag = _mig_mag(a)
    return _mono(mp.cosh, iv.mpf([mig, mag]))


UNARY = {
    ca.OP_NEG: lambda a: -a, ca.OP_TWICE: lambda a: 2 * a, ca.OP_INV: _inv,
    ca.OP_SQ: lambda a: a ** 2, ca.OP_SQRT: _sqrt, ca.OP_SIN: iv.sin, ca.OP_COS: iv.cos,
    ca.OP_TAN: _tan, ca.OP_EXP: iv.exp, ca.OP_LOG: _log, ca.OP_ASSIGN: lambda a: a,
    ca.OP_FABS: lambda a: iv.mpf(list(_mig_mag(a))),
    ca.OP_SIGN: lambda a: iv.mpf([mp.sign(a.a), mp.sign(a.b)]),
    ca.OP_FLOOR: lambda a: iv.mpf([mp.floor(a.a), mp.floor(a.b)]),
    ca.OP_CEIL: lambda a: iv.mpf([mp.ceil(a.a), mp.ceil(a.b)]),
    ca.OP_ATAN: lambda a: _mono(mp.atan, a), ca.OP_ASIN: lambda a: _mono(mp.asin, a),
    ca.OP_ACOS: lambda a: _mono(mp.acos, a, inc=False), ca.OP_SINH: lambda a: _mono(mp.sinh, a),
    ca.OP_COSH: _cosh, ca.OP_TANH: lambda a: _mono(mp.tanh, a),
    ca.OP_ASINH: lambda a: _mono(mp.asinh, a), ca.OP_ACOSH: lambda a: _mono(mp.acosh, a),
    ca.OP_ATANH: lambda a: _mono(mp.atanh, a), ca.OP_ERF: lambda a: _mono(mp.erf, a),
    ca.OP_EXPM1: lambda a: _mono(mp.expm1, a), ca.OP_LOG1P: lambda a: _mono(mp.log1p, a),
}
BINARY = {
    ca.OP_ADD: lambda a, b: a + b, ca.OP_SUB: lambda a, b: a - b, ca.OP_MUL: lambda a, b: a * b,
    ca.OP_DIV: _div, ca.OP_POW: _pow, ca.OP_CONSTPOW: _pow,
    ca.OP_FMIN: lambda a, b: iv.mpf([min(a.a, b.a), min(a.b, b.b)]),
    ca.OP_FMAX: lambda a, b: iv.mpf([max(a.a, b.a), max(a.b, b.b)]),
}


class Reference:
    """Sequential mpmath.iv evaluation of an SX Function, one box per call."""

    def __init__(self, fun: ca.Function):
        self.fun = fun
        self.prog = []
        for k in range(fun.n_instructions()):
            op = fun.instruction_id(k)
            cst = float(fun.instruction_constant(k)) if op == ca.OP_CONST else None
            self.prog.append((op, list(fun.instruction_input(k)), list(fun.instruction_output(k)), cst))
        self.out_dense = [np.asarray(fun.sparsity_out(i).find()) for i in range(fun.n_out())]
        self.in_dense = [np.asarray(fun.sparsity_in(i).find()) for i in range(fun.n_in())]
        self.out_numel = [fun.sparsity_out(i).numel() for i in range(fun.n_out())]

    def __call__(self, lo: list, hi: list) -> list[list]:
        """``lo``/``hi``: lists of 1-D float arrays (dense, one per input) -> per output a list
        (dense, column-major) of ``mpmath.iv`` intervals."""
        iv.prec = 53
        w = [None] * self.fun.sz_w()
        out = [[iv.mpf(0)] * n for n in self.out_numel]
        for op, ins, outs, cst in self.prog:
            if op == ca.OP_INPUT:
                i, nz = ins
                d = self.in_dense[i][nz]
                w[outs[0]] = iv.mpf([float(lo[i][d]), float(hi[i][d])])
            elif op == ca.OP_CONST:
                w[outs[0]] = iv.mpf(cst)
            elif op == ca.OP_OUTPUT:
                o, nz = outs
                out[o][self.out_dense[o][nz]] = w[ins[0]]
            elif op in UNARY:
                w[outs[0]] = UNARY[op](w[ins[0]])
            elif op in BINARY:
                w[outs[0]] = BINARY[op](w[ins[0]], w[ins[1]])
            else:
                raise NotImplementedError(f"reference has no op {op}")
        return out


def as_arrays(vals: list) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper endpoints of a list of mpmath intervals as float arrays, rounded outward
    to floats (floor / ceiling: for a float ``y``, ``y <= a`` iff ``y <= floor(a)``, so checking
    that our float bounds contain these is exactly the check that they contain the interval)."""
    lo = np.array([to_float(v._mpi_[0], rnd="f") for v in vals])
    hi = np.array([to_float(v._mpi_[1], rnd="c") for v in vals])
    return lo, hi
