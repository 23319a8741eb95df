"""Problem validation, registry, user problem files and the CLI."""
import json
import subprocess
import sys

import numpy as np
import pytest

import ocreach
from ocreach import Problem, ProblemError, UnknownNameError
from ocreach.cli import main
from ocreach.models import vanderpol


def _vdp(**kw):
    base = dict(id="t", model=vanderpol(), x0=[0.5, 0.0], grid=np.linspace(0, 1, 11))
    base.update(kw)
    return Problem(**base)


def test_problem_validation_errors():
    with pytest.raises(ProblemError, match="x0 must have length n_x = 2"):
        _vdp(x0=[0.5, 0.0, 1.0])
    with pytest.raises(ProblemError, match="x0 must be finite"):
        _vdp(x0=[np.nan, 0.0])
    with pytest.raises(ProblemError, match="strictly increasing"):
        _vdp(grid=[0.0, 0.2, 0.1])
    with pytest.raises(ProblemError, match="at least 2"):
        _vdp(grid=[0.0])
    with pytest.raises(ProblemError, match="params must have 2"):
        _vdp(params=[1.0])
    with pytest.raises(ProblemError, match="grid must be finite"):
        _vdp(grid=[0.0, np.inf])
    with pytest.raises(ProblemError, match="strictly increasing"):
        _vdp(grid=[0.0, 0.0, 1.0])
    with pytest.raises(ProblemError, match="params must be finite"):
        _vdp(params=[1.0, np.nan])


def test_thrust_must_be_positive():
    with pytest.raises(ProblemError, match="thrust"):
        ocreach.get_problem("dro", thrust=0.0)
    p = ocreach.get_problem("dro")
    with pytest.raises(ProblemError, match="a_max"):
        Problem(id="x", model=p.model, x0=p.x0, grid=p.grid, params=[0.0122, -1.0])


def test_backward_grid_allowed():
    p = _vdp(grid=np.linspace(1, 0, 11))
    assert p.backward and p.n_segments == 10


def test_registry_and_overrides():
    listing = ocreach.list_problems()
    for pid in ("vdp", "dro", "l2-halo", "nrho-9-2", "earth-mars"):
        assert listing.get(pid)
    p = ocreach.get_problem("dro", t_final=1.0)
    assert p.grid[-1] == pytest.approx(1.0)
    with pytest.raises(UnknownNameError, match="unknown problem 'nope'"):
        ocreach.get_problem("nope")
    with pytest.raises(ProblemError, match="no option"):
        ocreach.get_problem("dro", colour="red")


def test_user_problem_file(tmp_path):
    f = tmp_path / "myprob.py"
    f.write_text(
        "import numpy as np\n"
        "from ocreach import Problem\n"
        "from ocreach.models import vanderpol\n"
        "def problem(t_final=1.0):\n"
        "    '''My VdP.'''\n"
        "    return Problem(id='mine', model=vanderpol(gain=0.1), x0=[0.1, 0.2],\n"
        "                   grid=np.linspace(0, t_final, 6))\n")
    p = ocreach.get_problem(str(f), t_final=2.0)
    assert p.id == "mine" and p.grid[-1] == 2.0
    r = ocreach.reach(p, "mc", samples=20)
    assert r.points[-1].shape == (20, 2)


def test_cli_list_and_errors(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "dro" in out and "mc" in out and "ode" in out
    assert main(["run", "nope", "--method", "mc"]) == 2
    assert "unknown problem" in capsys.readouterr().err
    assert main(["run", "vdp", "--method", "magic"]) == 2


def test_cli_run_and_compare_write_files(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "vdp", "--method", "mc", "--out", str(out), "--set", "samples=50"]) == 0
    assert (out / "result.npz").is_file() and (out / "summary.json").is_file()
    assert list(out.glob("projection_*.png"))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "mc" and summary["meta"]["options"]["samples"] == 50
    cmp_out = tmp_path / "cmp"
    rc = main(["compare", "dro", "--methods", "mc,ode", "--out", str(cmp_out),
               "--set", "mc.samples=200", "--set", "ode.samples=20", "--set", "problem.t_final=1.0"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "| mc |" in text and "| ode |" in text
    assert (cmp_out / "overlay.png").stat().st_size > 10_000
    metrics = json.loads((cmp_out / "metrics.json").read_text())
    assert metrics["mc"]["planes"]["pos"]["mc_covered"] == pytest.approx(1.0)


def test_compare_metrics_json_is_strict_json(tmp_path):
    """metrics.json holds no NaN (not JSON): a volume that cannot be computed (the stt set's,
    a polynomial zonotope) is written as null, and the table leaves it out."""
    out = tmp_path / "cmp"
    rc = main(["compare", "dro", "--methods", "mc,stt", "--out", str(out), "--set", "mc.samples=100",
               "--set", "stt.h_max=40", "--set", "problem.t_final=0.5"])
    assert rc == 0

    def refuse(name):
        raise ValueError(f"metrics.json holds {name}")

    metrics = json.loads((out / "metrics.json").read_text(), parse_constant=refuse)
    assert metrics["stt"]["volume_pos"] is None
    assert metrics["mc"]["volume_pos"] > 0
    line = [t for t in (out / "comparison.md").read_text().splitlines()
            if t.startswith("position-space volume")]
    assert len(line) == 1 and "mc " in line[0] and "stt" not in line[0]


@pytest.mark.parametrize("module", ["ocreach.cli", "ocreach"])
def test_console_script_entry_point(module):
    proc = subprocess.run([sys.executable, "-m", module, "list"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0 and "vdp" in proc.stdout
    bad = subprocess.run([sys.executable, "-m", module, "run", "nope", "-m", "mc"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "unknown problem 'nope'" in bad.stderr


def test_planes_fallback_and_dedup():
    assert _vdp().planes() == {"x": (0, 1)}  # 2-state model, default dims (0,) and (1,)
    assert ocreach.get_problem("vdp").planes() == {"pos": (0, 1)}
    assert ocreach.get_problem("dro").planes() == {"pos": (0, 1), "vel": (2, 3)}


def test_compare_backward_two_state_problem_has_finite_metrics():
    """A 2-state user problem on a backward grid: every metric finite (was silent NaN)."""
    import ocreach.compare

    p = _vdp(grid=np.linspace(1.0, 0.0, 11))
    cmp = ocreach.compare(p, ["mc", "ode"], options={"mc": {"samples": 60}, "ode": {"samples": 20}},
                          progress=False)
    for name in ("mc", "ode"):
        plane = cmp.metrics[name]["planes"]["x"]
        assert np.isfinite([plane["support_err"], plane["area"], plane["mc_covered"]]).all()
        assert cmp.results[name].times[-1] == 0.0
    assert "nan" not in cmp.table()
    # independent check of the backward endpoints: reverse-time scipy integration of one sample
    from scipy.integrate import solve_ivp
    r = cmp.results["mc"]
    u = r.controls[0]
    x = p.x0.copy()
    for k in range(p.n_segments):
        sol = solve_ivp(lambda t, y: [y[1], (1 - y[0] ** 2) * y[1] - y[0] + 0.05 * u[k, 0]],
                        (p.grid[k], p.grid[k + 1]), x, rtol=1e-12, atol=1e-13, method="DOP853")
        x = sol.y[:, -1]
    assert np.abs(x - r.points[-1][0]).max() < 1e-8


def test_cli_run_vdp_writes_one_figure_per_distinct_plane(tmp_path, capsys):
    out = tmp_path / "vdp"
    assert main(["run", "vdp", "--method", "mc", "--out", str(out), "--set", "samples=20"]) == 0
    assert [f.name for f in out.glob("projection_*.png")] == ["projection_0_1.png"]
    assert "result.npz, projection_0_1.png, summary.json" in capsys.readouterr().out


def test_compare_rejects_bad_names_and_stray_options(capsys):
    assert main(["compare", "dro", "--methods", "mc,ode", "--set", "samples=50"]) == 2
    assert "METHOD.KEY=VALUE" in capsys.readouterr().err
    assert main(["compare", "dro", "--methods", "mc,ode", "--set", "stt.h_max=3"]) == 2
    with pytest.raises(UnknownNameError, match="unknown method 'magic'"):
        ocreach.compare("vdp", ["mc", "magic"], progress=False)
    with pytest.raises(ProblemError, match="not compared"):
        ocreach.compare("vdp", ["mc"], options={"ode": {"samples": 3}}, progress=False)


def test_compare_ctrl_c_keeps_finished_work(tmp_path, monkeypatch, capsys):
    """Ctrl-C during the second method: the first result, the table and the figure are written."""
    cmp_mod = sys.modules["ocreach.compare"] if "ocreach.compare" in sys.modules else None
    if cmp_mod is None:
        import importlib
        cmp_mod = importlib.import_module("ocreach.compare")
    real_reach = cmp_mod.reach

    def fake_reach(problem, method, **kw):
        if method == "ode":
            raise KeyboardInterrupt
        return real_reach(problem, method, **kw)

    monkeypatch.setattr(cmp_mod, "reach", fake_reach)
    out = tmp_path / "cmp"
    rc = main(["compare", "vdp", "--methods", "mc,ode", "--out", str(out), "--set", "mc.samples=40"])
    assert rc == 130
    assert not out.exists()  # an interrupted comparison never poses as a complete one
    part = tmp_path / "cmp.partial"  # ... its finished work is kept beside it
    assert (part / "vdp_mc.npz").is_file() and not (part / "vdp_ode.npz").exists()
    assert (part / "comparison.md").is_file() and (part / "overlay.png").is_file()
    assert "interrupted" in (part / "comparison.md").read_text()
    assert json.loads((part / "MANIFEST.json").read_text())["complete"] is False
    assert f"kept in {part}" in capsys.readouterr().err


def test_axis_and_time_labels_carry_units():
    from ocreach.reach.plot import axis_label, time_label
    em = ocreach.get_problem("earth-mars")
    assert axis_label(em, 0) == "x [AU]" and axis_label(em, 4) == "vy [AU/TU]"
    dro = ocreach.get_problem("dro")
    assert axis_label(dro, 3) == "vy [DU/TU]" and time_label(dro, 3.0) == "t = 3 TU"
    assert axis_label(ocreach.get_problem("vdp"), 1) == "x2"  # no units: no invented label


def test_package_compare_is_the_function_after_submodule_import():
    import importlib

    importlib.import_module("ocreach.compare")
    importlib.import_module("ocreach.cli")
    assert callable(ocreach.compare) and ocreach.compare.__module__ == "ocreach.compare"


def test_body_tracks_for_figures():
    from ocreach.reach.plot import body_tracks

    dro = ocreach.get_problem("dro")
    tr = body_tracks(dro)
    assert np.allclose(tr["earth"][0], [-0.0122, 0, 0]) and np.allclose(tr["moon"][-1], [0.9878, 0, 0])
    lf = ocreach.get_problem("lunar-flyby", segments=4)
    tr = body_tracks(lf)
    moon_km = np.linalg.norm(tr["moon"], axis=1) * lf.units.length / 1e3
    assert np.all((moon_km > 356_000) & (moon_km < 407_000))  # lunar perigee..apogee
    assert np.allclose(tr["earth"], 0.0)
    assert body_tracks(ocreach.get_problem("vdp")) == {}
