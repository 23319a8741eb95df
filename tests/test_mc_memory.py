"""Stochastic Monte Carlo keeps only what is asked for, with the same numbers."""
from __future__ import annotations

import numpy as np
import pytest

import ocreach
from ocreach.dynamics import stochastic_mc
from ocreach.dynamics.stochastic_mc import stochastic_monte_carlo
from ocreach.errors import ProblemError
from ocreach.registry import get_problem


@pytest.fixture(scope="module")
def glider():
    return get_problem("glider-reentry", t_final=6.0)


def test_default_keeps_final_samples_and_grid_moments(glider, monkeypatch):
    K = glider.n_segments
    full = stochastic_monte_carlo(glider, samples=300, seed=2, times="all")
    assert full["trajectories"].shape == (300, K + 1, 6)
    monkeypatch.setattr(stochastic_mc, "_DRAW_BLOCK", 7)  # normals drawn a few steps at a time
    small = stochastic_monte_carlo(glider, samples=300, seed=2)
    assert small["trajectories"].shape == (300, 1, 6) and "controls" not in small
    np.testing.assert_array_equal(small["trajectories"][:, 0], full["trajectories"][:, -1])
    np.testing.assert_array_equal(small["grid_mean"], full["grid_mean"])
    np.testing.assert_array_equal(small["grid_std"], full["grid_std"])
    # the moments are those of the kept samples (independent check on the full history)
    np.testing.assert_allclose(full["grid_mean"], full["trajectories"].mean(axis=0), rtol=1e-12,
                               atol=1e-12)
    np.testing.assert_allclose(full["grid_std"], full["trajectories"].std(axis=0, ddof=1),
                               rtol=1e-10, atol=1e-12)
    with pytest.raises(ProblemError, match="times must be grid times, None"):
        stochastic_monte_carlo(glider, samples=10, times="every")


def test_mc_method_histories_option(glider):
    lean = ocreach.reach(glider, "mc", samples=200, seed=5)
    rich = ocreach.reach(glider, "mc", samples=200, seed=5, histories=True)
    assert lean.controls is None and rich.controls is not None
    assert rich.controls.shape == (200, glider.n_segments, glider.model.n_u)
    assert lean.times[0] == glider.grid[0] and lean.times[-1] == glider.grid[-1]
    assert len(lean.times) < len(rich.times)
    np.testing.assert_array_equal(lean.points[-1], rich.points[-1])
    assert lean.meta["grid_mean"].shape == (glider.grid.size, 6)
    np.testing.assert_allclose(lean.meta["grid_mean"][-1], rich.points[-1].mean(axis=0), rtol=1e-12)
    with pytest.raises(ProblemError, match="histories must be a boolean"):
        ocreach.reach(glider, "mc", samples=10, histories="maybe")
