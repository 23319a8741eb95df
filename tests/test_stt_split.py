"""Splitting of STT sets (``split``, ``max_parts``, ``split_tol``; ocreach/reach/stt_split.py).

Checked against independent truth: point-wise evaluation of the polynomial zonotopes (a split
must cover its part), Monte Carlo endpoints of the true dynamics (the split union must contain
them where the unsplit STT diverges), and the unsplit run (no split triggered = same sets).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ocreach.errors import ProblemError, SolverError
from ocreach.geometry import hull_area, outline_area, points_in_polygons
from ocreach.reach.mc import MonteCarlo
from ocreach.reach.stt import STTReach
from ocreach.reach.stt_split import error_samples, split_box, split_factor, truncation_error
from ocreach.registry import get_problem
from ocreach.sets import Interval, PolyZonotope, PZUnion, new_ids
from ocreach.sets.polyzonotope import make_dependent


def random_pz(rng, n, h, p, q):
    E = (rng.random((p, h)) < 0.4) * rng.integers(1, 3, (p, h))
    return PolyZonotope(0.1 * rng.standard_normal(n), rng.standard_normal((n, h)),
                        rng.standard_normal((n, q)), E, new_ids(p))


def evaluate_by_id(pz: PolyZonotope, values: dict) -> np.ndarray:
    """Points of a PZ without independent generators for factor values given per identifier."""
    return pz.evaluate(np.column_stack([values[int(i)] for i in pz.id]))


def vdp_box(width: float):
    base = get_problem("vdp")
    return dataclasses.replace(base, initial_set=Interval(base.x0 - width, base.x0 + width))


def test_split_factor_halves_cover_the_part_exactly():
    """Every point of the part is a point of one half (factor a -> 2a +- 1) and every point of a
    half is a point of the part: the union of the halves equals the part."""
    rng = np.random.default_rng(0)
    pz = random_pz(rng, 3, 12, 4, 3)
    dep = make_dependent(pz)
    phi2 = rng.standard_normal((3, 5, 5))
    lo, hi = split_factor(dep, phi2)
    A = {int(i): rng.uniform(-1, 1, 400) for i in dep.id}
    x = evaluate_by_id(dep, A)
    ok = False
    for fid in A:  # the split factor is the one whose values are re-expanded: try each
        a = A[fid]
        back = np.where(a <= 0, 2 * a + 1, 2 * a - 1)
        vals = {**A, fid: back}
        y = np.where((a <= 0)[:, None], evaluate_by_id(lo, vals), evaluate_by_id(hi, vals))
        if np.allclose(x, y, atol=1e-10):
            ok = True
            # and the converse: a half at a' is the part at (a' -+ 1) / 2
            b = rng.uniform(-1, 1, 400)
            np.testing.assert_allclose(evaluate_by_id(lo, {**A, fid: b}), evaluate_by_id(dep, {**A, fid: (b - 1) / 2}),
                                       atol=1e-10)
            np.testing.assert_allclose(evaluate_by_id(hi, {**A, fid: b}), evaluate_by_id(dep, {**A, fid: (b + 1) / 2}),
                                       atol=1e-10)
            break
    assert ok


def test_split_box_halves_contain_the_part():
    """Every point of the part (dense extreme and uniform factor samples) lies in one of the two
    halves, which are parallelotopes: solve for their factors and check |a| <= 1."""
    rng = np.random.default_rng(1)
    pz = random_pz(rng, 4, 10, 3, 2)
    x = np.vstack([pz.sample(3000, rng, mode="extreme"), pz.sample(3000, rng)])
    hit = np.zeros(len(x), dtype=bool)
    for h in split_box(pz, rng.standard_normal((4, 6, 6))):
        assert h.n_generators == 4 and h.n_independent == 0 and np.all(h.E.sum(axis=0) == 1)
        a = np.linalg.solve(h.G, (x - h.c).T).T
        hit |= np.max(np.abs(a), axis=1) <= 1 + 1e-9
    assert hit.all()
    # with kept generators the halves are no parallelotopes; their union still contains the part
    # (checked by the support function of the halves' exact enclosures against the samples)
    D = rng.standard_normal((200, 4))
    halves = split_box(pz, None, keep=3)
    h = np.max([hv.support(D) for hv in halves], axis=0)
    assert np.all(h >= (x @ D.T).max(axis=0) - 1e-9)
    # and point-wise: every sample lies in the zonotope enclosure of one half (a membership LP
    # per point; the support check above only tests the convex hull of the union), while each
    # half alone misses some of them (so the check can fail)
    inside = [hv.contains(x) for hv in halves]
    assert np.all(inside[0] | inside[1])
    assert not inside[0].all() and not inside[1].all()


def test_no_split_triggered_equals_unsplit():
    p = vdp_box(0.1)
    plain = STTReach(order=2, h_max=60).solve(p)
    same = STTReach(order=2, h_max=60, split="factor", split_tol=1e6).solve(p)
    assert same.meta["parts"] == [1] * len(p.grid) and same.meta["evaluations"]["splits"] == 0
    assert np.all(same.meta["truncation_error"] > 0)
    D = np.random.default_rng(0).standard_normal((32, 2))
    for a, b in zip(plain.sets, same.sets):
        np.testing.assert_allclose(a.support(D), b.support(D), rtol=1e-12, atol=1e-14)


def test_split_union_covers_mc_where_unsplit_diverges():
    """vdp with the initial box x0 +- 0.3: the unsplit order-2 STT diverges (measured area 1e31x
    the MC hull), the split one keeps every MC endpoint inside its union (measured 3.8x the MC
    hull with 12 parts, docs/validation/stt.md)."""
    p = vdp_box(0.3)
    with pytest.raises(SolverError):
        STTReach(order=2, h_max=40).solve(p)
    r = STTReach(order=2, h_max=40, split="factor", max_parts=12).solve(p)
    assert isinstance(r.sets[-1], PZUnion) and 2 <= r.meta["parts"][-1] <= 12
    assert r.meta["parts"][0] == 1 and r.meta["evaluations"]["splits"] == r.meta["parts"][-1] - 1
    end = MonteCarlo(samples=800, seed=3).solve(p).points[-1]
    polys = r.sets[-1].outline((0, 1), pieces=64)
    assert points_in_polygons(end, polys).mean() == 1.0
    assert outline_area(polys) < 10 * hull_area(end)


def test_truncation_error_is_zero_for_an_exact_polynomial():
    """A quadratic flow is reproduced exactly by its order-2 expansion; order 1 is not."""
    rng = np.random.default_rng(2)
    phi = [rng.standard_normal((2, 3)), rng.standard_normal((2, 3, 3))]
    phi[1] = phi[1] + phi[1].transpose(0, 2, 1)
    dZ = random_pz(rng, 3, 5, 3, 0)

    S = error_samples(dZ)
    true = S @ phi[0].T + 0.5 * np.einsum("iab,na,nb->ni", phi[1], S, S)
    assert S.shape == (24, 3) and np.all(np.abs(dZ.contains(S[:3])))
    assert truncation_error(phi, S, true) < 1e-12
    assert truncation_error(phi[:1], S, true) > 1e-3


@pytest.mark.parametrize("opts, word", [
    (dict(split=(4, 0.01)), "replaced"), (dict(split="x"), "split"), (dict(split="factor", max_parts=0), "max_parts"),
    (dict(max_parts=2.5), "max_parts"), (dict(max_parts="many"), "max_parts"), (dict(split_tol=0), "split_tol"),
    (dict(split_tol=-1.0), "split_tol"), (dict(split_tol=float("nan")), "split_tol"),
    (dict(split_tol="a"), "split_tol"),
    (dict(split_keep=-1), "split_keep"), (dict(split_keep=1.5), "split_keep")])
def test_bad_split_options(opts, word):
    with pytest.raises(ProblemError, match=word):
        STTReach(**opts)


def test_option_forms_are_accepted():
    o = STTReach(split="box", max_parts=8.0, split_tol="0.05", split_keep=0).options
    assert (o.split, o.max_parts, o.split_tol, o.split_keep) == ("box", 8, 0.05, 0)
    assert STTReach(split="none").options.split is None
