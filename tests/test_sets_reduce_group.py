"""reduce_pz(group="parallel"): the grouped enclosure of removed parallel monomials is sound
(every point of the original set is in the reduced set for the SAME kept factor values) and
tighter than the monomial-wise enclosure on a compact-ball-like input."""
import importlib

import numpy as np
import pytest
from _sets_truth import lp_in_zonotope
from hypothesis import given, settings
from hypothesis import strategies as st

from ocreach.errors import ProblemError, SetError
from ocreach.reach.stt import STTReach, fused_step
from ocreach.sets import PolyZonotope, new_ids, tensor_map
from ocreach.sets.polyzonotope import enclose_monomials

R = importlib.import_module("ocreach.sets.reduce")  # the package re-exports the function `reduce`

SET = settings(max_examples=25, deadline=None)


def grouped_pz(rng, n, p, n_dirs, per_dir, n_free, q=0, emax=4):
    """A PZ whose dependent generators come in bundles of parallel (some nearly parallel) columns
    along ``n_dirs`` directions, plus ``n_free`` generic columns and ``q`` independent ones."""
    cols = []
    for _ in range(n_dirs):
        d = rng.standard_normal(n)
        for _ in range(per_dir):
            g = rng.standard_normal() * d
            if rng.random() < 0.3:  # nearly parallel: a residual far below the grouping grid
                g = g + 1e-9 * rng.standard_normal(n)
            cols.append(g)
    cols += [0.3 * rng.standard_normal(n) for _ in range(n_free)]
    G = np.column_stack(cols)
    E = rng.integers(0, emax + 1, size=(p, G.shape[1])) * (rng.random((p, G.shape[1])) < 0.6)
    return PolyZonotope(rng.standard_normal(n), G, 0.2 * rng.standard_normal((n, q)), E, new_ids(p))


def assert_contains_pointwise(orig, red, rng, N=120):
    """x(a, b) of ``orig`` minus the reduced set's dependent part at the same factor values ``a``
    must lie in the reduced set's independent zonotope (an LP over its independent factors): the
    reduced set contains the point with the same dependent factors (stronger than membership)."""
    A = rng.uniform(-1, 1, (N, orig.n_factors))
    A[: N // 3] = np.sign(A[: N // 3])                     # vertices of the factor box too
    A[N // 3: N // 2] = 0.0
    A[N // 3: N // 2, rng.integers(0, orig.n_factors, N // 2 - N // 3)] = 1.0
    B = rng.choice([-1.0, 1.0], (N, orig.n_independent)) if orig.n_independent else None
    X = orig.evaluate(A, B)
    Ar = A[:, np.searchsorted(orig.id, red.id)]             # the reduced set's (kept) factors
    if red.n_factors:
        Xd = PolyZonotope(red.c, red.G, None, red.E, red.id).evaluate(Ar)
    else:                                                   # only constant monomials kept
        Xd = np.tile(red.c + red.G.sum(axis=1), (N, 1))
    for x, xd in zip(X, Xd):
        assert lp_in_zonotope(np.zeros(red.dim), red.GI, x - xd)   # tol 1e-7 (HiGHS)


@pytest.mark.parametrize("group", ["parallel", "parallel-drop"])
@SET
@given(seed=st.integers(0, 10_000), n=st.integers(1, 3), q=st.integers(0, 2))
def test_grouped_reduction_contains_every_point_with_the_same_factors(group, seed, n, q):
    rng = np.random.default_rng(seed)
    pz = grouped_pz(rng, n, int(rng.integers(1, 4)), 3, 4, 5, q)
    h_max = int(rng.integers(n, pz.n_generators))
    red = R.reduce_pz(pz, h_max, "pca", group=group)
    assert red.n_generators <= h_max
    assert_contains_pointwise(pz, red, rng)


def test_regroup_drop_removes_split_groups_whole():
    rng = np.random.default_rng(1)
    d = rng.standard_normal(3)
    G = np.column_stack([3 * d, 0.1 * d, 0.05 * d] + [rng.standard_normal(3) for _ in range(5)])
    norms = np.linalg.norm(G, axis=0)
    dep = np.ones(8, dtype=bool)
    keep = np.zeros(8, dtype=bool)
    keep[np.argsort(-norms)[:4]] = True
    assert keep[0] and not keep[1:3].any()                   # the ranking splits the group
    kd = R.regroup_drop(G, dep, keep, "parallel-drop")
    assert not kd[:3].any() and (kd[3:] == keep[3:]).all()
    assert (R.regroup_drop(G, dep, keep, "parallel") == keep).all()
    dep[:3] = False                                          # only dependent generators group
    assert (R.regroup_drop(G, dep, keep, "parallel-drop") == keep).all()


def ball_like(c0=1.0, c1=-0.31):
    """Two parallel monomials of a compact PZ ball component ``a1 (c0 + c1 a2^2)`` along v, and
    three larger generators, two of which a reduction to 4 generators removes too."""
    v = np.array([0.3, -1.2, 0.5])
    G = np.column_stack([np.diag([5.0, 4.0, 3.0]), c0 * v, c1 * v])
    E = np.zeros((5, 5), dtype=np.int64)
    E[np.arange(2, 5), np.arange(3)] = 1
    E[0, 3] = 1
    E[0, 4], E[1, 4] = 1, 2
    return PolyZonotope(np.zeros(3), G, None, E, new_ids(5)), v


def test_grouped_ball_component_is_enclosed_by_its_range_not_the_coefficient_sum():
    pz, v = ball_like()
    # the removed part alone: its range along v against a dense grid of a1 (1 - 0.31 a2^2)
    a = np.linspace(-1, 1, 401)
    q = (a[:, None] * (1.0 - 0.31 * a[None, :] ** 2)).ravel()
    true_half = np.linalg.norm(v) * (q.max() - q.min()) / 2
    d = v / np.linalg.norm(v)
    shift, Z = R.enclose_removed(pz.G[:, 3:], pz.E[:, 3:], "parallel")
    shift0, Z0 = enclose_monomials(pz.G[:, 3:], pz.E[:, 3:])
    half1, half0 = np.abs(d @ Z).sum(), np.abs(d @ Z0).sum()
    assert abs(d @ shift) <= 1e-12 and abs(d @ shift0) <= 1e-12
    assert true_half * (1 - 1e-12) <= half1 <= true_half * 1.01   # the range, within 1 %
    assert half0 / half1 == pytest.approx(1.31, rel=0.01)         # old: |c0| + |c1|
    # through reduce_pz (two of the big generators are boxed with them): tighter along v too
    red0 = R.reduce_pz(pz, 4, "girard")
    red1 = R.reduce_pz(pz, 4, "girard", group="parallel")
    assert red0.n_dependent == red1.n_dependent == 1
    assert np.abs(d @ red1.GI).sum() < np.abs(d @ red0.GI).sum() - 0.2 * np.linalg.norm(v) * 0.9


def test_scalar_range_against_dense_grid():
    rng = np.random.default_rng(3)
    for _ in range(10):
        alpha = rng.standard_normal(5)
        E = rng.integers(0, 4, (2, 5))
        lo, hi = R.scalar_range(alpha, E)
        a = np.linspace(-1, 1, 301)
        A1, A2 = np.meshgrid(a, a)
        vals = sum(al * A1 ** e[0] * A2 ** e[1] for al, e in zip(alpha, E.T))
        assert lo <= vals.min() + 1e-12 and hi >= vals.max() - 1e-12
        naive = np.abs(alpha[np.any(E, axis=0)]).sum()
        assert hi - lo <= 2 * naive + 1e-12


def test_bad_group_values_are_refused():
    pz, _ = ball_like()
    with pytest.raises(SetError, match="group must be one of"):
        R.reduce_pz(pz, 4, group="paralel")
    with pytest.raises(ProblemError, match="reduce_group must be one of"):
        STTReach.Options(reduce_group="yes")


def test_default_is_unchanged_and_fused_equals_library_with_groups():
    rng = np.random.default_rng(7)
    pz = grouped_pz(rng, 3, 4, 2, 3, 6)
    phi = [rng.standard_normal((2, 3)), rng.standard_normal((2, 3, 3))]
    assert R.reduce_pz(pz, 8, "pca").support(np.eye(3)).tolist() == \
        R.reduce_pz(pz, 8, "pca", group=None).support(np.eye(3)).tolist()
    L = phi[0] @ pz + tensor_map(phi[1] / 2.0, pz)
    for group in R.GROUPS:
        F = fused_step(phi, pz, 15, group=group)
        Lr = R.reduce_pz(L, 15, "pca", group=group)
        D = rng.standard_normal((20, 2))
        np.testing.assert_allclose(F.support(D), Lr.support(D), rtol=1e-9, atol=1e-9)
        assert_contains_pointwise(L, Lr, rng, N=60)
