"""Orbit maintenance as flown (ocreach.control.stationkeeping): SRP, navigation and execution
errors, burn placement, x-axis control, STT target point, the loop, the Monte Carlo store and
the report, on a few revolutions (the year-long Monte Carlo is benchmarks/bench_orbit_maintenance.py
and docs/validation/orbit-maintenance.md)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ocreach.control.stationkeeping import (
    ExecutionErrors,
    MaintenanceSettings,
    NavigationErrors,
    SolarRadiationPressure,
    make_controller,
    run_maintenance,
    scenario,
)
from ocreach.errors import ProblemError

#: a short scenario: 0.04 years (2.2 revolutions) plus 3 revolutions of look-ahead
SHORT = {"years": 0.04, "lookahead": 3}


@pytest.fixture(scope="module")
def short():
    settings = MaintenanceSettings.from_options(**SHORT)
    return settings, scenario(settings.scenario)


# ------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("make, word", [
    (lambda: SolarRadiationPressure(area_to_mass=-0.01), "area_to_mass"),
    (lambda: SolarRadiationPressure(cr=0.5), "cr"),
    (lambda: SolarRadiationPressure(uncertainty=-0.1), "uncertainty"),
    (lambda: NavigationErrors(position_sigma_km=-1.0), "nav_position_sigma_km"),
    (lambda: NavigationErrors(velocity_sigma_mps=float("nan")), "nav_velocity_sigma_mps"),
    (lambda: NavigationErrors(od_interval_h=0), "od_interval_h"),
    (lambda: ExecutionErrors(magnitude_sigma=-0.01), "magnitude_sigma"),
    (lambda: ExecutionErrors(pointing_sigma_deg=-1), "pointing_sigma_deg"),
    (lambda: ExecutionErrors(min_burn_mps=-0.01), "min_burn_mps"),
    (lambda: ExecutionErrors(skip_probability=1.5), "skip_probability"),
    (lambda: ExecutionErrors(skipped_burns=(-1,)), "skipped_burns"),
    (lambda: MaintenanceSettings.from_options(burn_anomaly_deg=360.0), "burn_anomaly_deg"),
    (lambda: MaintenanceSettings.from_options(burn_anomaly_deg=-1.0), "burn_anomaly_deg"),
    (lambda: MaintenanceSettings.from_options(area_to_mass=-1), "area_to_mass"),
    (lambda: MaintenanceSettings.from_options(nav_position_sigma_km=-1), "nav_position"),
    (lambda: MaintenanceSettings.from_options(no_such_option=1), "no_such_option"),
    (lambda: make_controller("xaxis", {"target_revolutions": 0}), "target_revolutions"),
    (lambda: make_controller("nope"), "controller"),
    (lambda: make_controller("corridor", {"corridor_position_km": -5.0}), "corridor_position_km"),
    (lambda: make_controller("corridor", {"corridor_velocity_mps": 0.0}),
     "corridor_velocity_mps"),
    (lambda: make_controller("corridor", {"horizon_revolutions": 0}), "horizon_revolutions"),
    (lambda: make_controller("corridor", {"horizon_revolutions": 1.5}), "horizon_revolutions"),
    (lambda: make_controller("corridor", {"execution_in_tube": "yes"}), "execution_in_tube"),
    (lambda: make_controller("corridor", {"null_unstable": 1}), "null_unstable"),
    (lambda: make_controller("corridor", {"beta": 0.5}), "beta"),
])
def test_bad_input_is_refused_with_the_parameter_named(make, word):
    with pytest.raises(ProblemError, match=word):
        make()


def test_bad_input_fails_before_any_work(tmp_path, monkeypatch):
    """Zero runs, a negative area/mass or an anomaly of 360 deg: ProblemError before the
    scenario is built or anything is written (the Monte Carlo is never reached)."""
    import ocreach
    from ocreach.cli import main
    from ocreach.control.stationkeeping import maintenance_report

    def boom(*a, **k):
        raise AssertionError("work started")

    monkeypatch.setattr(maintenance_report, "run_monte_carlo", boom)
    p = ocreach.get_problem("nrho-9-2")
    out = tmp_path / "om"
    for kw, word in (({"runs": 0}, "runs"), ({"area_to_mass": -0.1}, "area_to_mass"),
                     ({"burn_anomaly_deg": 360}, "burn_anomaly_deg"),
                     ({"nav_velocity_sigma_mps": -1e-3}, "nav_velocity_sigma_mps"),
                     ({"magnitude_sigma": -0.1}, "magnitude_sigma"),
                     ({"controllers": "xaxis,bogus"}, "controller")):
        with pytest.raises(ProblemError, match=word):
            maintenance_report.orbit_maintenance_report(p, out, **kw)
    for argv in (["--runs", "0"], ["--years", "-1"], ["--workers", "0"],
                 ["--set", "area_to_mass=-0.1"], ["--set", "burn_anomaly_deg=360"],
                 ["--set", "burn_anomaly_deg=-5"], ["--set", "nav_position_sigma_km=-1"],
                 ["--set", "magnitude_sigma=-0.01"], ["--set", "pointing_sigma_deg=-1"],
                 ["--controllers", "xaxis,bogus"],
                 ["--set", "corridor.corridor_position_km=-5"],
                 ["--set", "corridor.corridor_velocity_mps=0"],
                 ["--set", "corridor.horizon_revolutions=0"]):
        assert main(["report", "orbit-maintenance", "--problem", "nrho-9-2", *argv,
                     "--out", str(out)]) == 2, argv
    assert not any(tmp_path.iterdir())


# ------------------------------------------------------------------------------ error models
def test_execution_errors_have_the_stated_statistics():
    exe = ExecutionErrors(magnitude_sigma=0.02, pointing_sigma_deg=0.5, min_burn_mps=0.01)
    rng = np.random.default_rng(1)
    dv = np.array([0.03, -0.04, 0.0])  # 5 cm/s
    out = np.array([exe.execute(dv, i, rng)[0] for i in range(6000)])
    ratio = np.linalg.norm(out, axis=1) / 0.05
    angle = np.degrees(np.arccos(np.clip(out @ dv / (np.linalg.norm(out, axis=1) * 0.05), -1, 1)))
    assert abs(ratio.mean() - 1) < 2e-3 and abs(ratio.std() - 0.02) < 1.5e-3
    # two independent N(0, s^2) tilts: the angle is Rayleigh, RMS sqrt(2) s
    assert abs(np.sqrt(np.mean(angle**2)) - np.sqrt(2) * 0.5) < 0.03
    assert exe.execute(np.array([0.005, 0, 0]), 0, rng)[1] == "below_minimum"
    skip = ExecutionErrors(skipped_burns=(3,))
    assert skip.execute(dv, 3, rng) == (pytest.approx(np.zeros(3)), "skipped")
    assert skip.execute(dv, 2, rng)[1] == "executed"
    assert ExecutionErrors(skip_probability=1.0).execute(dv, 0, rng)[1] == "skipped"


def test_navigation_draws_have_the_stated_sigma():
    from ocreach.units import EARTH_MOON_PATEL as U

    nav = NavigationErrors(position_sigma_km=2.0, velocity_sigma_mps=0.03)
    rng = np.random.default_rng(2)
    E = np.array([nav.draw(rng, U) for _ in range(20000)])
    assert np.allclose(E[:, :3].std(axis=0) * U.length / 1e3, 2.0, rtol=0.03)
    assert np.allclose(E[:, 3:].std(axis=0) * U.velocity, 0.03, rtol=0.03)
    assert np.allclose(nav.box(U, 3.0)[:3] * U.length / 1e3, 6.0)


def test_srp_acceleration_is_the_cannonball_formula(short):
    """The frame model with SRP minus the one without, at a reference state: magnitude
    C_r (A/m) P (1 AU / d)^2, directed away from the Sun (checked in the inertial frame)."""
    from ocreach.control.stationkeeping.srp import AU_KM, P_1AU_N_M2

    _, sc = short
    srp = sc.spec.srp
    x, t = sc.X[40], sc.times[40]
    with_srp = np.asarray(sc.model.f_fun(x, np.zeros(3), t, sc.params_with(1.5))).ravel()
    base = np.asarray(sc.model.f_fun(x, np.zeros(3), t, sc.params_with(0.0))).ravel()
    a = (with_srp - base)[3:] * sc.units.acceleration
    C = sc.plant.axes(t)
    r_sc = C @ (x[:3] - np.array([1 - sc.params[0], 0, 0])) * sc.units.length / 1e3
    d = r_sc - sc.plant.ephemeris.position("sun", t * sc.units.time, "moon")
    expect = 1.5 * srp.cr * srp.area_to_mass * P_1AU_N_M2 * (AU_KM / np.linalg.norm(d)) ** 2
    assert np.linalg.norm(a) == pytest.approx(expect, rel=1e-9)
    assert np.dot(C @ a, d) / (np.linalg.norm(a) * np.linalg.norm(d)) == pytest.approx(1, abs=1e-9)


# ------------------------------------------------------------------------------ scenario
def test_burn_steps_at_apolune_and_step_jacobians(short):
    _, sc = short
    d = np.linalg.norm(sc.X[:, :3] - np.array([1 - sc.params[0], 0, 0]), axis=1)
    for k in sc.anomaly_steps(180.0, last=sc.X.shape[0] - 1):
        lo, hi = max(k - 3, 0), min(k + 4, d.size)
        assert abs(int(np.argmax(d[lo:hi])) + lo - k) <= 1
    for k in sc.anomaly_steps(0.0, last=sc.X.shape[0] - 1):
        assert abs(int(np.argmin(d[k - 3:k + 4])) + k - 3 - k) <= 1
    A, B = sc.jacobians
    k, e = 60, 1e-7
    J = np.column_stack([(sc.propagate(sc.X[k] + e * np.eye(6)[i], k, k + 1, sc.params)[-1]
                          - sc.propagate(sc.X[k] - e * np.eye(6)[i], k, k + 1, sc.params)[-1])
                         / (2 * e) for i in range(6)])
    assert np.abs(J - A[k]).max() < 1e-6 * np.abs(A[k]).max()


def _scipy_flow(sc, x, t0, t1, p):
    def rhs(t, y):
        return np.asarray(sc.model.f_fun(y, np.zeros(3), t, p)).ravel()

    return solve_ivp(rhs, (t0, t1), x, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]


def test_synodic_map_puts_the_earth_on_the_negative_x_axis_at_rest(short):
    """The Earth, written in the controllers' frame and mapped by Scenario.synodic_map, sits at
    (-|r_EM|, 0, 0) with velocity (-d|r_EM|/dt, 0, 0): the frame's axes and angular velocity
    (about z and about x) are the true Earth-Moon rotating frame's."""
    _, sc = short
    du, tu = sc.units.length / 1e3, sc.units.time
    E = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    for k in (0, 50, 200):
        t = sc.times[k]
        r = sc.plant.ephemeris.position("moon", t * tu, "earth")
        v = sc.plant.ephemeris.position("moon", t * tu, "earth", derivative=1)
        C = sc.plant.axes(t)
        s_ = C.T @ (-r) / du
        x = np.r_[s_ + np.array([1 - sc.params[0], 0, 0]), C.T @ (-v) * tu / du - E @ s_]
        q = sc.synodic(t, x)
        rdot = r @ v / np.linalg.norm(r)
        assert np.allclose(q[:3] * du, [-np.linalg.norm(r), 0, 0], atol=1e-6)
        assert np.allclose(q[3:] * du / tu, [-rdot, 0, 0], atol=1e-9)


def test_xaxis_burn_meets_the_targeted_crossing_velocity(short):
    """From an estimate 20 km / 3 cm/s off at apolune, the x-axis burn makes the trajectory
    cross the Earth-Moon x-z plane at the targeted perilune with the reference's v_x there
    (within 1 mm/s), checked by an independent SciPy DOP853 propagation and root find."""
    _, sc = short
    ctl = make_controller("xaxis", {"target_revolutions": 1})
    ctl.prepare(sc, None)
    k = int(sc.anomaly_steps(180.0)[1])
    dx = np.r_[np.array([12.0, -10.0, 11.0]) * 1e3 / sc.units.length,
               np.array([0.02, 0.015, -0.015]) / sc.units.velocity]
    x = sc.X[k] + dx
    dv = ctl.burn(sc, k, x)
    assert ctl.last_converged
    cross = sc.perilune_crossings
    i = int(np.flatnonzero(cross["time"] > sc.times[k])[0])
    x1 = x.copy()
    x1[3:] += dv
    t = cross["time"][i]
    for _ in range(8):
        q = sc.synodic(t, _scipy_flow(sc, x1, sc.times[k], t, sc.params))
        t -= q[1] / q[4]
    q = sc.synodic(t, _scipy_flow(sc, x1, sc.times[k], t, sc.params))
    assert abs(q[1]) * sc.units.length < 1.0
    assert abs(q[3] - cross["synodic"][i, 3]) * sc.units.velocity < 1e-3
    assert 1e-3 < np.linalg.norm(dv) * sc.units.velocity < 1.0


def test_target_point_second_order_prediction_beats_the_first(short):
    """The composed order-2 STTs of the target-point method predict the deviation at each
    target better than order 1, for a 30 km / 3 cm/s deviation (independent SciPy flow)."""
    settings, sc = short
    k = int(sc.anomaly_steps(180.0)[0])
    dz = np.r_[np.array([20.0, 15.0, -15.0]) * 1e3 / sc.units.length,
               np.array([0.02, -0.02, 0.01]) / sc.units.velocity]
    errs = {}
    for order in (1, 2):
        tp = make_controller("target-point", {"order": order})
        tp.prepare(sc, settings)
        c, P1, P2 = tp.tensors(sc, k)
        pred = c + np.einsum("nia,a->ni", P1, dz) + 0.5 * np.einsum("niab,a,b->ni", P2, dz, dz)
        true = np.array([_scipy_flow(sc, sc.X[k] + dz, sc.times[k], sc.times[k + s], sc.params)
                         - sc.X[k + s] for s in tp._steps])
        errs[order] = np.abs(pred - true)[:, :3].max() * sc.units.length / 1e3
    assert errs[2] < 0.2 * errs[1]


# ------------------------------------------------------------------------------ the loop
@pytest.mark.parametrize("name, options", [("xaxis", {}), ("target-point", {}), ("lqr", {}),
                                           ("tube-mpc", {"tube_source": "linear"}),
                                           ("corridor", {"horizon_revolutions": 2})])
def test_short_runs_keep_the_orbit(short, name, options):
    settings, sc = short
    r = run_maintenance(settings, make_controller(name, options), 0)
    assert not r["lost"], r["loss"]
    assert r["steps"] == sc.steps and np.isfinite(r["dv_total_mps"])
    assert 0 <= r["dv_total_mps"] < 2.0 and r["max_position_deviation_km"] < 200.0
    assert r["srp_scale"] == run_maintenance(settings, make_controller("xaxis"), 0)["srp_scale"]
    if name in ("xaxis", "target-point"):  # one burn opportunity per revolution, at apolune
        assert r["burns_planned"] == len(sc.anomaly_steps(180.0))
    if name in ("xaxis", "target-point", "corridor"):
        assert r["opportunities"] == len(sc.anomaly_steps(180.0))
        assert all(170 < b["anomaly_deg"] < 190 for b in r["burns"])
    if name == "corridor":  # the true state never left the corridor; no burn below the minimum
        assert r["corridor_exit_steps"] == 0 and 0 < r["corridor_max_ratio"] < 1
        assert all(b["status"] == "executed" for b in r["burns"])


def test_execution_bound_holds_for_the_drawn_burns():
    """The execution-error ball of the corridor's sets: an executed burn lies within c_e |dv|
    of its command in all but 0.1 % of the draws (at most), and the bound is not loose: the
    0.999 quantile of the drawn errors is above 0.75 c_e."""
    from ocreach.control.stationkeeping.corridor import execution_bound

    exe = ExecutionErrors(magnitude_sigma=0.01, pointing_sigma_deg=1 / 3, min_burn_mps=0.0)
    ce = execution_bound(exe)
    rng = np.random.default_rng(3)
    dv = np.array([0.02, 0.01, -0.03])
    err = np.array([np.linalg.norm(exe.execute(dv, i, rng)[0] - dv)
                    for i in range(10000)]) / np.linalg.norm(dv)
    assert np.mean(err > ce) < 0.0015
    assert np.quantile(err, 0.999) > 0.75 * ce


def test_corridor_sets_contain_the_sampled_true_states(short):
    """The set box of the corridor's gauge at the next opportunity (predicted deviation, mapped
    navigation ellipsoid, SRP dispersion tube) contains the true deviation of every sampled
    navigation error and SRP scale, propagated in the nonlinear plant; a deviation that needs
    a burn gets one, at least the minimum burn, and the set after it (with the execution
    ball) is back inside the corridor."""
    settings, sc = short
    ctl = make_controller("corridor", {"horizon_revolutions": 2})
    ctl.prepare(sc, settings)
    k = int(ctl._opp[1])
    a = ctl._index[k]
    k1 = int(ctl._opp[a + 1])
    rng = np.random.default_rng(5)
    sigma = settings.navigation.sigma(sc.units)
    d = np.r_[np.array([12.0, -9.0, 7.0]) * 1e3 / sc.units.length,
              np.array([0.02, -0.015, 0.01]) / sc.units.velocity]
    xhat = sc.X[k] + d
    box = np.abs(ctl._Phi[a] @ d) + ctl._nav[a] + ctl._srp[a]
    for _ in range(300):
        p = sc.params_with(1.0 + settings.scenario.srp.uncertainty * (2 * rng.random() - 1))
        x1 = sc.propagate(xhat - sigma * rng.standard_normal(6), k, k1, p)[-1]
        assert np.all(np.abs(x1 - sc.X[k1]) <= box)
    assert ctl.gauge(sc, k, xhat) > 1.0 and ctl.triggered(sc, k, xhat)
    dv = ctl.burn(sc, k, xhat)
    assert np.linalg.norm(dv) * sc.units.velocity >= settings.execution.min_burn_mps
    z = d.copy()
    z[3:] += dv
    after = (np.abs(ctl._Phi[a] @ z) + ctl._nav[a] + ctl._srp[a]
             + ctl._exe[a] * np.linalg.norm(dv)) / ctl._C
    assert after.max() <= 1.0 + 1e-6
    assert not ctl.triggered(sc, k, sc.X[k])  # on the reference: no burn


def test_skipped_burn_scenario(short):
    settings, _ = short
    s = MaintenanceSettings.from_options(skipped_burns=[0, 1], min_burn_mps=0.0, **SHORT)
    r = run_maintenance(s, make_controller("xaxis"), 1)
    assert [b["status"] for b in r["burns"][:2]] == ["skipped", "skipped"]
    assert r["burns_skipped"] == 2 and not r["lost"]
    free = run_maintenance(MaintenanceSettings.from_options(min_burn_mps=0.0, **SHORT),
                           make_controller("xaxis"), 1)
    assert free["burns"][0]["status"] == "executed"


# ------------------------------------------------------------------------------ Monte Carlo
def test_interrupted_monte_carlo_resumes_from_its_store(tmp_path, short):
    from ocreach.control.stationkeeping.maintenance_mc import run_monte_carlo
    from ocreach.sweep.store import LOG, read_log

    settings, _ = short
    ctl = {"xaxis": {}}
    seen = []

    def interrupt(rec):
        seen.append(rec)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_monte_carlo(settings, ctl, 3, tmp_path / "store", serial=True, progress=False,
                        on_record=interrupt)
    done = len(read_log(tmp_path / "store" / LOG).records)  # the serial executor ran 1-2
    assert len(seen) == 1 and 1 <= done < 3
    mc = run_monte_carlo(settings, ctl, 3, tmp_path / "store", serial=True, progress=False)
    assert mc.timing["ran_now"] == 3 - done and mc.timing["already_finished"] == done
    assert [r["run"] for r in mc.records["xaxis"]] == [0, 1, 2]
    again = run_maintenance(settings, make_controller("xaxis"), 0)
    assert mc.records["xaxis"][0]["dv_total_mps"] == again["dv_total_mps"]  # seeded


def test_tube_intervals_on_pool_workers_equal_the_driver_s(short, monkeypatch):
    """A first run computes the drift tubes' refresh intervals on the Monte Carlo's workers
    (each rebuilds the scenario from the plain settings): the same tubes as in the driver."""
    import ocreach.control.stationkeeping.ephemeris_tubes as et
    from ocreach.control.stationkeeping.impulsive_tube import _compute_tubes
    from ocreach.sweep.executors import process_pool

    settings, sc = short
    # three short intervals (the driver chooses them; a worker encloses the one it is given)
    monkeypatch.setattr(et, "refresh_starts", lambda reference, end: [0, 5, 10])
    G = settings.navigation.box(sc.units)
    W = 1e-9
    here = _compute_tubes(sc, G, W, "taylor-or-linear", 16, settings, None, False)
    with process_pool(2) as pool:
        there = _compute_tubes(sc, G, W, "taylor-or-linear", 16, settings, pool.executor, False)
    assert [r["steps"][0] for r in here["log"]] == list(here["starts"])
    assert here["starts"][:3].tolist() == [0, 5, 10]
    assert all(r["guaranteed"] for r in here["log"]), here["log"]
    assert np.all(np.isfinite(here["half_widths"])) and here["half_widths"].shape == (16, 6)
    np.testing.assert_array_equal(there["half_widths"], here["half_widths"])
    np.testing.assert_array_equal(there["starts"], here["starts"])
    assert there["log"] == here["log"]


def test_an_interrupted_first_run_keeps_the_tube_intervals_it_finished(short, monkeypatch,
                                                                        tmp_path):
    """The refresh intervals finished before an interruption are kept and not computed again:
    the resumed tubes equal an uninterrupted computation exactly."""
    import ocreach.control.stationkeeping.ephemeris_tubes as et
    import ocreach.control.stationkeeping.impulsive_tube as it

    settings, sc = short
    monkeypatch.setattr(et, "refresh_starts", lambda reference, end: [0, 5, 10])
    G = settings.navigation.box(sc.units)
    W = 1e-9
    whole = it._compute_tubes(sc, G, W, "taylor-or-linear", 16, settings, None, False)
    real, computed = it.interval_rows, []

    def interrupted(sc, G, W, source, a, b):
        if a == 5:
            raise KeyboardInterrupt
        computed.append(a)
        return real(sc, G, W, source, a, b)

    monkeypatch.setattr(it, "interval_rows", interrupted)
    with pytest.raises(KeyboardInterrupt):
        it._compute_tubes(sc, G, W, "taylor-or-linear", 16, settings, None, False, tmp_path)
    assert computed == [0] and len(list(tmp_path.glob("interval_*.json"))) == 1

    def counted(sc, G, W, source, a, b):
        computed.append(a)
        return real(sc, G, W, source, a, b)

    monkeypatch.setattr(it, "interval_rows", counted)
    resumed = it._compute_tubes(sc, G, W, "taylor-or-linear", 16, settings, None, False, tmp_path)
    assert computed == [0, 5, 10]
    np.testing.assert_array_equal(resumed["half_widths"], whole["half_widths"])
    np.testing.assert_array_equal(resumed["starts"], whole["starts"])
    assert resumed["log"] == whole["log"]


def test_monte_carlo_runs_run_by_run_across_the_controllers(short):
    """An interrupted Monte Carlo keeps comparable runs: run i of every controller is queued
    before run i + 1 of any."""
    from ocreach.control.stationkeeping.maintenance_mc import task_spec

    spec = task_spec(short[0], {"xaxis": {}, "lqr": {}}, 2)
    assert [(t["run"], t["controller"]) for t in spec.tasks] == [
        (0, "xaxis"), (0, "lqr"), (1, "xaxis"), (1, "lqr")]


def test_report_writes_the_folder_as_a_unit(tmp_path, short):
    import ocreach
    from ocreach.control.stationkeeping.maintenance_report import (
        FIGURES,
        orbit_maintenance_report,
    )

    out = tmp_path / "om"
    res = orbit_maintenance_report(ocreach.get_problem("nrho-9-2"), out, runs=2,
                                   controllers="xaxis,corridor,lqr", serial=True,
                                   progress=False, **SHORT,
                                   **{"corridor.horizon_revolutions": 2})
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(["metrics.json", "report.md", *FIGURES])
    data = json.loads((out / "metrics.json").read_text())
    assert set(data["summary"]) == {"xaxis", "corridor", "lqr"} and data["runs"] == 2
    assert data["summary"]["xaxis"]["lost"] == 0
    corridor = data["summary"]["corridor"]
    assert corridor["corridor_exit_steps"] == 0 and corridor["opportunities"] > 0
    assert "corridor_max_ratio" not in data["summary"]["xaxis"]
    md = (out / "report.md").read_text()
    assert "Delta-V per year, 95th percentile" in md and "CAPSTONE" in md
    assert "corridor: worst ratio" in md
    assert res["store"] == str(tmp_path / "om.runs")
    assert not list(tmp_path.glob(".om.tmp-*"))


def test_cli_report_is_written_as_a_unit_with_its_store_beside_it(tmp_path, short):
    """``ocreach report orbit-maintenance`` writes the folder through the CLI's temporary twin;
    the store is named after the folder (so the same command resumes), not after the twin."""
    from ocreach.cli import main

    out = tmp_path / "om"
    argv = ["report", "orbit-maintenance", "--problem", "nrho-9-2", "--runs", "1", "--years",
            str(SHORT["years"]), "--controllers", "lqr", "--set",
            f"lookahead={SHORT['lookahead']}", "--set", "serial=True", "--set",
            "progress=False", "--out", str(out)]
    assert main(argv) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["om", "om.runs"]
    data = json.loads((out / "metrics.json").read_text())
    assert data["store"] == str(tmp_path / "om.runs") and data["summary"]["lqr"]["runs"] == 1
    assert main(argv) == 0  # the same command again: the run comes from the store
    assert json.loads((out / "metrics.json").read_text())["timing"]["already_finished"] == 1
