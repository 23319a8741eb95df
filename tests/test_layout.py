"""The module house: no import circles, no arrow from a low layer up to a high one, and
docs/layout.md (the module map and its layers) naming exactly the packages and modules that exist.

The import graph is read from the source with ``ast``: every ``import`` / ``from ... import``
counts, at module level, inside functions and under ``if TYPE_CHECKING:`` alike.  Names loaded
by string (the method registry's ``"module:Class"``, ``importlib.import_module``) are plug-ins,
not arrows.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "docs" / "layout.md"


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for ocreach/ and the bundled problems (ocreach.problems)."""
    mods = {}
    for p in sorted((ROOT / "ocreach").rglob("*.py")):
        parts = p.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = p
    for p in sorted((ROOT / "problems").glob("*.py")):
        mods["ocreach.problems" + ("" if p.stem == "__init__" else "." + p.stem)] = p
    return mods


def _target(name: str, mods: dict[str, Path]) -> str | None:
    while name not in mods and "." in name:
        name = name.rsplit(".", 1)[0]
    return name if name in mods else None


def import_graph() -> dict[str, set[str]]:
    """``{module: modules it imports}`` (ocreach modules only)."""
    mods = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                deps |= {_target(a.name, mods) for a in node.names if a.name.startswith("ocreach")}
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    pkg = name.split(".") if is_pkg else name.split(".")[:-1]
                    pkg = pkg[:len(pkg) - (node.level - 1)]
                    base = ".".join(pkg + ([node.module] if node.module else []))
                else:
                    base = node.module or ""
                if not base.startswith("ocreach"):
                    continue
                for a in node.names:
                    full = f"{base}.{a.name}"
                    deps.add(full if full in mods else _target(base, mods))
        graph[name] = {d for d in deps if d is not None and d != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def layers() -> dict[str, int]:
    """``{path prefix: layer}`` from the table under '## Layers' in docs/layout.md."""
    text = LAYOUT.read_text()
    section = text.split("## Layers", 1)[1].split("\n## ", 1)[0]
    out = {}
    for line in section.splitlines():
        m = re.match(r"\|\s*(\d+)\s*\|[^|]*\|(.*)\|\s*$", line)
        if m:
            for path in re.findall(r"`(ocreach/[^`]*)`", m.group(2)):
                out[path] = int(m.group(1))
    return out


def _path_of(module: str, mods: dict[str, Path]) -> str:
    p = mods[module].relative_to(ROOT).as_posix()
    return p.replace("problems/", "ocreach/problems/", 1) if p.startswith("problems/") else p


def layer_of(module: str, mods: dict[str, Path], table: dict[str, int]) -> int | None:
    path = _path_of(module, mods)
    best = None
    for prefix, layer in table.items():
        if path == prefix or (prefix.endswith("/") and path.startswith(prefix)):
            if best is None or len(prefix) > len(best[0]):
                best = (prefix, layer)
    return None if best is None else best[1]


def test_no_import_circles():
    found = cycles(import_graph())
    assert found == [], "import circles (each line: files that import each other):\n" + "\n".join(
        " <-> ".join(c) for c in found)


def test_no_arrow_runs_up_a_layer():
    mods, table, graph = _modules(), layers(), import_graph()
    unplaced = sorted(m for m in mods if layer_of(m, mods, table) is None)
    assert unplaced == [], f"modules in no layer of docs/layout.md: {unplaced}"
    upward = sorted(f"{a} (layer {layer_of(a, mods, table)}) -> {b} (layer {layer_of(b, mods, table)})"
                    for a, deps in graph.items() for b in deps
                    if layer_of(b, mods, table) > layer_of(a, mods, table))
    assert upward == [], "imports from a low layer up to a high one:\n" + "\n".join(upward)


def test_the_module_map_matches_the_code():
    """Every package and module of ocreach/ is in docs/layout.md, and every path it names exists."""
    text = LAYOUT.read_text()
    named = set(re.findall(r"`(ocreach/[^`\s]*)`", text))
    exists = {p if not p.startswith("ocreach/problems") else p for p in named}
    missing_on_disk = sorted(
        p for p in exists
        if not (ROOT / p.replace("ocreach/problems", "problems", 1)).exists())
    assert missing_on_disk == [], f"docs/layout.md names paths that do not exist: {missing_on_disk}"
    mods = _modules()
    packages = sorted({_path_of(m, mods).rsplit("/", 1)[0] + "/" for m in mods
                       if mods[m].name == "__init__.py" and m != "ocreach"})
    assert [p for p in packages if p not in named] == [], "packages missing from docs/layout.md"
    # each module: its full path, or its file name in the paragraph / row of its package
    blocks = re.split(r"\n\s*\n|\n(?=\|)", text)
    unnamed = []
    for m, p in mods.items():
        path = _path_of(m, mods)
        if p.name == "__init__.py" or f"`{path}`" in text:
            continue
        pkg, fname = path.rsplit("/", 1)
        if not any(f"`{pkg}/`" in b and f"`{fname}`" in b for b in blocks):
            unnamed.append(path)
    assert unnamed == [], f"modules docs/layout.md does not name: {sorted(unnamed)}"


def test_pyproject_lists_every_package():
    """An editable install finds unlisted subpackages, a wheel does not: keep the list whole."""
    text = (ROOT / "pyproject.toml").read_text()
    listed = set(re.findall(r'"(ocreach(?:\.\w+)*)"', text.split("packages = [", 1)[1].split("]", 1)[0]))
    mods = _modules()
    packages = {m for m, p in mods.items() if p.name == "__init__.py"}
    assert packages - listed == set(), f"packages missing from pyproject.toml: {sorted(packages - listed)}"
    assert listed - packages == set(), f"pyproject.toml lists packages that do not exist: {sorted(listed - packages)}"
