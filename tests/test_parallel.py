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
