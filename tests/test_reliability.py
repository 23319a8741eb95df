"""Reliability checks: divergence guard, typed options, argument checks before work,
discoverability (methods, list, FILE.py:ID, thrust metadata)."""
from __future__ import annotations

import io
import json
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest

import ocreach
from ocreach.cli import main
from ocreach.errors import ProblemError, SolverError
from ocreach.options import coerce, parse_bool
from ocreach.problem import time_grid
from ocreach.reach.base import method_class
from ocreach.reach.guard import check_result, problem_scale
from ocreach.reach.result import ReachResult
from ocreach.registry import get_problem


def _cli(*argv):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = main(list(argv))
    return rc, out.getvalue(), err.getvalue()


# ------------------------------------------------------------------ divergence guard
def test_nrho_stt_divergence_stops_with_error_and_flagged_partial(tmp_path):
    """Foss STT on the 9:2 NRHO to perilune blows up (~1e4 DU at 76 h vs ~1 DU Monte Carlo):
    the run stops with a SolverError naming method, time and size, the CLI exits 3 and keeps the
    truncated, flagged, bounded part in DIR.partial (DIR itself is not created)."""
    out = tmp_path / "nrho"
    rc, _, err = _cli("run", "nrho-9-2", "--method", "stt", "--out", str(out))
    assert rc == 3
    assert "method 'stt' diverged on 'nrho-9-2'" in err and "t = " in err and "beyond the bound" in err
    assert not out.exists()
    part = tmp_path / "nrho.partial"
    r = ocreach.load(part / "result.npz")
    assert r.meta["truncated"] is True and len(r.times) < get_problem("nrho-9-2").grid.size
    bound = 100 * problem_scale(get_problem("nrho-9-2"))
    for k in range(len(r.times)):
        h = r.sets[k].interval_hull()
        assert np.all(np.abs(np.concatenate([h.lo, h.hi])) <= bound)
    assert json.loads((part / "summary.json").read_text())["truncated"] is True
    assert json.loads((part / "MANIFEST.json").read_text())["complete"] is False


def test_guard_non_finite_points_and_sets_keep_prefix():
    p = get_problem("vdp")
    traj = np.zeros((4, p.grid.size, 2))
    traj[1, 7, 0] = np.nan
    with pytest.raises(SolverError, match="must be finite") as exc:
        ReachResult.from_trajectories(p.grid, traj, meta={"method": "mc"})
    assert exc.value.partial.times.size == 7 and exc.value.partial.meta["truncated"]
    from ocreach.sets import Interval

    sets = [Interval([-1, -1], [1, 1])] * 5 + [Interval([-1e9, -1], [1, 1])] * (p.grid.size - 5)
    r = ReachResult(times=p.grid, sets=sets, meta={"method": "x"})
    with pytest.raises(SolverError, match=r"method 'x' diverged on 'vdp': the estimate at t = 0.5 "
                                          r"has grown to 1e\+09") as exc:
        check_result(r, p)
    assert len(exc.value.partial.sets) == 5
    assert check_result(r, p, factor=float("inf")) is r  # the option switches the size check off


def test_divergence_factor_option_checked():
    with pytest.raises(ProblemError, match="divergence_factor must be a number > 1"):
        ocreach.reach("vdp", "mc", divergence_factor=0.5)
    with pytest.raises(ProblemError, match="max_memory_gb must be > 0"):
        ocreach.reach("vdp", "mc", max_memory_gb=-1)


# ------------------------------------------------------------------ typed options
@pytest.mark.parametrize("raw,val", [("true", True), ("False", False), ("1", True), ("0", False),
                                     ("yes", True), ("NO", False), ("on", True), ("off", False)])
def test_parse_bool_words(raw, val):
    assert parse_bool("x", raw) is val


@pytest.mark.parametrize("raw", ["maybe", "2", "", "truee", "None"])
def test_parse_bool_refuses(raw):
    with pytest.raises(ProblemError, match="lift_independent must be a boolean"):
        coerce({"lift_independent": raw}, method_class("stt").Options, "")


def test_cli_false_is_false(tmp_path):
    out = tmp_path / "o"
    rc, _, err = _cli("run", "vdp", "-m", "cut", "--out", str(out))  # not applicable: clear error
    assert rc == 2 and "does not apply" in err and not out.exists()
    opts = coerce({"lift_independent": "false", "h_max": "50", "split": "box", "max_parts": "8",
                   "split_tol": "0.05"}, method_class("stt").Options)
    assert opts == {"lift_independent": False, "h_max": 50, "split": "box", "max_parts": 8, "split_tol": 0.05}
    assert method_class("stt")(lift_independent="false").options.lift_independent is False  # API too
    with pytest.raises(ProblemError, match="stt option lift_independent must be a boolean"):
        ocreach.reach("vdp", "stt", lift_independent="maybe")


# ------------------------------------------------------------------ checks before work
@pytest.mark.parametrize("kw,msg", [
    ({"t_final": 3.05}, r"t_final = 3.05 TU must be a whole multiple of dt = 0.1 TU .* nearest valid t_final: 3 or 3.1"),
    ({"dt": 5}, "must be a whole multiple of dt = 5"),
    ({"dt": 0}, "dt must be > 0"), ({"dt": -0.1}, "dt must be > 0"),
    ({"t_final": -1}, "t_final must be > 0"), ({"t_final": float("nan")}, "t_final must be a finite"),
])
def test_grid_rule(kw, msg):
    with pytest.raises(ProblemError, match=msg):
        get_problem("vdp", **kw)


def test_time_grid_exact_and_fit():
    g = time_grid(3.0, 0.1)
    assert g.size == 31 and g[-1] == pytest.approx(3.0)
    f = time_grid(1.0, 0.3, fit=True)
    assert f[-1] == 1.0 and f.size == 4


def test_out_checked_before_work(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    for bad, msg in ((f, "exists and is not a folder"), (f / "sub", "is a file, not a folder")):
        rc, out, err = _cli("run", "vdp", "-m", "mc", "--out", str(bad))
        assert rc == 2 and msg in err and "Van der Pol" not in out  # nothing ran


def test_memory_estimate_refuses_before_work():
    with pytest.raises(ProblemError, match=r"samples = 1000000000 .* max_memory_gb = 4"):
        ocreach.reach("vdp", "mc", samples=1e9)
    with pytest.raises(ProblemError, match="max_memory_gb = 0.001"):
        ocreach.reach("vdp", "mc", samples=10_000, max_memory_gb=1e-3)


def test_stochastic_mc_memory_estimate_counts_what_is_kept():
    """The stochastic Monte Carlo keeps states at a few report times (and ~200 grid times with
    histories), so 100,000 shuttle samples (Jain et al.) pass the default 4 GB check; the estimate
    is computed independently here from what the result holds."""
    shuttle = get_problem("shuttle-reentry")
    n_x, n_u = shuttle.model.n_x, shuttle.model.n_u
    mc = method_class("mc")(samples=100_000)
    mc.check_before(shuttle)  # refused as 51 GB before
    kept = mc._stochastic_times(shuttle).size
    assert 2 <= kept < 20
    assert mc.memory_estimate(shuttle) == pytest.approx(
        100_000 * (kept * n_x + 16 * (n_x + n_u)) * 8 * 4)
    hist = method_class("mc")(samples=100_000, histories=True)
    kept_h = hist._stochastic_times(shuttle).size
    assert 200 <= kept_h <= 220
    assert hist.memory_estimate(shuttle) == pytest.approx(
        100_000 * (kept_h * n_x + 16 * (n_x + n_u) + (shuttle.grid.size - 1) * n_u) * 8 * 4)
    with pytest.raises(ProblemError, match=r"samples = 100000 of method 'mc' on problem "
                                           r"'shuttle-reentry' .* max_memory_gb = 1"):
        method_class("mc")(samples=100_000, histories=True, max_memory_gb=1).check_before(shuttle)
    # a small stochastic run holds what the estimate counts
    res = ocreach.reach("shuttle-reentry", "mc", samples=50, seed=1)
    assert res.times.size == mc._stochastic_times(shuttle).size


def test_implausible_thrust_refused_with_rule():
    with pytest.raises(ProblemError, match=r"thrust acceleration of 1000 m/s\^2 \(thrust 1e\+06 N\), "
                                          r"above the limit 9.80665 m/s\^2 \(1 g0\)"):
        get_problem("l2-halo", thrust=1e6)
    assert get_problem("l2-halo").thrust_acceleration_si() == pytest.approx(1e-4)


def test_compare_empty_methods_and_bench_peer(monkeypatch):
    rc, _, err = _cli("compare", "vdp", "--methods", "")
    assert rc == 2 and "--methods must name at least one method" in err
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "do_mpc" else real(name, *a))
    rc, _, err = _cli("bench", "--only", "mpc")
    assert rc == 2 and "pip install do-mpc" in err


def test_support_refuses_bad_directions():
    r = ocreach.reach("vdp", "mc", samples=10)
    for d, msg in (([np.nan, 1.0], "finite"), ([0.0, 0.0], "non-zero"), ([np.inf, 0], "finite")):
        with pytest.raises(ProblemError, match=f"direction d must be {msg}"):
            r.support(d)


# ------------------------------------------------------------------ discoverability
def test_methods_lists_options_with_defaults_and_docs():
    rc, out, _ = _cli("methods", "stt")
    assert rc == 0
    assert "lift_independent : bool = False" in out and "h_max : int = 200" in out
    assert "most generators (dependent + independent)" in out
    assert "divergence_factor : float = 100.0" in out


def test_every_method_option_is_described_on_its_own():
    """Each option of each registered method has its own description (a ``#:`` comment on the
    field), not a fragment of a docstring sentence that runs into the next option."""
    from ocreach.options import describe_fields, field_comments
    from ocreach.reach.base import available_methods, method_class

    for name in available_methods():
        cls = method_class(name).Options
        comments = field_comments(cls)
        for row in describe_fields(cls):
            assert row["name"] in comments, f"{name}: option {row['name']!r} has no #: comment"
            assert row["doc"] and "``" not in row["doc"], (name, row)


def test_field_comments_above_trailing_and_inherited():
    import dataclasses

    from ocreach.options import field_comments

    @dataclasses.dataclass
    class Base:
        #: first line
        #: second line
        a: int = 1
        b: int = 2  #: on the line
        c: int = 3

    @dataclasses.dataclass
    class Child(Base):
        #: the child's a
        a: int = 4

    assert field_comments(Base) == {"a": "first line second line", "b": "on the line"}
    assert field_comments(Child) == {"a": "the child's a", "b": "on the line"}


def test_list_shows_applicable_methods_and_why():
    rc, out, _ = _cli("list", "--why")
    assert rc == 0
    assert "not cut: needs a stochastic problem" in out
    assert "not ode: needs a control-affine model" in out  # the variable-mass ephemeris models


def test_problem_file_with_two_problems(tmp_path):
    f = tmp_path / "mine.py"
    f.write_text("from ocreach.problems.foss import vdp\n"
                 "PROBLEMS = {'short': lambda t_final=1.0: vdp(t_final=t_final),\n"
                 "            'long': lambda: vdp(t_final=2.0)}\n")
    with pytest.raises(ProblemError, match=r"several problems \['long', 'short'\]; name one as .*:ID"):
        get_problem(str(f))
    assert get_problem(f"{f}:long").grid[-1] == pytest.approx(2.0)
    rc, out, _ = _cli("run", f"{f}:short", "-m", "mc", "--set", "samples=5", "--set",
                      "problem.t_final=0.5", "--out", str(tmp_path / "o"))
    assert rc == 0 and (tmp_path / "o" / "result.npz").is_file()


@pytest.mark.parametrize("method", ["ffoe", "ole", "bvp"])
def test_thrust_methods_run_on_vdp_via_declared_thrust_param(method):
    """vdp declares thrust_param="gain": ffoe/ole/bvp run and their samples are real trajectories
    (independent check: scipy re-integration of a sample's controls)."""
    from scipy.integrate import solve_ivp

    p = get_problem("vdp", t_final=1.0)
    r = ocreach.reach(p, method, samples=4)
    u = r.controls[0]
    assert np.all(np.abs(u) <= 1 + 1e-9)
    x = np.asarray(r.trajectories[0, 0])
    if method == "bvp":  # bvp's controls are the sampled optimal law; compare endpoint loosely
        assert np.all(np.isfinite(r.points[-1]))
        return
    for k in range(p.n_segments):
        sol = solve_ivp(lambda t, y: [y[1], (1 - y[0] ** 2) * y[1] - y[0] + 0.05 * u[k, 0]],
                        (p.grid[k], p.grid[k + 1]), x, rtol=1e-11, atol=1e-12, method="DOP853")
        x = sol.y[:, -1]
    assert np.abs(x - r.points[-1][0]).max() < 1e-7


def test_model_builders_declare_thrust_and_twobody_default_is_usable():
    from ocreach.models import cr3bp, twobody, vanderpol
    from ocreach.problem import Problem

    assert cr3bp(0.01215).thrust_param == "a_max" and vanderpol().thrust_param == "gain"
    m = twobody()
    assert m.param("a_max") > 0
    Problem(id="tb", model=m, x0=[1, 0, 0, 0, 1, 0], grid=np.linspace(0, 1, 3))


def test_reentry_plots_in_seconds():
    from ocreach.reach.plot import time_label

    assert time_label(get_problem("shuttle-reentry", t_final=10.0), 5.0) == "t = 5 s"


def test_summary_small_and_print_short(tmp_path):
    rc, _, _ = _cli("run", "vdp", "-m", "mc", "--set", "samples=3000", "--out", str(tmp_path / "o"))
    assert rc == 0
    assert (tmp_path / "o" / "summary.json").stat().st_size < 4000
    r = ocreach.load(tmp_path / "o" / "result.npz")
    assert len(str(r)) < 300


def test_ffoe_on_a_control_affine_user_model_without_thrust_parameter():
    """A double integrator x1' = x2, x2' = u (box) declares no thrust parameter: ffoe applies
    (control-affine); its samples satisfy the exact solution x2(T) = x2(0) + sum_k u_k dt."""
    import casadi as ca

    from ocreach.model import Model
    from ocreach.problem import Problem

    x, u = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    m = Model.build("di", x, u, ca.vertcat(x[1], u[0]), control_set="box")
    p = Problem(id="di", model=m, x0=[0.0, 0.0], grid=np.linspace(0, 1, 5),
                position_dims=(0, 1), velocity_dims=(0, 1))
    assert method_class("ffoe").applicable(p) == (True, "")
    r = ocreach.reach(p, "ffoe", samples=6)
    dt = np.diff(p.grid)
    np.testing.assert_allclose(r.trajectories[:, -1, 1], r.controls[..., 0] @ dt, atol=1e-9)
    with pytest.raises(ProblemError, match="declares no thrust parameter"):
        ocreach.reach(p, "ffoe", samples=6, thrust=0.5)


def test_output_dir_commit_is_a_unit_even_with_sigint_during_the_renames(tmp_path, monkeypatch):
    import os
    import signal

    from ocreach.interrupt import install, restore
    from ocreach.outdir import OutputDir

    target = tmp_path / "d"
    target.mkdir()
    (target / "old.txt").write_text("old")
    out = OutputDir(target)
    (out.path / "new.txt").write_text("new")
    real_rename = os.rename
    calls = []

    def rename(a, b):  # Ctrl-C between "old aside" and "new in"
        calls.append((a, b))
        real_rename(a, b)
        if len(calls) == 1:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(os, "rename", rename)
    prev = install()
    try:
        with pytest.raises(KeyboardInterrupt):
            out.commit()
    finally:
        restore(prev)
    assert len(calls) == 2 and out.done == "committed"
    assert sorted(p.name for p in target.iterdir()) == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["d"]  # no temporary or old folder left
    from ocreach.interrupt import interrupt_requested

    assert not interrupt_requested()  # handled: later work in this process is not interrupted


def test_output_dir_partial_and_nothing(tmp_path):
    from ocreach.outdir import OutputDir

    out = OutputDir(tmp_path / "d")
    assert out.keep_partial("x") is None and not list(tmp_path.iterdir())
    out = OutputDir(tmp_path / "d")
    (out.path / "a.npz").write_bytes(b"1")
    kept = out.keep_partial("interrupted")
    assert kept == tmp_path / "d.partial" and not (tmp_path / "d").exists()
    assert "not created; the finished files are kept in" in out.describe_partial(kept)
    assert json.loads((kept / "MANIFEST.json").read_text())["files"] == ["a.npz"]


def test_staged_files_replace_all_or_nothing(tmp_path):
    """``StagedFiles``: nothing in the folder changes until commit; an error before it leaves the
    old files and no staging folder."""
    from ocreach.outdir import StagedFiles

    (tmp_path / "a.csv").write_text("old a")
    (tmp_path / "b.md").write_text("old b")
    with pytest.raises(RuntimeError), StagedFiles(tmp_path) as st:
        st.path("a.csv").write_text("new a")
        assert (tmp_path / "a.csv").read_text() == "old a"
        raise RuntimeError("the second table failed")
    assert (tmp_path / "a.csv").read_text() == "old a"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.md"]
    with StagedFiles(tmp_path) as st:
        st.path("a.csv").write_text("new a")
        seeded = st.path("b.md", seed=True)
        assert seeded.read_text() == "old b"
        seeded.write_text(seeded.read_text() + " + section")
        assert st.commit() == [tmp_path / "a.csv", tmp_path / "b.md"]
    assert (tmp_path / "a.csv").read_text() == "new a"
    assert (tmp_path / "b.md").read_text() == "old b + section"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.md"]
    with pytest.raises(ProblemError, match="not a folder"):
        StagedFiles(tmp_path / "a.csv")


def test_bench_write_publishes_the_staged_document_only_if_every_script_succeeds(tmp_path,
                                                                                monkeypatch):
    """``ocreach bench --write``: the scripts write their sections into a staged copy of
    ``docs/benchmarks.md`` (``benchmarks_doc``); a failing script leaves the document as it was."""
    import subprocess

    from ocreach import cli
    from ocreach.fileio import replace_markdown_section
    from ocreach.outdir import BENCH_DOC_ENV, benchmarks_doc

    docs = tmp_path / "docs"
    bench = tmp_path / "benchmarks"
    docs.mkdir()
    bench.mkdir()
    (docs / "benchmarks.md").write_text("# Benchmarks\n\n## A\n\nold\n")
    for name in ("bench_a.py", "bench_b.py"):
        (bench / name).write_text("")
    monkeypatch.setattr(cli, "__file__", str(tmp_path / "ocreach" / "cli.py"))

    def fake_call(cmd, env=None):  # a benchmark: its section into benchmarks_doc(...)
        monkeypatch.setenv(BENCH_DOC_ENV, env[BENCH_DOC_ENV])
        name = Path(cmd[1]).stem
        replace_markdown_section(benchmarks_doc(docs / "benchmarks.md"), f"## {name}\n\nnew\n")
        return 1 if state["fail"] and name == "bench_b" else 0

    monkeypatch.setattr(subprocess, "call", fake_call)
    state = {}
    for fail in (True, False):
        state["fail"] = fail
        rc = cli.main(["bench", "--write"])
        text = (docs / "benchmarks.md").read_text()
        if fail:
            assert rc == 1 and text == "# Benchmarks\n\n## A\n\nold\n"
        else:
            assert rc == 0 and "## bench_a\n\nnew" in text and "## bench_b\n\nnew" in text
        assert sorted(p.name for p in docs.iterdir()) == ["benchmarks.md"]


def test_listing_into_a_closed_pipe_ends_quietly():
    """``ocreach methods | head -1``: the reader closes the pipe; no traceback, exit 0.  The pipe
    holds one page (Linux F_SETPIPE_SZ), so the listing (17 kB) cannot fit before it closes."""
    import fcntl
    import os
    import subprocess
    import sys

    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, getattr(fcntl, "F_SETPIPE_SZ", 1031), 4096)
    proc = subprocess.Popen([sys.executable, "-m", "ocreach.cli", "methods"], stdout=write_end,
                            stderr=subprocess.PIPE)
    os.close(write_end)
    with os.fdopen(read_end, "rb") as reader:
        first = reader.readline()
    err = proc.stderr.read().decode()
    assert first.startswith(b"mc:") and proc.wait(timeout=120) == 0, err
    assert "Traceback" not in err and "BrokenPipe" not in err, err


@pytest.mark.parametrize("method, options", [("mc", {"samples": 8}), ("ode", {"samples": 8}),
                                             ("ffoe", {"samples": 8})])
def test_an_estimate_says_it_is_not_guaranteed(method, options):
    r = ocreach.reach("vdp", method, **options)
    assert r.meta["guaranteed"] is False


def test_every_problem_parameter_is_described():
    """``ocreach problem ID`` describes every parameter of every bundled problem from its
    factory's docstring (an ``Options:`` paragraph), with the parameter's own sentence."""
    from ocreach.options import describe_fields
    from ocreach.registry import problem_factories, problem_factory

    for pid in sorted(problem_factories()):
        _, factory = problem_factory(pid)
        for row in describe_fields(factory):
            assert row["doc"].startswith(f"``{row['name']}``"), (pid, row)
