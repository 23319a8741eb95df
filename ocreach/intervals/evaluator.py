"""Sound interval evaluation of CasADi SX Functions, vectorised over many boxes.

CasADi has no interval arithmetic, so this module walks a Function's algorithm (the instruction
list: ``n_instructions``, ``instruction_id``, ``instruction_input``, ``instruction_output``,
``instruction_constant`` and the ``casadi.OP_*`` codes) once, renames CasADi's reused work slots
into single-assignment values, groups independent instructions of one operation code (list
scheduling on the graph, fewer groups than grouping by depth), and evaluates every group as one
numpy operation on arrays of shape ``(n_values, B)``: ``B`` boxes at once.  This is the bound
the remainders of Patel & Subbarao's methods need (the Lagrange remainder of Method 1, Eq.
13-15, bounded by the interval Hessian over the interval hull of the reachable set; ``R_err`` of
Method 2, Eq. 25, which the paper leaves undefined).

Soundness (``docs/intervals.md`` has the argument)
-------------------------------------------------
* ``+ - * /`` and ``sqrt`` are correctly rounded in IEEE 754 (error <= 1/2 ulp), so every bound
  they produce is moved outward past the neighbouring float (:func:`_dn`, :func:`_up`).
* libm/SIMD functions (``sin cos tan exp log pow atan2 ...``) are not correctly rounded; their
  bounds are moved outward by ``LIBM_REL * |y| + LIBM_ABS`` and then one more ulp.  ``LIBM_REL =
  2**-46`` is 64 ulps, 32 times the worst error measured for numpy's kernels (AVX-512 SVML and
  glibc; the measurements are in ``docs/intervals.md``).
* Non-monotone functions are bounded exactly: ``sin``/``cos`` detect the extrema inside the
  interval (with a generous tolerance that can only make the bound wider), even powers and
  ``fabs``/``cosh`` use the smallest and largest magnitude, ``fmin``/``fmax``/``sign``/``floor``
  are monotone and exact.
* Where no finite bound exists the evaluator raises :class:`IntervalDomainError`, naming the op
  and the box: division by (or a negative power of) an interval containing 0 (a primary body may
  lie inside the box), ``sqrt``/``log`` of negative numbers, a pole of ``tan``, and an
  ``if_else`` whose condition is undecided on the box (or a comparison feeding one).
"""
from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError, SolverError, check_count

#: Relative outward margin after a libm/SIMD function (64 ulps of the result).
LIBM_REL = 2.0**-46
#: Absolute outward margin after a libm/SIMD function (covers results in the subnormal range).
LIBM_ABS = 2.0**-1000
#: An evaluation whose largest group has at most this many entries (rows x boxes of the whole
#: call, so the choice does not depend on the chunking) is rounded outward by ``np.nextafter``
#: (one call, faster for small arrays, e.g. the few boxes of one reachability step), larger ones
#: by the scaled-ulp formula of :func:`_dn` (both sound; they may differ by one ulp).
NEXTAFTER_MAX = 1024


class _RoundingMode(threading.local):
    """The rounding mode of the evaluation in progress in this thread (set by
    ``IntervalFunction.__call__``; thread-local, so concurrent evaluations in other threads keep
    their own)."""

    nextafter = False


_ROUNDING = _RoundingMode()
#: Memory budget (bytes) of the value arrays of one evaluation chunk.
CHUNK_BYTES = 2**27
#: Target number of elements (rows x boxes) of the largest group's temporaries per chunk: boxes
#: are evaluated in chunks that keep those in cache (measured up to ~1.5x faster than one chunk).
CHUNK_GROUP_ELEMS = 2**16

_OP_NAMES = {getattr(ca, n): n[3:].lower() for n in dir(ca) if n.startswith("OP_")}
_INF = np.inf
_PI_LO = 3.141592653589793          # float(pi) < pi
_PI_HI = np.nextafter(_PI_LO, _INF)
_HALF_PI_LO = _PI_LO / 2            # exact halving
_HALF_PI_HI = _PI_HI / 2


class IntervalDomainError(SolverError):
    """An interval bound does not exist (or is not decidable) on a box.

    Attributes: ``op`` (CasADi operation name), ``box`` (index of the offending box among the
    ``B`` evaluated), ``inputs`` (list of ``(lo, hi)`` of every Function input on that box).
    """

    def __init__(self, message: str, op: str = "", box: int = -1, inputs: list | None = None):
        super().__init__(message)
        self.op = op
        self.box = box
        self.inputs = inputs or []


class _Fail(Exception):
    """Raised inside an op kernel: ``mask`` (g, B) marks the entries that have no bound."""

    def __init__(self, mask: np.ndarray, reason: str):
        super().__init__(reason)
        self.mask = mask
        self.reason = reason


# ---------------------------------------------------------------------------- rounding helpers
_ULP_REL = 2.0**-52     # |x| * 2**-52 >= ulp(x) for every finite x (and exact for normal x)
_ETA = 2.0**-1074       # the smallest subnormal
_FMAX = np.finfo(float).max


def _dn(x):
    """A float <= the predecessor of ``x`` (so below every real that rounds to ``x``).

    ``x - (|x| 2**-52 + 2**-1074)`` in round-to-nearest: the subtracted amount is at least
    ulp(x) (the product is a power-of-two scaling, exact unless it underflows, and then still
    >= the power of two ulp(x) by monotone rounding), so the exact difference is <= pred(x) and
    rounding to nearest (monotone, pred(x) is a float) cannot go above pred(x).  Cf. Rump,
    Zimmermann, Boldo & Melquiond, BIT 49 (2009).  About 4x faster than ``np.nextafter``, which
    numpy does not vectorise -- for large arrays; for evaluations of few values (see
    :data:`NEXTAFTER_MAX`) the one ``np.nextafter`` call (exactly the predecessor) is faster than
    these five.  An overflowed
    ``x = +inf`` (the exact value is a finite number above the largest float) gives a float just
    below the largest float (``nextafter``: the largest float); NaN stays NaN."""
    if _ROUNDING.nextafter:
        return np.nextafter(x, -_INF)
    x = np.minimum(x, _FMAX)
    return x - (np.abs(x) * _ULP_REL + _ETA)


def _up(x):
    """A float >= the successor of ``x`` (see :func:`_dn`); ``-inf`` gives about ``-FMAX``."""
    if _ROUNDING.nextafter:
        return np.nextafter(x, _INF)
    x = np.maximum(x, -_FMAX)
    return x + (np.abs(x) * _ULP_REL + _ETA)


def _ldn(y):
    """Lower bound of a true value whose libm approximation is ``y`` (``y = +inf`` from an
    overflow gives the largest float, less the margin)."""
    y = np.clip(y, -_FMAX, _FMAX)
    return _dn(y - (np.abs(y) * LIBM_REL + LIBM_ABS))


def _lup(y):
    """Upper bound of a true value whose libm approximation is ``y``."""
    y = np.clip(y, -_FMAX, _FMAX)
    return _up(y + (np.abs(y) * LIBM_REL + LIBM_ABS))


def _mono_inc(fn, lo, hi, rng=(-_INF, _INF)):
    """Bound of a non-decreasing libm function, clipped to its true range ``rng``."""
    with np.errstate(all="ignore"):
        return (np.maximum(_ldn(fn(lo)), rng[0]), np.minimum(_lup(fn(hi)), rng[1]))


def _mono_dec(fn, lo, hi, rng=(-_INF, _INF)):
    with np.errstate(all="ignore"):
        return (np.maximum(_ldn(fn(hi)), rng[0]), np.minimum(_lup(fn(lo)), rng[1]))


def _mig_mag(lo, hi):
    """Smallest and largest ``|x|`` over ``[lo, hi]``."""
    mig = np.where((lo <= 0) & (hi >= 0), 0.0, np.minimum(np.abs(lo), np.abs(hi)))
    return mig, np.maximum(np.abs(lo), np.abs(hi))


def _require(mask, reason):
    if mask.any():
        raise _Fail(mask, reason)


# ---------------------------------------------------------------------------- op kernels
# Every kernel takes (alo, ahi, blo, bhi, undecided) with arrays of shape (g, B) (b is None for
# unary ops) and returns (lo, hi).  Invariant: lower bounds are never +inf, upper never -inf.

def _sum_dn(s):
    """Lower bound of an exact sum whose rounded value is ``s``.  With gradual underflow a
    float sum is 0 only if it is exactly 0, so 0 is kept (a sum of squares stays >= 0)."""
    return np.where(s == 0, 0.0, _dn(s))


def _sum_up(s):
    return np.where(s == 0, 0.0, _up(s))


def _add(alo, ahi, blo, bhi, und):
    lo, hi = alo + blo, ahi + bhi
    # x + 0 is exact: no widening where an addend end is 0 (e.g. the zero branch of if_else)
    return (np.where((alo == 0) | (blo == 0), lo, _sum_dn(lo)),
            np.where((ahi == 0) | (bhi == 0), hi, _sum_up(hi)))


def _sub(alo, ahi, blo, bhi, und):
    lo, hi = alo - bhi, ahi - blo
    return (np.where((alo == 0) | (bhi == 0), lo, _sum_dn(lo)),
            np.where((ahi == 0) | (blo == 0), hi, _sum_up(hi)))


def _corners(p):
    """Hull of four corner values.  ``fmin``/``fmax`` skip a NaN corner: one from ``0 * inf``
    (an overflowed bound is 'unbounded', and 0 times a finite number is the 0 corner, which
    another corner holds) or ``inf / inf`` (the other corners hold 0 and inf)."""
    return (np.fmin(np.fmin(p[0], p[1]), np.fmin(p[2], p[3])),
            np.fmax(np.fmax(p[0], p[1]), np.fmax(p[2], p[3])))


def _mul(alo, ahi, blo, bhi, und):
    lo, hi = _corners((alo * blo, alo * bhi, ahi * blo, ahi * bhi))
    exact0 = (alo == 0) & (ahi == 0) | (blo == 0) & (bhi == 0)   # a factor is exactly 0
    return np.where(exact0, 0.0, _dn(lo)), np.where(exact0, 0.0, _up(hi))


def _mulc(alo, ahi, c, _, und):
    """``x * c`` with a constant ``c`` (a pseudo op made at compile time): two products."""
    p, q = alo * c, ahi * c
    return _dn(np.minimum(p, q)), _up(np.maximum(p, q))


def _div(alo, ahi, blo, bhi, und):
    _require((blo <= 0) & (bhi >= 0), "division by an interval containing 0")
    lo, hi = _corners((alo / blo, alo / bhi, ahi / blo, ahi / bhi))
    return _dn(lo), _up(hi)


def _inv(alo, ahi, blo, bhi, und):
    _require((alo <= 0) & (ahi >= 0), "inverse (1/x) of an interval containing 0")
    return _dn(1.0 / ahi), _up(1.0 / alo)


def _neg(alo, ahi, blo, bhi, und):
    return -ahi, -alo


def _twice(alo, ahi, blo, bhi, und):
    # exact, except on overflow: keep a lower bound below +inf (and an upper above -inf)
    return np.minimum(2.0 * alo, _FMAX), np.maximum(2.0 * ahi, -_FMAX)


def _assign(alo, ahi, blo, bhi, und):
    return alo.copy(), ahi.copy()


def _sq(alo, ahi, blo, bhi, und):
    mig, mag = _mig_mag(alo, ahi)
    return np.maximum(_dn(mig * mig), 0.0), _up(mag * mag)


def _sqrt(alo, ahi, blo, bhi, und):
    _require(alo < 0, "sqrt of an interval with negative numbers")
    return np.maximum(_dn(np.sqrt(alo)), 0.0), _up(np.sqrt(ahi))


def _fabs(alo, ahi, blo, bhi, und):
    return _mig_mag(alo, ahi)


def _sign(alo, ahi, blo, bhi, und):
    return np.sign(alo), np.sign(ahi)  # sign is non-decreasing


def _floor(alo, ahi, blo, bhi, und):
    return np.floor(alo), np.floor(ahi)


def _ceil(alo, ahi, blo, bhi, und):
    return np.ceil(alo), np.ceil(ahi)


def _fmin(alo, ahi, blo, bhi, und):
    return np.minimum(alo, blo), np.minimum(ahi, bhi)


def _fmax(alo, ahi, blo, bhi, und):
    return np.maximum(alo, blo), np.maximum(ahi, bhi)


def _copysign(alo, ahi, blo, bhi, und):
    mig, mag = _mig_mag(alo, ahi)
    pos, neg = blo >= 0, bhi < 0  # the real number 0 has a positive sign
    return np.where(pos, mig, -mag), np.where(pos, mag, np.where(neg, -mig, mag))


def _contains_point(lo, hi, c, period):
    """True where ``[lo, hi]`` contains (or nearly contains) a point ``c + k * period``.

    The test is loose by ``1e-9 (1 + |x|)``: rounding in the reduction can only produce a false
    'contains', which widens the bound to the extremum (sound)."""
    tol = (1e-9 * (1.0 + np.maximum(np.abs(lo), np.abs(hi)))) / period
    return np.ceil((lo - c) / period - tol) <= np.floor((hi - c) / period + tol)


def _trig(fn, c_max, c_min, alo, ahi):
    # an argument lying entirely beyond 1e300 is an overflowed value (its lower bound is the
    # largest float rounded down, its upper inf): floats give NaN for its sine, so this is a
    # domain error, not a falsely informative [-1, 1]
    _require((alo > 1e300) | (ahi < -1e300), "sin/cos of an argument beyond 1e300 (overflowed to +-inf)")
    with np.errstate(all="ignore"):
        ya, yb = fn(alo), fn(ahi)
    lo = _ldn(np.minimum(ya, yb))
    hi = _lup(np.maximum(ya, yb))
    full = (ahi - alo >= 6.0) | (np.maximum(np.abs(alo), np.abs(ahi)) > 1e12)
    hi = np.where(full | _contains_point(alo, ahi, c_max, 2 * math.pi), 1.0, hi)
    lo = np.where(full | _contains_point(alo, ahi, c_min, 2 * math.pi), -1.0, lo)
    return np.maximum(lo, -1.0), np.minimum(hi, 1.0)


def _sin(alo, ahi, blo, bhi, und):
    return _trig(np.sin, 0.5 * math.pi, -0.5 * math.pi, alo, ahi)


def _cos(alo, ahi, blo, bhi, und):
    return _trig(np.cos, 0.0, math.pi, alo, ahi)


def _tan(alo, ahi, blo, bhi, und):
    big = np.maximum(np.abs(alo), np.abs(ahi)) > 1e12
    _require(big | (ahi - alo >= 3.0) | _contains_point(alo, ahi, 0.5 * math.pi, math.pi),
             "tan over an interval containing a pole pi/2 + k pi")
    return _mono_inc(np.tan, alo, ahi)


def _exp(alo, ahi, blo, bhi, und):
    return _mono_inc(np.exp, alo, ahi, (0.0, _INF))


def _expm1(alo, ahi, blo, bhi, und):
    return _mono_inc(np.expm1, alo, ahi, (-1.0, _INF))


def _log(alo, ahi, blo, bhi, und):
    _require(alo <= 0, "log of an interval containing numbers <= 0")
    return _mono_inc(np.log, alo, ahi)


def _log1p(alo, ahi, blo, bhi, und):
    _require(alo <= -1, "log1p of an interval containing numbers <= -1")
    return _mono_inc(np.log1p, alo, ahi)


def _asin(alo, ahi, blo, bhi, und):
    _require((alo < -1) | (ahi > 1), "asin of an interval outside [-1, 1]")
    return _mono_inc(np.arcsin, alo, ahi, (-_HALF_PI_HI, _HALF_PI_HI))


def _acos(alo, ahi, blo, bhi, und):
    _require((alo < -1) | (ahi > 1), "acos of an interval outside [-1, 1]")
    return _mono_dec(np.arccos, alo, ahi, (0.0, _PI_HI))


def _atan(alo, ahi, blo, bhi, und):
    return _mono_inc(np.arctan, alo, ahi, (-_HALF_PI_HI, _HALF_PI_HI))


def _sinh(alo, ahi, blo, bhi, und):
    return _mono_inc(np.sinh, alo, ahi)


def _cosh(alo, ahi, blo, bhi, und):
    mig, mag = _mig_mag(alo, ahi)
    lo, hi = _mono_inc(np.cosh, mig, mag, (1.0, _INF))
    return lo, hi


def _tanh(alo, ahi, blo, bhi, und):
    return _mono_inc(np.tanh, alo, ahi, (-1.0, 1.0))


def _asinh(alo, ahi, blo, bhi, und):
    return _mono_inc(np.arcsinh, alo, ahi)


def _acosh(alo, ahi, blo, bhi, und):
    _require(alo < 1, "acosh of an interval containing numbers < 1")
    return _mono_inc(np.arccosh, alo, ahi, (0.0, _INF))


def _atanh(alo, ahi, blo, bhi, und):
    _require((alo <= -1) | (ahi >= 1), "atanh of an interval not inside (-1, 1)")
    return _mono_inc(np.arctanh, alo, ahi)


def _erf(alo, ahi, blo, bhi, und):
    from scipy.special import erf

    return _mono_inc(erf, alo, ahi, (-1.0, 1.0))


def _hypot(alo, ahi, blo, bhi, und):
    amig, amag = _mig_mag(alo, ahi)
    bmig, bmag = _mig_mag(blo, bhi)
    with np.errstate(all="ignore"):
        return np.maximum(_ldn(np.hypot(amig, bmig)), 0.0), _lup(np.hypot(amag, bmag))


def _atan2(ylo, yhi, xlo, xhi, und):
    """atan2(y, x) over a box: the extreme angles are at corners unless the box meets the branch
    cut (x < 0, y = 0) or the origin, where the range is [-pi, pi]."""
    with np.errstate(all="ignore"):
        c = (np.arctan2(ylo, xlo), np.arctan2(ylo, xhi), np.arctan2(yhi, xlo), np.arctan2(yhi, xhi))
    lo = _ldn(np.minimum(np.minimum(c[0], c[1]), np.minimum(c[2], c[3])))
    hi = _lup(np.maximum(np.maximum(c[0], c[1]), np.maximum(c[2], c[3])))
    cut = (xlo <= 0) & (ylo <= 0) & (yhi >= 0)
    return np.maximum(np.where(cut, -_PI_HI, lo), -_PI_HI), np.minimum(np.where(cut, _PI_HI, hi), _PI_HI)


def _pow(alo, ahi, blo, bhi, und):
    """x**y.  A point integer exponent is an integer power (any sign of x; even powers use the
    magnitude, negative powers need 0 outside x); otherwise x must be >= 0 (> 0 where y <= 0)
    and x**y is monotone in each argument, so the range is spanned by the four corners."""
    point_int = (blo == bhi) & (np.floor(blo) == blo) & (np.abs(blo) < 2**53)
    n = np.where(point_int, blo, 0.0)
    odd = point_int & (np.fmod(n, 2.0) != 0)
    even = point_int & ~odd
    zero_in = (alo <= 0) & (ahi >= 0)
    _require(point_int & (n < 0) & zero_in, "negative integer power of an interval containing 0")
    _require(~point_int & (alo < 0), "non-integer power of an interval with negative numbers")
    _require(~point_int & (alo <= 0) & (blo <= 0),
             "power with exponent <= 0 of an interval containing 0")
    with np.errstate(all="ignore"):
        # integer powers
        mig, mag = _mig_mag(alo, ahi)
        e_lo, e_hi = np.power(mig, n), np.power(mag, n)       # |x|**n, n even
        e_lo, e_hi = np.minimum(e_lo, e_hi), np.maximum(e_lo, e_hi)
        o_a, o_b = np.power(alo, n), np.power(ahi, n)          # odd: monotone (inc n>0, dec n<0)
        o_lo, o_hi = np.minimum(o_a, o_b), np.maximum(o_a, o_b)
        # general powers: the four corners (x >= 0)
        xa, xb = np.maximum(alo, 0.0), np.maximum(ahi, 0.0)
        c = (np.power(xa, blo), np.power(xa, bhi), np.power(xb, blo), np.power(xb, bhi))
        g_lo = np.minimum(np.minimum(c[0], c[1]), np.minimum(c[2], c[3]))
        g_hi = np.maximum(np.maximum(c[0], c[1]), np.maximum(c[2], c[3]))
        lo = np.where(even, e_lo, np.where(odd, o_lo, g_lo))
        hi = np.where(even, e_hi, np.where(odd, o_hi, g_hi))
        lo, hi = _ldn(lo), _lup(hi)
        nonneg = even | ~point_int
        lo = np.where(nonneg, np.maximum(lo, 0.0), lo)
        lo = np.where(point_int & (n == 0), 1.0, lo)
        hi = np.where(point_int & (n == 0), 1.0, hi)
    return lo, hi


def _decided(lo, hi, true_mask, false_mask, und, what):
    """0/1 result of a comparison: exact where decided, [0, 1] or an error where undecided."""
    undecided = ~(true_mask | false_mask)
    if und == "error":
        _require(undecided, f"{what} undecided on the box (the two intervals overlap)")
    return (np.where(true_mask, 1.0, 0.0), np.where(false_mask, 0.0, 1.0))


def _lt(alo, ahi, blo, bhi, und):
    return _decided(alo, ahi, ahi < blo, alo >= bhi, und, "comparison a < b")


def _le(alo, ahi, blo, bhi, und):
    return _decided(alo, ahi, ahi <= blo, alo > bhi, und, "comparison a <= b")


def _eq(alo, ahi, blo, bhi, und):
    t = (alo == ahi) & (blo == bhi) & (alo == blo)
    return _decided(alo, ahi, t, (ahi < blo) | (bhi < alo), und, "comparison a == b")


def _ne(alo, ahi, blo, bhi, und):
    f = (alo == ahi) & (blo == bhi) & (alo == blo)
    return _decided(alo, ahi, (ahi < blo) | (bhi < alo), f, und, "comparison a != b")


def _truth(lo, hi):
    """(surely nonzero, surely zero) of an interval."""
    return (lo > 0) | (hi < 0), (lo == 0) & (hi == 0)


def _not(alo, ahi, blo, bhi, und):
    nz, z = _truth(alo, ahi)
    return _decided(alo, ahi, z, nz, und, "logical not")


def _and(alo, ahi, blo, bhi, und):
    anz, az = _truth(alo, ahi)
    bnz, bz = _truth(blo, bhi)
    return _decided(alo, ahi, anz & bnz, az | bz, und, "logical and")


def _or(alo, ahi, blo, bhi, und):
    anz, az = _truth(alo, ahi)
    bnz, bz = _truth(blo, bhi)
    return _decided(alo, ahi, anz | bnz, az & bz, und, "logical or")


def _if_else_zero(clo, chi, xlo, xhi, und):
    nz, z = _truth(clo, chi)
    if und == "error":
        _require(~(nz | z), "if_else condition undecided on the box (both branches possible); "
                 "split the box or use undecided='hull'")
    lo = np.where(nz, xlo, np.where(z, 0.0, np.minimum(xlo, 0.0)))
    hi = np.where(nz, xhi, np.where(z, 0.0, np.maximum(xhi, 0.0)))
    return lo, hi


_KERNELS: dict[int, tuple[int, Callable]] = {
    ca.OP_ADD: (2, _add), ca.OP_SUB: (2, _sub), ca.OP_MUL: (2, _mul), ca.OP_DIV: (2, _div),
    ca.OP_NEG: (1, _neg), ca.OP_TWICE: (1, _twice), ca.OP_INV: (1, _inv), ca.OP_SQ: (1, _sq),
    ca.OP_SQRT: (1, _sqrt), ca.OP_ASSIGN: (1, _assign), ca.OP_FABS: (1, _fabs),
    ca.OP_SIGN: (1, _sign), ca.OP_FLOOR: (1, _floor), ca.OP_CEIL: (1, _ceil),
    ca.OP_FMIN: (2, _fmin), ca.OP_FMAX: (2, _fmax), ca.OP_COPYSIGN: (2, _copysign),
    ca.OP_SIN: (1, _sin), ca.OP_COS: (1, _cos), ca.OP_TAN: (1, _tan), ca.OP_EXP: (1, _exp),
    ca.OP_EXPM1: (1, _expm1), ca.OP_LOG: (1, _log), ca.OP_LOG1P: (1, _log1p),
    ca.OP_ASIN: (1, _asin), ca.OP_ACOS: (1, _acos), ca.OP_ATAN: (1, _atan),
    ca.OP_SINH: (1, _sinh), ca.OP_COSH: (1, _cosh), ca.OP_TANH: (1, _tanh),
    ca.OP_ASINH: (1, _asinh), ca.OP_ACOSH: (1, _acosh), ca.OP_ATANH: (1, _atanh),
    ca.OP_ERF: (1, _erf), ca.OP_HYPOT: (2, _hypot), ca.OP_ATAN2: (2, _atan2),
    ca.OP_POW: (2, _pow), ca.OP_CONSTPOW: (2, _pow),
    ca.OP_LT: (2, _lt), ca.OP_LE: (2, _le), ca.OP_EQ: (2, _eq), ca.OP_NE: (2, _ne),
    ca.OP_NOT: (1, _not), ca.OP_AND: (2, _and), ca.OP_OR: (2, _or),
    ca.OP_IF_ELSE_ZERO: (2, _if_else_zero),
}
#: Pseudo op code: a multiplication whose second argument is a constant.
_OP_MULC = -1
_KERNELS[_OP_MULC] = (2, _mulc)
_OP_NAMES[_OP_MULC] = "mul"

# ---------------------------------------------------------------------------- stacked kernels
# The four most frequent ops once more, on the stacked bounds A = V[:, a], B = V[:, b] of shape
# (2, g, nb) (row 0 lower, row 1 upper bounds), writing into ``out`` = V[:, start:stop]: the same
# roundings as the kernels above (bit for bit, up to the sign of a zero bound) in about a third
# of the numpy calls, which dominate for the few boxes of a reachability step.
_DIRS = np.array([-_INF, _INF]).reshape(2, 1, 1)    # row 0 rounds down, row 1 up
_SIGNS = np.array([-1.0, 1.0]).reshape(2, 1, 1)


def _round_pair(S, out):
    """``out[0] = _dn(S[0])``, ``out[1] = _up(S[1])`` (``S`` is not modified)."""
    if _ROUNDING.nextafter:
        return np.nextafter(S, _DIRS, out=out)
    np.minimum(S[0], _FMAX, out=out[0])
    np.maximum(S[1], -_FMAX, out=out[1])
    t = np.abs(out)
    t *= _ULP_REL
    t += _ETA
    t *= _SIGNS          # x - y == x + (-y) exactly
    return np.add(out, t, out=out)


def _add2(A, B, out):
    S = A + B
    keep = (A == 0) | (B == 0) | (S == 0)   # exact: an addend 0, or an exact 0 sum (see _sum_dn)
    _round_pair(S, out)
    np.copyto(out, S, where=keep)


def _sub2(A, B, out):
    Bs = B[::-1]                            # lo = alo - bhi, hi = ahi - blo
    S = A - Bs
    keep = (A == 0) | (Bs == 0) | (S == 0)
    _round_pair(S, out)
    np.copyto(out, S, where=keep)


def _corners2(P, out_shape):
    """Hull (``fmin``/``fmax``, see :func:`_corners`) of the four corners ``P`` (2, 2, g, nb)."""
    P = P.reshape(4, *out_shape)
    S = np.empty((2, *out_shape))
    np.fmin.reduce(P, axis=0, out=S[0])
    np.fmax.reduce(P, axis=0, out=S[1])
    return S


def _mul2(A, B, out):
    S = _corners2(A[:, None] * B[None, :], A.shape[1:])
    _round_pair(S, out)
    exact0 = (A == 0).all(axis=0) | (B == 0).all(axis=0)   # a factor is exactly 0
    np.copyto(out, 0.0, where=exact0)


def _div2(A, B, out):
    _require((B[0] <= 0) & (B[1] >= 0), "division by an interval containing 0")
    _round_pair(_corners2(A[:, None] / B[None, :], A.shape[1:]), out)


def _addsub2(A, B, out, neg):
    """Additions and subtractions (``neg`` (g, 1): the subtractions) in one group."""
    Bp = np.where(neg, -B[::-1], B)
    _add2(A, Bp, out)


def _muldiv2(A, B, out, isdiv, ismul):
    """Products and quotients (``isdiv`` (g, 1): the divisions) in one group: the corners of
    each entry's own op, the exact-zero rule of :func:`_mul` only for ``mul`` entries (``ismul``,
    not the constant products of :func:`_mulc`), the zero-divisor check only for divisions."""
    _require(isdiv & (B[0] <= 0) & (B[1] >= 0), "division by an interval containing 0")
    Aa, Bb = A[:, None], B[None, :]
    S = _corners2(np.where(isdiv, Aa / Bb, Aa * Bb), A.shape[1:])
    _round_pair(S, out)
    exact0 = ismul & ((A == 0).all(axis=0) | (B == 0).all(axis=0))
    np.copyto(out, 0.0, where=exact0)


_STACKED: dict[int, Callable] = {ca.OP_ADD: _add2, ca.OP_SUB: _sub2, ca.OP_MUL: _mul2,
                                 ca.OP_DIV: _div2}

#: CasADi operation codes the evaluator bounds (besides OP_INPUT, OP_OUTPUT, OP_CONST).
SUPPORTED_OPS = tuple(sorted({_OP_NAMES[k] for k in _KERNELS}))
#: Pseudo op code: a group of additions and subtractions (scheduled as one class; a subtraction
#: ``a - b`` is the addition ``a + (-b)``, the same IEEE result, so the same rounding).
_OP_ADDSUB = -2
_OP_NAMES[_OP_ADDSUB] = "add/sub"
_KERNELS[_OP_ADDSUB] = (2, None)   # stacked kernel only (add and sub have no kink test)
#: Pseudo op code: a group of multiplications (``mul``, ``mul`` by a constant) and divisions,
#: scheduled as one class: each entry keeps its own op's products or quotients and rounding.
_OP_MULDIV = -3
_OP_NAMES[_OP_MULDIV] = "mul/div"
_KERNELS[_OP_MULDIV] = (2, None)
#: op code -> scheduling class (ops of one class may share a group)
_CLASS = {ca.OP_SUB: ca.OP_ADD, _OP_MULC: ca.OP_MUL, ca.OP_DIV: ca.OP_MUL}
UNDECIDED = ("error", "hull")
KINKS = ("bound", "error")


def _strictly_inside0(lo, hi):
    return (lo < 0) & (hi > 0)


def _touches0(lo, hi):   # a jump at 0 inside or at an end (sign(0) = 0 differs from both sides)
    return (lo <= 0) & (hi >= 0) & ~((lo == 0) & (hi == 0))


#: Where an op is not differentiable (a kink or a jump) inside the box: (alo, ahi, blo, bhi) -> mask.
_KINK_TESTS: dict[int, Callable] = {
    ca.OP_FABS: lambda al, ah, bl, bh: _strictly_inside0(al, ah),
    ca.OP_SIGN: lambda al, ah, bl, bh: _touches0(al, ah),
    ca.OP_COPYSIGN: lambda al, ah, bl, bh: _strictly_inside0(al, ah) | _touches0(bl, bh),
    ca.OP_FMIN: lambda al, ah, bl, bh: (al < bh) & (bl < ah),
    ca.OP_FMAX: lambda al, ah, bl, bh: (al < bh) & (bl < ah),
    ca.OP_FLOOR: lambda al, ah, bl, bh: np.floor(al) != np.floor(ah),
    ca.OP_CEIL: lambda al, ah, bl, bh: np.ceil(al) != np.ceil(ah),
}


# ---------------------------------------------------------------------------- compilation
@dataclass(frozen=True)
class _Group:
    op: int
    start: int          # first value row written by the group
    stop: int
    a: np.ndarray | slice    # value rows of the first argument (a slice if consecutive)
    b: np.ndarray | slice | None
    instr: np.ndarray   # CasADi instruction index of each row (for messages)


def _rows_or_slice(rows: list[int]) -> np.ndarray | slice:
    """Value rows read by a group: a slice (a view, no copy) when they are consecutive."""
    r = np.asarray(rows, dtype=np.int64)
    if r.size and np.all(np.diff(r) == 1):
        return slice(int(r[0]), int(r[-1]) + 1)
    return r


def _as_sx(fun: ca.Function) -> ca.Function:
    if not isinstance(fun, ca.Function):
        raise ProblemError(f"fun must be a casadi.Function; got {type(fun).__name__}")
    if fun.is_a("SXFunction"):
        return fun
    try:
        out = fun.expand()
    except Exception as exc:
        raise ProblemError(f"Function {fun.name()!r} ({fun.class_name()}) cannot be expanded to an "
                           f"SX Function for interval evaluation: {exc}") from exc
    if not out.is_a("SXFunction"):
        raise ProblemError(f"Function {fun.name()!r} expanded to {out.class_name()}, not an SX "
                           "Function; interval evaluation needs SX")
    return out


def _schedule(ops: list[int], args: list[tuple[int, ...]]) -> list[list[int]]:
    """Group operation nodes into batches of one op code whose arguments are all computed.

    List scheduling on the DAG (``args[i]``: the operation nodes node ``i`` reads): at every step
    the op code of the ready node with the longest path still below it is run, for *all* ready
    nodes of that code.  This gives far fewer groups than grouping by (depth, op) (e.g. 27 instead
    of 53 for the spatial CR3BP Hessian), and so fewer numpy calls per evaluation.  ``ops`` may be
    scheduling classes (:data:`_CLASS`: add with sub, mul with div), whose mixed groups run as
    one stacked kernel.
    """
    n = len(ops)
    users: list[list[int]] = [[] for _ in range(n)]
    waiting = [len(set(a)) for a in args]
    for i, a in enumerate(args):
        for j in set(a):
            users[j].append(i)
    height = [0] * n
    for i in range(n - 1, -1, -1):          # instructions are in topological order
        for j in args[i]:
            height[j] = max(height[j], height[i] + 1)
    ready: dict[int, list[int]] = {}
    for i in range(n):
        if waiting[i] == 0:
            ready.setdefault(ops[i], []).append(i)
    batches = []
    while ready:
        op = max(ready, key=lambda o: (max(height[i] for i in ready[o]), len(ready[o]), -o))
        batch = ready.pop(op)
        batches.append(batch)
        for i in batch:
            for u in users[i]:
                waiting[u] -= 1
                if waiting[u] == 0:
                    ready.setdefault(ops[u], []).append(u)
    return batches


class IntervalFunction:
    """Sound interval extension of a CasADi Function, evaluated over many boxes at once.

    Built once per Function (the instruction list is analysed in ``__init__``); call with
    ``lo``/``hi``: lists (one per Function input) of arrays of shape ``(numel_i,)`` or
    ``(numel_i, B)`` (matrix inputs flattened column-major, as CasADi does; a scalar input also
    takes shape ``(B,)``; a single column broadcasts over the ``B`` boxes).  Returns a list (one
    per output) of ``(lo, hi)`` arrays of shape ``(numel_out, B)``, dense column-major (structural
    zeros are exact zeros).  :meth:`reshape` turns one of them into ``(rows, cols, B)``.

    ``undecided``: ``"error"`` (default) raises :class:`IntervalDomainError` where a comparison or
    an ``if_else`` condition is undecided on a box; ``"hull"`` returns the sound hull of both
    branches instead (wider, never wrong).

    ``kinks``: ``"bound"`` (default) bounds ``fabs``, ``sign``, ``copysign``, ``fmin``, ``fmax``,
    ``floor``, ``ceil`` exactly, also where the box contains their kink or jump.  ``"error"``
    raises there instead: then a passing evaluation of ``f`` certifies that every non-smooth op
    of ``f`` keeps one smooth branch on the box, which a derivative-based bound (a Lagrange
    remainder from the Hessian) needs -- CasADi differentiates ``fabs`` to ``sign`` and ``sign``
    to 0, so the Hessian of a kinked ``f`` alone would silently give a wrong remainder.

    ``native``: ``True`` evaluates Functions made of the correctly rounded operations
    (``+ - * /``, ``sq``, ``sqrt``, ``inv``, ``neg``, ``twice``) in a compiled C interpreter, one
    box at a time (:mod:`ocreach.intervals.kernel`: the bounds of the ``nextafter`` mode,
    ~20x faster for the few boxes of a reachability step); any failure re-runs the numpy
    evaluator, which reports it.  Without a compiler, or for other operations, numpy is used.
    """

    def __init__(self, fun: ca.Function, *, undecided: str = "error", kinks: str = "bound",
                 native: bool = False):
        if undecided not in UNDECIDED:
            raise ProblemError(f"undecided must be one of {UNDECIDED}; got {undecided!r}")
        if kinks not in KINKS:
            raise ProblemError(f"kinks must be one of {KINKS}; got {kinks!r}")
        self.undecided = undecided
        self.kinks = kinks
        self.fun = _as_sx(fun)
        f = self.fun
        self.name = f.name()
        self.names_in = [f.name_in(i) for i in range(f.n_in())]
        self.n_in, self.n_out = f.n_in(), f.n_out()
        self.in_numel = [f.sparsity_in(i).numel() for i in range(self.n_in)]
        self.out_shape = [f.sparsity_out(i).shape for i in range(self.n_out)]
        self._out_numel = [int(r * c) for r, c in self.out_shape]
        in_dense = [np.asarray(f.sparsity_in(i).find(), dtype=np.int64) for i in range(self.n_in)]
        out_dense = [np.asarray(f.sparsity_out(i).find(), dtype=np.int64) for i in range(self.n_out)]

        # --- pass 1: rename CasADi's reused work slots into single-assignment values.  Leaves:
        # input entries and constants (deduplicated); nodes: one per operation instruction.
        slot: dict[int, tuple[str, int]] = {}
        inputs: dict[tuple[int, int], int] = {}      # (input, dense index) -> leaf number
        consts: dict[float, int] = {}
        node_op: list[int] = []
        node_args: list[tuple[tuple[str, int], ...]] = []
        node_instr: list[int] = []
        outputs: list[tuple[int, int, tuple[str, int]]] = []   # (output, dense index, value)
        for k in range(f.n_instructions()):
            op = f.instruction_id(k)
            if op == ca.OP_INPUT:
                i, nz = f.instruction_input(k)
                key = (i, int(in_dense[i][nz]))
                slot[f.instruction_output(k)[0]] = ("in", inputs.setdefault(key, len(inputs)))
            elif op == ca.OP_CONST:
                v = float(f.instruction_constant(k))   # -0.0 and 0.0 are the same real number
                slot[f.instruction_output(k)[0]] = ("const", consts.setdefault(v, len(consts)))
            elif op == ca.OP_OUTPUT:
                o, nz = f.instruction_output(k)
                outputs.append((o, int(out_dense[o][nz]), slot[f.instruction_input(k)[0]]))
            elif op in _KERNELS:
                arity = _KERNELS[op][0]
                args = tuple(slot[s] for s in f.instruction_input(k)[:arity])
                if op == ca.OP_MUL and "const" in (args[0][0], args[1][0]):
                    op = _OP_MULC                      # constant second: 2 products, not 4
                    args = args if args[1][0] == "const" else (args[1], args[0])
                node_args.append(args)
                node_op.append(op)
                node_instr.append(k)
                slot[f.instruction_output(k)[0]] = ("op", len(node_op) - 1)
            else:
                name = _OP_NAMES.get(op, f"code {op}")
                hint = (" (a free SX symbol: make it a Function input)" if op == ca.OP_PARAMETER
                        else " (a call node, e.g. a Callback or external Function whose graph "
                        "the evaluator cannot see: inline it or write it in SX)"
                        if op == ca.OP_CALL else "")
                raise ProblemError(f"interval evaluation of Function {f.name()!r}: operation "
                                   f"{name!r}{hint} (instruction {k}) is not supported; "
                                   f"supported: {list(SUPPORTED_OPS)}")

        # --- pass 2: schedule the nodes into groups, lay out the value rows (inputs, constants,
        # then the groups in order, each a contiguous slice)
        op_class = [_CLASS.get(op, op) for op in node_op]
        self._instr_op = {k: (ca.OP_MUL if op == _OP_MULC else op)
                          for k, op in zip(node_instr, node_op)}
        batches = _schedule(op_class, [tuple(j for kind, j in a if kind == "op") for a in node_args])
        n_in_vals, n_const = len(inputs), len(consts)
        op_row = np.empty(len(node_op), dtype=np.int64)
        pos = n_in_vals + n_const
        for batch in batches:
            op_row[batch] = np.arange(pos, pos + len(batch))
            pos += len(batch)
        self.n_values = pos

        def row(v: tuple[str, int]) -> int:
            kind, j = v
            return j if kind == "in" else n_in_vals + j if kind == "const" else int(op_row[j])

        self._groups = []
        group_neg = []
        for batch in batches:
            op = node_op[batch[0]]
            neg = np.asarray([node_op[i] == ca.OP_SUB for i in batch])[:, None]
            if op in (ca.OP_ADD, ca.OP_SUB) and neg.any() and not neg.all():
                op = _OP_ADDSUB
            elif _CLASS.get(op, op) == ca.OP_MUL and len({node_op[i] for i in batch}) > 1:
                op = _OP_MULDIV
                neg = (np.asarray([node_op[i] == ca.OP_DIV for i in batch])[:, None],
                       np.asarray([node_op[i] == ca.OP_MUL for i in batch])[:, None])
            group_neg.append(neg)
            a = _rows_or_slice([row(node_args[i][0]) for i in batch])
            b = (_rows_or_slice([row(node_args[i][1]) for i in batch])
                 if _KERNELS[op][0] == 2 else None)
            start = int(op_row[batch[0]])
            self._groups.append(_Group(op, start, start + len(batch), a, b,
                                       np.asarray([node_instr[i] for i in batch], dtype=np.int64)))
        self._group_neg = group_neg
        self._starts = np.asarray([g.start for g in self._groups], dtype=np.int64)
        self._plan = [(g, _KERNELS[g.op][1], isinstance(g.a, slice), isinstance(g.b, slice),
                       functools.partial(_addsub2, neg=neg) if g.op == _OP_ADDSUB
                       else functools.partial(_muldiv2, isdiv=neg[0], ismul=neg[1])
                       if g.op == _OP_MULDIV
                       else _STACKED.get(g.op) if not (kinks == "error" and g.op in _KINK_TESTS)
                       else None)
                      for g, neg in zip(self._groups, group_neg)]
        self._max_group = max((g.stop - g.start for g in self._groups), default=1)
        # input gathers: per Function input, the value rows and the dense entries they read
        keys = sorted(inputs, key=inputs.get)
        self._in_gather = []
        for i in range(self.n_in):
            rows = [inputs[key] for key in keys if key[0] == i]
            self._in_gather.append((np.asarray(rows, dtype=np.int64),
                                    np.asarray([key[1] for key in keys if key[0] == i], dtype=np.int64)))
        self._const_rows = slice(n_in_vals, n_in_vals + n_const)
        self._const_vals = np.asarray(sorted(consts, key=consts.get), dtype=float)[:, None]
        self._op_start = n_in_vals + n_const
        self._out_rows = [np.asarray([row(v) for (o, d, v) in outputs if o == i], dtype=np.int64)
                          for i in range(self.n_out)]
        self._out_dense = [np.asarray([d for (o, d, v) in outputs if o == i], dtype=np.int64)
                           for i in range(self.n_out)]
        self.n_ops = len(node_op)
        if not isinstance(native, (bool, np.bool_)):
            raise ProblemError(f"native must be True or False; got {native!r}")
        #: the compiled kernel (:mod:`ocreach.intervals.kernel`), built on the first call
        #: when ``native=True``; False when not wanted or not available
        self._native: Any = None if native else False

    # ------------------------------------------------------------------ evaluation
    @property
    def n_groups(self) -> int:
        """Number of vectorised numpy steps (operation groups) per evaluation."""
        return len(self._groups)

    def _check_inputs(self, lo, hi) -> tuple[list[np.ndarray], list[np.ndarray], int]:
        name = self.name
        if not isinstance(lo, (list, tuple)) or not isinstance(hi, (list, tuple)) \
                or len(lo) != self.n_in or len(hi) != self.n_in:
            raise ProblemError(f"lo and hi must be lists of {self.n_in} arrays (one per input of "
                               f"Function {name!r}: {self.names_in})")
        los, his, widths = [], [], set()
        for i in range(self.n_in):
            arg = self.names_in[i]
            l = np.asarray(lo[i], dtype=float)
            h = np.asarray(hi[i], dtype=float)
            n = self.in_numel[i]
            shape_1d = (1, -1) if n == 1 else (-1, 1)   # a scalar input: (B,) is B boxes
            l = l.reshape(shape_1d) if l.ndim <= 1 else l
            h = h.reshape(shape_1d) if h.ndim <= 1 else h
            if l.ndim != 2 or h.ndim != 2 or l.shape[0] != n or h.shape != l.shape:
                raise ProblemError(f"input {arg!r} of {name!r}: lo and hi must have shape ({n},) "
                                   f"or ({n}, B); got {np.shape(lo[i])} and {np.shape(hi[i])}")
            if not (np.isfinite(l).all() and np.isfinite(h).all()):
                raise ProblemError(f"input {arg!r} of {name!r}: box bounds must be finite; "
                                   f"got lo={l.ravel()[:8]!r}, hi={h.ravel()[:8]!r}")
            if (l > h).any():
                j, b = np.argwhere(l > h)[0]
                raise ProblemError(f"input {arg!r} of {name!r}: inverted box (lo > hi) at entry "
                                   f"{j} of box {b}: lo={l[j, b]!r} > hi={h[j, b]!r}")
            if n:
                widths.add(l.shape[1])
            los.append(l)
            his.append(h)
        widths.discard(1)
        if len(widths) > 1:
            raise ProblemError(f"inputs of {name!r} have different numbers of boxes {sorted(widths)}; "
                               "give each input B columns (or 1 to broadcast)")
        B = widths.pop() if widths else 1
        return los, his, B

    def _trusted_inputs(self, lo, hi) -> tuple[list[np.ndarray], list[np.ndarray], int]:
        """Shapes only (``check=False``): float arrays of the documented shapes from the caller."""
        los, his, B = [], [], 1
        for i, n in enumerate(self.in_numel):
            l, h = lo[i], hi[i]
            if l.ndim <= 1:
                shape_1d = (1, -1) if n == 1 else (-1, 1)
                l, h = l.reshape(shape_1d), h.reshape(shape_1d)
            if n and l.shape[1] != 1:
                B = l.shape[1]
            los.append(l)
            his.append(h)
        return los, his, B

    def __call__(self, lo: Sequence, hi: Sequence, *, check: bool = True
                 ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Bounds over the boxes (class docstring).  ``check=False`` skips the validation of the
        inputs (shapes, finiteness, ``lo <= hi``) for internal callers that pass float arrays of
        the right shapes; non-finite results are still reported by the NaN guard and the caller."""
        los, his, B = self._check_inputs(lo, hi) if check else self._trusted_inputs(lo, hi)
        if self._native is None:
            from ocreach.intervals.kernel import build_interval_kernel
            self._native = build_interval_kernel(self) or False
        if self._native:
            res = self._native(los, his, B)
            if res is not None:
                return res
            # a flagged failure (domain error, NaN): numpy reports it (or bounds it its own way)
        outs = [(np.zeros((k, B)), np.zeros((k, B))) for k in self._out_numel]
        cache_chunk = int(np.clip(CHUNK_GROUP_ELEMS // max(self._max_group, 1), 256, 2048))
        chunk = max(1, min(B, cache_chunk, CHUNK_BYTES // (16 * max(self.n_values, 1))))
        previous = _ROUNDING.nextafter
        _ROUNDING.nextafter = self._max_group * B <= NEXTAFTER_MAX
        try:
            for s in range(0, B, chunk):
                e = min(B, s + chunk)
                self._eval_chunk(los, his, s, e, outs)
        finally:
            _ROUNDING.nextafter = previous
        return outs

    def _eval_chunk(self, los, his, s, e, outs):
        # lower and upper bounds in one array V[0], V[1]: one gather per argument of a group
        nb = e - s
        V = np.empty((2, self.n_values, nb))
        for i, (rows, idx) in enumerate(self._in_gather):
            if rows.size:
                li, hi_ = los[i], his[i]
                V[0, rows] = li[idx] if li.shape[1] == 1 else li[idx, s:e]
                V[1, rows] = hi_[idx] if hi_.shape[1] == 1 else hi_[idx, s:e]
        V[:, self._const_rows] = self._const_vals
        und = self.undecided
        kink_check = self.kinks == "error"
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            for g, fn, a_slice, b_slice, fn2 in self._plan:
                try:
                    # ndarray.take is several times faster than fancy indexing on small arrays
                    A = V[:, g.a] if a_slice else V.take(g.a, axis=1)
                    if fn2 is not None:
                        fn2(A, V[:, g.b] if b_slice else V.take(g.b, axis=1),
                            V[:, g.start:g.stop])
                        continue
                    if g.b is None:
                        args = (A[0], A[1], None, None)
                    else:
                        Bv = V[:, g.b] if b_slice else V.take(g.b, axis=1)
                        args = (A[0], A[1], Bv[0], Bv[1])
                    if kink_check and g.op in _KINK_TESTS:
                        _require(_KINK_TESTS[g.op](*args), "non-smooth point (kink or jump of "
                                 "the op) inside the box, so derivative-based bounds of this "
                                 "function do not hold there; split the box")
                    rlo, rhi = fn(*args, und)
                except _Fail as fail:
                    self._raise(fail.mask, fail.reason, g, los, his, s)
                V[0, g.start:g.stop] = rlo
                V[1, g.start:g.stop] = rhi
        # NaN guard, once per chunk: values are never overwritten, so a NaN made by any group is
        # still in its row (NaN arguments make later comparisons undecided, i.e. errors, too)
        bad = np.isnan(V[:, self._op_start:]).any(axis=0)
        if bad.any():
            r0 = self._op_start + int(np.argwhere(bad)[0][0])
            g = self._groups[int(np.searchsorted(self._starts, r0, side="right")) - 1]
            self._raise(bad[g.start - self._op_start:g.stop - self._op_start],
                        "the bound is not a number (an overflow to inf, then inf - inf or 0 * inf)",
                        g, los, his, s)
        for i, (olo, ohi) in enumerate(outs):
            O = V.take(self._out_rows[i], axis=1)
            olo[self._out_dense[i], s:e] = O[0]
            ohi[self._out_dense[i], s:e] = O[1]

    def _raise(self, mask, reason, g: _Group, los, his, offset):
        r, c = np.argwhere(mask)[0]
        box = int(offset + c)
        inputs = [(l[:, 0 if l.shape[1] == 1 else box].copy(), h[:, 0 if h.shape[1] == 1 else box].copy())
                  for l, h in zip(los, his)]
        real = self._instr_op.get(int(g.instr[r]), g.op)   # a mixed group: the entry's op
        op = _OP_NAMES.get(real, str(real))

        def fmt(a):   # repr of each float (exact, round-trips); cheap, unlike array2string
            items = [repr(float(v)) for v in a[:24]]
            return "[" + ", ".join(items) + (", ..." if a.size > 24 else "") + "]"

        desc = "; ".join(f"{self.names_in[i]}: lo={fmt(l)} hi={fmt(h)}"
                         for i, (l, h) in enumerate(inputs))
        extra = (" A primary (a singularity of the dynamics, e.g. the centre of a body) may lie "
                 "inside the box: shrink or split the box, or move it away from the singularity."
                 if real in (ca.OP_DIV, ca.OP_INV, ca.OP_POW, ca.OP_CONSTPOW, ca.OP_LOG, ca.OP_TAN)
                 else "")
        raise IntervalDomainError(
            f"interval evaluation of {self.name!r} failed at instruction {int(g.instr[r])} "
            f"({op}): {reason}, on box {box}: {desc}.{extra}", op=op, box=box, inputs=inputs) from None

    # ------------------------------------------------------------------ helpers
    def reshape(self, out: tuple[np.ndarray, np.ndarray], i: int) -> tuple[np.ndarray, np.ndarray]:
        """Output ``i`` (as returned by ``__call__``) reshaped to ``(rows, cols, B)``."""
        rows, cols = self.out_shape[i]
        return tuple(np.reshape(a, (cols, rows, a.shape[-1])).transpose(1, 0, 2) for a in out)

    def __repr__(self) -> str:
        return (f"IntervalFunction({self.name!r}: {self.n_ops} operations in "
                f"{len(self._groups)} groups, {self.n_values} values)")


def interval_function(fun: ca.Function, *, model: Any = None, key: Any = None,
                      undecided: str = "error", kinks: str = "bound",
                      native: bool = False) -> IntervalFunction:
    """:class:`IntervalFunction` of ``fun``, cached through ``model.cached`` when ``model`` is
    given (``key`` defaults to the Function's name); ``native=True`` evaluates it in compiled C
    where it can (:mod:`ocreach.intervals.kernel`, the same bounds)."""
    if model is None:
        return IntervalFunction(fun, undecided=undecided, kinks=kinks, native=native)
    k = ("intervals", key if key is not None else fun.name(), undecided, kinks, native)
    return model.cached(k, lambda: IntervalFunction(fun, undecided=undecided, kinks=kinks,
                                                    native=native))


# ---------------------------------------------------------------------------- sub-box splitting
def split_boxes(lo: Sequence, hi: Sequence, splits: int, *, max_boxes: int = 4096,
                dims: Sequence[tuple[int, int]] | None = None) -> tuple[list, list, int]:
    """Split one box (lists of ``(n_i,)`` arrays per input) into a uniform grid of sub-boxes.

    The widest entries (over all inputs; or the ``(input, entry)`` pairs in ``dims``) are cut into
    ``splits`` pieces each, as many entries as fit into ``max_boxes`` sub-boxes.  Neighbouring
    sub-boxes share their cut points exactly, so the sub-boxes cover the box.  Returns
    ``(lo_list, hi_list, S)`` with arrays of shape ``(n_i, S)``.
    """
    splits = check_count("splits", splits, 1)
    max_boxes = check_count("max_boxes", max_boxes, 1)
    lo = [np.asarray(a, dtype=float).ravel() for a in lo]
    hi = [np.asarray(a, dtype=float).ravel() for a in hi]
    if dims is None:
        cand = sorted(((float(h[j] - l[j]), i, j) for i, (l, h) in enumerate(zip(lo, hi))
                       for j in range(l.size) if h[j] > l[j]), reverse=True)
        n_dims = 0 if splits == 1 else math.floor(math.log(max_boxes) / math.log(splits) + 1e-12)
        dims = [(i, j) for (_, i, j) in cand[:n_dims]]
    dims = list(dims)
    if splits ** len(dims) > max_boxes:
        raise ProblemError(f"splits={splits} over {len(dims)} dims gives {splits ** len(dims)} "
                           f"sub-boxes > max_boxes={max_boxes}")
    S = splits ** len(dims)
    out_lo = [np.repeat(l[:, None], S, axis=1) for l in lo]
    out_hi = [np.repeat(h[:, None], S, axis=1) for h in hi]
    if dims:
        grid = np.indices((splits,) * len(dims)).reshape(len(dims), S)
        for d, (i, j) in enumerate(dims):
            cuts = lo[i][j] + (hi[i][j] - lo[i][j]) * (np.arange(splits + 1) / splits)
            cuts[0], cuts[-1] = lo[i][j], hi[i][j]
            cuts = np.maximum.accumulate(np.clip(cuts, lo[i][j], hi[i][j]))
            out_lo[i][j] = cuts[grid[d]]
            out_hi[i][j] = cuts[grid[d] + 1]
    return out_lo, out_hi, S


def bound(fun: ca.Function | IntervalFunction, lo: Sequence, hi: Sequence, *, splits: int = 1,
          max_boxes: int = 4096, dims: Sequence[tuple[int, int]] | None = None
          ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Interval bound of ``fun`` over one box, tightened by splitting it into sub-boxes.

    ``lo``/``hi``: lists of ``(n_i,)`` arrays (one per input).  With ``splits = k`` the widest
    entries are each cut into ``k`` pieces (as many as fit into ``max_boxes`` sub-boxes, see
    :func:`split_boxes`); the result is the union hull over the sub-boxes, as a list of
    ``(lo, hi)`` arrays of shape ``(numel_out,)``.
    """
    ifun = fun if isinstance(fun, IntervalFunction) else IntervalFunction(fun)
    ifun._check_inputs([np.asarray(a, dtype=float).ravel() for a in lo],
                       [np.asarray(a, dtype=float).ravel() for a in hi])
    slo, shi, _ = split_boxes(lo, hi, splits, max_boxes=max_boxes, dims=dims)
    return [(l.min(axis=1), h.max(axis=1)) for (l, h) in ifun(slo, shi)]


# ---------------------------------------------------------------------------- model bounds
Box = tuple[Any, Any]


class ModelIntervals:
    """Interval bounds of a :class:`ocreach.model.Model`'s ``f``, Jacobians and Hessian tensor.

    Every method takes boxes ``x = (lo, hi)``, ``u = (lo, hi)`` with arrays of shape ``(n,)`` or
    ``(n, B)`` (``u`` is required: the control set enters every remainder); ``t`` a number, a
    ``(B,)`` array or a box ``(lo, hi)`` (default 0); ``p`` ``None`` (the model's defaults), a
    vector or a box.  Get it with :func:`for_model` (cached on the model).
    """

    def __init__(self, model: Any, undecided: str = "error"):
        self.model = model
        self.undecided = undecided

    FUNCTIONS = ("f", "jac", "hessian", "all")

    def function(self, what: str, kinks: str = "bound") -> IntervalFunction:
        """The :class:`IntervalFunction` behind :meth:`f` (``"f"``, the model's ``f_fun``),
        :meth:`jacobians` (``"jac"``, ``jac_fun``), :meth:`hessian` (``"hessian"``) and
        :meth:`all` (``"all"``), built once per model (``Model.cached``); inputs ``(x, u, t, p)``."""
        if what not in self.FUNCTIONS:
            raise ProblemError(f"unknown model interval function {what!r}; allowed: "
                               f"{list(self.FUNCTIONS)}")
        m = self.model

        def build() -> ca.Function:
            args = [m.x, m.u, m.t, m.p]
            names = ["x", "u", "t", "p"]
            if what == "f":
                return m.f_fun
            if what == "jac":
                return m.jac_fun
            if what == "hessian":
                return ca.Function("f_hessian", args, [m.derivative_expressions(2)[1]], names, ["H"])
            d1, d2 = m.derivative_expressions(2)[:2]
            return ca.Function("f_jac_hess", args, [m.f, d1, d2], names, ["f", "J", "H"])

        return m.cached(("intervals", "model", what, self.undecided, kinks),
                        lambda: IntervalFunction(build(), undecided=self.undecided, kinks=kinks))

    def _args(self, x: Box, u: Box, t, p) -> tuple[list, list]:
        m = self.model
        t = (t, t) if np.ndim(t) == 0 or (not isinstance(t, tuple)) else t
        if p is None:
            p = (m.p_default, m.p_default)
        elif not isinstance(p, tuple):
            p = (p, p)
        lo = [x[0], u[0], np.reshape(np.asarray(t[0], dtype=float), (1, -1)), p[0]]
        hi = [x[1], u[1], np.reshape(np.asarray(t[1], dtype=float), (1, -1)), p[1]]
        return lo, hi

    def f(self, x: Box, u: Box, t=0.0, p=None) -> tuple[np.ndarray, np.ndarray]:
        """Bound of ``f(x, u, t; p)``: ``(lo, hi)`` of shape ``(n_x, B)``."""
        return self.function("f")(*self._args(x, u, t, p))[0]

    def jacobians(self, x: Box, u: Box, t=0.0, p=None) -> list[tuple[np.ndarray, np.ndarray]]:
        """Bounds of ``[f, df/dx, df/du]``: shapes ``(n_x, B)``, ``(n_x, n_x, B)``, ``(n_x, n_u, B)``."""
        F = self.function("jac")
        out = F(*self._args(x, u, t, p))
        return [out[0], F.reshape(out[1], 1), F.reshape(out[2], 2)]

    def check_smooth(self, x: Box, u: Box, t=0.0, p=None) -> None:
        """Raise :class:`IntervalDomainError` unless every non-smooth op of ``f`` (``fabs``,
        ``sign``, ``fmin``, ``if_else`` ...) keeps one smooth branch on the boxes: the condition
        for derivative bounds (:meth:`hessian`, :meth:`all`) to bound a Taylor remainder."""
        self.function("f", kinks="error")(*self._args(x, u, t, p))

    def hessian(self, x: Box, u: Box, t=0.0, p=None, *, smooth_check: bool = True
                ) -> tuple[np.ndarray, np.ndarray]:
        """Bound of the Hessian tensor ``H[i, a, b] = d^2 f_i / dz_a dz_b``, ``z = (x, u)``:
        ``(lo, hi)`` of shape ``(n_x, n_z, n_z, B)`` (Foss et al. Eq. 11 layout, as
        :meth:`ocreach.model.Model.tensors`).  ``smooth_check`` first runs :meth:`check_smooth`."""
        if smooth_check:
            self.check_smooth(x, u, t, p)
        F = self.function("hessian")
        return self._hess(F, F(*self._args(x, u, t, p))[0])

    def all(self, x: Box, u: Box, t=0.0, p=None, *, smooth_check: bool = True
            ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """``f`` (n_x, B), ``J = df/dz`` (n_x, n_z, B) and ``H`` (n_x, n_z, n_z, B) in one pass
        (after :meth:`check_smooth` unless ``smooth_check=False``)."""
        if smooth_check:
            self.check_smooth(x, u, t, p)
        F = self.function("all")
        out = F(*self._args(x, u, t, p))
        return {"f": out[0], "J": F.reshape(out[1], 1), "H": self._hess(F, out[2])}

    def _hess(self, F: IntervalFunction, out, i: int = -1):
        m = self.model
        lo, hi = F.reshape(out, F.n_out - 1 if i < 0 else i)
        B = lo.shape[-1]
        return (lo.reshape(m.n_x, m.n_z, m.n_z, B), hi.reshape(m.n_x, m.n_z, m.n_z, B))


def for_model(model: Any, *, undecided: str = "error") -> ModelIntervals:
    """The :class:`ModelIntervals` of ``model`` (cached with ``model.cached``)."""
    if undecided not in UNDECIDED:
        raise ProblemError(f"undecided must be one of {UNDECIDED}; got {undecided!r}")
    return model.cached(("intervals", "model", undecided), lambda: ModelIntervals(model, undecided))
