"""Bad inputs across the CLI and the Python API.

Every case must raise an :class:`ocreach.errors.OcreachError` (the CLI: exit code 2 with
``error: ...``) whose message names the parameter, before any long work.  With
``OCREACH_WRITE_BAD_INPUT_TABLE=1`` the test also writes the table (input -> error) into the
"Bad input" section of ``docs/validation/bad-input.md``.
"""
from __future__ import annotations

import io
import os
import re
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest

import ocreach
from ocreach.cli import main
from ocreach.errors import OcreachError

ROOT = Path(__file__).resolve().parent.parent
SECTION = "## Bad input"


def cli(*argv: str):
    return ("cli", "ocreach " + " ".join(repr(a) if (" " in a or not a) else a for a in argv), argv)


def api(text: str, fn):
    return ("api", text, fn)


def _cli_cases(tmp: Path) -> list[tuple]:
    f = tmp / "afile"
    f.write_text("x")
    two = tmp / "two.py"
    two.write_text("from ocreach.problems.foss import vdp\nPROBLEMS = {'a': vdp, 'b': vdp}\n")
    none = tmp / "none.py"
    none.write_text("x = 1\n")
    files = _problem_files(tmp)
    C = []
    add = C.append
    # -- command structure
    for argv, param in [((), "command"), (("frob",), "command"), (("run",), "problem"),
                        (("run", "vdp"), "--method"), (("run", "vdp", "-m"), "--method"),
                        (("run", "nope", "-m", "mc"), "problem"), (("run", "vdp", "-m", "nope"), "method"),
                        (("run", "vdp", "-m", "mc", "--set", "samples"), "--set"),
                        (("run", "vdp", "-m", "mc", "--set", "=3"), "--set"),
                        (("run", "vdp", "-m", "mc", "--set", "bogus=1"), "bogus"),
                        (("run", "vdp", "-m", "mc", "--set", "problem.bogus=1"), "bogus"),
                        (("run", "vdp", "-m", "mc", "--out", str(f)), "--out"),
                        (("run", "vdp", "-m", "mc", "--out", str(f / "sub")), "--out"),
                        (("run", "/proc/none/x.py", "-m", "mc"), "problem file"),
                        (("run", str(two), "-m", "mc"), "name one"),
                        (("run", f"{two}:c", "-m", "mc"), "problem 'c'"),
                        (("run", str(none), "-m", "mc"), "PROBLEMS"),
                        (("run", "vdp", "-m", "cut"), "method 'cut'"),
                        (("run", "glider-reentry", "-m", "stt"), "method 'stt'"),
                        (("run", "lunar-flyby", "-m", "ode"), "method 'ode'"),
                        (("compare", "vdp", "--methods", ""), "--methods"),
                        (("compare", "vdp", "--methods", ",,"), "--methods"),
                        (("compare", "vdp", "--methods", "mc,mc"), "--methods"),
                        (("compare", "vdp", "--methods", "mc,nope"), "method"),
                        (("compare", "vdp", "--methods", "mc", "--set", "samples=3"), "METHOD.KEY"),
                        (("compare", "vdp", "--methods", "mc", "--set", "ode.samples=3"), "METHOD.KEY"),
                        (("compare", "vdp", "--methods", "mc", "--set", "mc.samples=0"), "samples"),
                        (("compare", "vdp", "--methods", "mc", "--truth-samples", "0"), "--truth-samples"),
                        (("compare", "vdp", "--methods", "mc", "--truth-samples", "abc"), "--truth-samples"),
                        (("compare", "vdp", "--methods", "mc", "--out", str(f)), "--out"),
                        (("report", "nope"), "report"), (("methods", "nope"), "method"),
                        (("problem", "nope"), "problem"), (("bench", "--only", "nothing"), "--only"),
                        (("list", "--bogus"), "--bogus")]:
        add((cli(*argv), param))
    # -- users' problem files (the file and the line) and the folder-writing commands: exit 2
    for argv, param in _file_cases(files) + LEAVE_NO_FOLDER:
        add((cli(*argv), param))
    # -- method options, typed by their declared types
    opts = {
        ("vdp", "mc"): {"samples": ["0", "-5", "2.5", "abc", "nan", "inf", "1e9", "True"],
                        "seed": ["-1", "1.5", "x"], "rtol": ["0", "1", "-1e-9", "x"],
                        "atol": ["-1", "nan"], "mix": ["(1,2)", "(-1,0,0)", "(0,0,0)", "x"],
                        "divergence_factor": ["0.5", "x"], "max_memory_gb": ["0", "-1", "x"]},
        ("vdp", "stt"): {"order": ["0", "4", "x"], "h_max": ["0", "x"], "input_set": ["circle"],
                         "reduction": ["x"], "split": ["x", "(4,0.01)"], "max_parts": ["0", "2.5"],
                         "split_tol": ["0", "-1", "x"], "split_keep": ["-1"],
                         "tube_substeps": ["1", "-1"], "engine": ["x"], "pruned_box": ["x"],
                         "lift_independent": ["maybe", "2"], "rtol": ["1"], "atol": ["-1"]},
        ("vdp", "ode"): {"samples": ["0", "x"], "seed": ["-3"], "rtol": ["0.5"]},
        ("vdp", "ffoe"): {"samples": ["0"], "thrust": ["0", "-1", "nan"],
                          "uncertainty_radius": ["-1", "nan"], "dv_max": ["-1"],
                          "random": ["maybe"], "dims": ["nope"]},
        ("vdp", "ole"): {"tol": ["0", "-1"], "samples": ["-2"]},
        ("vdp", "bvp"): {"cost": ["x"], "smooth": ["-1"], "tol": ["0"]},
        ("glider-reentry", "cut"): {"order": ["5", "x"], "rule": ["x"], "control_rule": ["x"],
                                    "sigma_level": ["0", "-1", "nan"], "third_moments": ["maybe"],
                                    "reduce": ["2"], "compiled": ["perhaps"]},
    }
    for (pid, m), fields in opts.items():
        for key, vals in fields.items():
            for v in vals:
                add((cli("run", pid, "-m", m, "--set", f"{key}={v}"), key))
    # -- problem overrides
    prob = {"vdp": {"t_final": ["3.05", "-1", "0", "nan", "inf", "abc"], "dt": ["0", "-0.1", "5", "nan"],
                    "gain": ["0", "-1"]},
            "dro": {"t_final": ["3.05"], "dt": ["0.07"], "thrust": ["0", "1e6"], "mass": ["0"],
                    "input_set": ["circle"]},
            "l2-halo": {"thrust": ["1e6", "0", "-1"], "mass": ["0", "-1"], "isp": ["0"], "dt": ["-1"],
                        "t_final": ["0.005"]},
            "earth-mars": {"t_days": ["0", "200.5"], "dt_days": ["0"], "thrust": ["-1"]},
            "shuttle-reentry": {"t_final": ["-1"], "dt": ["0", "0.3"], "sigma_u_deg": ["-1"]}}
    for pid, fields in prob.items():
        for key, vals in fields.items():
            for v in vals:
                add((cli("run", pid, "-m", "mc", "--set", f"problem.{key}={v}"), key))
    return C


def _api_cases(tmp: Path) -> list[tuple]:
    from ocreach.control.stationkeeping.runs import run_station_keeping
    from ocreach.models.ephemeris import ephemeris_inertial
    from ocreach.problem import ControlSet, Problem, time_grid
    from ocreach.reach.result import ReachResult
    from ocreach.sets import Ellipsoid, Interval, MatrixZonotope, PolyZonotope, Zonotope

    vdp = ocreach.get_problem("vdp")
    nrho = ocreach.get_problem("nrho-9-2")
    model = vdp.model
    r = ReachResult.from_trajectories(vdp.grid, np.zeros((3, vdp.grid.size, 2)), meta={"method": "mc"})
    text = tmp / "text.npz"
    text.write_text("hello")
    wrong = tmp / "wrong.npz"
    np.savez(wrong, a=np.zeros(2))
    trunc = tmp / "trunc.npz"
    raw = r.save(tmp / "good.npz").read_bytes()
    trunc.write_bytes(raw[: len(raw) // 3])
    old = tmp / "old.npz"
    np.savez(old, times=np.zeros(2), sets_pickle=np.zeros(3, np.uint8), meta_json=np.array("{}"))
    P = dict(id="p", model=model, x0=[0.5, 0.0], grid=np.linspace(0, 1, 5))
    C = []
    add = C.append
    for path, what in ((tmp / "missing.npz", "missing"), (text, "text"), (wrong, "foreign .npz"),
                       (trunc, "truncated"), (old, "old pickle-bearing")):
        add((api(f"ocreach.load({what} file)", lambda p=path: ocreach.load(p)), "result file"))
    for d, param in (([np.nan, 1], "direction d"), ([np.inf, 0], "direction d"), ([0, 0], "direction d"),
                     ([1], "direction d"), ("ab", "direction d"), ([[1, 0], [0, 0]], "direction d")):
        add((api(f"result.support({d!r})", lambda d=d: r.support(d)), param))
    for kw, param in (({"k": 1.5}, "time index k"), ({"k": 99}, "time index k"), ({"dims": [0, 5]}, "dims"),
                      ({"dims": [0, 0]}, "dims"), ({"dims": []}, "dims")):
        add((api(f"result.support([1, 0], **{kw})", lambda kw=kw: r.support([1, 0], **kw)), param))
    for over, param in (({"x0": [1.0]}, "x0"), ({"x0": [np.nan, 0]}, "x0"), ({"grid": [0.0]}, "grid"),
                        ({"grid": [0, 1, 0.5]}, "grid"), ({"grid": [0, np.nan]}, "grid"),
                        ({"params": [1.0]}, "params"), ({"params": [1.0, np.nan]}, "params"),
                        ({"params": [1.0, 0.0]}, "gain"), ({"position_dims": (0, 7)}, "dims")):
        add((api(f"Problem(vdp model, {over})", lambda o=over: Problem(**{**P, **o})), param))
    add((api("ControlSet('circle', 2)", lambda: ControlSet("circle", 2)), "control set kind"))
    add((api("ControlSet('ball', 0)", lambda: ControlSet("ball", 0)), "control dimension"))
    for args, param in (((3.05, 0.1), "t_final"), ((1.0, 0.0), "dt"), ((np.inf, 0.1), "t_final"),
                        (("x", 0.1), "t_final")):
        add((api(f"time_grid{args}", lambda a=args: time_grid(*a)), param))
    for text_, fn, param in (
            ("Interval([1], [0])", lambda: Interval([1], [0]), "lo <= hi"),
            ("Interval([nan], [1])", lambda: Interval([np.nan], [1]), "Interval lo"),
            ("Zonotope([0, 0], G 3x1)", lambda: Zonotope([0, 0], np.ones((3, 1))), "Zonotope generators G"),
            ("Ellipsoid([0, 0], non-symmetric)", lambda: Ellipsoid([0, 0], [[1, 1], [0, 1]]), "symmetric"),
            ("Ellipsoid([0, 0], indefinite)", lambda: Ellipsoid([0, 0], [[1, 0], [0, -1]]), "positive semi-definite"),
            ("PolyZonotope E negative", lambda: PolyZonotope([0], [[1.0]], None, [[-1]]), "exponent matrix E"),
            ("PolyZonotope repeated ids", lambda: PolyZonotope([0], [[1.0, 1.0]], None, [[1, 0], [0, 1]], [3, 3]), "identifiers id"),
            ("MatrixZonotope(vector)", lambda: MatrixZonotope([1.0, 2.0]), "MatrixZonotope centre C"),
            ("MatrixZonotope(nan)", lambda: MatrixZonotope([[np.nan]]), "MatrixZonotope entries"),
            ("reach(vdp, 'nope')", lambda: ocreach.reach(vdp, "nope"), "method"),
            ("reach('nope', 'mc')", lambda: ocreach.reach("nope", "mc"), "problem"),
            ("reach(vdp, 'mc', bogus=1)", lambda: ocreach.reach(vdp, "mc", bogus=1), "bogus"),
            ("reach(vdp, 'stt', lift_independent='maybe')", lambda: ocreach.reach(vdp, "stt", lift_independent="maybe"), "lift_independent"),
            ("reach(vdp, 'stt', engine='library', pruned_box='exact')", lambda: ocreach.reach(vdp, "stt", engine="library", pruned_box="exact"), "pruned_box"),
            ("reach(vdp, 'mc', samples=10**9)", lambda: ocreach.reach(vdp, "mc", samples=10**9), "max_memory_gb"),
            ("reach(vdp, 'cut')", lambda: ocreach.reach(vdp, "cut"), "method 'cut'"),
            ("compare(vdp, ['mc', 'nope'])", lambda: ocreach.compare(vdp, ["mc", "nope"], progress=False), "method"),
            ("compare(vdp, ['mc'], options={'ode': ...})", lambda: ocreach.compare(vdp, ["mc"], options={"ode": {}}, progress=False), "not compared"),
            ("get_problem('vdp', bogus=1)", lambda: ocreach.get_problem("vdp", bogus=1), "bogus"),
            ("get_problem('vdp', t_final=3.05)", lambda: ocreach.get_problem("vdp", t_final=3.05), "t_final"),
            ("get_problem('l2-halo', thrust=1e6)", lambda: ocreach.get_problem("l2-halo", thrust=1e6), "thrust"),
            ("save(set of unknown type)", lambda: ReachResult(times=[0, 1], sets=[object(), object()]).save(tmp / "u.npz"), "cannot save a set"),
            ("run_station_keeping(nrho-9-2, plant/reference='ephemeris', controllers=('lqr',), initial='nonsense')",
             lambda: run_station_keeping(nrho, plant="ephemeris", reference="ephemeris",
                                         controllers=("lqr",), initial="nonsense"), "initial"),
            ("run_station_keeping(nrho-9-2, plant/reference='ephemeris', controllers=('lqr', 'mpc'), initial=[1e-4] * 6)",
             lambda: run_station_keeping(nrho, plant="ephemeris", reference="ephemeris",
                                         controllers=("lqr", "mpc"), initial=[1e-4] * 6), "initial"),
            ("ephemeris_inertial(..., window=('a', 1))",
             lambda: ephemeris_inertial(["earth", "moon"], "earth", "2025-01-01", 2.0, 0.1, 3000.0,
                                        1000.0, window=("a", 1)), "window[0]"),
            ("ephemeris_inertial(..., window=(1,))",
             lambda: ephemeris_inertial(["earth", "moon"], "earth", "2025-01-01", 2.0, 0.1, 3000.0,
                                        1000.0, window=(1,)), "window"),
    ):
        add((api(text_, fn), param))
    return C


#: bad inputs of commands that write an output folder: exit 2 and no folder (nor a temporary or
#: partial one) left behind (:func:`test_bad_inputs_leave_no_folder_behind`)
LEAVE_NO_FOLDER = [
    (("report", "station-keeping", "--problem", "nrho-9-2", "--revolutions", "0", "--out", "r1"),
     "revolutions"),
    (("report", "station-keeping", "--problem", "nrho-9-2", "--controllers", "nonsense", "--out",
      "r2"), "controllers"),
    (("report", "station-keeping", "--problem", "nrho-9-2", "--plant", "ephemeris", "--reference",
      "ephemeris", "--controllers", "lqr", "--set", "initial=nonsense", "--out", "r3"), "initial"),
    (("report", "lqr-vs-mpc", "--problem", "l2-halo", "--set", "bogus=1", "--out", "r4"), "bogus"),
    (("custody", "custody-l1", "--fov", "1", "--p", "2", "--out", "c1"), "probability"),
]


def _file_cases(files: dict[str, Path]) -> list[tuple[tuple[str, ...], str]]:
    """``ocreach run FILE.py`` on each broken problem file, with an output folder."""
    return [(("run", str(files[name]), "-m", "mc", "--out", "u1"), param) for name, param in (
        ("syntax.py", "syntax.py: line 2: SyntaxError"),
        ("import_raises.py", "import_raises.py: line 3: error while importing"),
        ("factory_raises.py", "factory_raises.py: line 5: factory 'boom' raised: IndexError"),
        ("not_a_problem.py", "not_a_problem.py: line 1: factory for 'not_a_problem' must return "
                             "an ocreach.Problem"),
        ("problems_list.py", "PROBLEMS must be a non-empty dict"),
        ("problems_values.py", "PROBLEMS must map problem ids"))]


def _problem_files(tmp: Path) -> dict[str, Path]:
    """Users' problem files that are broken in the ways a user breaks them."""
    texts = {
        "syntax.py": "import numpy as np\ndef problem(:\n",
        "import_raises.py": "import numpy as np\n\nraise RuntimeError('no data file here')\n",
        "factory_raises.py": ("import numpy as np\n\n\ndef boom():\n    return np.zeros(2)[5]\n\n\n"
                              "PROBLEMS = {'boom': boom}\n"),
        "not_a_problem.py": "def problem():\n    return 42\n",
        "problems_list.py": "PROBLEMS = [1, 2]\n",
        "problems_values.py": "PROBLEMS = {'a': 3}\n",
    }
    out = {}
    for name, text in texts.items():
        out[name] = tmp / name
        out[name].write_text(text)
    return out


def test_bad_inputs_leave_no_folder_behind(tmp_path, monkeypatch):
    """The output-folder commands refuse these inputs with exit 2 and create nothing: no
    ``--out`` folder, no temporary ``.NAME.tmp-*`` folder, no ``NAME.partial``."""
    monkeypatch.chdir(tmp_path)
    files = _problem_files(tmp_path)
    cases = _file_cases(files) + LEAVE_NO_FOLDER
    cases += [(("compare", "vdp", "--methods", "mc", "--set", "mc.samples=0", "--out", "m1"),
               "samples")]
    before = sorted(p.name for p in tmp_path.iterdir())
    for argv, param in cases:
        msg = _message(("cli", " ".join(argv), argv))
        assert param in msg
        assert sorted(p.name for p in tmp_path.iterdir()) == before, (argv, msg)


def _message(case) -> str:
    surface, text, arg = case
    if surface == "cli":
        out, err = io.StringIO(), io.StringIO()
        with redirect_stdout(out), redirect_stderr(err):
            rc = main(list(arg))
        lines = [ln for ln in err.getvalue().splitlines() if ln.startswith("error: ")]
        assert rc == 2 and lines, f"{text}: exit {rc}, stderr {err.getvalue()[-500:]!r}"
        return lines[-1].removeprefix("error: ")
    with pytest.raises(OcreachError) as exc:
        arg()
    return str(exc.value)


def test_bad_inputs_raise_ocreach_errors_naming_the_parameter(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a case that wrongly ran would write out/ here, not in the repo
    cases = _cli_cases(tmp_path) + _api_cases(tmp_path)
    texts = [c[0][1] for c in cases]
    assert len(set(texts)) == len(texts), "cases must be distinct"
    assert len(cases) >= 150, len(cases)
    rows, bad = [], []
    for case, param in cases:
        t0 = time.perf_counter()
        try:
            msg = _message(case)
        except (Exception, pytest.fail.Exception) as exc:  # noqa: BLE001 (collected and reported)
            bad.append((case[1], param, f"{type(exc).__name__}: {exc}"))
            continue
        if param.lower() not in msg.lower():
            bad.append((case[1], param, msg))
        rows.append((case[0], case[1], msg, time.perf_counter() - t0))
    assert not bad, "\n".join(f"{t}: expected {p!r} in {m!r}" for t, p, m in bad)
    if os.environ.get("OCREACH_WRITE_BAD_INPUT_TABLE"):
        _write_table(rows)


def _cell(s: str) -> str:
    s = s.replace(str(ROOT), "REPO").replace(str(Path.home()), "~")
    s = re.sub(r"/tmp/pytest-of-[^/]+/pytest-\d+/[^/ ']+", "TMP", s)
    return s.replace("|", "\\|").replace("\n", " ")


def _write_table(rows) -> None:
    from ocreach.fileio import atomic_write_text

    n_cli = sum(1 for r in rows if r[0] == "cli")
    lines = [SECTION, "",
             f"{len(rows)} distinct bad inputs ({n_cli} through the CLI, {len(rows) - n_cli} through "
             "the Python API), each refused with an `ocreach.errors` error that names the parameter "
             "(the CLI prints `error: ...` and exits 2), before any long work. Generated by "
             "`OCREACH_WRITE_BAD_INPUT_TABLE=1 pytest tests/test_bad_inputs.py`, which checks every "
             "row."]
    unit = {cli(*argv)[1] for argv, _ in LEAVE_NO_FOLDER} | {
        r[1] for r in rows if r[0] == "cli" and r[1].startswith("ocreach run ") and "--out u1" in r[1]}
    folder_rows = [i for i, r in enumerate(rows, 1) if r[1] in unit]
    lines += ["", f"The inputs of rows {', '.join(map(str, folder_rows))} name an output folder: "
              "they exit 2 and leave nothing behind (no `--out` folder, no temporary or partial "
              "one), checked by `test_bad_inputs_leave_no_folder_behind`.", "",
              "| # | via | input | error |", "|---|---|---|---|"]
    for i, (surface, text, msg, _) in enumerate(rows, 1):
        lines.append(f"| {i} | {surface} | `{_cell(text)}` | {_cell(msg)} |")
    doc = ROOT / "docs" / "validation" / "bad-input.md"
    old = doc.read_text()
    block = "\n".join(lines) + "\n"
    if SECTION in old:
        head, _, rest = old.partition(SECTION)
        nxt = re.search(r"^## ", rest, flags=re.M)
        tail = rest[nxt.start():] if nxt else ""
        new = head + block + ("\n" + tail if tail else "")
    else:
        new = old.rstrip("\n") + "\n\n" + block
    atomic_write_text(doc, new)
