"""Compact polynomial-zonotope balls (ocreach/sets/ball_pz.py) and the n-D unit_ball_pz.

Containment of the leaves is *proved* by the finite certificates of tests/_ball_certify.py
(Lemma 1: odd map with ``|F| >= 1`` on the cube's boundary), their radii too (both by Bernstein
bounds of ``|F|^2`` with subdivision); the certifiers are themselves checked against dense evaluation.
Products (Lemma 2): the proof's witnesses evaluated through the built set, branch-and-bound
support bounds in random directions (within [1, 1.03]) and a Bernstein proof of the radius.
"""
from __future__ import annotations

import itertools
from fractions import Fraction

import numpy as np
import pytest
from _ball_certify import (
    _values,
    boundary_at_least_one,
    boundary_at_least_one_exact,
    face_at_least,
    max_over_unit_box,
    max_over_unit_box_exact,
    squared_norm_in_squares,
)

from ocreach.errors import ProblemError, SetError
from ocreach.reach.stt import BALL_INPUT_AUTO, BALL_INPUT_AUTO_ND, input_pz
from ocreach.sets import unit_ball_pz
from ocreach.sets.ball_pz import (
    LEAF_RADIUS,
    RADIUS_TARGET,
    compact_ball_plan,
    compact_ball_pz,
    plan_radius,
)
from ocreach.sets.pz_exact import find_witnesses, support_bounds

LEAVES = [("d4", 2), ("d6", 2), ("b3", 3)]


def _unit(rng, N, n):
    X = rng.standard_normal((N, n))
    return X / np.linalg.norm(X, axis=1, keepdims=True)


# ------------------------------------------------------------------ the certifiers can fail


def test_boundary_certificate_refuses_a_set_inside_the_ball():
    P = compact_ball_pz(2, plan="d4")
    G = np.asarray(P.G)
    assert boundary_at_least_one(G, P.E)
    assert not boundary_at_least_one(0.995 * G, P.E)          # touches 1 -> dips below
    a = np.linspace(-1, 1, 20001)
    low = np.linalg.norm(_values(G, P.E, np.c_[np.ones_like(a), a]), axis=1).min()   # face a1 = 1
    C = squared_norm_in_squares(G, P.E)
    assert face_at_least(C, 0, (low - 1e-4) ** 2)
    assert not face_at_least(C, 0, (low + 1e-4) ** 2)


# ------------------------------------------------------------------ leaves: proofs
@pytest.mark.parametrize("kind, n", LEAVES)
def test_leaf_contains_the_ball_and_radius_is_proved(kind, n):
    P = compact_ball_pz(n, plan=kind)
    G, E = np.asarray(P.G), np.asarray(P.E)
    # Lemma 1: F odd (every monomial of odd total degree), |F| >= 1 on every face
    assert np.all(E.sum(axis=0) % 2 == 1) and np.all(P.c == 0) and P.n_independent == 0
    assert P.n_factors == n
    assert boundary_at_least_one(G, E)
    C = squared_norm_in_squares(G, E)
    assert C is not None
    R = LEAF_RADIUS[kind]
    assert R <= RADIUS_TARGET
    assert max_over_unit_box(C, R * R)[0]
    # ... and R is not loose: a corner of the cube reaches within 2e-4 of it
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=n)))
    assert np.linalg.norm(_values(G, E, corners), axis=1).max() >= R - 2e-4


@pytest.mark.parametrize("n", [3, 4, 5])
def test_cube_to_ball_pz_radius_is_proved_within_3_percent(n):
    P = unit_ball_pz(n)
    C = squared_norm_in_squares(np.asarray(P.G), P.E)
    assert max_over_unit_box(C, {3: 1.0012, 4: 1.0030, 5: 1.0230}[n] ** 2, max_boxes=200_000)[0]


def _float_certifier(C, bound):
    return max_over_unit_box(C, bound)[0]


def _exact_certifier(C, bound):
    return max_over_unit_box_exact(np.vectorize(Fraction, otypes=[object])(C), bound)[0]


@pytest.mark.parametrize("certify, seed, grid", [(_float_certifier, 0, (201, 61)),
                                                 (_exact_certifier, 1, (101, 41))],
                         ids=["float", "exact"])
def test_certifier_matches_dense_evaluation(certify, seed, grid):
    """max over [0, 1]^m of random polynomials: the Bernstein certifier (floats, and exact
    rationals) proves the dense maximum + 1e-3 and refuses the dense maximum - 1e-3 (a
    counterexample is found)."""
    rng = np.random.default_rng(seed)
    for m, deg in [(1, 4), (2, 3), (3, 2)]:
        C = rng.normal(size=(deg + 1,) * m)
        g = np.linspace(0, 1, grid[0] if m < 3 else grid[1])
        X = np.array(list(itertools.product(g, repeat=m)))
        vals = np.zeros(len(X))
        for e in itertools.product(range(deg + 1), repeat=m):
            vals += C[e] * np.prod(X ** np.array(e), axis=1)
        top = vals.max()
        assert certify(C, top + 1e-3)
        assert not certify(C, top - 1e-3)


@pytest.mark.parametrize("kind, n", LEAVES)
def test_leaf_proofs_hold_in_exact_arithmetic(kind, n):
    """The float certificates above round in |F|^2's coefficients and in the Bernstein basis
    change; redone in exact rationals (the stored float coefficients taken exactly), the leaves'
    containment (|F| >= 1 on the boundary) and radius (max |F| <= LEAF_RADIUS) are proofs without
    a round-off caveat; a set shrunk by 0.1 % and a radius 1e-4 below are refused."""
    P = compact_ball_pz(n, plan=kind)
    G, E = np.asarray(P.G), np.asarray(P.E)
    assert boundary_at_least_one_exact(G, E)
    assert not boundary_at_least_one_exact(0.999 * G, E)
    if n == 2:   # the disks' margin, which covers the products' rounding (ball_pz docstring)
        assert boundary_at_least_one_exact(G, E, Fraction(10004, 10000))
        assert not boundary_at_least_one_exact(G, E, Fraction(10007, 10000))
    C = squared_norm_in_squares(G, E, exact=True)
    R = Fraction(LEAF_RADIUS[kind])
    assert max_over_unit_box_exact(C, R * R)[0]
    assert not max_over_unit_box_exact(C, (R - Fraction(1, 10_000)) ** 2)[0]


@pytest.mark.parametrize("n, R", [(3, 1.0012), (4, 1.0030)])
def test_cube_to_ball_proofs_hold_in_exact_arithmetic(n, R):
    """unit_ball_pz(3 / 4) (48 / 256 generators): |F| >= 1 on the boundary of the factor cube (so
    Lemma 1 of ball_pz gives containment directly; dense sampling in 3-D: min 1.00003, a thin
    margin) and radius <= R, in exact rationals (n = 5 takes ~25 s exact: float below)."""
    P = unit_ball_pz(n)
    G, E = np.asarray(P.G), np.asarray(P.E)
    assert P.n_factors == n and np.all(E.sum(axis=0) % 2 == 1) and np.all(P.c == 0)
    assert boundary_at_least_one_exact(G, E)
    assert max_over_unit_box_exact(squared_norm_in_squares(G, E, exact=True), Fraction(R) ** 2)[0]


def test_cube_to_ball_5d_boundary_certificate():
    """unit_ball_pz(5): |F| >= 1 on the boundary (Lemma 1 containment), float certifier."""
    P = unit_ball_pz(5)
    G, E = np.asarray(P.G), np.asarray(P.E)
    assert P.n_factors == 5 and np.all(E.sum(axis=0) % 2 == 1) and np.all(P.c == 0)
    assert boundary_at_least_one(G, E)
    assert not boundary_at_least_one(0.995 * G, E)


# ------------------------------------------------------------------ products: n-D
@pytest.mark.parametrize("n, gens", [(2, 4), (3, 10), (4, 16), (5, 32), (6, 48), (7, 72), (8, 96)])
def test_compact_ball_plan_generators_and_radius(n, gens):
    tree, g, R = compact_ball_plan(n)
    P = compact_ball_pz(n)
    assert P.dim == n and P.n_generators == g == gens
    assert R == pytest.approx(plan_radius(tree)) and 1 <= R <= RADIUS_TARGET


def _dim(tree) -> int:
    return {"i": 1, "d4": 2, "d6": 2, "b3": 3}[tree] if isinstance(tree, str) else _dim(tree[1]) + _dim(tree[2])


def _witness(tree, U: np.ndarray) -> np.ndarray:
    """Factor values mapping to the points ``U`` (N, n) of the unit ball, built as in the proof of
    Lemma 2: ``(c, s) = (|u_left|, |u_right|)`` in the disk, ``x = u_left / c``, ``y = u_right / s``
    (unit vectors), each found in its leaf by Gauss-Newton (``find_witnesses``); factors ordered
    disk, left, right."""
    if isinstance(tree, str):
        if tree == "i":
            return U.copy()
        a, _, r = find_witnesses(compact_ball_pz(U.shape[1], plan=tree), U, tol=1e-11, starts=30, iters=80)
        assert np.all(r <= 1e-10), r.max()
        return a
    disk, left, right = tree
    p = _dim(left)
    c, s = np.linalg.norm(U[:, :p], axis=1), np.linalg.norm(U[:, p:], axis=1)
    unit = lambda V, r: np.where(r[:, None] > 0, V / np.maximum(r, 1e-300)[:, None], 0.0)  # noqa: E731
    return np.hstack([_witness(disk, np.c_[c, s]), _witness(left, unit(U[:, :p], c)),
                      _witness(right, unit(U[:, p:], s))])


@pytest.mark.parametrize("n", [3, 4, 5, 6, 8])
def test_compact_ball_contains_the_ball_and_support_within_target(n):
    """The set holds 600 points of the unit sphere and 200 inside it: the factor vector of Lemma 2's
    proof, evaluated through the set's own generators and exponents, reproduces each point (so a
    wrong product construction fails here); branch-and-bound support in random directions and
    the radius of 20,000 boundary samples are within the plan's bound R <= 1.03."""
    P = compact_ball_pz(n)
    tree, _, R = compact_ball_plan(n)
    rng = np.random.default_rng(n)
    U = _unit(rng, 800, n)
    U[600:] *= rng.uniform(0, 1, (200, 1))
    A = _witness(tree, U)
    assert A.shape == (800, P.n_factors) and np.all(np.abs(A) <= 1)
    np.testing.assert_allclose(_values(P.G, P.E, A), U, atol=1e-9)
    sb = support_bounds(P, _unit(rng, 40, n), tol=1e-4)
    # the lower bound is a point of the set (reaches the sphere in each d); with 14 factors (n = 8)
    # the block-wise search is too coarse for that, where it converges upper <= R must hold
    assert n == 8 or np.all(sb.lower >= 1 - 1e-9)
    assert (n > 4 or np.all(sb.converged)) and np.all(sb.upper[sb.converged] <= R + 1e-9)
    B = rng.uniform(-1, 1, (20_000, P.n_factors))
    B[np.arange(len(B)), rng.integers(0, P.n_factors, len(B))] = rng.choice((-1.0, 1.0), len(B))
    assert np.linalg.norm(_values(P.G, P.E, B), axis=1).max() <= R


@pytest.mark.parametrize("n", [4, 6])
def test_compact_product_radius_proved_by_bernstein(n):
    """The products' radius bound (Lemma 2) checked by an independent proof on |F|^2."""
    P = compact_ball_pz(n)
    C = squared_norm_in_squares(np.asarray(P.G), P.E)
    assert C is not None and max_over_unit_box(C, compact_ball_plan(n)[2] ** 2, max_boxes=100_000)[0]


def test_unit_ball_pz_beyond_five_is_the_compact_ball():
    P, Q = unit_ball_pz(6), compact_ball_pz(6)
    np.testing.assert_array_equal(P.G, Q.G)
    np.testing.assert_array_equal(P.E, Q.E)


def test_compact_ball_bad_input():
    with pytest.raises(SetError, match="n must be >= 1; got 0"):
        compact_ball_pz(0)
    with pytest.raises(SetError, match="not n=3"):
        compact_ball_pz(3, plan="d4")
    with pytest.raises(SetError, match="no plan with radius <= 1.001"):
        compact_ball_plan(4, 1.001)
    # ids: one per factor (8 for n = 6), not one per dimension; named in the message
    with pytest.raises(SetError, match=r"ids must hold one identifier per factor, 8 for n=6"):
        unit_ball_pz(6, ids=list(range(6)))
    assert list(compact_ball_pz(6, ids=list(range(100, 108))).id) == list(range(100, 108))


# ------------------------------------------------------------------ the stt input
@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_pz_compact_input_has_fresh_factors_and_the_throttle(n):
    U1, U2 = input_pz("ball", n, 1, "pz-compact"), input_pz("ball", n, 1, "pz-compact")
    assert U1.dim == n + 1 and not set(U1.id) & set(U2.id)
    assert U1.n_generators == compact_ball_plan(n)[1] + 1
    with pytest.raises(ProblemError, match="ball_input"):
        input_pz("ball", n, 0, "disk")


@pytest.mark.parametrize("n", [4, 5])
def test_pz_compact_and_auto_from_5d_on_are_within_3_percent(n):
    """No loose default: from 5-D on ``auto`` is the compact PZ, support in [1, 1.03] (branch and
    bound over all its factors jointly; 6-D takes ~1 min, covered by the radius tests above);
    4-D ``auto`` is the 16-direction zonotope by measurement (tests/test_stt_ball_input.py)."""
    U = input_pz("ball", n, 0, "auto" if n >= 5 else "pz-compact")
    assert BALL_INPUT_AUTO.get(n, BALL_INPUT_AUTO_ND) == ("pz-compact" if n >= 5 else "zonotope-coarse")
    assert U.n_generators == compact_ball_plan(n)[1]
    rng = np.random.default_rng(1)
    sb = support_bounds(U, _unit(rng, 30, n), tol=1e-3, max_block=U.n_factors)
    assert np.all(sb.converged) and np.all(sb.lower >= 1 - 1e-9) and np.all(sb.upper <= RADIUS_TARGET)
