"""ocreach.custody.sweep_task (the hook of the sweep layer's keep.custody) on tiny cases.

Truth: positions on spheres of known radius r_k around a fixed centre seen from the geocentre
on the line of sight, so the MEB is the sphere, the covered fraction of a circular FOV of
half-angle h is exactly tan^2(h) / tan^2(asin(r/D)) (capped at 1), and the first failing grid
time follows in closed form.
"""
import json

import numpy as np
import pytest

from ocreach.custody import sweep_task
from ocreach.errors import ProblemError
from ocreach.reach.result import ReachResult
from ocreach.registry import get_problem


@pytest.fixture(scope="module")
def prob():
    return get_problem("custody-l1")


def _sphere_result(prob, radii_km, dt_days=0.25):
    mu = prob.model.param("mu", prob.params)
    km = prob.units.length / 1e3
    day = 86400.0 / prob.units.time
    c = np.array([0.8, 0.0, 0.0])
    rng = np.random.default_rng(0)
    u = rng.normal(size=(400, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u = np.vstack([u, np.eye(3), -np.eye(3)])
    pts = [np.hstack([c + (r / km) * u, np.zeros((u.shape[0], 3))]) for r in radii_km]
    times = np.arange(len(radii_km)) * dt_days * day
    return ReachResult(times=times, points=pts), c, mu, km


def test_sweep_task_matches_closed_form(prob):
    radii = np.array([0.0, 500.0, 1500.0, 3000.0, 6000.0, 12000.0])
    res, c, mu, km = _sphere_result(prob, radii)
    D_km = (c[0] + mu) * km
    fov_deg = 1.0
    h = np.deg2rad(fov_deg / 2)
    frac = np.minimum(1.0, np.tan(h) ** 2 / np.tan(np.arcsin(np.maximum(radii, 1e-9) / D_km)) ** 2)
    for p in (1.0, 0.5):
        out = sweep_task(prob, res, observer="geocentre", fov_deg=fov_deg, p_required=p)
        json.dumps(out)  # plain JSON
        fail = np.flatnonzero(frac[1:] < p)
        assert fail.size, "the synthetic case must lose custody"
        k = fail[0] + 1
        assert out["lost"] and out["t_loss_days"] == pytest.approx(0.25 * k)
        assert out["t_safe_days"] == pytest.approx(0.25 * (k - 1))
        assert out["t_safe_days"] < out["t_loss_days"]
        assert out["horizon_resolution_days"] == pytest.approx(0.25)
        assert out["meb_radius_km"] == pytest.approx(radii[-1], rel=1e-9)
        assert out["p_end"] == pytest.approx(frac[-1], rel=1e-9)
    # with t_max_days before the loss, custody holds to the end of the window
    out = sweep_task(prob, res, fov_deg=fov_deg, p=1.0, t_max_days=0.25)
    assert out["t_loss_days"] is None and not out["lost"] and out["t_safe_days"] == pytest.approx(0.25)


def test_sweep_task_scores_the_start(prob):
    # a set already too large for the FOV at t = 0: custody is lost at the start, no horizon
    res, *_ = _sphere_result(prob, [12000.0, 12000.0, 12000.0])
    out = sweep_task(prob, res, observer="geocentre", fov_deg=1.0, p_required=0.95)
    assert out["lost_at_start"] and out["t_safe_days"] is None and out["t_loss_days"] == 0.0
    ok = sweep_task(prob, _sphere_result(prob, [0.0, 12000.0])[0], fov_deg=1.0, p_required=0.95)
    assert not ok["lost_at_start"] and ok["t_safe_days"] == 0.0 and ok["t_loss_days"] == pytest.approx(0.25)


def test_sweep_task_real_mc_result(prob):
    from ocreach.reach.base import reach

    small = get_problem("custody-l1", t_days=0.5, dt_hours=6.0)
    res = reach(small, "mc", samples=60, seed=1)
    out = sweep_task(small, res, observer="L2", fov_deg=0.5, fov_shape="square", p=0.9)
    json.dumps(out)
    # the MEB radius bounds every sampled distance from the sample mean (independent check)
    P = np.asarray(res.points[-1])[:, :3]
    spread = np.linalg.norm(P - P.mean(axis=0), axis=1).max() * small.units.length / 1e3
    assert spread / 2 <= out["meb_radius_km"] <= spread * (1 + 1e-9)
    assert out["observer"] == "L2" and out["fov_shape"] == "square"


def test_sweep_task_bad_input(prob):
    res, *_ = _sphere_result(prob, [0.0, 100.0])
    with pytest.raises(ProblemError, match="unknown argument.*fov_degs.*allowed"):
        sweep_task(prob, res, fov_degs=1.0)
    with pytest.raises(ProblemError, match="fov_deg"):
        sweep_task(prob, res)
    with pytest.raises(ProblemError, match=r"\(0, 180\)"):
        sweep_task(prob, res, fov_deg=0.0)
    with pytest.raises(ProblemError, match=r"\(0, 1\]"):
        sweep_task(prob, res, fov_deg=1.0, p=1.5)
    with pytest.raises(ProblemError, match="observer must be"):
        sweep_task(prob, res, fov_deg=1.0, observer="moonbase")
    with pytest.raises(ProblemError, match="t_max_days"):
        sweep_task(prob, res, fov_deg=1.0, t_max_days=-1)
