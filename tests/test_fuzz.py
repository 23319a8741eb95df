"""Fuzz suite (hypothesis) over the CLI parser and the public API entry points.

Every case ends in either a result (finite numbers, a loadable file) or an
:class:`~ocreach.errors.OcreachError` whose message names something the caller typed (the option,
problem, method or value); never another exception type, a NaN result or a hang (each case is
bounded by an alarm).  Problem sizes are tiny (Van der Pol, <= 3 TU, <= 40 samples).
"""
from __future__ import annotations

import io
import math
import signal
from contextlib import contextmanager, redirect_stderr, redirect_stdout

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import ocreach
from ocreach.cli import main
from ocreach.errors import OcreachError

CASE_SECONDS = 60
SETTINGS = settings(max_examples=25, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

junk = st.sampled_from(["", "x", "nan", "inf", "-inf", "-1", "0", "1e9", "true", "maybe", "None",
                        "(1,2)", "[0, 1]", "1e-400", "0x10", "💥", "a=b", "3.05", "--out"])
small_num = st.one_of(st.integers(-3, 40).map(str), st.floats(-5, 5).map(repr))
value = st.one_of(junk, small_num)
OPTION_KEYS = {
    "mc": ["samples", "seed", "rtol", "mix", "divergence_factor", "max_memory_gb", "bogus"],
    "stt": ["order", "h_max", "input_set", "reduction", "lift_independent", "split", "max_parts", "split_tol",
            "engine"],
    "ode": ["samples", "seed", "atol"],
    "ffoe": ["samples", "thrust", "dims", "random", "uncertainty_radius"],
}
PROBLEM_KEYS = ["t_final", "dt", "gain", "nope"]


@contextmanager
def _alarm(seconds: int = CASE_SECONDS):
    def boom(signum, frame):
        raise TimeoutError(f"case took longer than {seconds} s (a hang)")

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _mentions(msg: str, tokens: list[str]) -> bool:
    low = msg.lower()
    return any(t and t.lower() in low for t in tokens)


@st.composite
def run_argv(draw):
    method = draw(st.sampled_from(list(OPTION_KEYS) + ["nope"]))
    keys = OPTION_KEYS.get(method, ["samples"])
    sets = []
    for _ in range(draw(st.integers(0, 3))):
        if draw(st.booleans()):
            sets.append((f"problem.{draw(st.sampled_from(PROBLEM_KEYS))}", draw(value)))
        else:
            sets.append((draw(st.sampled_from(keys)), draw(value)))
    sizes = [("samples", "12")] if method in ("mc", "ode", "ffoe") else []
    sizes += [("problem.t_final", "1.0")] if not any(k == "problem.t_final" for k, _ in sets) else []
    given_keys = {k for k, _ in sets}
    sets += [(k, v) for k, v in sizes if k not in given_keys]  # keep valid runs tiny
    if method == "mc":
        sets = [(k, v) if k != "samples" or _small_count(v) else (k, "12") for k, v in sets]
    argv = ["run", draw(st.sampled_from(["vdp", "vdp", "nope", "vdp.py"])), "-m", method]
    for k, v in sets:
        argv += ["--set", f"{k}={v}"]
    return argv, [method, *(k.removeprefix("problem.") for k, _ in sets), *(v for _, v in sets),
                  "problem", "method", "--set", "vdp"]


def _small_count(v: str) -> bool:
    try:
        return float(v) <= 40
    except ValueError:
        return True


OUTCOMES: list[int] = []


@given(case=run_argv())
@SETTINGS
def test_fuzz_cli_run(case, tmp_path_factory):
    argv, tokens = case
    out = tmp_path_factory.mktemp("fz") / "o"
    err = io.StringIO()
    with _alarm(), redirect_stdout(io.StringIO()), redirect_stderr(err):
        rc = main([*argv, "--out", str(out)])
    text = err.getvalue()
    assert "Traceback" not in text
    OUTCOMES.append(rc)
    if rc == 0:
        r = ocreach.load(out / "result.npz")
        pts = r.points if r.points is not None else [s.interval_hull().lo for s in r.sets]
        assert all(np.all(np.isfinite(p)) for p in pts)
    else:
        assert rc in (2, 3), (rc, text)
        msg = [ln for ln in text.splitlines() if ln.startswith("error: ")][-1]
        assert _mentions(msg, tokens), (argv, msg)


@given(argv=st.lists(st.one_of(st.sampled_from(["list", "methods", "problem", "compare", "report",
                                                "bench", "run", "--set", "--methods", "--out",
                                                "--only", "-m", "vdp", "nope", "mc,", ""]), junk),
                     max_size=5))
@settings(max_examples=40, deadline=None, derandomize=True)
def test_fuzz_cli_parser_words(argv):
    """Random word sequences (no long work can start: compare/run need --methods/-m with a valid
    problem, bench needs a match): an exit code or a clear error, never a traceback."""
    if "bench" in argv or ("compare" in argv and "--methods" in argv) or ("run" in argv and "-m" in argv):
        argv = [a for a in argv if a not in ("bench", "compare", "run")] or ["list"]
    err = io.StringIO()
    with _alarm(), redirect_stdout(io.StringIO()), redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as exc:  # only --help style exits are allowed to leave argparse
            assert exc.code == 0
            return
    assert rc in (0, 2), (argv, rc, err.getvalue())
    if rc == 2:
        assert err.getvalue().startswith("error: ")


api_value = st.one_of(st.integers(-5, 40), st.floats(allow_nan=True, allow_infinity=True, width=32),
                      st.text(max_size=4), st.booleans(), st.none(), st.tuples(st.integers(-1, 2)),
                      st.lists(st.floats(-2, 2), max_size=3))


@given(method=st.sampled_from(list(OPTION_KEYS)), opts=st.dictionaries(
    st.sampled_from(sorted({k for ks in OPTION_KEYS.values() for k in ks})), api_value, max_size=3))
@SETTINGS
def test_fuzz_api_reach(method, opts):
    p = ocreach.get_problem("vdp", t_final=1.0)
    if method in ("mc", "ode", "ffoe") and not (isinstance(opts.get("samples"), int)
                                                 and 1 <= opts["samples"] <= 40):
        opts = {**opts, "samples": 12} if "samples" not in opts else opts
    with _alarm():
        try:
            r = ocreach.reach(p, method, **opts)
        except OcreachError as exc:
            assert _mentions(str(exc), [*opts, *map(str, opts.values()), method]), (opts, str(exc))
            return
    final = r.points[-1] if r.points is not None else r.sets[-1].interval_hull().hi
    assert np.all(np.isfinite(final))


_MC: list = []


@given(d=st.one_of(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=3),
                   st.text(max_size=3), st.integers()),
       k=st.one_of(st.integers(-40, 40), st.floats(-3, 3), st.none()),
       dims=st.one_of(st.none(), st.lists(st.integers(-2, 3), max_size=3)))
@settings(max_examples=60, deadline=None, derandomize=True)
def test_fuzz_api_support(d, k, dims):
    if not _MC:
        _MC.append(ocreach.reach("vdp", "mc", samples=10))
    r = _MC[0]
    kw = {} if k is None else {"k": k}
    try:
        v = r.support(d, dims=dims, **kw)
    except OcreachError as exc:
        assert _mentions(str(exc), ["direction d", "time index k", "dims"]), str(exc)
        return
    assert np.all(np.isfinite(v))


@given(lo=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=3),
       hi=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=3),
       G=st.lists(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=2), min_size=0, max_size=3))
@settings(max_examples=60, deadline=None, derandomize=True)
def test_fuzz_set_constructors(lo, hi, G):
    from ocreach.sets import Ellipsoid, Interval, Zonotope

    for build in (lambda: Interval(lo, hi), lambda: Zonotope(lo, G or None),
                  lambda: Ellipsoid(lo, np.diag(np.abs(hi[: len(lo)])) if len(hi) >= len(lo) else hi)):
        try:
            s = build()
        except OcreachError as exc:
            assert str(exc)
            continue
        try:  # huge (1e307) entries may overflow in the hull: a SetError, never a silent inf
            h = s.interval_hull()
        except OcreachError as exc:
            assert "finite" in str(exc)
            continue
        assert np.all(np.isfinite(h.lo)) and np.all(np.isfinite(h.hi))


@given(data=st.binary(max_size=400))
@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_fuzz_load_bytes(data, tmp_path_factory):
    path = tmp_path_factory.mktemp("ld") / "f.npz"
    path.write_bytes(b"PK\x03\x04" + data if data[:1] == b"\x00" else data)
    with pytest.raises(OcreachError, match="result file"):
        ocreach.load(path)


@given(t_final=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=3)),
       dt=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2, 2)))
@settings(max_examples=60, deadline=None, derandomize=True)
def test_fuzz_time_grid(t_final, dt):
    from ocreach.problem import time_grid

    try:
        g = time_grid(t_final, dt)
    except OcreachError as exc:
        assert _mentions(str(exc), ["t_final", "dt"])
        return
    assert g.size >= 2 and np.all(np.diff(g) > 0) and math.isclose(g[-1], float(t_final), rel_tol=1e-6)


def test_fuzz_cli_run_reached_both_outcomes():
    """The run fuzzer is not vacuous: it produced finished runs and refused inputs."""
    if not OUTCOMES:
        pytest.skip("run after test_fuzz_cli_run")
    assert 0 in OUTCOMES and 2 in OUTCOMES, OUTCOMES
