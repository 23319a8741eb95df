"""The compiled interval kernel (ocreach.native.interval_kernel) against the numpy evaluator.

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

from ocreach import intervals as iv
from ocreach.intervals import IntervalDomainError, IntervalFunction
from ocreach.native.interval_kernel import _entries
from ocreach.problem import get_problem
from ocreach.reach.sdc import third_interval
from ocreach.reach.taylor import hessian_interval

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
        kinds |= {e[0] for e in _entries(nat)}
        _assert_same(*_pair(nat, ref, lo, hi))
    assert {"add", "sub", "mul", "mulc_min", "mulc_corner", "neg", "twice", "sq"} <= kinds
    # quotients, inverses and roots where they exist (x >= 0, y without 0)
    G = ca.Function("dom_ops", [x, y], [ca.vertcat(x / y, 1 / y, ca.sqrt(x), x / y * 3.0 + x * y)])
    natg, refg = IntervalFunction(G, native=True), IntervalFunction(G)
    assert {"div", "inv", "sqrt", "mul"} <= {e[0] for e in _entries(natg)}
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
