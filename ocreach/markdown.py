"""Markdown report helpers shared by the benchmarks and the examples."""
from __future__ import annotations

from pathlib import Path

from ocreach.errors import ProblemError
from ocreach.fileio import atomic_write_text


def replace_markdown_section(path: str | Path, text: str) -> Path:
    """Replace the ``## Heading`` section of a markdown file by ``text`` (or append it).

    ``text`` starts with its ``## `` heading line; the old section runs to the next ``## ``
    heading.  The rest of the file is left alone and the file is written atomically, so several
    scripts can each keep their own section of ``docs/benchmarks.md`` or ``docs/validation.md``.
    """
    path = Path(path)
    heading = text.lstrip().splitlines()[0].strip() if text.strip() else ""
    if not heading.startswith("## "):
        raise ProblemError(f"text must start with a '## ' heading line; got {heading[:40]!r}")
    old = path.read_text() if path.exists() else ""
    lines = old.splitlines()
    start = next((i for i, ln in enumerate(lines) if ln.strip() == heading), None)
    body = text.strip().splitlines()
    if start is None:
        new = (old.rstrip() + "\n\n" if old.strip() else "") + "\n".join(body) + "\n"
    else:
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")),
                   len(lines))
        tail = [""] + lines[end:] if end < len(lines) else []
        new = "\n".join(lines[:start] + body + tail) + "\n"
    return atomic_write_text(path, new)
