"""The user's guide runs: every fenced ``python`` and ``bash`` block of docs/guide.md, in order.

The blocks run in one scratch folder that has the repository's ``examples/`` in it (a symlink), so
the guide's relative paths (``examples/cw_chaser.py``, ``out/...``) work as they do from a clone.
Python blocks share one namespace, as at the prompt; bash blocks run with ``bash -e -o pipefail``
and find ``ocreach`` and ``python`` of the running interpreter first on ``PATH``.  ``console``
and ``sh`` blocks count as bash (a ``console`` block runs its ``$ `` lines only).

Markers, an HTML comment on the line just before a fence (invisible in the rendered guide):

* ``<!-- guide: skip -->``: the block is not run (installing packages; there should be almost
  no such block);
* ``<!-- guide: file PATH -->``: the block is the content of the repository file PATH, and the
  test checks that they are equal instead of running it.

Blocks of other languages (``text``, ``json``, ...) are output or formats and are not run.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import matplotlib.pyplot as plt
import pytest

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guide.md"
RUN = {"python": "python", "py": "python", "bash": "bash", "sh": "bash", "shell": "bash",
       "console": "console"}
MARKER = re.compile(r"<!--\s*guide:\s*(skip|file\s+(\S+))\s*-->")
#: most blocks that may carry ``guide: skip`` (the install block)
MAX_SKIPPED = 2


@dataclass
class Block:
    line: int           # 1-based line of the opening fence
    lang: str
    code: str
    marker: str | None  # "skip", "file" or None
    path: str | None    # the file of a "file" marker


def guide_blocks(text: str) -> list[Block]:
    """The fenced code blocks of ``text`` with their language and marker."""
    lines = text.splitlines()
    blocks, i = [], 0
    while i < len(lines):
        m = re.match(r"^(`{3,}|~{3,})\s*([\w+-]*)", lines[i])
        if not m:
            i += 1
            continue
        fence, lang, start = m.group(1), m.group(2).lower(), i
        j = i + 1
        while j < len(lines) and not lines[j].startswith(fence):
            j += 1
        if j == len(lines):
            raise AssertionError(f"line {start + 1}: code block never closed")
        prev = next((lines[k] for k in range(start - 1, -1, -1) if lines[k].strip()), "")
        mk = MARKER.search(prev)
        marker = None if mk is None else mk.group(1).split()[0]
        blocks.append(Block(start + 1, lang, "\n".join(lines[start + 1:j]) + "\n", marker,
                            mk.group(2) if mk is not None else None))
        i = j + 1
    return blocks


def console_commands(code: str) -> str:
    """The ``$ `` lines of a console block (continuation lines ending in ``\\`` kept)."""
    out, cont = [], False
    for ln in code.splitlines():
        if ln.startswith("$ ") or cont:
            out.append(ln[2:] if ln.startswith("$ ") else ln)
            cont = ln.rstrip().endswith("\\")
    return "\n".join(out) + "\n"


def test_guide_blocks_are_parsed_and_marked_sparingly():
    """The parser sees the guide's blocks, every marker names a known action, and (almost) every
    runnable block runs."""
    blocks = guide_blocks(GUIDE.read_text())
    runnable = [b for b in blocks if b.lang in RUN]
    assert len(runnable) >= 15
    assert sum(b.marker == "skip" for b in runnable) <= MAX_SKIPPED
    for b in blocks:
        assert b.lang, f"docs/guide.md:{b.line}: a code block needs a language"
        if b.marker == "file":
            assert (ROOT / b.path).is_file(), f"docs/guide.md:{b.line}: no file {b.path}"


def test_guide_parser_on_a_sample():
    text = ("intro\n<!-- guide: skip -->\n```bash\npip install x\n```\n\n```python\nx = 1\n```\n"
            "<!-- guide: file examples/a.py -->\n\n```python\ny = 2\n```\n"
            "```console\n$ ocreach list \\\n  --why\nout\n```\n```text\n1\n```\n")
    b = guide_blocks(text)
    assert [(x.lang, x.marker, x.path) for x in b] == [
        ("bash", "skip", None), ("python", None, None), ("python", "file", "examples/a.py"),
        ("console", None, None), ("text", None, None)]
    assert b[1].code == "x = 1\n" and b[0].line == 3
    assert console_commands(b[3].code) == "ocreach list \\\n  --why\n"


def test_every_guide_block_runs(tmp_path, monkeypatch):
    """Runs the guide top to bottom with its own (small) settings."""
    (tmp_path / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    namespace: dict = {"__name__": "__guide__"}
    try:
        for b in guide_blocks(GUIDE.read_text()):
            where = f"docs/guide.md:{b.line}"
            if b.lang not in RUN or b.marker == "skip":
                continue
            if b.marker == "file":
                assert b.code == (ROOT / b.path).read_text(), \
                    f"{where}: the block differs from {b.path}; copy the file into the guide"
                continue
            if RUN[b.lang] == "python":
                try:
                    exec(compile(b.code, where, "exec"), namespace)
                except Exception as exc:  # name the block in the failure
                    pytest.fail(f"{where}: {type(exc).__name__}: {exc}")
                continue
            code = console_commands(b.code) if RUN[b.lang] == "console" else b.code
            proc = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", code], cwd=tmp_path,
                                  env=env, capture_output=True, text=True, timeout=600)
            assert proc.returncode == 0, (f"{where}: exit {proc.returncode}\n"
                                          f"stdout:\n{proc.stdout[-3000:]}\n"
                                          f"stderr:\n{proc.stderr[-3000:]}")
    finally:
        plt.close("all")


def test_guide_problem_table_lists_every_bundled_problem():
    """The guide's table of bundled problems names each id of ``ocreach.list_problems()`` once
    (``custody-l1`` ... ``custody-l5`` stands for the five)."""
    import ocreach

    text = GUIDE.read_text()
    table = text[text.index("| id | scenario | source |"):]
    table = table[:table.index("\n\n")]
    ids = re.findall(r"`([a-z0-9-]+)`", table)
    if "custody-l1" in ids and "custody-l5" in ids:
        ids += [f"custody-l{i}" for i in range(2, 5)]
    assert sorted(ids) == sorted(ocreach.list_problems())


def test_readme_python_blocks_run(tmp_path, monkeypatch):
    """The README's Python example runs too (its two commands are the CI's own job)."""
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__readme__"}
    for b in guide_blocks((ROOT / "README.md").read_text()):
        if b.lang == "python":
            exec(compile(b.code, f"README.md:{b.line}", "exec"), namespace)
