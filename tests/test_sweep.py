"""ocreach.sweep: executors agree, resume, failures, corrupt logs, keys, validation.

Tasks are tiny (Monte Carlo with 4 samples on Van der Pol) so the whole file stays fast.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from ocreach.sweep import SweepError, collect_table, load_spec, run_sweep, spec_from_dict, status
from ocreach.sweep import executors as ex_mod
from ocreach.sweep.collect import RUN_COLUMNS, write_table
from ocreach.sweep.keys import task_key
from ocreach.sweep.store import LOG, META

ROOT = Path(__file__).resolve().parent.parent
SPEC = {
    "name": "test",
    "base": {"problem": "vdp", "method": "mc", "options": {"samples": 4},
             "keep": {"support": [[1.0, 0.0], [0.6, 0.8]], "meb": True, "volume": True}},
    "product": {"options.seed": [0, 1, 2], "horizon": [1.0, {"value": 2.0, "unit": "TU"}]},
}


def table(out) -> list[dict]:
    _, rows = collect_table(out)
    return [{k: v for k, v in r.items() if k not in RUN_COLUMNS} for r in rows]


def worker_pids(out) -> set[int]:
    return {int(json.loads(ln)["worker"].rsplit(":", 1)[1]) for ln in (out / LOG).read_text().splitlines()}


@pytest.fixture(scope="module")
def serial_table(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / "o"
    s = run_sweep(spec_from_dict(SPEC), out, serial=True, progress=False)
    assert (s.ran, s.ok, s.failed) == (6, 6, 0)
    return table(out)


def _brute_force_meb_radius(P: np.ndarray) -> float:
    """Smallest circle containing the 2-D points ``P``: the best of all circles through two points
    (as diameter) or three points (circumcircle) that contain every point."""
    from itertools import combinations

    best = np.inf
    cands = [((P[i] + P[j]) / 2, np.linalg.norm(P[i] - P[j]) / 2) for i, j in combinations(range(len(P)), 2)]
    for i, j, k in combinations(range(len(P)), 3):
        A = 2 * np.array([P[j] - P[i], P[k] - P[i]])
        if abs(np.linalg.det(A)) > 1e-14:
            c = np.linalg.solve(A, [P[j] @ P[j] - P[i] @ P[i], P[k] @ P[k] - P[i] @ P[i]])
            cands.append((c, np.linalg.norm(P[i] - c)))
    for c, r in cands:
        if np.all(np.linalg.norm(P - c, axis=1) <= r * (1 + 1e-12)):
            best = min(best, r)
    return float(best)


def _hull_area(P: np.ndarray) -> float:
    """Area of the convex hull of 2-D points: monotone chain, then the shoelace formula."""
    pts = sorted(map(tuple, P))

    def half(seq):
        out: list = []
        for p in seq:
            while len(out) >= 2 and np.cross(np.subtract(out[-1], out[-2]), np.subtract(p, out[-2])) <= 0:
                out.pop()
            out.append(p)
        return out[:-1]

    h = np.array(half(pts) + half(pts[::-1]))
    return 0.5 * abs(np.dot(h[:, 0], np.roll(h[:, 1], -1)) - np.dot(h[:, 1], np.roll(h[:, 0], -1)))


def test_serial_table_content(serial_table):
    """Each row against the same problem and method run directly through ``ocreach.reach`` at
    that seed and horizon, post-processed here by independent code (maxima of dot products,
    brute-force smallest circle, monotone-chain hull)."""
    import ocreach

    rows = serial_table
    assert [r["status"] for r in rows] == ["ok"] * 6
    assert [(r["options.seed"], r["out.t_final"]) for r in rows] == [
        (s, pytest.approx(h)) for s in (0, 1, 2) for h in (1.0, 2.0)]
    D = np.array(SPEC["base"]["keep"]["support"])
    for r in rows:
        prob = ocreach.get_problem("vdp", t_final=r["out.t_final"])
        P = ocreach.reach(prob, "mc", samples=4, seed=r["options.seed"]).points[-1][:, :2]
        assert P.shape == (4, 2)
        for j, name in enumerate(("x1", "x2")):
            assert r[f"out.{name}_min"] == pytest.approx(P[:, j].min(), rel=1e-9, abs=1e-12)
            assert r[f"out.{name}_max"] == pytest.approx(P[:, j].max(), rel=1e-9, abs=1e-12)
        for i, d in enumerate(D):
            assert r[f"out.support_{i}"] == pytest.approx(np.max(P @ d), rel=1e-9, abs=1e-12)
        assert r["out.meb_radius"] == pytest.approx(_brute_force_meb_radius(P), rel=1e-9)
        assert r["out.hull_volume"] == pytest.approx(_hull_area(P), rel=1e-9)
    assert len({r["out.x1_max"] for r in rows}) == 6  # seeds and horizons really differ


def test_process_pool_and_dask_give_the_same_table(serial_table, tmp_path, monkeypatch):
    # fresh compiled-code caches: the 2 workers of each executor compile the same kernels at once
    monkeypatch.setenv("OCREACH_CACHE_DIR", str(tmp_path / "cache_pool"))
    run_sweep(spec_from_dict(SPEC), tmp_path / "pool", workers=2, chunk=2, progress=False)
    assert table(tmp_path / "pool") == serial_table
    assert os.getpid() not in worker_pids(tmp_path / "pool")
    monkeypatch.setenv("OCREACH_CACHE_DIR", str(tmp_path / "cache_dask"))
    run_sweep(spec_from_dict(SPEC), tmp_path / "dask2", dask_local=2, progress=False)
    assert table(tmp_path / "dask2") == serial_table
    assert os.getpid() not in worker_pids(tmp_path / "dask2")
    with ex_mod.dask_local(1, processes=False) as handle:  # in-process LocalCluster
        run_sweep(spec_from_dict(SPEC), tmp_path / "dask0", executor=handle.executor, progress=False)
    assert table(tmp_path / "dask0") == serial_table
    import distributed

    with distributed.LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster:
        run_sweep(spec_from_dict(SPEC), tmp_path / "dask_addr", scheduler=cluster.scheduler_address,
                  progress=False)  # the --scheduler ADDRESS path
    assert table(tmp_path / "dask_addr") == serial_table


def test_resume_after_limit_and_interrupt_runs_only_the_rest(serial_table, tmp_path):
    out = tmp_path / "o"
    spec = spec_from_dict(SPEC)
    first = run_sweep(spec, out, serial=True, limit=2, progress=False)
    assert first.ran == 2
    seen: list[str] = []

    def stop_after_one(rec):
        seen.append(rec["key"])
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, out, serial=True, progress=False, on_record=stop_after_one)
    k = status(out)["ok"]  # the records of the interrupted batch are on disk, the rest pending
    assert 3 <= k < 6 and status(out)["pending"] == 6 - k and seen == spec.keys[2:3]
    rest: list[str] = []
    last = run_sweep(spec, out, serial=True, progress=False, on_record=lambda r: rest.append(r["key"]))
    assert (last.skipped, last.ran) == (k, 6 - k)
    assert rest == spec.keys[k:]
    assert table(out) == serial_table
    again = run_sweep(spec, out, serial=True, progress=False)
    assert again.ran == 0


def test_a_raising_task_is_recorded_and_the_rest_finish(tmp_path):
    # a failure only the computation can find: Van der Pol with negative damping started outside
    # its unstable limit cycle escapes to infinity in finite time (the integrator stops, SolverError)
    (tmp_path / "unstable.py").write_text(
        "import dataclasses\n\nimport numpy as np\n\nfrom ocreach.registry import get_problem\n\n\n"
        "def problem(mu: float = 1.0):\n    base = get_problem('vdp')\n"
        "    return dataclasses.replace(base, params=np.array([mu, base.params[1]]))\n")
    data = {"base": {"problem": "unstable.py", "options": {"samples": 4}},
            "tasks": [{"method": "mc"}, {"method": "mc", "overrides": {"mu": -5.0}, "state": [3.0, 0.0]},
                      {"method": "mc", "options": {"seed": 3}}]}
    out = tmp_path / "o"
    s = run_sweep(spec_from_dict(data, base_dir=tmp_path), out, serial=True, progress=False)
    assert (s.ok, s.failed) == (2, 1)
    st = status(out)
    assert st["failed"] == 1 and "step size underflow" in st["errors"][0]["message"]
    rows = table(out)
    assert [r["status"] for r in rows] == ["ok", "error", "ok"]
    assert rows[1]["error"].startswith("SolverError")
    assert run_sweep(spec_from_dict(data, base_dir=tmp_path), out, serial=True, progress=False).ran == 0
    retry = run_sweep(spec_from_dict(data, base_dir=tmp_path), out, serial=True, progress=False,
                      retry_failed=True)
    assert (retry.ran, retry.failed) == (1, 1)


@pytest.mark.parametrize("damage", ["half_line", "garbage_line"])
def test_corrupt_last_log_line_is_detected_and_its_task_rerun(serial_table, tmp_path, damage):
    out = tmp_path / "o"
    spec = spec_from_dict(SPEC)
    run_sweep(spec, out, serial=True, progress=False)
    log = out / LOG
    lines = log.read_bytes().split(b"\n")[:-1]
    last_key = json.loads(lines[-1])["key"]
    if damage == "half_line":  # a driver killed in the middle of a write
        log.write_bytes(b"\n".join(lines[:-1]) + b"\n" + lines[-1][:25])
    else:
        log.write_bytes(b"\n".join(lines[:-1]) + b"\n" + b'{"key": "x", "stat\n')
    assert status(out)["pending"] == 1 and status(out)["notes"]
    rerun: list[str] = []
    run_sweep(spec, out, serial=True, progress=False, on_record=lambda r: rerun.append(r["key"]))
    assert rerun == [last_key]
    assert table(out) == serial_table
    assert all(json.loads(ln) for ln in log.read_text().splitlines())


def test_keys_are_stable():
    spec = spec_from_dict(SPEC, package_versions={"ocreach": "0", "python": "3"})
    assert spec.keys == spec_from_dict(json.loads(json.dumps(SPEC)),
                                       package_versions={"ocreach": "0", "python": "3"}).keys
    assert len(set(spec.keys)) == 6
    # a literal value: the key must not change between processes, hosts or releases of this code
    assert spec.keys[0] == task_key(spec.tasks[0], {"ocreach": "0", "python": "3"})
    assert spec.keys[0] == "2e66236433a008a5c49e54ff"
    other = spec_from_dict(SPEC, package_versions={"ocreach": "1", "python": "3"})
    assert other.keys[0] != spec.keys[0]  # versions are part of the key


def test_json_and_toml_specs_agree(tmp_path):
    (tmp_path / "s.json").write_text(json.dumps(SPEC))
    (tmp_path / "s.toml").write_text(
        'name = "test"\n[base]\nproblem = "vdp"\nmethod = "mc"\noptions = {samples = 4}\n'
        'keep = {support = [[1.0, 0.0], [0.6, 0.8]], meb = true, volume = true}\n'
        '[product]\n"options.seed" = [0, 1, 2]\nhorizon = [1.0, {value = 2.0, unit = "TU"}]\n')
    assert load_spec(tmp_path / "s.json").keys == load_spec(tmp_path / "s.toml").keys


@pytest.mark.parametrize("change, message", [
    ({"colour": 1}, "unknown key(s) ['colour']"),
    ({"base": {**SPEC["base"], "methd": "mc"}}, "unknown key(s) ['methd']"),
    ({"base": {**SPEC["base"], "problem": "no-such"}}, "unknown problem 'no-such'"),
    ({"base": {**SPEC["base"], "method": "magic"}}, "unknown method 'magic'"),
    ({"base": {**SPEC["base"], "options": {"sample": 4}}}, "no option(s) ['sample']"),
    ({"base": {**SPEC["base"], "options": {"samples": -1}}}, "samples"),
    ({"base": {**SPEC["base"], "overrides": {"gian": 1}}}, "no override(s) ['gian']"),
    ({"base": {**SPEC["base"], "keep": {"meb": "yes"}}}, "keep.meb must be true or false"),
    ({"product": {"options.seed": [0, 0]}}, "identical"),
    ({"product": {"horizon": [-1.0]}}, "horizon must be > 0"),
    ({"product": {"colour.x": [1]}}, "not a task field"),
])
def test_bad_specs_are_rejected_before_work(change, message):
    with pytest.raises(SweepError) as err:
        spec_from_dict({**SPEC, **change})
    assert message in str(err.value)


@pytest.mark.parametrize("header, expected", [
    ("name,x[km],q[km],vx[km/s],vy[km/s]", ["catalog cat.csv data row 1", "unknown state column(s) "
                                             "['q[km]']", "missing state(s) ['y']", "['x', 'y', 'vx', 'vy']"]),
    ("name,x[km],vx[km/s],vy[km/s],family", ["data row 1", "missing state(s) ['y']"]),
    ("name,x[km],y[km/s],vx[km/s],vy[km/s]", ["state y[km/s]", "'km/s' is a velocity unit and 'y' is a "
                                              "position state", "allowed units for 'y'", "'km'"]),
    ("name,x[km],y[km],vx[km/s],vy[kg]", ["state vy[kg]", "mass unit", "allowed units for 'vy'", "'m/s'"]),
    ("name,x[km],x[m],vx[km/s],vy[km/s]", ["repeated state column(s) ['x[km]', 'x[m]']"]),
])
def test_bad_catalog_columns_are_rejected_by_the_driver(tmp_path, header, expected):
    """Catalog columns against the problem's states (the driver builds the problem once; nothing runs)."""
    values = ["105764.0", "0", "0", "0.8", "DRO"][: header.count(",")]
    (tmp_path / "cat.csv").write_text(f"{header}\na,{','.join(values)}\n")
    data = {"catalog": {"file": "cat.csv"}, "base": {"problem": "dro", "method": "mc",
                                                     "options": {"samples": 4}}, "tasks": [{}]}
    with pytest.raises(SweepError) as err:
        spec_from_dict(data, base_dir=tmp_path)
    for text in expected:
        assert text in str(err.value)
    assert not (tmp_path / "o").exists()


def test_catalog_units_need_a_problem_with_units(tmp_path):
    (tmp_path / "cat.csv").write_text("name,x1[km],x2[nd]\na,1,2\nb,1,3\n")
    data = {"catalog": {"file": "cat.csv"}, "base": {"problem": "vdp", "method": "mc"}, "tasks": [{}]}
    with pytest.raises(SweepError, match=r"task 0 \(a\), catalog cat.csv data row 1: state x1\[km\] "
                                         r"of problem 'vdp': problem 'vdp' has no units; allowed units "
                                         r"for 'x1': \['DU', 'DU/TU', 'nd'\]"):
        spec_from_dict(data, base_dir=tmp_path)
    (tmp_path / "cat.csv").write_text("name,x1[nd],x2[DU/TU]\na,1,2\nb,1,3\n")
    spec = spec_from_dict(data, base_dir=tmp_path)
    from ocreach.sweep.worker import build_problem

    assert build_problem(spec.tasks[1], spec.base_dir).x0.tolist() == [1.0, 3.0]


@pytest.mark.parametrize("problem, overrides, expected", [
    ("dro", {"thrust": "lots"}, "task 0: problem 'dro' override 'thrust' = 'lots' does not fit its declared "
                                "type float: thrust must be a finite number; got 'lots'"),
    ("dro", {"thrust": True}, "override 'thrust' = True does not fit its declared type float"),
    ("dro", {"thrust": [1e-3]}, "override 'thrust' = [0.001] does not fit its declared type float"),
    ("dro", {"input_set": 3}, "override 'input_set' must be text (declared str); got 3"),
    ("elliptic-earth", {"segments": 2.5}, "segments must be an integer; got 2.5"),
    ("custody-l1", {"uncertain": "maybe"}, "uncertain must be a boolean"),
    ("prob.py", {"thrus": 1e-3}, "problem 'prob.py' has no override(s) ['thrus']; allowed: ['thrust']"),
    ("prob.py", {"thrust": "x"}, "problem 'prob.py' override 'thrust' = 'x' does not fit"),
    ("prob.py", {"thrust": -1e-3}, ("problem 'prob.py' with overrides {'thrust': -0.001} cannot be built: "
                                    "ProblemError: ", "prob.py: line 4: factory 'prob' raised: thrust")),
    ("vdp", {"t_final": 3.05}, "problem 'vdp' with overrides {'t_final': 3.05} cannot be built: "
                               "ProblemError: t_final = 3.05 TU must be a whole multiple of dt"),
])
def test_bad_problem_overrides_are_rejected_by_the_driver(tmp_path, problem, overrides, expected):
    (tmp_path / "prob.py").write_text("from ocreach.registry import get_problem\n\n"
                                      "def problem(thrust: float = 1.1e-3):\n"
                                      "    return get_problem('dro', thrust=thrust)\n")
    data = {"base": {"problem": problem, "method": "mc", "options": {"samples": 4}},
            "tasks": [{"overrides": overrides}]}
    with pytest.raises(SweepError) as err:
        spec_from_dict(data, base_dir=tmp_path)
    for part in (expected,) if isinstance(expected, str) else expected:
        assert part in str(err.value)


@pytest.mark.parametrize("task, expected", [
    ({"horizon": {"value": 1, "unit": "d"}}, "horizon in 'd' needs units; problem 'vdp' has none"),
    ({"keep": {"dims": [5]}}, "task 0: dims [5] out of range"),
    ({"keep": {"support": [[1.0, 0.0, 0.0]]}}, "keep.support directions have 3 entries"),
    ({"keep": {"custody": {"fov": 1.0}}}, "keep.custody has unknown argument(s) ['fov']; allowed:"),
    ({"keep": {"custody": {"observer": "L1"}}}, "keep.custody needs fov_deg"),
    # the FOV value too, before any task runs (one check shared with custody.sweep_task)
    ({"keep": {"custody": {"fov_deg": 180.0}}}, "must be in (0, 180) deg; got 180.0"),
    ({"keep": {"custody": {"fov_deg": 1.0, "fov_shape": "hex"}}}, "'circle' or 'square'"),
    ({"state": [1.0, 2.0, 3.0]}, "state has 3 values; problem 'vdp' has 2 states ['x1', 'x2']"),
])
def test_task_fields_are_checked_against_the_problem(task, expected):
    with pytest.raises(SweepError) as err:
        spec_from_dict({"base": {"problem": "vdp", "method": "mc"}, "tasks": [task]})
    assert expected in str(err.value)


def test_unreachable_scheduler_and_foreign_folder_fail_before_work(tmp_path, monkeypatch):
    monkeypatch.setattr(ex_mod, "CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(SweepError, match="cannot reach the Dask scheduler at 'tcp://127.0.0.1:9'"):
        run_sweep(spec_from_dict(SPEC), tmp_path / "o", scheduler="tcp://127.0.0.1:9", progress=False)
    with pytest.raises(SweepError, match="tcp://HOST:PORT"):
        run_sweep(spec_from_dict(SPEC), tmp_path / "o", scheduler="localhost", progress=False)
    assert not (tmp_path / "o").exists()  # nothing was written
    run_sweep(spec_from_dict(SPEC), tmp_path / "o", serial=True, limit=1, progress=False)
    other = {**SPEC, "product": {"options.seed": [7]}}
    with pytest.raises(SweepError, match="belongs to a different spec"):
        run_sweep(spec_from_dict(other), tmp_path / "o", serial=True, progress=False)
    from ocreach.sweep.store import Store

    with Store.open(tmp_path / "o", spec_from_dict(SPEC)):  # a second driver on the same folder
        with pytest.raises(SweepError, match="another sweep driver"):
            run_sweep(spec_from_dict(SPEC), tmp_path / "o", serial=True, progress=False)
    (tmp_path / "new").mkdir()  # a driver killed after taking the lock, before sweep.json
    (tmp_path / "new" / ".sweep.lock").write_text("")
    assert run_sweep(spec_from_dict(SPEC), tmp_path / "new", serial=True, limit=1,
                     progress=False).ok == 1
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "x.txt").write_text("x")
    with pytest.raises(SweepError, match="not a sweep folder"):
        run_sweep(spec_from_dict(SPEC), tmp_path / "junk", serial=True, progress=False)


def test_catalog_units_and_problem_file(tmp_path):
    from ocreach.registry import get_problem
    from ocreach.sweep.worker import build_problem

    (tmp_path / "prob.py").write_text(
        "from ocreach.registry import get_problem\n\n"
        "def problem(thrust=1.1e-3):\n    return get_problem('dro', thrust=thrust)\n")
    (tmp_path / "cat.csv").write_text(
        "# two objects\nname,family,x[km],y[km],vx[km/s],vy[km/s]\n"
        "a,DRO,105764.0,0,0,0.8\nb,DRO,100000.0,10.0,0.01,0.8\n")
    data = {"catalog": {"file": "cat.csv"},
            "base": {"problem": "prob.py", "method": "ffoe", "options": {"samples": 4}},
            "product": {"horizon": [{"value": 1.0, "unit": "d"}]}}
    spec = spec_from_dict(data, base_dir=tmp_path)
    assert [t["tags"] for t in spec.tasks] == [{"object": "a", "family": "DRO"},
                                               {"object": "b", "family": "DRO"}]
    prob = build_problem(spec.tasks[1], spec.base_dir)
    u = get_problem("dro").units  # independent conversion: SI over the problem's units
    assert prob.x0 == pytest.approx([1e8 / u.length, 1e4 / u.length, 10.0 / u.velocity,
                                     800.0 / u.velocity], rel=1e-15)
    assert prob.grid[-1] == pytest.approx(86400.0 / u.time)
    s = run_sweep(spec, tmp_path / "o", serial=True, progress=False)
    assert s.ok == 2
    (tmp_path / "prob.py").write_text((tmp_path / "prob.py").read_text() + "\n# edited\n")
    assert spec_from_dict(data, base_dir=tmp_path).keys != spec.keys  # file content is in the key
    (tmp_path / "bad.csv").write_text("name,x[furlong]\na,1\n")
    with pytest.raises(SweepError, match="unit 'furlong'"):
        spec_from_dict({**data, "catalog": {"file": "bad.csv"}}, base_dir=tmp_path)


def test_cli_run_status_collect_and_result_files(tmp_path, capsys):
    from ocreach import load
    from ocreach.cli import main

    data = {"base": {"problem": "vdp", "method": "mc", "options": {"samples": 4},
                     "keep": {"result": True}}, "tasks": [{"options": {"seed": 1}}]}
    spec = tmp_path / "s.json"
    spec.write_text(json.dumps(data))
    out = tmp_path / "o"
    assert main(["sweep", str(spec), "--out", str(out), "--serial", "--no-progress"]) == 0
    assert main(["sweep", "status", str(out)]) == 0
    assert "1 ok, 0 failed, 0 pending" in capsys.readouterr().out
    assert main(["sweep", "collect", str(out)]) == 0
    rows = (out / "table.csv").read_text().splitlines()
    assert len(rows) == 2 and "out.x1_max" in rows[0]
    with pytest.raises(SweepError, match="--format"):
        write_table(out, "xlsx")
    rec = json.loads((out / LOG).read_text())
    res = load(out / rec["result_file"])
    assert np.max(res.points[-1][:, 0]) == pytest.approx(rec["outputs"]["x1_max"])
    meta = json.loads((out / META).read_text())
    assert meta["tasks"][0]["key"] == rec["key"] and meta["versions"]["casadi"]
    assert main(["sweep", str(spec)]) == 2  # --out missing: a clear error, exit code 2
    assert "--out" in capsys.readouterr().err


def test_parquet_table_matches_the_csv(serial_table, tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    out = tmp_path / "o"
    run_sweep(spec_from_dict(SPEC), out, serial=True, progress=False)
    assert [p.name for p in write_table(out, "csv,parquet")] == ["table.csv", "table.parquet"]
    back = pq.read_table(out / "table.parquet").to_pylist()  # read back by pyarrow itself
    columns, rows = collect_table(out)
    assert list(back[0]) == columns and len(back) == len(rows) == 6
    for b, r in zip(back, rows):
        assert {c: b[c] for c in columns} == {c: r.get(c) for c in columns}


def test_parquet_without_pyarrow_names_the_extra(serial_table, tmp_path, monkeypatch):
    import sys

    out = tmp_path / "o"
    run_sweep(spec_from_dict(SPEC), out, serial=True, limit=1, progress=False)
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # import pyarrow now raises ImportError
    with pytest.raises(SweepError, match=r"pip install 'ocreach\[parquet\]'"):
        write_table(out, "csv,parquet")
    assert not (out / "table.csv").exists()  # nothing written before the error


def test_hull_volume_of_known_sets():
    from ocreach.sweep.outputs import hull_volume

    cube = np.array([[i, j, k] for i in (0, 2) for j in (0, 1) for k in (0, 3)], dtype=float)
    inner = np.random.default_rng(1).uniform([0, 0, 0], [2, 1, 3], (50, 3))
    assert hull_volume(np.vstack([cube, inner])) == pytest.approx(6.0)
    assert hull_volume(np.array([[0, 0], [1, 0], [0, 1.0]])) == pytest.approx(0.5)
    assert hull_volume(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])) == 0.0  # flat


def test_example_specs_validate():
    small = load_spec(ROOT / "examples" / "sweep_small.json")
    assert 15 <= len(small) <= 30
    assert len(load_spec(ROOT / "examples" / "sweep_thrust.json")) == 14
    assert len(load_spec(ROOT / "examples" / "sweep_catalog.json")) == 3000
    custody = load_spec(ROOT / "examples" / "sweep_custody.json")
    assert len(custody) == 180 and all(t["keep"]["custody"]["fov_deg"] for t in custody.tasks)


def test_a_dying_worker_is_recorded_and_the_run_stops_clearly(tmp_path):
    (tmp_path / "die.py").write_text(
        "import os\nfrom ocreach.registry import get_problem\n\n"
        "import multiprocessing\n\n"
        "def problem(die=False):\n    if die and multiprocessing.parent_process() is not None:\n"
        "        os._exit(3)  # only in a worker process: the driver builds every problem once to check it\n"
        "    return get_problem('vdp')\n")
    data = {"base": {"problem": "die.py", "method": "mc", "options": {"samples": 2}},
            "tasks": [{}, {"overrides": {"die": True}}, {"options": {"seed": 5}}]}
    spec = spec_from_dict(data, base_dir=tmp_path)
    with pytest.raises(SweepError, match="broke"):
        run_sweep(spec, tmp_path / "o", workers=1, chunk=1, max_in_flight=1, progress=False)
    st = status(tmp_path / "o")
    assert (st["ok"], st["failed"], st["pending"]) == (1, 1, 1)
    assert "lost the task" in st["errors"][0]["message"]
    again = run_sweep(spec, tmp_path / "o", serial=True, progress=False)
    assert (again.ran, again.ok) == (1, 1)


def test_extents_match_the_free_space_reach_of_the_thrust():
    """Independent truth for the override pipeline (state in m and m/s, thrust in N, horizon in
    hours): far from both primaries and over 6 h the CR3BP is nearly free space, where the reach
    along an axis is +-a t^2 / 2 (width a t^2) with a = T_max / m."""
    from ocreach.registry import get_problem
    from ocreach.sweep.worker import run_task

    T, m, t = 2e-3, 14.0, 6 * 3600.0
    data = {"base": {"problem": "dro", "method": "ffoe", "options": {"samples": 8},
                     "overrides": {"thrust": T, "mass": m}, "horizon": {"value": 6, "unit": "h"},
                     "state": {"names": ["x", "y", "vx", "vy"], "values": [1.9e8, 3.3e8, 5.0, -3.0],
                               "units": ["m", "m", "m/s", "m/s"]}},
            "tasks": [{}]}
    spec = spec_from_dict(data)
    rec = run_task({"key": spec.keys[0], "task": spec.tasks[0], "base_dir": "."})
    assert rec["status"] == "ok", rec.get("error")
    L = get_problem("dro").units.length
    for axis in ("x", "y"):
        assert rec["outputs"][f"extent_{axis}"] * L == pytest.approx(T / m * t**2, rel=0.02)


def test_a_killed_driver_resumes_with_the_same_table(tmp_path):
    """SIGKILL a real `ocreach sweep` process mid-run, then resume: only unfinished tasks run."""
    import signal
    import subprocess
    import sys
    import time

    data = {"base": {"problem": "vdp", "method": "mc", "options": {"samples": 200}},
            "product": {"options.seed": list(range(40))}}
    (tmp_path / "s.json").write_text(json.dumps(data))
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "ocreach.cli", "sweep", str(tmp_path / "s.json"), "--out",
           str(out), "--serial", "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if (out / LOG).exists() and (out / LOG).read_bytes().count(b"\n") >= 3:
                break
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    before = status(out)
    if before["pending"] == 0:
        pytest.skip("the driver finished before it could be killed")
    rest: list[str] = []
    spec = spec_from_dict(data)
    s = run_sweep(spec, out, serial=True, progress=False, on_record=lambda r: rest.append(r["key"]))
    assert s.ran == before["pending"] and set(rest).isdisjoint(
        {k for k in spec.keys[: before["ok"]]})
    ref = tmp_path / "ref"
    run_sweep(spec, ref, serial=True, progress=False)
    assert table(out) == table(ref)


def test_serial_executor_runs_with_one_blas_thread_and_restores_the_callers():
    """Serial sweeps get the workers' single BLAS thread (a serial catalog was 16% slower with
    OpenBLAS's two), and the caller's setting comes back when the run ends."""
    threadpoolctl = pytest.importorskip("threadpoolctl")
    import numpy  # noqa: F401 - loads the BLAS whose threads are counted

    from ocreach.sweep.executors import make_executor

    def blas_threads() -> list[int]:
        return [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]

    with threadpoolctl.threadpool_limits(2, user_api="blas"):
        before = blas_threads()
        handle = make_executor(serial=True)
        try:
            assert handle.executor.submit(blas_threads).result() == [1] * len(before)
        finally:
            handle.close()
        assert blas_threads() == before


_SLOW_RUNNER = '''
import os, time
from pathlib import Path

def run(payloads):
    Path(os.environ["PID_DIR"], str(os.getpid())).write_text("")
    time.sleep(120)
    return [{"key": p["key"], "status": "ok", "outputs": {}} for p in payloads]
'''
_DRIVER = '''
import sys
sys.path.insert(0, sys.argv[2])
import slow_runner
from ocreach.sweep import run_sweep, spec_from_dict
spec = {"name": "slow", "base": {"problem": "vdp", "method": "mc", "options": {"samples": 4}},
        "product": {"options.seed": list(range(8))}}
if __name__ == "__main__":
    run_sweep(spec_from_dict(spec), sys.argv[1], workers=2, runner=slow_runner.run, chunk=1,
              progress=False)
'''


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as fh:   # a zombie (exited, not yet reaped) is not running
        return fh.read().rsplit(")", 1)[1].split()[0] != "Z"


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc for process states")
@pytest.mark.parametrize("sig", ["SIGTERM", "SIGKILL"])
def test_stopped_driver_leaves_no_worker_computing(tmp_path, sig):
    """A driver stopped by SIGTERM stops its pool workers (it handles SIGTERM like Ctrl-C); one
    killed outright leaves workers that notice and exit (their orphan check): no process goes on
    computing for a driver that is gone."""
    import signal
    import subprocess
    import sys
    import time

    (tmp_path / "slow_runner.py").write_text(_SLOW_RUNNER)
    (tmp_path / "driver.py").write_text(_DRIVER)
    pids = tmp_path / "pids"
    pids.mkdir()
    env = {**os.environ, "PID_DIR": str(pids), "PYTHONPATH": str(tmp_path)}
    drv = subprocess.Popen([sys.executable, str(tmp_path / "driver.py"), str(tmp_path / "out"),
                            str(tmp_path)], env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while len(list(pids.iterdir())) < 2 and time.time() < deadline and drv.poll() is None:
        time.sleep(0.2)
    workers = [int(p.name) for p in pids.iterdir()]
    assert len(workers) == 2, drv.stderr.read() if drv.poll() is not None else "workers not started"
    drv.send_signal(getattr(signal, sig))
    drv.wait(timeout=60)
    assert drv.returncode != 0
    deadline = time.time() + 30
    while any(_alive(w) for w in workers) and time.time() < deadline:
        time.sleep(0.2)
    left = [w for w in workers if _alive(w)]
    for w in left:   # a failing run does not leave them to the rest of the suite
        os.kill(w, signal.SIGKILL)
    assert not left, f"workers still running after {sig}"
