"""nrho-flyby (Foss Sec. 4.2): the ``x0`` / ``epoch`` options and the perilune measurement."""
from __future__ import annotations

import numpy as np
import pytest
from ocreach.problems.foss_ephemeris import X0, flyby_model, moon_position, perilune
from scipy.integrate import solve_ivp

from ocreach.errors import ProblemError
from ocreach.geometry.directions import fibonacci_sphere
from ocreach.models.ephemeris import synodic_to_inertial
from ocreach.registry import get_problem


def test_default_x0_is_the_papers_and_override_is_used():
    p = get_problem("nrho-flyby")
    np.testing.assert_array_equal(p.x0, [0.91, -0.01, 0.16, 0.03, -0.08, 0.01])
    x1 = [0.912, -0.011, 0.158, 0.031, -0.079, 0.012]
    q = get_problem("nrho-flyby", x0=x1)
    np.testing.assert_array_equal(q.x0, x1)
    assert q.extra["x0"] == x1 and "x0 = " in q.description
    # the override changes the trajectory (a different reference), the default stays the paper's
    from ocreach.dynamics.flow import propagate

    U = np.zeros((q.n_segments, 3))
    assert np.linalg.norm(propagate(q.model, q.x0, U, q.grid)[-1] - propagate(p.model, p.x0, U, p.grid)[-1]) > 1e-3
    np.testing.assert_array_equal(X0, [0.91, -0.01, 0.16, 0.03, -0.08, 0.01])  # not mutated


def test_x0_from_the_cli(tmp_path):
    from ocreach.cli import main

    rc = main(["run", "nrho-flyby", "--method", "mc", "--set", "samples=4", "--set",
               "problem.x0=[0.912, -0.011, 0.158, 0.031, -0.079, 0.012]", "--set", "problem.t_final=0.1",
               "--out", str(tmp_path / "o")])
    assert rc == 0
    traj = np.load(tmp_path / "o" / "result.npz")["trajectories"]
    np.testing.assert_array_equal(traj[:, 0], np.tile([0.912, -0.011, 0.158, 0.031, -0.079, 0.012], (4, 1)))


@pytest.mark.parametrize("bad", [[0.91, -0.01, 0.16], [0.91, -0.01, 0.16, 0.03, -0.08, np.nan],
                                 [0.91, -0.01, 0.16, 0.03, -0.08, np.inf], "0.91,0.1", [[0.9] * 6],
                                 [0.91, -0.01, 0.16, 0.03, -0.08, "a"], 0.91])
def test_bad_x0_names_the_parameter(bad):
    with pytest.raises(ProblemError, match=r"x0 must"):
        get_problem("nrho-flyby", x0=bad)


def test_bad_epoch_names_the_parameter():
    with pytest.raises(ProblemError, match="epoch"):
        get_problem("nrho-flyby", epoch="May 1st")


def test_moon_position_is_the_moon():
    """The Moon on the synodic +x axis, mapped back to ICRF by the frame transform, is the
    ephemeris Moon (independent: the inertial DE421 fit)."""
    m = flyby_model()
    eph, tu = m.cache["ephemeris"], m.cache["frame"]["tu"]
    for t in (0.0, 0.37, 1.0):
        r = synodic_to_inertial(m, t, np.r_[moon_position(m, t), 0, 0, 0])[:3]
        np.testing.assert_allclose(r, eph.position("moon", t * tu, "ssb"), atol=1e-6)


def _event_perilune(model, x0, t_final):
    """Perilune by scipy DOP853 with a root-found event on the radial velocity w.r.t. the Moon."""
    p = model.p_default
    du, tu = model.cache["frame"]["du_km"], model.cache["frame"]["tu"]
    eph = model.cache["ephemeris"]

    def moon(t):
        r = eph.position("moon", t * tu, "emb")
        v = eph.position("moon", t * tu, "emb", derivative=1) * tu
        d = np.linalg.norm(r)
        return np.array([d, 0, 0]) / du, np.array([r @ v / d, 0, 0]) / du

    def radial(t, x):
        rm, vm = moon(t)
        return (x[:3] - rm) @ (x[3:] - vm)

    radial.direction = 1.0
    sol = solve_ivp(lambda t, x: np.asarray(model(x, np.zeros(3), t, p)).ravel(), (0, t_final), x0,
                    method="DOP853", rtol=1e-12, atol=1e-13, events=radial)
    te, xe = sol.t_events[0], sol.y_events[0]
    return te, np.array([np.linalg.norm(x[:3] - moon(t)[0]) * du for t, x in zip(te, xe)])


def test_perilune_against_an_event_located_perilune():
    m = flyby_model()
    x0 = np.vstack([X0, X0 + [0.004, -0.003, 0.002, -0.004, 0.005, -0.002]])
    got = perilune(m, x0)
    for j in range(2):
        te, de = _event_perilune(m, x0[j], 1.0)
        assert te.size >= 1 and got["interior"][j]
        i = int(np.argmin(de))
        assert abs(got["time"][j] - te[i]) < 2e-5  # TU (7 s)
        assert abs(got["distance_km"][j] - de[i]) < 0.1  # km, of ~10,000
    # before the perilune: no interior minimum, the distance at t_final
    early = perilune(m, X0, t_final=0.5)
    assert not early["interior"][0] and early["time"][0] == pytest.approx(0.5)
    from ocreach.dynamics.flow import propagate

    x_end = propagate(m, X0, np.zeros((1, 3)), [0.0, 0.5])[-1]
    d_end = np.linalg.norm(x_end[:3] - moon_position(m, 0.5)) * m.cache["frame"]["du_km"]
    assert early["distance_km"][0] == pytest.approx(d_end, rel=1e-9)


def _example(name):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"example_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_fig6_truth_data_against_the_points():
    """The extents of examples/foss_fig6_nrho.truth_data: the reference is the ballistic
    trajectory (scipy DOP853, independent integrator), and each extent (max over 64 directions
    of the support about the reference) lies between cos(largest gap) and 1 times the largest
    distance of the points from the reference."""
    ex = _example("foss_fig6_nrho")
    p = get_problem("nrho-flyby", t_final=0.2, x0=[0.912, -0.011, 0.158, 0.031, -0.079, 0.012])
    tr = ex.truth_data(p, extremals=40, mc_samples=30)
    sol = solve_ivp(lambda t, x: p.model(x, np.zeros(3), t), (0, 0.2), p.x0, method="DOP853",
                    rtol=1e-12, atol=1e-13, t_eval=p.grid)
    np.testing.assert_allclose(tr["ref"], sol.y.T, atol=1e-9)
    D = tr["D"]
    gap = np.max(np.min(np.arccos(np.clip(fibonacci_sphere(4000) @ D.T, -1, 1)), axis=1))
    for res, ext in ((tr["ode"], tr["ode_extent"]), (tr["mc"], tr["mc_extent"])):
        for k in range(1, p.grid.size):
            r = np.linalg.norm(np.asarray(res.points[k])[:, :3] - sol.y[:3, k], axis=1).max()
            assert np.cos(gap) * r - 1e-12 <= ext[k] <= r + 1e-12
    pts = np.vstack([np.asarray(tr["mc"].points[-1])[:, :3], np.asarray(tr["ode"].points[-1])[:, :3]])
    np.testing.assert_allclose(tr["support"][-1], (pts @ D.T).max(axis=0))
    assert ex.parse_x0("[0.9, -0.01,0.16,0.03,-0.08,0.01]") == [0.9, -0.01, 0.16, 0.03, -0.08, 0.01]
