"""DE421 ephemeris plant under CR3BP-predicting controllers.

Truth: with the circular Earth-Moon stand-in the plant must reproduce the CR3BP plant (an
independent model and integrator path) step by step, thrust and disturbance included; the frame
at the epoch must put the DE421 Earth on the CR3BP x axis; with DE421 the uncontrolled drift must
differ from the CR3BP's; a closed loop on it must stay bounded.
"""
from __future__ import annotations

import numpy as np
import pytest

import ocreach
from ocreach.control.reference import natural_reference, reference_from_problem
from ocreach.control.simulate import Plant
from ocreach.control.stationkeeping.ephemeris_plant import EphemerisPlant
from ocreach.control.stationkeeping.runs import run_station_keeping
from ocreach.ephemeris import gm
from ocreach.errors import ProblemError
from ocreach.models import cr3bp
from ocreach.units import Units


@pytest.fixture(scope="module")
def nrho():
    return ocreach.get_problem("nrho-9-2")


@pytest.fixture(scope="module")
def nrho_ref(nrho):
    return reference_from_problem(nrho, n_sub=2)


def test_circular_stand_in_equals_the_cr3bp_plant(nrho):
    # the CR3BP whose mu and t* are those of the circular stand-in (DE421 GMs, distance l*)
    L = nrho.units.length
    gm_em = (gm("earth") + gm("moon")) * 1e9
    units = Units(length=L, time=float(np.sqrt(L**3 / gm_em)))
    mu = gm("moon") / (gm("earth") + gm("moon"))
    a_max = units.thrust_acceleration(0.1, 1000.0)
    model = cr3bp(mu, a_max=a_max, units=units)
    dt = 3 * 3600.0 / units.time
    ref = natural_reference(model, nrho.x0, dt, 52, params=[mu, a_max])  # one revolution
    cp = Plant(ref, "ball", (3, 4, 5))
    ep = EphemerisPlant(ref, "ball", (3, 4, 5), span_days=7.0, circular=True)
    rng = np.random.default_rng(3)
    worst = 0.0
    for k in range(ref.n_steps):
        x = ref.state(k) + rng.uniform(-1e-4, 1e-4, 6)
        u = rng.uniform(-1, 1, 3)
        u *= rng.uniform(0, 1.2) / np.linalg.norm(u)  # some beyond the bound: saturated alike
        w = rng.uniform(-1e-4, 1e-4, 3)
        a = cp.step(x, u, w, float(ref.time(k)), ref.dt)
        b = ep.step(x, u, w, float(ref.time(k)), ref.dt)
        worst = max(worst, float(np.max(np.abs(a - b) / (1.0 + np.abs(a)))))
    assert worst < 1e-8
    # the transform alone is invertible
    x = ref.state(7)
    assert np.allclose(ep.from_inertial(0.3, ep.to_inertial(0.3, x)), x, rtol=0, atol=1e-14)


def test_frame_at_the_epoch_puts_the_de421_earth_on_the_x_axis(nrho, nrho_ref):
    ep = EphemerisPlant(nrho_ref, "ball", nrho.velocity_dims, span_days=2.0)
    eph = ep.ephemeris
    L = nrho.units.length / 1e3
    r_e = np.asarray(eph.position("earth", 0.0, "moon"), float).ravel() / L
    v_e = np.asarray(eph.position("earth", 0.0, "moon", derivative=1), float).ravel()
    v_e *= nrho.units.time / L
    x = ep.from_inertial(0.0, np.r_[r_e, v_e, 1.0])
    mu = float(nrho.params[0])
    assert abs(x[1]) < 1e-12 and abs(x[2]) < 1e-12  # on the x axis
    assert -1.1 < x[0] - (1 - mu) < -0.9  # about one Earth-Moon distance behind the Moon
    # the Earth's velocity in the rotating frame lies in the x-y plane (z along h at the epoch)
    assert abs(x[5]) < 1e-12


def test_ephemeris_plant_drift_differs_from_the_cr3bp(nrho, nrho_ref):
    ref = nrho_ref
    ep = EphemerisPlant(ref, "ball", nrho.velocity_dims, span_days=7.0)
    cp = Plant(ref, "ball", nrho.velocity_dims)
    L = nrho.units.length / 1e3
    dev = {}
    for name, pl in (("cr3bp", cp), ("ephemeris", ep)):
        x, d = ref.state(0), []
        for k in range(ref.n_steps):
            x = pl.step(x, np.zeros(3), np.zeros(3), float(ref.time(k)), ref.dt)
            d.append(np.linalg.norm(x[:3] - ref.state(k + 1)[:3]) * L)
        dev[name] = max(d)
    assert dev["cr3bp"] < 1.0  # the corrected orbit: metres after a revolution
    assert dev["ephemeris"] > 1000.0  # measured 7000 km (Earth eccentricity, Sun)


def test_ephemeris_plant_closed_loop_stays_bounded(nrho):
    run = run_station_keeping(nrho, controllers=("lqr",), revolutions=3, plant="ephemeris")
    m = run.metrics["lqr"]
    s = run.settings["plant"]
    assert s["plant"] == "ephemeris" and s["bodies"] == ["moon", "earth", "sun"]
    # uncontrolled: thousands of km after one revolution (test above); with the LQR it returns
    assert m["final_deviation_km"] < 500.0  # measured 139 km
    assert m["max_deviation_km"] < 3000.0  # measured 1415 km, at perilune
    assert m["delta_v_per_rev_mps"] > 1.0  # the CR3BP-vs-DE421 mismatch costs thrust
    cr = run_station_keeping(nrho, controllers=("lqr",), revolutions=3, plant="cr3bp")
    assert cr.metrics["lqr"]["delta_v_mps"] < m["delta_v_mps"]
    assert cr.settings["plant"]["plant"] == "cr3bp"


def test_ephemeris_plant_bad_input(nrho, nrho_ref):
    with pytest.raises(ProblemError, match="plant must be one of"):
        run_station_keeping(nrho, controllers=("lqr",), revolutions=1, plant="de440")
    with pytest.raises(ProblemError, match="span_days"):
        EphemerisPlant(nrho_ref, "ball", nrho.velocity_dims, span_days=-1.0)
    with pytest.raises(ProblemError, match="must include 'moon'"):
        EphemerisPlant(nrho_ref, "ball", nrho.velocity_dims, span_days=1.0, bodies=("earth",))
    planar = natural_reference(cr3bp(0.01215, planar=True, units=nrho.units), [1.1, 0, 0, 0.1],
                               0.01, 3)
    with pytest.raises(ProblemError, match="spatial CR3BP"):
        EphemerisPlant(planar, "ball", (2, 3), span_days=1.0)


def test_report_plant_option_on_the_command_line(tmp_path):
    import json

    from ocreach.cli import main

    rc = main(["report", "station-keeping", "--problem", "nrho-9-2", "--controllers", "lqr",
               "--revolutions", "0.3", "--plant", "ephemeris", "--out", str(tmp_path),
               "--set", "progress=False", "--set", "tube_source=linear"])
    assert rc == 0
    data = json.loads((tmp_path / "metrics.json").read_text())
    assert data["settings"]["plant"]["plant"] == "ephemeris"
    md = (tmp_path / "report.md").read_text()
    assert "Plant: DE421 ephemeris, point masses moon, earth, sun" in md
    assert f"{data['lqr']['delta_v_mps']:.4g} m/s" in md
    # which tube per revolution (here the linearised one throughout, chosen above)
    tubes = data["settings"]["tubes"]
    assert tubes and all(t["source"].startswith("interval hull of linear") for t in tubes)
    assert not any(t["guaranteed"] for t in tubes) and data["lqr"]["tube_guaranteed"] is False
    assert "LINEARISED, not guaranteed" in md


def test_frame_model_is_the_plant_in_cr3bp_coordinates(nrho, nrho_ref):
    """The CasADi model the ephemeris reference and its controllers use, integrated with SciPy,
    equals the plant's step (Moon-centred ICRF integration and the frame map), thrust and
    disturbance included."""
    from scipy.integrate import solve_ivp

    plant = EphemerisPlant(nrho_ref, "ball", nrho.velocity_dims, span_days=3.0)
    model = plant.frame_model()
    assert list(model.param_names) == ["mu", "a_max"] and model.n_x == 6
    f, p = model.f_fun, nrho_ref.params
    rng = np.random.default_rng(5)
    for k in (0, 40, 78):  # apolune, in between, near perilune
        x = nrho_ref.state(k) + rng.uniform(-1e-4, 1e-4, 6)
        u, w = np.array([0.3, -0.2, 0.5]), np.array([1e-7, 2e-7, -1e-7])
        t0 = float(nrho_ref.time(k))

        def rhs(t, y, u=u, w=w):
            d = np.asarray(f(y, u, t, p)).ravel()
            d[3:] += w
            return d

        sol = solve_ivp(rhs, (t0, t0 + 5 * nrho_ref.dt), x, method="DOP853", rtol=1e-12,
                        atol=1e-13)
        b = plant.step(x, u, w, t0, 5 * nrho_ref.dt)
        np.testing.assert_allclose(sol.y[:, -1], b, rtol=0, atol=1e-9)


def test_reference_option_bad_combinations(nrho):
    with pytest.raises(ProblemError, match="reference must be one of"):
        run_station_keeping(nrho, controllers=("lqr",), revolutions=1, plant="ephemeris",
                            reference="de440")
    with pytest.raises(ProblemError, match="needs plant='ephemeris'"):
        run_station_keeping(nrho, controllers=("lqr",), revolutions=1, reference="ephemeris")


def test_report_reference_option_on_the_command_line(tmp_path):
    import json

    from ocreach.cli import main

    rc = main(["report", "station-keeping", "--problem", "nrho-9-2", "--controllers", "lqr",
               "--revolutions", "0.3", "--plant", "ephemeris", "--reference", "ephemeris",
               "--out", str(tmp_path), "--set", "progress=False"])
    assert rc == 0
    data = json.loads((tmp_path / "metrics.json").read_text())
    rf = data["settings"]["reference"]
    assert rf["reference"] == "ephemeris" and rf["max_defect"] <= 1e-9
    assert data["lqr"]["max_gauge"] is None and data["settings"]["tubes"] == []
    md = (tmp_path / "report.md").read_text()
    assert "orbit of the DE421 plant" in md and f"{data['lqr']['delta_v_mps']:.4g} m/s" in md
    assert not (tmp_path / "gauge.png").exists()
    # corrected reference, paper offset: the offset's cost only (CR3BP reference: ~30 m/s/rev)
    assert data["lqr"]["delta_v_per_rev_mps"] < 3.0


def test_cr3bp_tubes_are_not_called_guaranteed_on_the_ephemeris_plant(nrho):
    """With the DE421 plant and the CR3BP reference the tubes (taylor, sound for the CR3BP) do not
    enclose the plant's drift -- the true state leaves them within 0.05 revolutions -- so the run
    must not report them as guaranteed (review finding: metrics said tube_guaranteed True)."""
    run = run_station_keeping(nrho, controllers=("lqr",), revolutions=0.05, plant="ephemeris",
                              tube_source="taylor", tube_interval="adaptive")
    assert all(t["guaranteed"] for t in run.settings["tubes"])  # sound for the CR3BP model
    assert run.metrics["lqr"]["max_gauge"] > 1.0  # and the plant leaves them
    assert run.settings["tube_guaranteed"] is False
    assert run.metrics["lqr"]["tube_guaranteed"] is False
    assert run.settings["tube_model"] == "cr3bp"
    from ocreach.control.stationkeeping.runs import tubes_enclose_plant

    tubes = [{"guaranteed": True}]
    assert tubes_enclose_plant(tubes, "cr3bp", "cr3bp") is True
    assert tubes_enclose_plant(tubes, "ephemeris", "ephemeris") is True
    assert tubes_enclose_plant([], "ephemeris", "cr3bp") is None
