"""Links in the docs resolve: every relative Markdown link in README.md and docs/ names a file or
folder of the repository, and so does every repository path the docs quote as text."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
#: ``[text](target)`` and ``![alt](target "title")``; the target ends at a space or ``)``
INLINE = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
#: reference definitions ``[label]: target``
REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$", re.M)
#: repository paths quoted as text, e.g. ``docs/validation/stt.md`` or ``examples/cw_chaser.py``
QUOTED = re.compile(r"(?<![\w./-])((?:docs|examples|benchmarks|tests|problems)/"
                    r"[\w./-]*\w\.(?:md|py|json|csv))\b")


def _code_free(text: str) -> str:
    """``text`` without fenced code blocks (their brackets are code, not links)."""
    return re.sub(r"^(`{3,}|~{3,}).*?^\1", "", text, flags=re.M | re.S)


def targets(text: str) -> list[tuple[str, str]]:
    """``(path, anchor)`` of every relative link of a Markdown text (no URLs; ``path`` is empty
    for an anchor in the same page, ``anchor`` empty when there is none)."""
    text = _code_free(text)
    out = []
    for target in INLINE.findall(text) + REFERENCE.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):
            continue  # http:, https:, mailto:, ...
        path, _, anchor = target.partition("#")
        out.append((path, anchor))
    return out


def links(text: str) -> list[str]:
    """The relative link targets of a Markdown text that name a file (no URLs, no anchors)."""
    return [path for path, _ in targets(text) if path]


def anchors(text: str) -> set[str]:
    """The heading anchors of a Markdown page as GitHub makes them (lower case, punctuation
    dropped, spaces to hyphens, ``-1``, ``-2`` for repeats)."""
    out: set[str] = set()
    count: dict[str, int] = {}
    for heading in re.findall(r"^#{1,6}\s+(.+?)\s*#*\s*$", _code_free(text), flags=re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-")
        n = count.get(slug, 0)
        count[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def test_link_parser_on_a_sample():
    text = ("see [a](b.md), ![fig](figures/x.png \"title\"), [web](https://x.org/y), [top](#t),\n"
            "[sec](other.md#part) and <b>[c](<angle.md>)</b>\n"
            "```python\nx = d[0](1)\n```\n[ref]: ../up.md\n")
    assert links(text) == ["b.md", "figures/x.png", "other.md", "angle.md", "../up.md"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_to_files(page):
    missing = [t for t in links(page.read_text()) if not (page.parent / t).exists()]
    assert not missing, f"{page.relative_to(ROOT)}: links to missing files {missing}"


def test_anchor_slugs_on_a_sample():
    text = ("# Guide\n## 2. Run a bundled problem\n## Interval evaluator (`ocreach.intervals`)\n"
            "## Guide\n")
    assert anchors(text) == {"guide", "2-run-a-bundled-problem",
                             "interval-evaluator-ocreachintervals", "guide-1"}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_anchors_of_links_exist(page):
    """A link ``page.md#section`` names a heading of that page."""
    bad = []
    for path, anchor in targets(page.read_text()):
        dest = page if not path else page.parent / path
        if (anchor and dest.suffix == ".md" and dest.is_file()
                and anchor not in anchors(dest.read_text())):
            bad.append(f"{path}#{anchor}")
    assert not bad, f"{page.relative_to(ROOT)}: links to missing headings {bad}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_quoted_repository_paths_exist(page):
    """A path such as ``docs/validation/stt.md`` quoted in the text is a file of the repository
    (output files under ``out/`` and patterns with ``<...>`` or ``{...}`` are not matched)."""
    missing = sorted({p for p in QUOTED.findall(page.read_text()) if not (ROOT / p).exists()})
    assert not missing, f"{page.relative_to(ROOT)}: names missing files {missing}"


SOURCES = sorted(p for d in ("ocreach", "problems", "examples", "benchmarks", "tests")
                 for p in (ROOT / d).rglob("*.py"))


def test_docs_named_in_the_code_exist():
    """Docstrings, comments and generated texts that name a file under docs/ name one that exists
    (``docs/validation/stt.md``; not patterns such as ``docs/figures/*.json``)."""
    missing = {}
    for src in SOURCES:
        names = {p for p in QUOTED.findall(src.read_text()) if p.startswith("docs/")}
        bad = sorted(p for p in names if not (ROOT / p).exists())
        if bad:
            missing[str(src.relative_to(ROOT))] = bad
    assert not missing, f"files under docs/ named in the code but missing: {missing}"


#: ``ocreach/...`` paths the docs quote, e.g. ``ocreach/sets/zonotope.py`` or ``ocreach/custody/``
MODULE_PATH = re.compile(r"(?<![\w./-])(ocreach/[\w./-]*\w)")
#: dotted names in backticks, e.g. ```ocreach.sets.pz_exact.support_bounds```
DOTTED = re.compile(r"`(ocreach(?:\.\w+)+)")


def _repo_path(path: str) -> Path:
    """The file behind a package path (``ocreach/problems`` is the folder ``problems/``)."""
    rel = path.replace("ocreach/problems", "problems", 1) if path.startswith("ocreach/problems") \
        else path
    return ROOT / rel


def _resolves(name: str) -> bool:
    """Whether ``ocreach.a.b.c`` names a module, or an attribute of one, that exists."""
    import importlib

    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_modules_named_in_the_docs_exist(page):
    """The module map moves; the docs follow it: every ``ocreach/...`` path and every dotted
    ``ocreach.x.y`` name in backticks names a file, module or attribute that exists."""
    text = page.read_text()
    paths = {p for p in MODULE_PATH.findall(text)
             if not _repo_path(p).exists() and not _repo_path(p + ".py").exists()}
    names = {n for n in DOTTED.findall(text) if not _resolves(n)}
    missing = sorted(paths | names)
    assert not missing, f"{page.relative_to(ROOT)}: names missing modules {missing}"
