"""Thread settings of ocreach.parallel: kernel threads and the BLAS limit around reach()."""
from __future__ import annotations

import sys

import pytest
from threadpoolctl import threadpool_info

import ocreach
from ocreach import parallel
from ocreach.errors import ProblemError
from ocreach.reach.mc import MonteCarlo


def _blas_threads() -> set[int]:
    return {d["num_threads"] for d in threadpool_info() if d.get("user_api") == "blas"}


def test_reach_runs_under_the_blas_limit_and_thread_setting(monkeypatch):
    seen = {}
    original = MonteCarlo.solve

    def spy(self, problem):
        seen["threads"], seen["blas"] = parallel.threads(), _blas_threads()
        return original(self, problem)

    monkeypatch.setattr(MonteCarlo, "solve", spy)
    monkeypatch.delenv("OCREACH_BLAS_THREADS", raising=False)
    before = parallel.threads()
    ocreach.reach("vdp", "mc", samples=4, threads=3)
    assert seen["threads"] == 3 and seen["blas"] <= {1}
    assert parallel.threads() == before  # restored afterwards
    monkeypatch.setenv("OCREACH_BLAS_THREADS", "2")
    with parallel.settings():
        assert max(_blas_threads()) <= 2  # a limit: a library may run fewer
    with pytest.raises(ProblemError, match="threads must be an integer >= 1"):
        ocreach.reach("vdp", "mc", samples=4, threads=-1)


def test_default_threads_from_environment(monkeypatch):
    monkeypatch.setenv("OCREACH_THREADS", "5")
    assert parallel.default_threads() == 5
    monkeypatch.delenv("OCREACH_THREADS")
    assert parallel.default_threads() >= 1
    monkeypatch.setenv("OCREACH_BLAS_THREADS", "0")
    with pytest.raises(ProblemError, match="OCREACH_BLAS_THREADS must be an integer >= 1"):
        parallel.blas_default()


def test_blas_limit_keeps_its_controller_until_a_module_is_imported(monkeypatch):
    """The threadpoolctl controller (a scan of the loaded libraries, ~4 ms) is built once and
    again after an import, which may have loaded another BLAS; the limit holds either way."""
    import types

    with parallel.blas_limit(1):
        assert _blas_threads() <= {1}
    first = parallel._controller[1]
    with parallel.blas_limit(1):
        assert _blas_threads() <= {1}
    assert parallel._controller[1] is first
    monkeypatch.setitem(sys.modules, "ocreach_test_new_module", types.ModuleType("ocreach_test_new_module"))
    with parallel.blas_limit(1):
        assert _blas_threads() <= {1}
    assert parallel._controller[1] is not first


@pytest.mark.parametrize("env, first, expect", [
    ({}, "ocreach", "1"),                                  # ocreach first: OpenBLAS starts with 1
    ({"OCREACH_BLAS_THREADS": "2"}, "ocreach", "2"),       # the limit's own setting
    ({"OMP_NUM_THREADS": "2"}, "ocreach", None),           # the environment decides: untouched
    ({}, "numpy", None),                                   # numpy first: too late, untouched
])
def test_import_presets_openblas_threads_only_before_numpy(env, first, expect):
    """``import ocreach`` before numpy sets OPENBLAS_NUM_THREADS to the BLAS limit (OpenBLAS
    started with 2 threads costs CPU time even under the limit), and leaves it alone when the
    environment already sets a thread count or numpy is loaded; checked in a fresh process."""
    import json
    import os
    import subprocess

    drop = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS", "OCREACH_BLAS_THREADS")
    base = {k: v for k, v in os.environ.items() if k not in drop}
    other = "numpy" if first == "ocreach" else "ocreach"
    code = (f"import {first}, {other}, json, os; from threadpoolctl import threadpool_info; "
            "print(json.dumps([os.environ.get('OPENBLAS_NUM_THREADS'), "
            "[d['num_threads'] for d in threadpool_info() if d['internal_api'] == 'openblas']]))")
    out = subprocess.run([sys.executable, "-c", code], env={**base, **env}, capture_output=True, text=True,
                         check=True)
    var, threads = json.loads(out.stdout.strip().splitlines()[-1])
    assert var == expect
    if expect is not None:
        assert set(threads) == {int(expect)}
