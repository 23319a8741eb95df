"""The compiled interval kernel (ocreach.intervals.kernel) against the numpy evaluator.

The numpy evaluator of ocreach.intervals is checked against mpmath in tests/test_intervals.py;
the C kernel must give the same bounds as its ``nextafter`` mode, value for value (zeros may
differ in sign), on every operation it compiles, on special values (zeros, subnormals, the
largest floats, overflow to inf), on the Hessians the zonotope methods use, and it must report
every failure exactly as the numpy evaluator does (it re-runs it).
"""
from __future__ import annotations

import itertools

import casadi as ca
import numpy as np
import pytest

from ocreach.intervals import IntervalDomainError, IntervalFunction
from ocreach.intervals import evaluator as iv
from ocreach.intervals.kernel import _entries
from ocreach.reach.sdc import third_interval
from ocreach.reach.taylor_step import hessian_interval
from ocreach.registry import get_problem

TINY = 5e-324
BIG = 1.7976931348623157e308
#: intervals with zeros, signed zeros, subnormals, the largest floats and ordinary values
SPECIAL = [(-1.0, 2.0), (0.0, 0.0), (-0.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (TINY, 2 * TINY),
           (-TINY, TINY), (1e-310, 3e-308), (1e300, BIG), (-BIG, -1e300), (0.5, 0.5),
           (-3.0, -1e-300), (1.0, 1.0 + 2**-52), (-BIG, BIG), (3.0, 7.0)]


@pytest.fixture
def nextafter_mode(monkeypatch):
    """numpy evaluator in its ``np.nextafter`` mode for any number of boxes."""
    monkeypatch.setattr(iv, "NEXTAFTER_MAX", 10**12)


def _pair(ivf_native, ivf_numpy, lo, hi):
    a = ivf_native(lo, hi)
    assert ivf_native._native, "the kernel was not built"
    b = ivf_numpy(lo, hi)
    return a, b


def _assert_same(a, b):
    for (alo, ahi), (blo, bhi) in zip(a, b):
        assert alo.shape == blo.shape and ahi.shape == bhi.shape
        assert np.array_equal(alo, blo) and np.array_equal(ahi, bhi)


def _boxes(pairs):
    xs, ys = zip(*pairs)
    lo = [np.array([p[0] for p in xs]), np.array([p[0] for p in ys])]
    hi = [np.array([p[1] for p in xs]), np.array([p[1] for p in ys])]
    return lo, hi


def test_every_compiled_op_matches_numpy_on_special_values(nextafter_mode):
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    outs = [x + y, x - y, x * y, x * 3.0, -x, 2 * x, x**2, x * y + x * 3.0, (x + y) - (x * y),
            x * 3.0 - y * 5.0, x * 1e300]
    lo, hi = _boxes(list(itertools.product(SPECIAL, SPECIAL)))
    kinds = set()
    # the second Function is a group of constant products alone (NaN-propagating min/max)
    for F in (ca.Function("safe_ops", [x, y], [ca.vertcat(*outs)]),
              ca.Function("const_products", [x, y], [ca.vertcat(x * 3.0, y * -1e300)])):
        nat, ref = IntervalFunction(F, native=True), IntervalFunction(F)
        kinds |= {e[0] for e in _entries(nat.schedule)}
        _assert_same(*_pair(nat, ref, lo, hi))
    assert {"add", "sub", "mul", "mulc_min", "mulc_corner", "neg", "twice", "sq"} <= kinds
    # quotients, inverses and roots where they exist (x >= 0, y without 0)
    G = ca.Function("dom_ops", [x, y], [ca.vertcat(x / y, 1 / y, ca.sqrt(x), x / y * 3.0 + x * y)])
    natg, refg = IntervalFunction(G, native=True), IntervalFunction(G)
    assert {"div", "inv", "sqrt", "mul"} <= {e[0] for e in _entries(natg.schedule)}
    xs_ = [p for p in SPECIAL if p[0] >= 0]
    ys_ = [p for p in SPECIAL if p[0] > 0 or p[1] < 0]
    lo, hi = _boxes(list(itertools.product(xs_, ys_)))
    _assert_same(*_pair(natg, refg, lo, hi))


@pytest.mark.parametrize("expr, box", [
    ("x / y", ((1.0, 2.0), (-1.0, 1.0))),
    ("1 / y", ((1.0, 2.0), (0.0, 1.0))),
    ("sqrt(x)", ((-1e-300, 2.0), (1.0, 2.0))),
])
def test_failures_are_reported_by_the_numpy_evaluator(expr, box):
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    F = ca.Function("f", [x, y], [eval(expr, {"x": x, "y": y, "sqrt": ca.sqrt})])
    nat, ref = IntervalFunction(F, native=True), IntervalFunction(F)
    lo, hi = [np.array([box[0][0]]), np.array([box[1][0]])], [np.array([box[0][1]]), np.array([box[1][1]])]
    with pytest.raises(IntervalDomainError) as e_ref:
        ref(lo, hi)
    with pytest.raises(IntervalDomainError) as e_nat:
        nat(lo, hi)
    assert str(e_nat.value) == str(e_ref.value)
    assert nat._native  # the kernel exists; it flagged the failure and numpy reported it


@pytest.mark.parametrize("pid", ["earth-mars", "nrho-9-2"])
@pytest.mark.parametrize("which", ["taylor", "sdc"])
def test_step_functions_match_numpy(pid, which, nextafter_mode):
    """The Hessian (taylor) and third-derivative (sdc) functions on random boxes around states of
    the problem's initial set: 2 boxes (a step's call) and 40."""
    p = get_problem(pid)
    m = p.model
    nat = hessian_interval(m) if which == "taylor" else third_interval(m)
    ref = IntervalFunction(nat.fun)
    rng = np.random.default_rng(11)
    x0 = np.asarray(p.x0, dtype=float)
    par = np.asarray(p.params, dtype=float)
    for B in (2, 40):
        c = x0[:, None] + 1e-3 * rng.standard_normal((m.n_x, B))
        w = 10.0 ** rng.uniform(-9, -2, (m.n_x, B))
        uc = rng.uniform(-0.2, 0.2, (m.n_u, B))
        uw = rng.uniform(0, 1, (m.n_u, B))
        lo = [c - w, uc - uw, np.zeros(B), par]
        hi = [c + w, uc + uw, np.zeros(B), par]
        _assert_same(*_pair(nat, ref, lo, hi))


def test_unsupported_ops_stay_in_numpy():
    x = ca.SX.sym("x")
    F = ca.Function("s", [x], [ca.sin(x) * x])
    nat = IntervalFunction(F, native=True)
    lo, hi = nat([np.array([0.1])], [np.array([0.2])])[0]
    assert nat._native is False and lo[0, 0] <= np.sin(0.1) * 0.1 and hi[0, 0] >= np.sin(0.2) * 0.2


def test_native_switched_off(monkeypatch):
    monkeypatch.setenv("OCREACH_JIT", "0")
    x = ca.SX.sym("x")
    nat = IntervalFunction(ca.Function("q", [x], [x * x + x]), native=True)
    nat([np.array([1.0])], [np.array([2.0])])
    assert nat._native is False
    with pytest.raises(Exception, match="native must be True or False"):
        IntervalFunction(ca.Function("q", [x], [x]), native="yes")


@pytest.mark.parametrize("method", ["taylor", "sdc"])
def test_reach_sets_equal_with_the_numpy_evaluator(method, nextafter_mode):
    """End to end: earth-mars over 8 days with the compiled remainder bounds and with the numpy
    evaluator (same model cache, the kernel switched off): the same sets, bit for bit."""
    import ocreach

    p = get_problem("earth-mars", t_days=8.0)
    fun = hessian_interval(p.model) if method == "taylor" else third_interval(p.model)
    fast = ocreach.reach(p, method, max_parts=1)
    assert fun._native
    kernel, fun._native = fun._native, False
    try:
        slow = ocreach.reach(p, method, max_parts=1)
    finally:
        fun._native = kernel
    assert len(fast.sets) == len(slow.sets) == 9
    for a, b in zip(fast.sets + fast.tubes, slow.sets + slow.tubes):
        assert np.array_equal(a.c, b.c) and np.array_equal(a.G, b.G)


def _quadratic_interval_reference(Hlo, Hhi, dlo, dhi):
    """The formula of quadratic_interval before its products were stacked (commit ebdb05a)."""
    plo = np.minimum.reduce([np.outer(dlo, dlo), np.outer(dlo, dhi), np.outer(dhi, dlo), np.outer(dhi, dhi)])
    phi = np.maximum.reduce([np.outer(dlo, dlo), np.outer(dlo, dhi), np.outer(dhi, dlo), np.outer(dhi, dhi)])
    mag = np.maximum(np.abs(dlo), np.abs(dhi))
    mig = np.where((dlo <= 0) & (dhi >= 0), 0.0, np.minimum(np.abs(dlo), np.abs(dhi)))
    idx = np.arange(dlo.size)
    plo[idx, idx] = mig**2
    phi[idx, idx] = mag**2
    cands = [Hlo * plo, Hlo * phi, Hhi * plo, Hhi * phi]
    lo = 0.5 * np.minimum.reduce(cands).sum(axis=(1, 2))
    hi = 0.5 * np.maximum.reduce(cands).sum(axis=(1, 2))
    Hmag = np.maximum(np.abs(Hlo), np.abs(Hhi))
    m = 0.5e-12 * (Hmag * np.outer(mag, mag)[None]).sum(axis=(1, 2))
    return lo - m - 1e-300, hi + m + 1e-300


def test_stacked_quadratic_interval_equals_the_previous_formula():
    from ocreach.reach.taylor_step import quadratic_interval

    rng = np.random.default_rng(5)
    for nx, nz in ((6, 9), (4, 6), (2, 3), (7, 11)):
        for _ in range(50):
            H1, H2 = rng.standard_normal((2, nx, nz, nz)) * 10.0 ** rng.uniform(-3, 3)
            Hlo, Hhi = np.minimum(H1, H2), np.maximum(H1, H2)
            d1, d2 = rng.standard_normal((2, nz)) * 10.0 ** rng.uniform(-8, 0, nz)
            d1[rng.random(nz) < 0.2] = 0.0
            dlo, dhi = np.minimum(d1, d2), np.maximum(d1, d2)
            new, old = quadratic_interval(Hlo, Hhi, dlo, dhi), _quadratic_interval_reference(Hlo, Hhi, dlo, dhi)
            assert np.array_equal(new[0], old[0]) and np.array_equal(new[1], old[1])
