"""The outward-rounded interval operations: one numpy kernel per CasADi operation code.

Every kernel bounds one operation over a group of entries at once (arrays of shape ``(g, B)``:
``g`` entries of one operation, ``B`` boxes); :mod:`ocreach.intervals.evaluator` runs them on the
schedule of :mod:`ocreach.intervals.walker`.  This is the arithmetic behind the remainders of Patel &
Subbarao's methods (the Lagrange remainder of Method 1, Eq. 13-15; ``R_err`` of Method 2, Eq. 25).

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
* Where no finite bound exists a kernel raises :class:`_Fail` with the mask of the entries
  concerned (the evaluator turns it into :class:`~ocreach.intervals.IntervalDomainError`, naming
  the op and the box): division by (or a negative power of) an interval containing 0, ``sqrt``/
  ``log`` of negative numbers, a pole of ``tan``, and an ``if_else`` whose condition is undecided
  on the box (or a comparison feeding one).

Besides the kernels: the rounding mode (:data:`_ROUNDING`, thread-local), the op tables
(:data:`_KERNELS`: op code -> (arity, kernel); :data:`_STACKED`: the four most frequent ops on
stacked bounds), the pseudo op codes of the schedule (:data:`_OP_MULC`, :data:`_OP_ADDSUB`,
:data:`_OP_MULDIV`) and the scheduling classes (:data:`_CLASS`), :data:`SUPPORTED_OPS` and the
kink tests of the non-smooth ops (:data:`_KINK_TESTS`).  Imports numpy, SciPy (``erf``) and CasADi
only.
"""
from __future__ import annotations

import math
import threading
from collections.abc import Callable

import casadi as ca
import numpy as np

#: Relative outward margin after a libm/SIMD function (64 ulps of the result).
LIBM_REL = 2.0**-46
#: Absolute outward margin after a libm/SIMD function (covers results in the subnormal range).
LIBM_ABS = 2.0**-1000


class _RoundingMode(threading.local):
    """The rounding mode of the evaluation in progress in this thread (set by
    ``IntervalFunction.__call__``; thread-local, so concurrent evaluations in other threads keep
    their own)."""

    nextafter = False


_ROUNDING = _RoundingMode()

#: CasADi op code -> operation name (for messages), plus the pseudo op codes below
_OP_NAMES = {getattr(ca, n): n[3:].lower() for n in dir(ca) if n.startswith("OP_")}
_INF = np.inf
_PI_LO = 3.141592653589793          # float(pi) < pi
_PI_HI = np.nextafter(_PI_LO, _INF)
_HALF_PI_LO = _PI_LO / 2            # exact halving
_HALF_PI_HI = _PI_HI / 2


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
    :data:`~ocreach.intervals.evaluator.NEXTAFTER_MAX`) the one ``np.nextafter`` call (exactly
    the predecessor) is faster than these five.  An overflowed ``x = +inf`` (the exact value is
    a finite number above the largest float) gives a float just below the largest float
    (``nextafter``: the largest float); NaN stays NaN."""
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

