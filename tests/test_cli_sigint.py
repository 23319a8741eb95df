"""Ctrl-C at named stages of `ocreach run` / `ocreach compare`.

Each case runs the CLI in a subprocess that waits at a stage (``OCREACH_PAUSE_AT``), sends SIGINT
there, and checks: exit code 130, the output folder is exactly the old complete one (or, after the
commit, the new complete one), and the partial results the message promises exist.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ocreach.cli import main

RUN = ["run", "vdp", "-m", "mc", "--set", "samples=30"]
COMPARE = ["compare", "vdp", "--methods", "mc,ode", "--truth-samples", "30",
           "--set", "mc.samples=30", "--set", "ode.samples=20"]


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _interrupt_at(args: list[str], stage: str, timeout: float = 120.0) -> tuple[int, str]:
    env = {**os.environ, "OCREACH_PAUSE_AT": stage, "OCREACH_STAGE_LOG": "1", "MPLBACKEND": "Agg"}
    proc = subprocess.Popen([sys.executable, "-m", "ocreach.cli", *args], stderr=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, text=True, env=env)
    lines, t0, sent = [], time.monotonic(), False
    assert proc.stderr is not None
    for line in proc.stderr:
        lines.append(line)
        if not sent and line.strip() == f"[ocreach-stage] {stage}":
            time.sleep(0.2)
            os.kill(proc.pid, signal.SIGINT)
            sent = True
        if time.monotonic() - t0 > timeout:
            proc.kill()
            break
    rc = proc.wait(timeout=timeout)
    assert sent, f"stage {stage!r} never reached:\n{''.join(lines)}"
    return rc, "".join(lines)


def _promised_partial(msg: str, target: Path) -> None:
    """The message names DIR.partial and its files, or says nothing was kept; check it is true."""
    partial = Path(str(target) + ".partial")
    if "nothing was finished" in msg:
        assert not partial.exists()
        return
    m = re.search(r"kept in (\S+) \(([^;]*);", msg)
    assert m, msg
    assert Path(m.group(1)) == partial and partial.is_dir()
    files = [f.strip() for f in m.group(2).split(",")]
    assert files and all((partial / f).is_file() for f in files), (files, list(partial.iterdir()))
    manifest = json.loads((partial / "MANIFEST.json").read_text())
    assert manifest["complete"] is False and set(files) <= set(manifest["files"])


@pytest.fixture(scope="module")
def old_run(tmp_path_factory):
    base = tmp_path_factory.mktemp("sigint")
    assert main([*RUN, "--out", str(base / "run")]) == 0
    assert main([*COMPARE, "--out", str(base / "cmp")]) == 0
    return base


@pytest.mark.parametrize("stage,expect", [
    ("solve", "old"), ("saved", "old"), ("figure:projection_0_1.png", "old"), ("commit", "old"),
    ("done", "new"),
])
def test_sigint_during_run_keeps_old_or_new_folder(old_run, tmp_path, stage, expect):
    import shutil

    target = tmp_path / "run"
    shutil.copytree(old_run / "run", target)
    before = _digest(target)
    rc, err = _interrupt_at([*RUN, "--set", "seed=7", "--out", str(target)], stage)
    assert rc == 130, err
    assert "interrupted" in err and "Traceback" not in err, err
    after = _digest(target)
    assert set(after) == set(before)  # always one complete folder: no mix of old and new files
    if expect == "old":
        assert after == before, err
        msg = err.strip().splitlines()[-1]
        assert "left unchanged" in msg, msg
        _promised_partial(msg, target)
    else:
        assert after["result.npz"] != before["result.npz"] and "holds the new results" in err
    assert not list(tmp_path.glob(".run.tmp-*"))  # no temporary folder left behind


@pytest.mark.parametrize("stage", ["method:mc", "method:ode", "written"])
def test_sigint_during_compare(old_run, tmp_path, stage):
    import shutil

    target = tmp_path / "cmp"
    shutil.copytree(old_run / "cmp", target)
    before = _digest(target)
    rc, err = _interrupt_at([*COMPARE, "--out", str(target)], stage)
    assert rc == 130, err
    assert "Traceback" not in err, err
    assert _digest(target) == before  # the old complete comparison stays as it was
    msg = [ln for ln in err.splitlines() if "interrupted" in ln][-1]
    _promised_partial(msg, target)
    if stage == "method:ode":  # mc finished: its result and the table of it are the partial output
        partial = Path(str(target) + ".partial")
        assert (partial / "vdp_mc.npz").is_file() and (partial / "comparison.md").is_file()
        assert not (partial / "vdp_ode.npz").exists()


def test_fresh_folder_interrupted_is_not_created(tmp_path):
    target = tmp_path / "new"
    rc, err = _interrupt_at([*RUN, "--out", str(target)], "solve")
    assert rc == 130 and "not created" in err and not target.exists()
