"""Regularised coordinates (ocreach.models.coordinates): the charts, the sound way back to
Cartesian, and guaranteed methods run in the charts, checked against independent truth.

Truth: SciPy DOP853 at rtol 1e-12 on the numpy right-hand sides of ``tests/_reach_truth.py``, in
Cartesian coordinates, from the initial set's vertices and interior, with constant, bang-bang and
random admissible controls; every grid time against the set, the interior times of every step
against the step's tube (scaled gauge <= 1 + 1e-9).  Short horizons keep the suite fast; the
full-horizon measurements are in ``benchmarks/bench_coordinates.py``.
"""
from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest
from _reach_truth import assert_contained, ball_controls, initial_samples, simulate

import ocreach
from ocreach.errors import ProblemError, UnknownNameError
from ocreach.models import twobody
from ocreach.models.coordinates import chart_for, parse
from ocreach.models.coordinates.convert import MapEnclosure, slice_at
from ocreach.problem import Problem, time_grid
from ocreach.reach.coordinates import transform
from ocreach.registry import get_problem
from ocreach.sets.union import union_gauge
from ocreach.sets.zonotope import Zonotope

TOL = 1 + 1e-9
HOUR = 3600.0 / 375200.0


def _earth_mars(days: float, box: float = 1e-5) -> Problem:
    p = get_problem("earth-mars", t_days=days)
    n = p.model.n_x
    return dataclasses.replace(p, initial_set=Zonotope(p.x0, box * np.eye(n)))


def _truth(problem: Problem, n_per_law: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    K = problem.n_segments
    X0 = initial_samples(rng, problem.initial_set, 3 * n_per_law)
    U = np.concatenate([ball_controls(rng, n_per_law, K, law) for law in ("constant", "bang", "random")])
    return simulate(problem, X0, U, inner=2)


# ------------------------------------------------------------------------------------ the charts
def test_mee_round_trip_and_kepler_drift():
    p = get_problem("earth-mars")
    ch = chart_for(parse("mee:frame=inertial"), p.model, p.x0)
    z0 = np.asarray(ch.function("phi")(p.x0, p.params)).ravel()
    x_back = np.asarray(ch.function("psi")(z0, p.params)).ravel()
    assert np.allclose(x_back, p.x0, rtol=0, atol=1e-14)
    # coasting: only L moves, at sqrt(mu p) (w / p)^2; with thrust the generated rates equal the
    # chain rule dphi/dx f on the Cartesian state
    zdot = np.asarray(ch.dynamics.f_fun(z0, np.zeros(3), 0.0, p.params)).ravel()
    assert np.all(np.abs(zdot[:5]) == 0) and zdot[5] > 0
    J = ca.Function("J", [p.model.x], [ca.jacobian(ca.substitute(ch.phi, p.model.p, p.params), p.model.x)])
    u = np.array([0.3, -0.5, 0.7])
    chain = np.asarray(J(p.x0)) @ p.model(p.x0, u, 0.0, p.params)
    got = np.asarray(ch.dynamics.f_fun(z0, u, 0.0, p.params)).ravel()
    assert np.allclose(got, chain, rtol=1e-11, atol=1e-14)


def test_map_enclosure_contains_images_of_samples():
    p = get_problem("earth-mars")
    ch = chart_for(parse("mee"), p.model, p.x0)
    z0 = np.asarray(ch.function("phi")(p.x0, p.params)).ravel()
    back = MapEnclosure("psi", ch.z, ch.psi, p.model.p, p.params, ch.valid_z)
    psi = ch.function("psi")
    rng = np.random.default_rng(4)
    for scale in (1e-6, 1e-3, 1e-2, 3e-2):
        Z = Zonotope(z0, scale * rng.standard_normal((6, 8)) * np.array([1, 0.3, 0.3, 0.1, 0.1, 2])[:, None])
        S = back.image(Z, max_pieces=8)
        W = np.vstack([Z.sample(300, rng, "extreme"), Z.sample(300, rng)])
        X = np.asarray(psi.map(W.shape[0])(W.T, p.params)).T
        assert union_gauge(S, X).max() <= TOL


def test_slice_contains_the_states_at_that_time():
    rng = np.random.default_rng(5)
    T = Zonotope(rng.standard_normal(4), rng.standard_normal((4, 7)))
    for value in np.linspace(T.c[3] - 2, T.c[3] + 2, 9):
        C = slice_at(T, 3, float(value))
        xi = rng.uniform(-1, 1, (20000, 7))
        W = T.evaluate(xi)
        near = np.abs(W[:, 3] - value) < 1e-3
        if C is None:
            assert not near.any()
            continue
        # points of T on the hyperplane: move each near point onto it along the eliminated factor
        # is not needed for the check: the slice must contain its exact members, tested on points
        # of T that satisfy the constraint after correcting xi_j
        a = T.G[3]
        j = int(np.argmax(np.abs(a)))
        xi[:, j] = (value - T.c[3] - xi @ a + xi[:, j] * a[j]) / a[j]
        ok = np.abs(xi[:, j]) <= 1
        P = T.evaluate(xi[ok])[:, :3]
        assert union_gauge(C, P).max() <= TOL


# --------------------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize("spec, err", [("polar", UnknownNameError), ("mee:pieces=0", ProblemError),
                                       ("mee:foo=1", ProblemError), ("sundman:k=3", ProblemError),
                                       ("sundman:body=mars", ProblemError), ("", ProblemError),
                                       ("mee:frame=lvlh", ProblemError)])
def test_bad_coordinate_specs(spec, err):
    with pytest.raises(err):
        parse(spec)
    with pytest.raises(err):
        ocreach.reach(get_problem("earth-mars", t_days=2.0), "taylor", coordinates=spec)


def test_coordinates_that_do_not_fit_the_model_are_refused():
    with pytest.raises(ProblemError, match="two-body"):
        ocreach.reach(get_problem("nrho-9-2", t_final=2 * HOUR), "taylor", coordinates="mee")
    with pytest.raises(ProblemError, match="CR3BP"):
        ocreach.reach(get_problem("earth-mars", t_days=2.0), "taylor", coordinates="sundman")
    with pytest.raises(ProblemError):  # problem override, same check
        ocreach.reach(get_problem("nrho-9-2", t_final=2 * HOUR, coordinates="mee"), "mc")


def _circular(x_dir: np.ndarray, v_dir: np.ndarray, box: float = 0.0) -> Problem:
    model = twobody(mu=1.0, a_max=1e-3)
    x0 = np.concatenate([x_dir, v_dir])
    S = Zonotope(x0, box * np.eye(6)) if box else None
    return Problem(id="circ", model=model, x0=x0, grid=time_grid(0.2, 0.1), initial_set=S)


def test_singular_initial_sets():
    # zero eccentricity and inclination: regular
    res = ocreach.reach(_circular(np.array([1.0, 0, 0]), np.array([0, 1.0, 0])), "taylor",
                        coordinates="mee")
    assert res.meta["guaranteed"] and res.times.size == 3
    # retrograde equatorial: singular, refused before any work
    with pytest.raises(ProblemError, match="singular|retrograde"):
        ocreach.reach(_circular(np.array([1.0, 0, 0]), np.array([0, -1.0, 0])), "taylor",
                      coordinates="mee")
    # rectilinear
    with pytest.raises(ProblemError, match="singular|rectilinear"):
        ocreach.reach(_circular(np.array([1.0, 0, 0]), np.array([0.5, 0, 0])), "taylor",
                      coordinates="mee")
    # an initial box that reaches inclination 180 deg
    with pytest.raises(ProblemError, match="singular"):
        ocreach.reach(_circular(np.array([1.0, 0, 0]), np.array([0, -1.0, 1e-3]), box=1e-2),
                      "taylor", coordinates="mee")


def test_disturbance_and_sampling_in_time_transformed_charts_refused():
    p = _earth_mars(2.0)
    with pytest.raises(ProblemError, match="disturbance"):
        ocreach.reach(p, "taylor", coordinates="mee", disturbance=1e-3)
    with pytest.raises(ProblemError, match="sample"):
        ocreach.reach(p, "mc", coordinates="mee-longitude", samples=10)


def test_chart_refuses_a_model_with_another_drift():
    r = ca.SX.sym("r", 3)
    v = ca.SX.sym("v", 3)
    u = ca.SX.sym("u", 3)
    mu = ca.SX.sym("mu")
    a = ca.SX.sym("a_max")
    rn = ca.norm_2(r)
    f = ca.vertcat(v, -mu * r / rn**3 * (1 + 1e-3 / rn**2) + a * u)   # an oblate-like extra term
    model = ocreach.Model.build("twobody-j2", ca.vertcat(r, v), u, f, p=ca.vertcat(mu, a),
                                p_default=[1.0, 1e-3], param_names=["mu", "a_max"],
                                thrust_param="a_max")
    prob = Problem(id="j2", model=model, x0=np.array([1.0, 0, 0, 0, 1.0, 0.1]),
                   grid=time_grid(0.2, 0.1))
    with pytest.raises(ProblemError, match="another drift"):
        transform(prob, "mee")


# ------------------------------------------------------------------------ sound end to end
@pytest.mark.parametrize("coords", ["mee", "mee-longitude", "mee:frame=inertial"])
def test_taylor_in_mee_contains_cartesian_truth(coords):
    p = _earth_mars(6.0)
    res = ocreach.reach(p, "taylor", coordinates=coords, max_parts=1)
    assert res.meta["guaranteed"] and not res.meta.get("truncated")
    assert res.meta["coordinates"]["name"] == coords.partition(":")[0]
    assert np.allclose(res.times, p.grid)
    ends, mids = _truth(p, 20)
    assert res.times.size == ends.shape[1]
    assert_contained(res, ends, mids)


def test_taylor_sundman_on_the_nrho_contains_cartesian_truth():
    p = get_problem("nrho-9-2", t_final=4 * HOUR)
    res = ocreach.reach(p, "taylor", coordinates="sundman:k=1.5")
    assert res.meta["guaranteed"] and res.times.size == p.grid.size
    ends, mids = _truth(p, 20, seed=1)
    assert res.times.size == ends.shape[1]
    assert_contained(res, ends, mids)


def test_mc_in_mee_matches_cartesian_mc():
    p = get_problem("earth-mars", t_days=10.0)
    a = ocreach.reach(p, "mc", samples=30, seed=3)
    b = ocreach.reach(p, "mc", samples=30, seed=3, coordinates="mee:frame=inertial")
    assert b.meta["coordinates"]["name"] == "mee" and b.controls is not None
    for k in range(p.grid.size):
        assert np.allclose(a.points[k], b.points[k], rtol=0, atol=1e-8)
    # controls in the orbit's frame: other samples of the same set, controls not passed on
    c = ocreach.reach(p, "mc", samples=30, seed=3, coordinates="mee")
    assert c.controls is None and c.meta["coordinates"]["control_frame"] == "rtn"


def test_problem_override_and_cli_spec():
    p = get_problem("earth-mars", t_days=2.0, coordinates="mee:pieces=4")
    assert p.coordinates == "mee:pieces=4"
    res = ocreach.reach(p, "taylor")
    assert res.meta["coordinates"]["settings"]["pieces"] == 4
    with pytest.raises(UnknownNameError):
        get_problem("earth-mars", coordinates="polar")
