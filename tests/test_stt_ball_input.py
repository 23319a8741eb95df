"""Zonotope ball input of stt (issue 12: the ball input's tightness after reduction).

Truth: the support function of the true reachable set by direct multiple shooting
(``transcription_support``, independent of the STT code) and Monte Carlo endpoints."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import ocreach
from ocreach.errors import ProblemError
from ocreach.geometry import circle_directions
from ocreach.problem import ControlSet, get_problem
from ocreach.reach.direct import transcription_support
from ocreach.reach.mc import MonteCarlo
from ocreach.reach.stt import input_pz
from ocreach.sets import unit_ball_zonotope
from ocreach.sets.pz_exact import support_bounds


def _sphere(n: int) -> np.ndarray:
    """Fibonacci directions on the unit sphere."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    th = np.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(1 - z * z)
    return np.column_stack([r * np.cos(th), r * np.sin(th), z])


def test_dodecahedral_ball_zonotope_contains_the_ball_within_10_percent():
    Z = unit_ball_zonotope(3, 10)
    assert Z.G.shape == (3, 10)
    h = np.abs(_sphere(200_000) @ Z.G).sum(axis=1)          # support of a zonotope at the origin
    assert h.min() >= 1 - 1e-12                             # contains the ball (touches the facets)
    assert h.max() <= 1.0955                                # within 9.6 % (vertex directions)
    np.testing.assert_allclose(np.linalg.norm(Z.G, axis=0), np.linalg.norm(Z.G[:, 0]))  # one length


@pytest.mark.parametrize("n", [2, 3])
def test_zonotope_ball_input_is_linear_in_fresh_factors_and_contains_the_ball(n):
    U = input_pz("ball", n, 1, ball="zonotope")
    k = {2: 6, 3: 10}[n]
    assert U.n_factors == k + 1 and U.n_independent == 0 and np.all(U.E.sum(axis=0) == 1)
    D = _sphere(2000) if n == 3 else circle_directions(2000)
    h = np.asarray(U.project(list(range(n))).support(D))
    assert h.min() >= 1 - 1e-12 and h.max() <= (1.0955 if n == 3 else 1.0353)
    with pytest.raises(ProblemError, match="ball_input"):
        ocreach.reach(get_problem("vdp"), "stt", ball_input="disk")


def test_dro_disk_ball_input_support_within_10_percent_of_truth():
    """Foss's DRO with the disk control set, n = 2, h_max = 400 (issue 12's target: support never
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
