"""Sound interval evaluation (ocreach.intervals) against independent truth.

* Every model in ``ocreach.models``: ``f``, its Jacobians and the Hessian tensor on random boxes
  against a sequential ``mpmath.iv`` interpreter of the same graph (``tests/_interval_truth.py``):
  the rigorous mpmath interval must lie inside ours, and ours may be wider by at most
  ``TIGHT_REL * width_mpmath + TIGHT_MAG * |bound|`` (the one-ulp outward steps and the 2**-46
  libm margin, accumulated through the graph).
* Every operation code individually against high-precision mpmath values at the box corners,
  zeros and extrema (the exact range for these functions) and random interior points.
* Domain errors, undecided branches, input validation, sub-box splitting, model helpers, and
  hypothesis property tests on random expression graphs (CasADi's own float values inside).
"""
from __future__ import annotations

import math
import zlib

import casadi as ca
import numpy as np
import pytest
from _interval_truth import Reference, as_arrays
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from mpmath import mp

from ocreach.errors import ProblemError
from ocreach.intervals import IntervalDomainError, IntervalFunction, ops
from ocreach.intervals import evaluator as iv
from ocreach.models import cr3bp, ephemeris_synodic, twobody, vanderpol
from ocreach.models.reentry import reentry
from ocreach.units import Units

#: Allowed excess of our width over mpmath's: relative to mpmath's width ...
TIGHT_REL = 1e-9
#: ... plus relative to the magnitude of the bound (rounding accumulated over the graph).
TIGHT_MAG = 1e-9

MU = 0.01215058560962404
EM = Units(length=384400e3, time=375190.0)


def _models():
    eph = ephemeris_synodic(["earth", "moon", "sun"], "2025-01-01", 4.4, 1e-2)
    return {
        # name: (model, state centre, state spread, control box, time box, boxes for f/jac/hess)
        "cr3bp-planar": (cr3bp(MU, planar=True, a_max=0.01), [0.8, 0.05, 0.1, 0.2], 0.05,
                         ([-1, -1], [1, 1]), (0, 0), (1500, 300, 60)),
        "cr3bp-spatial": (cr3bp(MU, a_max=0.01), [1.1, 0.02, 0.1, 0.0, 0.2, 0.05], 0.05,
                          ([-1] * 3, [1] * 3), (0, 0), (1000, 200, 40)),
        "cr3bp-mass": (cr3bp(MU, variable_mass=True, thrust=0.1, isp=3000, units=EM),
                       [0.85, 0.0, 0.2, 0.0, 0.25, 0.0, 1e-3], 0.03,
                       ([-1] * 3, [1] * 3), (0, 0), (1000, 150, 30)),
        "twobody": (twobody(a_max=0.01), [1.0, 0.2, 0.1, 0.0, 1.0, 0.1], 0.1,
                    ([-1] * 3, [1] * 3), (0, 0), (1500, 300, 60)),
        "vdp": (vanderpol(), [1.0, -0.5], 1.0, ([-1], [1]), (0, 0), (2000, 1000, 500)),
        "reentry": (reentry(), [0.5, 0.8, -0.05, 0.3, 0.5, 0.1], 0.02,
                    ([0.1, -0.5], [0.3, 0.5]), (0, 0), (1000, 200, 40)),
        "ephemeris": (eph, [0.8, 0.05, 0.1, 0.0, 0.2, 0.05], 0.05, ([-1] * 3, [1] * 3),
                      (0.5, 0.5 + 1e-3), (60, 20, 5)),
    }


MODELS = _models()


def _boxes(rng, model, centre, spread, ubox, tbox, n):
    """Random boxes: centres around ``centre``, radii log-uniform in [1e-12, 1e-2] relative
    (10 % of the entries and 5 % of whole boxes are points)."""
    c = np.asarray(centre, float)[:, None] + spread * rng.normal(size=(model.n_x, n))
    r = (np.abs(c) + 1e-3) * 10.0 ** rng.uniform(-12, -2, size=c.shape)
    r *= rng.uniform(size=c.shape) > 0.1
    r[:, rng.uniform(size=n) < 0.05] = 0.0
    ul, uh = (np.asarray(a, float) for a in ubox)
    a, b = np.sort(rng.uniform(size=(2, model.n_u, n)), axis=0)
    u_lo, u_hi = ul[:, None] + (uh - ul)[:, None] * a, ul[:, None] + (uh - ul)[:, None] * b
    u_lo[:, : n // 4], u_hi[:, : n // 4] = ul[:, None], uh[:, None]   # whole control set
    t_lo, t_hi = np.full((1, n), float(tbox[0])), np.full((1, n), float(tbox[1]))
    p = np.repeat(model.p_default[:, None], n, axis=1)
    return [c - r, u_lo, t_lo, p], [c + r, u_hi, t_hi, p]


def _compare(ifun: IntervalFunction, lo, hi) -> dict:
    ours = ifun(lo, hi)
    ref = Reference(ifun.fun)
    B = lo[0].shape[1]
    worst = {"escapes": 0, "excess_width": 0.0, "excess_mag": 0.0, "n": 0, "ratio_med": []}
    for b in range(B):
        out = ref([a[:, b] for a in lo], [a[:, b] for a in hi])
        for o, (olo, ohi) in enumerate(ours):
            rl, rh = as_arrays(out[o])
            worst["escapes"] += int(np.sum((olo[:, b] > rl) | (ohi[:, b] < rh)))
            wr, wo = rh - rl, ohi[:, b] - olo[:, b]
            mag = np.maximum(np.abs(olo[:, b]), np.abs(ohi[:, b]))
            excess = wo - wr
            assert np.all(excess <= TIGHT_REL * wr + TIGHT_MAG * mag + 1e-300), \
                (o, b, np.max(excess - TIGHT_REL * wr - TIGHT_MAG * mag))
            worst["excess_mag"] = max(worst["excess_mag"], float(np.max(excess / np.maximum(mag, 1e-300))))
            big = wr > 1e-6 * np.maximum(mag, 1e-300)
            if np.any(big):
                worst["ratio_med"].append(float(np.median(wo[big] / wr[big])))
            worst["n"] += wo.size
    return worst


@pytest.mark.parametrize("name", list(MODELS))
def test_models_against_mpmath(name):
    model, centre, spread, ubox, tbox, counts = MODELS[name]
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    mi = iv.for_model(model)
    for what, n in zip(("f", "jac", "all"), counts):
        F = mi.function(what)
        lo, hi = _boxes(rng, model, centre, spread, ubox, tbox, n)
        res = _compare(F, lo, hi)
        assert res["escapes"] == 0, (name, what, res)
        if res["ratio_med"]:
            assert np.median(res["ratio_med"]) < 1 + 1e-9


@pytest.mark.parametrize("name", ["cr3bp-spatial", "reentry", "vdp"])
def test_point_boxes_match_casadi(name):
    model, centre, spread, ubox, tbox, _ = MODELS[name]
    rng = np.random.default_rng(5)
    F = iv.for_model(model).function("all")
    lo, _ = _boxes(rng, model, centre, spread, ubox, tbox, 200)
    lo[1] = np.clip(lo[1] + 0.05, *(np.asarray(a, float)[:, None] for a in ubox))
    out = F(lo, lo)
    num = F.fun.map(200)(*lo)
    for (olo, ohi), v in zip(out, num):
        v = np.asarray(ca.densify(v))           # (rows, 200 * cols), the boxes side by side
        rows = v.shape[0]
        v = v.reshape(rows, 200, -1).transpose(2, 0, 1).reshape(-1, 200)   # column-major per box
        assert np.all(olo <= v) and np.all(v <= ohi)
        # a point box is a point up to the outward rounding (accumulated over the graph; the
        # Hessian entries cancel terms ~1/r^5, hence the scale max(|v|, 1))
        assert np.all(ohi - olo <= 1e-10 * np.maximum(np.abs(v), 1.0))


def test_model_helpers_shapes_and_cache():
    model = MODELS["cr3bp-spatial"][0]
    mi = iv.for_model(model)
    assert iv.for_model(model) is mi and mi.function("hessian") is mi.function("hessian")
    assert mi.function("f").fun is model.f_fun and mi.function("jac").fun is model.jac_fun
    with pytest.raises(ProblemError, match=r"'hess'.*allowed.*'hessian'"):
        mi.function("hess")
    with pytest.raises(ProblemError, match="undecided must be one of"):
        iv.for_model(model, undecided="no")
    x = np.array([0.9, 0.1, 0.05, 0.0, 0.2, 0.0])
    box = (x - 1e-3, x + 1e-3)
    ubox = (-np.ones(3), np.ones(3))
    flo, _ = mi.f(box, ubox)
    assert flo.shape == (6, 1)
    _, (A_lo, A_hi), (B_lo, B_hi) = mi.jacobians(box, ubox)
    assert A_lo.shape == (6, 6, 1) and B_lo.shape == (6, 3, 1)
    H_lo, H_hi = mi.hessian(box, ubox)
    assert H_lo.shape == (6, 9, 9, 1)
    al = mi.all(box, ubox)
    np.testing.assert_array_equal(al["H"][0], H_lo)
    # sampled points: Jacobians and Hessian (Model.tensors layout) inside the bounds
    rng = np.random.default_rng(0)
    for _ in range(20):
        xs = x + rng.uniform(-1e-3, 1e-3, 6)
        us = rng.uniform(-1, 1, 3)
        _, A, Bm = (np.asarray(v) for v in model.jac_fun(xs, us, 0.0, model.p_default))
        assert np.all(A_lo[..., 0] <= A) and np.all(A <= A_hi[..., 0])
        assert np.all(B_lo[..., 0] <= Bm) and np.all(Bm <= B_hi[..., 0])
        T = model.tensors(xs, us, order=2)
        assert np.all(H_lo[..., 0] <= T[2][:6]) and np.all(T[2][:6] <= H_hi[..., 0])
        J = T[1][:6]
        assert np.all(al["J"][0][..., 0] <= J) and np.all(J <= al["J"][1][..., 0])
    # many boxes at once, t and p as boxes
    X = x[:, None] + np.zeros((6, 5))
    lo, _ = mi.f((X - 1e-4, X + 1e-4), ubox, t=(0.0, 1.0), p=(model.p_default, model.p_default))
    assert lo.shape == (6, 5)


def test_outward_rounding_steps_pass_the_neighbouring_float():
    """_dn(x) <= pred(x) and _up(x) >= succ(x) for floats of every magnitude (subnormals, powers
    of two and their neighbours, the largest floats): every real that rounds to x is inside."""
    rng = np.random.default_rng(0)
    e = rng.integers(-1074, 1024, 200_000)
    x = np.ldexp(rng.uniform(1, 2, e.size), e) * rng.choice([-1, 1], e.size)
    p2 = np.ldexp(1.0, np.arange(-1074, 1024))
    x = np.concatenate([x, p2, -p2, np.nextafter(p2, 0), -np.nextafter(p2, 0),
                        [0.0, -0.0, np.finfo(float).max, -np.finfo(float).max]])
    x = x[np.isfinite(x)]
    with np.errstate(over="ignore"):
        assert np.all(ops._up(x) >= np.nextafter(x, np.inf))
        assert np.all(ops._dn(x) <= np.nextafter(x, -np.inf))
        assert ops._up(np.inf) == np.inf and ops._dn(-np.inf) == -np.inf
        assert 1e308 < ops._dn(np.inf) < np.inf and -np.inf < ops._up(-np.inf) < -1e308
        assert np.isnan(ops._dn(np.nan)) and np.isnan(ops._up(np.nan))
        # and by at most 3 ulps of |x| (2 in general, 3 where |x| 2**-52 underflows)
        fin = np.abs(x) < 2.0**1023
        assert np.all((ops._up(x) - x)[fin] <= 3 * np.spacing(np.abs(x[fin])))
        assert np.all((x - ops._dn(x))[fin] <= 3 * np.spacing(np.abs(x[fin])))


# ---------------------------------------------------------------------------- single ops
_X, _Y = ca.SX.sym("x"), ca.SX.sym("y")

# name: (CasADi expression in x (and y), mpmath function, sampler of (lo, hi) in x (and y),
#        critical points of x where an extremum may lie (beside 0 and the ends))
UNARY_OPS = {
    "neg": (-_X, lambda a: -a, (-5, 5)),
    "twice": (2 * _X, lambda a: 2 * a, (-5, 5)),
    "inv": (1 / _X, lambda a: 1 / a, (0.1, 5)),
    "sq": (_X**2, lambda a: a * a, (-5, 5)),
    "sqrt": (ca.sqrt(_X), mp.sqrt, (0, 5)),
    "fabs": (ca.fabs(_X), abs, (-5, 5)),
    "sign": (ca.sign(_X), mp.sign, (-5, 5)),
    "floor": (ca.floor(_X), mp.floor, (-5, 5)),
    "ceil": (ca.ceil(_X), mp.ceil, (-5, 5)),
    "sin": (ca.sin(_X), mp.sin, (-20, 20)),
    "cos": (ca.cos(_X), mp.cos, (-20, 20)),
    "tan": (ca.tan(_X), mp.tan, (-1.4, 1.4)),
    "exp": (ca.exp(_X), mp.exp, (-30, 30)),
    "expm1": (ca.expm1(_X), mp.expm1, (-3, 3)),
    "log": (ca.log(_X), mp.log, (1e-3, 100)),
    "log1p": (ca.log1p(_X), mp.log1p, (-0.9, 10)),
    "asin": (ca.asin(_X), mp.asin, (-1, 1)),
    "acos": (ca.acos(_X), mp.acos, (-1, 1)),
    "atan": (ca.atan(_X), mp.atan, (-30, 30)),
    "sinh": (ca.sinh(_X), mp.sinh, (-5, 5)),
    "cosh": (ca.cosh(_X), mp.cosh, (-5, 5)),
    "tanh": (ca.tanh(_X), mp.tanh, (-5, 5)),
    "asinh": (ca.asinh(_X), mp.asinh, (-30, 30)),
    "acosh": (ca.acosh(_X), mp.acosh, (1, 30)),
    "atanh": (ca.atanh(_X), mp.atanh, (-0.99, 0.99)),
    "erf": (ca.erf(_X), mp.erf, (-4, 4)),
    "constpow_2.5": (_X**2.5, lambda a: mp.power(a, 2.5), (0, 5)),
    "constpow_-0.5": (_X**-0.5, lambda a: mp.power(a, -0.5), (0.01, 5)),
}
BINARY_OPS = {
    "add": (_X + _Y, lambda a, b: a + b, (-5, 5), (-5, 5)),
    "sub": (_X - _Y, lambda a, b: a - b, (-5, 5), (-5, 5)),
    "mul": (_X * _Y, lambda a, b: a * b, (-5, 5), (-5, 5)),
    "div": (_X / _Y, lambda a, b: a / b, (-5, 5), (0.1, 5)),
    "div_neg": (_X / _Y, lambda a, b: a / b, (-5, 5), (-5, -0.1)),
    "fmin": (ca.fmin(_X, _Y), min, (-5, 5), (-5, 5)),
    "fmax": (ca.fmax(_X, _Y), max, (-5, 5), (-5, 5)),
    "pow": (_X**_Y, mp.power, (0.01, 5), (-3, 3)),
    "hypot": (ca.hypot(_X, _Y), mp.hypot, (-5, 5), (-5, 5)),
    "atan2": (ca.atan2(_Y, _X), lambda a, b: mp.atan2(b, a), (0.01, 5), (-5, 5)),
    "copysign": (ca.copysign(_X, _Y), lambda a, b: abs(a) if b >= 0 else -abs(a), (-5, 5), (-5, 5)),
}


def _crit(name, lo, hi):
    """Points inside [lo, hi] where the function may have an extremum (exact, in mpmath)."""
    pts = [mp.mpf(0)] if lo <= 0 <= hi else []
    if name in ("sin", "cos"):
        off = mp.pi / 2 if name == "sin" else 0
        k0, k1 = int(mp.floor((lo - off) / mp.pi)) - 1, int(mp.ceil((hi - off) / mp.pi)) + 1
        pts += [off + k * mp.pi for k in range(k0, k1 + 1) if lo <= off + k * mp.pi <= hi]
    return pts


def _truth_hull(fn, axes):
    """Exact range (to 100 bits) of fn over the product of candidate point lists."""
    with mp.workprec(110):
        vals = [fn(*(mp.mpf(p) for p in pt)) for pt in _product(axes)]
    return min(vals), max(vals)


def _product(axes):
    import itertools

    return itertools.product(*axes)


def _check_op(F, fn, lo_list, hi_list, cands, name):
    out_lo, out_hi = F(lo_list, hi_list)[0]
    for b in range(out_lo.shape[1]):
        tl, th = _truth_hull(fn, [c[b] for c in cands])
        ol, oh = out_lo[0, b], out_hi[0, b]
        assert ol <= tl and th <= oh, (name, b, [(l[0, b], h[0, b]) for l, h in zip(lo_list, hi_list)],
                                       (ol, oh), (float(tl), float(th)))
        mag = max(abs(ol), abs(oh))
        slack = (oh - ol) - float(th - tl)
        assert slack <= 1e-12 * float(th - tl) + 4 * ops.LIBM_REL * mag + 4 * ops.LIBM_ABS, \
            (name, b, slack)


def _rand_boxes(rng, rng_lim, n):
    a, b = rng_lim
    x = np.sort(rng.uniform(a, b, size=(2, n)), axis=0)
    x[1, : n // 10] = x[0, : n // 10]            # point boxes
    x[0, n // 10: n // 5] = a                     # boxes touching the domain's edge
    # narrow boxes
    mid = rng.uniform(a, b, n // 5)
    w = 10.0 ** rng.uniform(-12, -3, n // 5) * (b - a)
    x[0, -(n // 5):], x[1, -(n // 5):] = np.maximum(mid - w, a), np.minimum(mid + w, b)
    return x[0], x[1]


@pytest.mark.parametrize("name", list(UNARY_OPS))
def test_unary_op(name):
    expr, fn, lim = UNARY_OPS[name]
    F = IntervalFunction(ca.Function("u_" + name.replace("-", "m").replace(".", "_"), [_X], [expr]))
    rng = np.random.default_rng(sum(map(ord, name)))
    lo, hi = _rand_boxes(rng, lim, 300)
    interior = rng.uniform(size=(3, lo.size)) * (hi - lo) + lo
    cands = [[[lo[b], hi[b], *interior[:, b], *_crit(name, mp.mpf(lo[b]), mp.mpf(hi[b]))]
              for b in range(lo.size)]]
    _check_op(F, fn, [lo[None]], [hi[None]], cands, name)


@pytest.mark.parametrize("rounding", ["nextafter", "ulp-scaled"])
@pytest.mark.parametrize("name", list(BINARY_OPS))
def test_binary_op(name, rounding, monkeypatch):
    """Both outward roundings (``np.nextafter`` for small evaluations, the scaled-ulp step of
    ``_dn``/``_up`` above NEXTAFTER_MAX values), through the stacked add/sub/mul/div kernels."""
    if rounding != "nextafter":
        monkeypatch.setattr(iv, "NEXTAFTER_MAX", 0)
    expr, fn, lx, ly = BINARY_OPS[name]
    F = IntervalFunction(ca.Function(name, [_X, _Y], [expr]))
    rng = np.random.default_rng(sum(map(ord, name)))
    xlo, xhi = _rand_boxes(rng, lx, 200)
    ylo, yhi = _rand_boxes(rng, ly, 200)
    cands = []
    for lo, hi in ((xlo, xhi), (ylo, yhi)):
        inner = rng.uniform(size=(2, lo.size)) * (hi - lo) + lo
        cands.append([[lo[b], hi[b], *inner[:, b], *([0.0] if lo[b] <= 0 <= hi[b] else [])]
                      for b in range(lo.size)])
    _check_op(F, fn, [xlo[None], ylo[None]], [xhi[None], yhi[None]], cands, name)


def test_sin_cos_extrema_exact():
    F = IntervalFunction(ca.Function("sc", [_X], [ca.sin(_X), ca.cos(_X)]))
    lo = np.array([0.0, 1.0, -0.1, 3.0, 0.0, -100.0, 1e13])
    hi = np.array([3.0, 2.0, 0.1, 3.3, 7.0, -99.0, 1e13 + 1])
    (slo, shi), (clo, chi) = F([lo], [hi])
    assert shi[0, 0] == 1.0 and shi[0, 1] == 1.0            # pi/2 inside
    assert clo[0, 3] == -1.0 and chi[0, 2] == 1.0           # pi inside, 0 inside
    assert slo[0, 4] == -1.0 and shi[0, 4] == 1.0           # a full period
    assert clo[0, 0] > -0.99 and chi[0, 0] == 1.0            # [0, 3]: cos max at 0, pi outside
    assert slo[0, 6] == -1.0 and shi[0, 6] == 1.0           # huge arguments: [-1, 1]
    # without extrema: the end values (monotone piece), not [-1, 1]
    assert slo[0, 1] > 0.84 and shi[0, 5] < 1 and clo[0, 1] > -0.42


def test_even_and_odd_integer_powers():
    F = IntervalFunction(ca.Function("p", [_X, _Y], [_X**_Y, ca.constpow(_X, 4)]))
    lo = [np.array([-2.0, -3.0, -3.0, 0.5]), np.array([2.0, 3.0, -2.0, -3.0])]
    hi = [np.array([1.0, -1.0, -1.0, 2.0]), np.array([2.0, 3.0, -2.0, -3.0])]
    (plo, phi), (qlo, qhi) = F(lo, hi)
    assert plo[0, 0] == 0.0 and 4.0 <= phi[0, 0] < 4.0 + 1e-12           # x^2 over [-2, 1]
    assert -27.0 - 1e-12 < plo[0, 1] <= -27.0 and -1.0 <= phi[0, 1] < -1.0 + 1e-12   # x^3, odd
    assert 1 / 9 - 1e-12 < plo[0, 2] <= 1 / 9 and 1.0 <= phi[0, 2] < 1 + 1e-12   # x^-2, [-3, -1]
    assert 0.125 - 1e-12 < plo[0, 3] <= 0.125 and 8.0 <= phi[0, 3] < 8 + 1e-12   # x^-3, [0.5, 2]
    assert qlo[0, 0] == 0.0 and 16.0 <= qhi[0, 0] < 16 + 1e-12               # x^4 over [-2, 1]


def test_comparisons_logic_and_if_else():
    c = ca.Function("c", [_X, _Y], [_X < _Y, _X <= _Y, _X == _Y, _X != _Y, ca.logic_not(_X),
                                    ca.logic_and(_X, _Y), ca.logic_or(_X, _Y),
                                    ca.if_else(_X > 0, _Y, -_Y)])
    F = IntervalFunction(c)
    lo = [np.array([0.5, 2.0, 1.0]), np.array([1.5, -1.0, 1.0])]
    hi = [np.array([1.0, 3.0, 1.0]), np.array([2.0, -0.5, 1.0])]
    out = F(lo, hi)
    expect = [[1, 0, 0], [1, 0, 1], [0, 0, 1], [1, 1, 0], [0, 0, 0], [1, 1, 1], [1, 1, 1]]
    for (l, h), e in zip(out, expect):
        np.testing.assert_array_equal(l[0], e)
        np.testing.assert_array_equal(h[0], e)
    np.testing.assert_array_equal(out[7][0][0], lo[1])
    np.testing.assert_array_equal(out[7][1][0], hi[1])
    z = np.zeros(1)
    (nl, nh), (al, ah) = IntervalFunction(ca.Function("z", [_X, _Y], [ca.logic_not(_X),
                                                                      ca.logic_and(_X, _Y)]))(
        [z, -np.ones(1)], [z, np.ones(1)])
    assert nl[0, 0] == nh[0, 0] == 1 and al[0, 0] == ah[0, 0] == 0   # not 0 = 1; 0 and y = 0
    # not x on [0, 1] is undecided -> error by default; here box 0 is undecided
    F2 = IntervalFunction(ca.Function("n", [_X], [ca.logic_not(_X)]))
    with pytest.raises(IntervalDomainError, match="undecided.*box 0"):
        F2([np.array([0.0])], [np.array([1.0])])
    # if_else decided per box
    F3 = IntervalFunction(ca.Function("ie", [_X, _Y], [ca.if_else(_X > 0, _Y, -2 * _Y)]))
    (l, h), = F3([np.array([0.5, -2.0]), np.array([1.0, 1.0])], [np.array([1.0, -1.0]), np.array([2.0, 2.0])])
    assert l[0, 0] == 1.0 and h[0, 0] == 2.0                  # y itself (y + exact 0)
    assert -4.0 - 1e-14 < l[0, 1] <= -4.0 and -2.0 <= h[0, 1] < -2.0 + 1e-14   # -2 y, rounded
    with pytest.raises(IntervalDomainError, match=r"undecided.*box 1.*i0: lo=\[-1\.0\] hi=\[1\.0\]"):
        F3([np.array([0.5, -1.0]), np.array([1.0, 1.0])], [np.array([1.0, 1.0]), np.array([2.0, 2.0])])
    # the hull mode: sound (contains both branches), never an error
    F4 = IntervalFunction(ca.Function("ie", [_X, _Y], [ca.if_else(_X > 0, _Y, -2 * _Y)], ["x", "y"], ["o"]),
                          undecided="hull")
    (l, h), = F4([np.array([-1.0]), np.array([1.0])], [np.array([1.0]), np.array([2.0])])
    assert l[0, 0] <= -4.0 and h[0, 0] >= 2.0


def test_if_else_undecided_names_box():
    F = IntervalFunction(ca.Function("ie", [_X, _Y], [ca.if_else(_X > 0, _Y, -2 * _Y)], ["x", "y"], ["o"]))
    lo = [np.array([0.5, 0.5, -1.0]), np.array([1.0, 1.0, 1.0])]
    hi = [np.array([1.0, 1.0, 1.0]), np.array([2.0, 2.0, 2.0])]
    with pytest.raises(IntervalDomainError, match=r"box 2: x: lo=\[-1\.0\] hi=\[1\.0\]") as e:
        F(lo, hi)
    assert e.value.box == 2 and e.value.op in ("lt", "if_else_zero")


@pytest.mark.parametrize("expr, lo, hi, what", [
    (1 / _X, -1.0, 2.0, "containing 0.*primary"),
    (_Y / _X, 0.0, 2.0, "division by an interval containing 0.*primary"),
    (ca.sqrt(_X), -1e-300, 2.0, "sqrt"),
    (ca.log(_X), 0.0, 2.0, "log"),
    (ca.tan(_X), 1.0, 2.0, "pole"),
    (ca.asin(_X), 0.5, 1.5, "asin"),
    (ca.acos(_X), -1.5, 0.5, "acos"),
    (ca.acosh(_X + 1), -0.5, 0.5, "acosh"),
    (ca.atanh(_X), 0.5, 1.0, "atanh"),
    (ca.log1p(_X), -1.0, 1.0, "log1p"),
    (_X**_Y, -1.0, 1.0, "non-integer power"),
    (_X**-3, -1.0, 1.0, "containing 0"),
    (_X**-0.5, 0.0, 1.0, "exponent <= 0"),
])
def test_domain_errors(expr, lo, hi, what):
    """Boxes 0 and 1 are fine, box 2 has no bound: the error names box 2 and its inputs."""
    F = IntervalFunction(ca.Function("d", [_X, _Y], [expr], ["x", "y"], ["o"]))
    y = np.full(3, 0.5)
    with pytest.raises(IntervalDomainError, match=what) as e:
        F([np.array([0.2, 0.4, lo]), y], [np.array([0.3, 0.45, hi]), y])
    assert e.value.box == 2 and "box 2" in str(e.value)
    assert e.value.inputs[0][0][0] == lo and e.value.inputs[0][1][0] == hi
    F([np.array([0.2, 0.4]), y[:2]], [np.array([0.3, 0.45]), y[:2]])   # no error without box 2


@pytest.mark.parametrize("expr, kink_box, smooth_box", [
    (ca.fabs(_X), (-0.1, 0.2), (0.0, 0.2)),          # |x| = x on [0, 0.2]: smooth
    (ca.sign(_X), (0.0, 0.2), (0.1, 0.2)),           # sign jumps at 0 (also at an end)
    (ca.copysign(_Y, _X), (-0.1, 0.2), (0.1, 0.2)),
    (ca.fmin(_X, _Y), (0.4, 0.6), (0.0, 0.5)),       # y = 0.5: touching is smooth
    (ca.fmax(_X, _Y), (0.4, 0.6), (0.5, 0.9)),
    (ca.floor(3 * _X), (0.2, 0.4), (0.34, 0.6)),
    (ca.ceil(3 * _X), (0.2, 0.4), (0.34, 0.6)),
])
def test_kinks_error_mode(expr, kink_box, smooth_box):
    f = ca.Function("k", [_X, _Y], [expr], ["x", "y"], ["o"])
    y = np.full(1, 0.5)
    strict = IntervalFunction(f, kinks="error")
    with pytest.raises(IntervalDomainError, match="non-smooth point.*box 0"):
        strict([np.array([kink_box[0]]), y], [np.array([kink_box[1]]), y])
    a = strict([np.array([smooth_box[0]]), y], [np.array([smooth_box[1]]), y])
    b = IntervalFunction(f)([np.array([smooth_box[0]]), y], [np.array([smooth_box[1]]), y])
    np.testing.assert_array_equal(a[0][0], b[0][0])
    IntervalFunction(f)([np.array([kink_box[0]]), y], [np.array([kink_box[1]]), y])  # default: bound
    with pytest.raises(ProblemError, match="kinks must be one of"):
        IntervalFunction(f, kinks="maybe")


def test_model_hessian_refuses_a_kinked_box():
    """CasADi differentiates |x| to sign(x) and sign to 0: the Hessian alone would claim a zero
    remainder across the kink; the model helpers check f's non-smooth ops first."""
    from ocreach.model import Model

    x, u = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    m = Model.build("kinky", x, u, ca.vertcat(x[1], -ca.fabs(x[0]) + u[0]))
    mi = iv.for_model(m)
    ubox = (np.zeros(1), np.zeros(1))
    lo, hi = mi.hessian((np.array([0.5, 0.0]), np.array([1.0, 1.0])), ubox)
    assert np.all(lo == 0) and np.all(hi == 0)
    with pytest.raises(IntervalDomainError, match=r"\(fabs\): non-smooth point"):
        mi.hessian((np.array([-0.5, 0.0]), np.array([1.0, 1.0])), ubox)
    with pytest.raises(IntervalDomainError, match="non-smooth"):
        mi.all((np.array([-0.5, 0.0]), np.array([1.0, 1.0])), ubox)
    mi.check_smooth((np.array([0.1, 0.0]), np.array([1.0, 1.0])), ubox)


def test_singularity_in_model_box_is_named():
    model = MODELS["cr3bp-spatial"][0]
    moon = np.array([1 - MU, 0, 0, 0, 0, 0])
    far = np.array([0.8, 0.1, 0, 0, 0, 0])
    X = np.stack([far, far, moon], axis=1)
    with pytest.raises(IntervalDomainError, match="box 2.*primary") as e:
        iv.for_model(model).f((X - 1e-3, X + 1e-3), (-np.ones(3), np.ones(3)))
    np.testing.assert_allclose(e.value.inputs[0][0], moon - 1e-3)


def test_overflow_is_unbounded_not_nan(monkeypatch):
    z = ca.SX.sym("z")
    F = IntervalFunction(ca.Function("o", [_X, _Y, z], [ca.exp(_X), ca.exp(_X) - ca.exp(z),
                                                        ca.exp(_X) * _Y, ca.exp(_X) / ca.exp(z),
                                                        ca.exp(_X) + ca.exp(z), (_X * 1e306)**2]))
    big = [np.array([800.0]), np.array([0.0]), np.array([800.0])]
    out = F(big, [np.array([801.0]), np.array([0.0]), np.array([801.0])])
    (l0, h0), (l1, h1), (l2, h2), (l3, h3), (l4, h4), (l5, h5) = [(a[0, 0], b[0, 0]) for a, b in out]
    assert 1e307 < l4 < np.inf and h4 == np.inf     # a lower bound past the largest float
    assert 1e307 < l5 < np.inf and h5 == np.inf
    assert h0 == np.inf and 1e300 < l0 < np.inf
    assert (l1, h1) == (-np.inf, np.inf)
    assert (l2, h2) == (0.0, 0.0)                 # exp(x) * 0 is 0, not 0 * inf = NaN
    assert l3 <= 1 <= h3
    # a kernel that returns NaN is caught and named (the guard behind every group)
    nan_kernel = (1, lambda alo, ahi, blo, bhi, und: (np.where(alo > 0.5, np.nan, alo), ahi))
    monkeypatch.setitem(ops._KERNELS, ca.OP_SIN, nan_kernel)
    G = IntervalFunction(ca.Function("n", [_X], [ca.sin(_X)]))
    with pytest.raises(IntervalDomainError, match=r"\(sin\).*not a number.*box 1"):
        G([np.array([0.0, 1.0])], [np.array([0.0, 1.0])])


# ---------------------------------------------------------------------------- inputs and setup
def test_bad_inputs():
    xs = ca.SX.sym("x", 2)
    F = IntervalFunction(ca.Function("f", [xs, _Y], [ca.sumsqr(xs) + _Y], ["x", "y"], ["o"]))
    ok = [np.zeros(2), np.zeros(1)]
    with pytest.raises(ProblemError, match="'x'.*finite"):
        F([np.array([0.0, np.nan]), np.zeros(1)], ok)
    with pytest.raises(ProblemError, match="'y'.*finite"):
        F(ok, [np.zeros(2), np.array([np.inf])])
    with pytest.raises(ProblemError, match=r"'x'.*inverted.*entry 1 of box 0"):
        F([np.array([0.0, 1.0]), np.zeros(1)], ok)
    with pytest.raises(ProblemError, match=r"'x'.*shape \(2,\) or \(2, B\)"):
        F([np.zeros(3), np.zeros(1)], [np.zeros(3), np.zeros(1)])
    with pytest.raises(ProblemError, match="lists of 2 arrays"):
        F([np.zeros(2)], [np.zeros(2)])
    with pytest.raises(ProblemError, match="different numbers of boxes"):
        F([np.zeros((2, 3)), np.zeros((1, 4))], [np.zeros((2, 3)), np.zeros((1, 4))])
    with pytest.raises(ProblemError, match="undecided must be one of"):
        IntervalFunction(ca.Function("g", [_X], [_X]), undecided="maybe")
    with pytest.raises(ProblemError, match="casadi.Function"):
        IntervalFunction("sin")


def test_unsupported_ops_and_mx():
    with pytest.raises(ProblemError, match="'fmod'.*not supported.*supported"):
        IntervalFunction(ca.Function("m", [_X], [ca.fmod(_X, 2.0)]))
    z = ca.SX.sym("z")
    with pytest.raises(ProblemError, match="'parameter'.*free SX symbol"):
        IntervalFunction(ca.Function("p", [_X], [_X * z], {"allow_free": True}))
    # MX: expanded to SX first
    M = ca.MX.sym("M", 2, 2)
    fm = ca.Function("fm", [M], [ca.mtimes(M, M)])
    F = IntervalFunction(fm)
    lo, hi = F([np.array([1.0, 2.0, 3.0, 4.0])], [np.array([1.0, 2.0, 3.0, 4.0])])[0]
    Mv = np.array([[1.0, 3.0], [2.0, 4.0]])
    rl, rh = F.reshape((lo, hi), 0)
    assert rl.shape == (2, 2, 1) and np.all(rl[..., 0] <= Mv @ Mv) and np.all(Mv @ Mv <= rh[..., 0])

    class Opaque(ca.Callback):
        def __init__(self):
            ca.Callback.__init__(self)
            self.construct("opaque", {})

        def eval(self, arg):
            return [arg[0] * 2]

    cb = Opaque()
    xm = ca.MX.sym("x")
    with pytest.raises(ProblemError, match="'call'.*Callback"):
        IntervalFunction(ca.Function("g", [xm], [cb(xm)]))


def test_sparse_inputs_outputs_and_chunking(monkeypatch):
    S = ca.SX.sym("S", ca.Sparsity.lower(3))
    f = ca.Function("s", [S], [ca.sin(S) * 2, S.T])   # sparse in and out
    F = IntervalFunction(f)
    rng = np.random.default_rng(3)
    dense = rng.uniform(-1, 1, (9, 50))
    dense[[3, 6, 7]] = 0.0   # structural zeros of the lower triangle
    out = F([dense], [dense + 1e-3])
    monkeypatch.setattr(iv, "CHUNK_BYTES", 2000)
    out2 = F([dense], [dense + 1e-3])
    for (a, b), (c, d) in zip(out, out2):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, d)
    for k in range(50):
        v = [np.asarray(ca.densify(o)).ravel(order="F") for o in f(ca.DM(ca.Sparsity.lower(3),
                                                                       dense[[0, 1, 2, 4, 5, 8], k]))]
        for (lo, hi), vv in zip(out, v):
            assert np.all(lo[:, k] <= vv) and np.all(vv <= hi[:, k])
    lo, hi = F.reshape(out[1], 1)
    assert lo.shape == (3, 3, 50) and np.all(lo[1, 0] == 0) and np.all(hi[2, 0] == 0)


# ---------------------------------------------------------------------------- splitting
def test_bound_splitting_tightens_and_contains():
    f = ca.Function("c", [_X, _Y], [_X * _X * _X - _X * _Y + ca.sin(3 * _Y)])
    F = IntervalFunction(f)
    lo, hi = [np.array([-1.0]), np.array([0.0])], [np.array([2.0]), np.array([1.0])]
    (l1, h1), = iv.bound(F, lo, hi)
    (l8, h8), = iv.bound(F, lo, hi, splits=8)
    (l64, h64), = iv.bound(f, lo, hi, splits=64)
    assert l1 < l8 <= l64 and h64 < h8 < h1   # the minimum -1 is at a corner: exact from 8 on
    xs, ys = np.meshgrid(np.linspace(-1, 2, 301), np.linspace(0, 1, 101))
    v = xs**3 - xs * ys + np.sin(3 * ys)
    assert l64 <= v.min() and v.max() <= h64
    assert h64 - l64 < 1.05 * (v.max() - v.min())
    # split only along x (input 0, entry 0)
    (lx, hx), = iv.bound(F, lo, hi, splits=16, dims=[(0, 0)])
    assert lx <= v.min() and hx >= v.max()
    slo, shi, S = iv.split_boxes(lo, hi, 4, max_boxes=16)
    assert S == 16 and slo[0].shape == (1, 16)
    assert slo[0].min() == -1.0 and shi[0].max() == 2.0
    with pytest.raises(ProblemError, match="splits"):
        iv.bound(F, lo, hi, splits=0)
    with pytest.raises(ProblemError, match="max_boxes"):
        iv.split_boxes(lo, hi, 4, max_boxes=8, dims=[(0, 0), (1, 0)])


# ---------------------------------------------------------------------------- property tests
_UN = [ca.sin, ca.cos, ca.exp, ca.atan, ca.tanh, ca.fabs, lambda a: a**2, lambda a: a**3,
       ca.sqrt, lambda a: 1 / a, ca.log, lambda a: -a, ca.cosh, ca.sign]
_BIN = [lambda a, b: a + b, lambda a, b: a - b, lambda a, b: a * b, lambda a, b: a / b,
        ca.fmin, ca.fmax, ca.atan2, ca.hypot, lambda a, b: ca.if_else(a < b, a, b * 2)]


@st.composite
def _exprs(draw, depth=4):
    if depth == 0 or draw(st.integers(0, 3)) == 0:
        return draw(st.sampled_from([_X, _Y, _X, _Y, ca.SX(draw(st.floats(-3, 3, width=32)))]))
    if draw(st.booleans()):
        return draw(st.sampled_from(_UN))(draw(_exprs(depth=depth - 1)))
    return draw(st.sampled_from(_BIN))(draw(_exprs(depth=depth - 1)), draw(_exprs(depth=depth - 1)))


@settings(max_examples=120, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(expr=_exprs(), x=st.floats(-4, 4), y=st.floats(-4, 4),
       wx=st.floats(0, 2), wy=st.floats(0, 2), seed=st.integers(0, 2**31))
def test_random_graphs_contain_sampled_values(expr, x, y, wx, wy, seed):
    f = ca.Function("r", [_X, _Y], [expr])
    F = IntervalFunction(f)
    try:
        (lo, hi), = F([np.array([x]), np.array([y])], [np.array([x + wx]), np.array([y + wy])])
    except IntervalDomainError:
        assume(False)
    rng = np.random.default_rng(seed)
    xs = np.concatenate([[x, x + wx, x, x + wx], rng.uniform(x, x + wx, 60)])
    ys = np.concatenate([[y, y, y + wy, y + wy], rng.uniform(y, y + wy, 60)])
    with np.errstate(all="ignore"):
        v = np.asarray(f.map(xs.size)(xs[None], ys[None])).ravel()
    # CasADi's float values (overflow to inf included) lie inside; a NaN sample (inf - inf in
    # floats) is only possible where our bound is unbounded
    assert np.all(lo[0, 0] <= v[~np.isnan(v)]) and np.all(v[~np.isnan(v)] <= hi[0, 0])
    assert not np.any(np.isnan(v)) or not (np.isfinite(lo[0, 0]) and np.isfinite(hi[0, 0]))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), r=st.floats(1e-9, 0.05))
def test_model_boxes_contain_sampled_values(seed, r):
    model = MODELS["cr3bp-spatial"][0]
    rng = np.random.default_rng(seed)
    c = np.array([0.9, 0.1, 0.05, 0.0, 0.2, 0.0]) + 0.05 * rng.normal(size=6)
    rr = r * rng.uniform(size=6)
    try:
        out = iv.for_model(model).all((c - rr, c + rr), (-np.ones(3), np.ones(3)))
    except IntervalDomainError:  # only where the box really holds the Moon (a singularity)
        moon = np.array([1.0 - float(model.p_default[0]), 0.0, 0.0])
        assert np.all(np.abs(c[:3] - moon) <= rr[:3] * (1 + 1e-9))
        assume(False)
    xs = c[:, None] + rr[:, None] * rng.uniform(-1, 1, (6, 50))
    us = rng.normal(size=(3, 50))
    us /= np.maximum(1, np.linalg.norm(us, axis=0))
    for k in range(0, 50, 10):
        T = model.tensors(xs[:, k], us[:, k], order=2)
        for key, tk in (("J", T[1][:6]), ("H", T[2][:6])):
            assert np.all(out[key][0][..., 0] <= tk) and np.all(tk <= out[key][1][..., 0])
    fv = np.asarray(model.f_fun.map(50)(xs, us, 0.0, model.p_default))
    assert np.all(out["f"][0] <= fv) and np.all(fv <= out["f"][1])
    assert math.isfinite(float(out["H"][1].max()))


def test_sine_of_an_overflowed_argument_is_a_domain_error():
    # found by hypothesis: sin(sin(x + inf)) is NaN in floats; [-1, 1] would claim a finite value
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    for inf in (ca.SX(np.inf), ca.SX(1e30) * ca.SX(1e300)):  # a literal and a folded overflow
        f = IntervalFunction(ca.Function("f", [x, y], [ca.sin(ca.sin(x + inf))]))
        with pytest.raises(IntervalDomainError, match="overflowed"):
            f([np.ones(1), np.zeros(1)], [np.ones(1), np.zeros(1)])


@pytest.mark.parametrize("rounding", ["nextafter", "ulp-scaled"])
def test_mixed_add_sub_group_matches_exact_ranges(rounding, monkeypatch):
    """Additions and subtractions of one depth run as one group (a - b as a + (-b)); every bound
    must enclose the exact range (rational arithmetic) and be within 2 ulps of it."""
    from fractions import Fraction
    if rounding != "nextafter":
        monkeypatch.setattr(iv, "NEXTAFTER_MAX", 0)
    F = IntervalFunction(ca.Function("addsub", [_X, _Y], [_X + _Y, _X - _Y, _Y - _X]))
    assert F.n_groups == 1
    rng = np.random.default_rng(7)
    B = 400
    xlo = rng.uniform(-3, 3, B) * 10.0 ** rng.integers(-8, 8, B)
    ylo = rng.uniform(-3, 3, B) * 10.0 ** rng.integers(-8, 8, B)
    xlo[:20], ylo[20:40] = 0.0, 0.0                      # exact zeros keep their exactness
    xhi = xlo + rng.uniform(0, 1, B) * np.abs(xlo)
    yhi = ylo + rng.uniform(0, 1, B) * np.abs(ylo)
    out = F([xlo, ylo], [xhi, yhi])
    q = Fraction
    for b in range(B):
        xl, xh, yl, yh = q(xlo[b]), q(xhi[b]), q(ylo[b]), q(yhi[b])
        for (lo, hi), (el, eh) in zip(out, ((xl + yl, xh + yh), (xl - yh, xh - yl),
                                            (yl - xh, yh - xl))):
            assert q(lo[0, b]) <= el and eh <= q(hi[0, b])
            assert float(el) - lo[0, b] <= 2 * np.spacing(abs(float(el)))
            assert hi[0, b] - float(eh) <= 2 * np.spacing(abs(float(eh)))


@pytest.mark.parametrize("rounding", ["nextafter", "ulp-scaled"])
def test_mixed_mul_div_group_matches_exact_ranges(rounding, monkeypatch):
    """Products, constant products and quotients of one depth run as one group; every bound must
    enclose the exact range (rational arithmetic, corners) and be within 2 ulps of it; a divisor
    box containing 0 is still a domain error of the division."""
    from fractions import Fraction as q
    if rounding != "nextafter":
        monkeypatch.setattr(iv, "NEXTAFTER_MAX", 0)
    F = IntervalFunction(ca.Function("muldiv", [_X, _Y], [_X * _Y, _X / _Y, 3.0 * _X]))
    assert F.n_groups == 1
    rng = np.random.default_rng(11)
    B = 400
    xlo = rng.uniform(-3, 3, B) * 10.0 ** rng.integers(-8, 8, B)
    ylo = rng.uniform(0.1, 3, B) * 10.0 ** rng.integers(-8, 8, B) * rng.choice([-1, 1], B)
    xlo[:20] = 0.0
    xhi = xlo + rng.uniform(0, 1, B) * np.abs(xlo)
    xhi[:10] = 0.0                                       # x exactly 0: x y is exactly 0
    yhi = ylo + rng.uniform(0, 0.5, B) * np.abs(ylo)
    out = F([xlo, ylo], [xhi, yhi])
    for b in range(B):
        xs, ys = (q(xlo[b]), q(xhi[b])), (q(ylo[b]), q(yhi[b]))
        prods = [u * v for u in xs for v in ys]
        quots = [u / v for u in xs for v in ys]
        for (lo, hi), vals in zip(out, (prods, quots, [3 * u for u in xs])):
            el, eh = min(vals), max(vals)
            assert q(lo[0, b]) <= el and eh <= q(hi[0, b])
            assert float(el) - lo[0, b] <= 2 * np.spacing(abs(float(el)))
            assert hi[0, b] - float(eh) <= 2 * np.spacing(abs(float(eh)))
        if b < 10:
            assert out[0][0][0, b] == 0.0 and out[0][1][0, b] == 0.0
    with pytest.raises(IntervalDomainError) as e:
        F([np.array([1.0, 1.0]), np.array([1.0, -1.0])], [np.array([2.0, 2.0]), np.array([2.0, 1.0])])
    assert e.value.op == "div" and e.value.box == 1


def test_rounding_mode_is_per_thread():
    """Two threads evaluate at once, one a large batch (scaled-ulp rounding), one a small one
    (``np.nextafter`` rounding), interleaved deterministically: the large one pauses after its
    first chunk while the small one is inside its evaluation.  Both results are bit for bit
    those of the same evaluations run alone (with a module-wide mode each took the other's)."""
    import threading

    import casadi as ca

    from ocreach.intervals import evaluator as iv

    x = ca.SX.sym("x", 2)
    f = ca.Function("f", [x], [ca.vertcat(x[0] * x[1] + ca.sin(x[0]) / (3 + x[1] ** 2),
                                          ca.exp(x[0] - x[1]) * x[0])])
    rng = np.random.default_rng(0)
    big_lo = rng.uniform(-1, 1, size=(2, 6000))
    big = ([big_lo], [big_lo + 1e-3])
    small = ([big_lo[:, :1]], [big_lo[:, :1] + 1e-3])
    fa, fb = iv.IntervalFunction(f), iv.IntervalFunction(f)
    fa._native = fb._native = False  # the numpy evaluator, where the mode applies
    ref_a, ref_b = fa(*big), fb(*small)
    # the two modes do round differently here, so a mixed-up mode would show
    fb2 = iv.IntervalFunction(f)
    fb2._native = False
    fb2._max_group = 10**9  # forces the scaled-ulp mode for the small evaluation
    assert any(np.any(a != b) for pa, pb in zip(fb2(*small), ref_b, strict=True)
               for a, b in zip(pa, pb, strict=True))

    a_in, b_in, a_done = threading.Event(), threading.Event(), threading.Event()
    chunk_a, chunk_b = fa._eval_chunk, fb._eval_chunk
    first = {"a": True, "b": True}

    def paused_a(*args):
        chunk_a(*args)
        if first["a"]:
            first["a"] = False
            a_in.set()
            assert b_in.wait(30)

    def paused_b(*args):
        if first["b"]:
            first["b"] = False
            b_in.set()
            assert a_done.wait(30)
        chunk_b(*args)

    fa._eval_chunk, fb._eval_chunk = paused_a, paused_b
    out = {}

    def run_a():
        out["a"] = fa(*big)
        a_done.set()

    def run_b():
        assert a_in.wait(30)
        out["b"] = fb(*small)

    threads = [threading.Thread(target=run_a), threading.Thread(target=run_b)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    for got, ref in ((out["a"], ref_a), (out["b"], ref_b)):
        for (gl, gh), (rl, rh) in zip(got, ref, strict=True):
            np.testing.assert_array_equal(gl, rl)
            np.testing.assert_array_equal(gh, rh)
