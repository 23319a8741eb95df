"""Order-3 products of the fused STT step with the pruned ones bounded, never formed
(``pruned_box="bound"``, :class:`ocreach.reach.stt_products.BoundedOrder3Products`)."""
from __future__ import annotations

import numpy as np
import pytest

import ocreach
from ocreach.dynamics.flow import stt_polynomial
from ocreach.errors import ProblemError
from ocreach.reach.mc import MonteCarlo
from ocreach.reach.stt import STTReach, fused_step
from ocreach.reach.stt_products import BoundedOrder3Products, Order3Products, order3_products
from ocreach.registry import get_problem
from ocreach.sets import PolyZonotope, new_ids
from ocreach.sets.polyzonotope import sym_tensor


def _products(T3, Ga, thr, chunk, cls):
    """The class's product object (after its pass) and its kept products, sorted by index."""
    prod = cls(T3, Ga, thr, chunk)
    vals, tris = zip(*prod.kept(absum=True))
    V, T = np.hstack(vals), np.hstack(tris)
    order = np.lexsort(T[::-1])
    return prod, V[:, order], T[:, order]


@pytest.mark.parametrize("n, nz, H, thr, chunk", [(2, 3, 70, 1e-3, 500), (3, 4, 45, 1e-2, 97),
                                                  (2, 2, 90, 1e-4, 10 ** 6), (2, 3, 30, 0.0, 50)])
def test_bounded_products_keep_the_same_products_and_bound_the_pruned(n, nz, H, thr, chunk):
    """Against the class that forms every product: the same kept products (indices and values to
    round-off), the same number pruned, their Gram matrix to round-off (it fixes the PCA frame),
    and sums of |D^T x| over the pruned products that are upper bounds (and not wildly loose)
    for the unit vectors and a random orthogonal frame."""
    rng = np.random.default_rng(H + nz)
    T3 = sym_tensor(rng.standard_normal((n, nz, nz, nz)))
    Ga = rng.standard_normal((nz, H)) * 0.9 ** rng.permutation(H)
    exact, Ve, Te = _products(T3, Ga, thr, chunk, Order3Products)
    bound, Vb, Tb = _products(T3, Ga, thr, chunk, BoundedOrder3Products)
    np.testing.assert_array_equal(Tb, Te)
    assert np.all(np.diff(Te[0] * Ga.shape[1] ** 2 + Te[1] * Ga.shape[1] + Te[2]) > 0)  # each once
    np.testing.assert_allclose(Vb, Ve, rtol=1e-12, atol=1e-15)
    assert bound.count == exact.count and (exact.count > 0) == (thr > 0)
    if exact.count == 0:
        return
    scale = np.abs(exact.gram).max()
    np.testing.assert_allclose(bound.gram, exact.gram, rtol=0, atol=1e-12 * scale)
    U = np.linalg.svd(rng.standard_normal((n, n)))[0]
    for b, e in [(bound.absum, exact.absum), (bound.proj_abs(U), exact.proj_abs(U))]:
        assert np.all(b >= e * (1 - 1e-12)) and np.all(b <= 3 * e), (b, e)


def test_bounded_pruned_box_contains_the_exact_step():
    """One fused step, 70 generators of decaying size (> 50,000 order-3 products: pruning on):
    the bound box changes only the reduction's box, so centre, dependent generators and
    exponents equal the exact path's, the set's support is >= the exact one in every direction,
    and the exact image (Eq. 13 on extreme samples) stays inside."""
    rng = np.random.default_rng(7)
    E = (rng.random((8, 70)) < 0.25) * rng.integers(1, 3, (8, 70))
    G = rng.standard_normal((3, 70)) * 0.8 ** np.arange(70)
    pz = PolyZonotope(0.1 * rng.standard_normal(3), G, None, E, new_ids(8))
    phi = [rng.standard_normal((2,) + (3,) * j) for j in (1, 2, 3)]
    D = rng.standard_normal((100, 2))
    h_pts = (sum(stt_polynomial(phi, pz.sample(10000, rng, mode="extreme"))) @ D.T).max(axis=0)
    for method in ("pca", "girard"):
        counts = {"tensor_maps": 0, "reductions": 0}
        exact = fused_step(phi, pz, 40, method, counts=counts)
        assert counts["pruned"] > 0
        bound = fused_step(phi, pz, 40, method, pruned_box="bound")
        np.testing.assert_allclose(bound.c, exact.c, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(bound.G, exact.G, rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(bound.E, exact.E)
        he, hb = exact.support(D), bound.support(D)
        assert np.all(hb >= he - 1e-12 * np.abs(he).max())
        assert np.all(hb >= h_pts - 1e-9)


def test_short_vdp_run_both_boxes_contain_mc_endpoints():
    """vdp (order 3, h_max 80: the order-3 step prunes) over 0.6 TU: both boxes contain 2,000 MC
    endpoints (support in 64 directions >= their maximum); the bound run's supports are the
    exact run's up to round-off and at most 1 % of the width above (pruned products are tiny
    over so few steps)."""
    p = get_problem("vdp", t_final=0.6)
    th = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    D = np.c_[np.cos(th), np.sin(th)]
    end = MonteCarlo(samples=2000, seed=3, mix=(0.3, 0.2, 0.5)).solve(p).points[-1]
    res = {box: ocreach.reach(p, "stt", order=3, h_max=80, pruned_box=box)
           for box in ("exact", "bound")}
    for box, r in res.items():
        assert r.meta["options"]["pruned_box"] == box
        assert np.all(r.sets[-1].support(D) >= (end @ D.T).max(axis=0) - 1e-9), box
    he, hb = (res[box].sets[-1].support(D) for box in ("exact", "bound"))
    width = he + np.roll(he, 32)
    assert np.all(hb >= he - 1e-12 * width) and np.all(hb - he <= 0.01 * width)   # measured: 1e-14


@pytest.mark.parametrize("thr", [1e-3, 1e-1])
def test_bounded_sums_are_exact_with_one_factor(thr):
    """With one factor (nz = 1) the triangle inequality is an equality, |u^T A g| = |u^T A| |g|,
    so the bounds must equal the exact sums: any pruned product missed, counted twice or with a
    wrong multiplicity shows here (the slack of the bound hides it with nz > 1)."""
    rng = np.random.default_rng(5)
    T3 = rng.standard_normal((3, 1, 1, 1))
    Ga = rng.standard_normal((1, 120)) * 0.95 ** np.arange(120)
    exact, _, _ = _products(T3, Ga, thr, 1000, Order3Products)
    bound, _, _ = _products(T3, Ga, thr, 1000, BoundedOrder3Products)
    assert 0 < exact.count == bound.count
    U = np.linalg.svd(rng.standard_normal((3, 3)))[0]
    np.testing.assert_allclose(bound.absum, exact.absum, rtol=1e-12)
    np.testing.assert_allclose(bound.proj_abs(U), exact.proj_abs(U), rtol=1e-12)
    np.testing.assert_allclose(bound.gram, exact.gram, rtol=1e-12, atol=1e-14 * np.abs(exact.gram).max())


def test_pruned_box_option_is_checked():
    with pytest.raises(ProblemError, match="pruned_box.*'exact', 'bound'.*'tight'"):
        STTReach(pruned_box="tight")
    assert STTReach(pruned_box="bound").options.pruned_box == "bound"
    # the library engine prunes nothing: an explicit "exact" there is refused, naming both options
    with pytest.raises(ProblemError, match="pruned_box='exact'.*engine='fused'.*engine='library'"):
        STTReach(engine="library", pruned_box="exact")
    assert STTReach(engine="library").options.pruned_box == "bound"
    assert STTReach(engine="fused", pruned_box="exact").options.pruned_box == "exact"
    with pytest.raises(ValueError, match="pruned_box"):
        order3_products(np.zeros((1, 1, 1, 1)), np.ones((1, 2)), 0.0, 10, "tight")
