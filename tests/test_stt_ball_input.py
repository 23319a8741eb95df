"""Zonotope ball input of stt: the ball input's tightness after reduction.

Truth: the support function of the true reachable set by direct multiple shooting
(``transcription_support``, independent of the STT code) and Monte Carlo endpoints."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import ocreach
from ocreach.errors import ProblemError, SetError
from ocreach.geometry import circle_directions
from ocreach.geometry.directions import fibonacci_sphere
from ocreach.problem import ControlSet
from ocreach.reach.direct import transcription_support
from ocreach.reach.mc import MonteCarlo
from ocreach.reach.stt import input_pz
from ocreach.registry import get_problem
from ocreach.sets import unit_ball_zonotope, zonotope_support_range
from ocreach.sets.pz_exact import support_bounds


def _latlong(step: float) -> np.ndarray:
    """Latitude-longitude grid on the unit sphere with spacing ``step`` (rad) in both angles:
    every unit vector is within arc length ``step / sqrt(2)`` of a grid point."""
    th = np.arange(0.0, np.pi + step, step)
    ph = np.arange(0.0, 2 * np.pi, step)
    T, P = np.meshgrid(th, ph, indexing="ij")
    return np.column_stack([(np.sin(T) * np.cos(P)).ravel(), (np.sin(T) * np.sin(P)).ravel(),
                            np.cos(T).ravel()])


def _grid_support_range(G: np.ndarray, D: np.ndarray) -> tuple[float, float]:
    lo, hi = np.inf, -np.inf
    for j in range(0, D.shape[0], 200_000):
        h = np.abs(D[j:j + 200_000] @ G).sum(axis=1)           # support of a zonotope at the origin
        lo, hi = min(lo, h.min()), max(hi, h.max())
    return float(lo), float(hi)


@pytest.mark.parametrize("k", [6, 7, 8])
def test_2d_ball_zonotope_support_range_is_the_regular_polygon(k):
    """Regular 2k-gon with inradius 1: circumradius 1 / cos(pi / 2k) (closed form)."""
    Z = unit_ball_zonotope(2, k)
    lo, hi = zonotope_support_range(Z)
    assert lo == pytest.approx(1.0, abs=1e-12)
    assert hi == pytest.approx(1 / np.cos(np.pi / (2 * k)), abs=1e-12)
    glo, ghi = _grid_support_range(Z.G, circle_directions(100_000))
    assert glo >= lo - 1e-12 and ghi <= hi + 1e-12 and ghi >= hi - 1e-6


@pytest.mark.parametrize("k, exact, bound", [(10, 1.0955, 1.099), (30, 1.0269, 1.03)])
def test_3d_ball_zonotope_contains_the_ball_and_support_range_is_exact(k, exact, bound):
    """Exact range (facet offsets, vertex norms) against a dense latitude-longitude grid: the
    support is Lipschitz with constant R = max support, so the true maximum over the sphere lies
    in [grid max, grid max + R step / sqrt(2)], independently of the vertex enumeration."""
    Z = unit_ball_zonotope(3, k)
    assert Z.G.shape == (3, k)
    np.testing.assert_allclose(np.linalg.norm(Z.G, axis=0), np.linalg.norm(Z.G[:, 0]))  # one length
    lo, hi = zonotope_support_range(Z)
    assert lo >= 1 - 1e-12 and hi <= exact                   # contains the ball (min facet offset)
    step = 0.004
    glo, ghi = _grid_support_range(Z.G, _latlong(step))
    margin = hi * step / np.sqrt(2)
    assert glo >= lo - 1e-12 and glo <= lo + margin          # the grid confirms the inradius
    assert ghi <= hi + 1e-12 and ghi >= hi - margin          # ... and the circumradius
    assert ghi + margin <= bound                             # target proved by the grid alone


def test_zonotope_support_range_bad_input():
    from ocreach.sets import Zonotope

    with pytest.raises(SetError, match="not full-dimensional"):
        zonotope_support_range(Zonotope(np.zeros(3), np.eye(3)[:, :2]))


@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("ball, k, bound", [("zonotope", {2: 8, 3: 30}, {2: 1.0196, 3: 1.027}),
                                            ("zonotope-coarse", {2: 6, 3: 10}, {2: 1.0353, 3: 1.0955})])
def test_zonotope_ball_input_is_linear_in_fresh_factors_and_contains_the_ball(n, ball, k, bound):
    U = input_pz("ball", n, 1, ball=ball)
    assert U.n_factors == k[n] + 1 and U.n_independent == 0 and np.all(U.E.sum(axis=0) == 1)
    D = fibonacci_sphere(2000) if n == 3 else circle_directions(2000)
    h = np.asarray(U.project(list(range(n))).support(D))
    assert h.min() >= 1 - 1e-12 and h.max() <= bound[n]
    with pytest.raises(ProblemError, match="ball_input"):
        ocreach.reach(get_problem("vdp"), "stt", ball_input="disk")


@pytest.mark.parametrize("n, k", [(1, 1), (2, 8), (3, 10), (4, 16), (5, 7)])
def test_auto_ball_input_per_dimension(n, k):
    """1-D the interval, 2-D 8 generators, 3-D / 4-D the coarse zonotope (by measurement), 5-D
    the compact PZ (7 factors, 32 generators)."""
    U = input_pz("ball", n, 0, ball="auto")
    assert U.n_factors == k
    if n in (3, 4):
        assert U.n_generators == k and np.all(U.E.sum(axis=0) == 1)


@pytest.mark.parametrize("k, exact", [(16, 1.1466), (24, 1.0990)])
def test_4d_ball_zonotope_spread_directions(k, exact):
    """4-D spread directions: exact range (facet offsets, vertex norms) confirmed by 400,000
    random unit directions (inside the range, and the sampled maximum close to it)."""
    Z = unit_ball_zonotope(4, k)
    lo, hi = zonotope_support_range(Z)
    assert lo == pytest.approx(1.0, abs=1e-12) and hi <= exact
    rng = np.random.default_rng(5)
    X = rng.standard_normal((400_000, 4))
    h = np.abs((X / np.linalg.norm(X, axis=1, keepdims=True)) @ Z.G).sum(axis=1)
    assert h.min() >= lo - 1e-12 and h.max() <= hi + 1e-12 and h.max() >= hi - 0.01


def test_nd_ball_zonotope_contains_the_ball():
    """n >= 4: axes plus pseudo-random directions, contains the ball (no tightness target)."""
    Z = unit_ball_zonotope(4, 8)
    lo, hi = zonotope_support_range(Z)
    assert lo >= 1 - 1e-12 and hi > 1.03                      # documented: looser than 3 %
    rng = np.random.default_rng(3)
    X = rng.standard_normal((50_000, 4))
    h = np.abs((X / np.linalg.norm(X, axis=1, keepdims=True)) @ Z.G).sum(axis=1)
    assert h.min() >= lo - 1e-12 and h.max() <= hi + 1e-12


def test_dro_disk_ball_input_support_within_10_percent_of_truth():
    """Foss's DRO with the disk control set, n = 2, h_max = 400 (the target: support never
    more than 10 % of the width above the true support; no MC endpoint outside)."""
    p = get_problem("dro")
    p = dataclasses.replace(p, control_set=ControlSet("ball", p.model.n_u))
    res = ocreach.reach(p, "stt", order=2, h_max=400, input_set="ball")
    S = res.sets[-1]
    mc = MonteCarlo(samples=2000, seed=11, mix=(0.3, 0.2, 0.5)).solve(p).points[-1]
    D = circle_directions(12)
    for dims in ([0, 1], [2, 3]):
        truth = []
        for d in D:
            z = np.zeros(p.model.n_x)
            z[dims] = d
            truth.append(transcription_support(p, z))
        h = np.maximum(np.array(truth), (mc[:, dims] @ D.T).max(axis=0))
        width = h + h[(np.arange(12) + 6) % 12]
        sb = support_bounds(S.project(dims), D)
        assert np.all(sb.upper >= h - 1e-6 * width)             # the truth's support is reached
        assert np.max((sb.upper - h) / width) <= 0.10, (dims, (sb.upper - h) / width)
