"""Tests of ocreach.native's compile cache: concurrent builds of one kernel, cache layout."""
from __future__ import annotations

import ctypes
import hashlib
import multiprocessing as mp
import os

import casadi as ca
import pytest

from ocreach.native import compile as nc
from ocreach.native.codegen import generate_c


def _kernel_sources() -> dict[str, bytes]:
    x = ca.SX.sym("x", 3)
    f = ca.Function("ocr_race_test", [x], [ca.vertcat(ca.sin(x[0]) * x[1], x[2] ** 2, ca.exp(x[0]))])
    return {"gen.c": generate_c([f])}


def _build(cache: str, barrier, queue) -> None:
    os.environ["OCREACH_CACHE_DIR"] = cache
    try:
        sources = _kernel_sources()
        barrier.wait(timeout=60)  # everybody finds an empty cache and compiles at the same time
        lib = nc.compile_source("ocr_race_test", sources, "gen.c", ("-O2",))
        data = lib.read_bytes()
        dll = ctypes.CDLL(str(lib))
        queue.put((str(lib), hashlib.sha256(data).hexdigest(), bool(dll.ocr_race_test)))
    except BaseException as exc:  # reported to the parent, which fails the test
        queue.put(("error", repr(exc), False))


def test_concurrent_builds_into_an_empty_cache_agree(tmp_path):
    ctx = mp.get_context("spawn")
    n = 4
    barrier, queue = ctx.Barrier(n), ctx.Queue()
    procs = [ctx.Process(target=_build, args=(str(tmp_path), barrier, queue)) for _ in range(n)]
    for p in procs:
        p.start()
    out = [queue.get(timeout=240) for _ in range(n)]
    for p in procs:
        p.join(timeout=60)
    assert all(p.exitcode == 0 for p in procs)
    assert all(o[0] != "error" for o in out), out
    assert len({o[0] for o in out}) == 1 and len({o[1] for o in out}) == 1 and all(o[2] for o in out)
    jit = tmp_path / "jit"
    assert [f.name for f in jit.iterdir()] == [os.path.basename(out[0][0])]  # no temporaries left
    # a later build in this process finds the published library and does not rebuild it
    with pytest.MonkeyPatch.context() as mpatch:
        mpatch.setenv("OCREACH_CACHE_DIR", str(tmp_path))
        mpatch.setattr(nc.subprocess, "run", lambda *a, **k: pytest.fail("rebuilt a cached library"))
        assert str(nc.compile_source("ocr_race_test", _kernel_sources(), "gen.c", ("-O2",))) == out[0][0]


def test_one_cache_root_and_unique_temporary_names(tmp_path, monkeypatch):
    monkeypatch.setenv("OCREACH_CACHE_DIR", str(tmp_path))
    assert nc.cache_dir() == tmp_path / "jit"
    from ocreach import quadrature

    assert quadrature._disk_cache_path(5, 8, "cut").parent == tmp_path / "cut_rules"
    target = tmp_path / "x" / "data.bin"
    names = {nc._temp_name(target).name for _ in range(50)}
    assert len(names) == 50 and all(str(os.getpid()) in n for n in names)
    nc.write_atomic(target, b"abc")
    assert target.read_bytes() == b"abc" and os.listdir(target.parent) == ["data.bin"]


def test_compiler_failure_is_a_compile_error(tmp_path, monkeypatch):
    monkeypatch.setenv("OCREACH_CACHE_DIR", str(tmp_path))
    with pytest.raises(nc.COMPILE_ERRORS, match="failed"):
        nc.compile_source("ocr_broken", {"main.c": b"this is not C"}, "main.c", ("-O0",))
    assert not any((tmp_path / "jit").iterdir())
