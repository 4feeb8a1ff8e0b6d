"""No import circles between the modules of ``core``.

Every import counts: at module level, inside functions and under ``TYPE_CHECKING`` (import-linter
counts them too). Circles untied so far: geometry/camera <-> mayacam, io/cine <-> sequences,
study/study <-> trial (and <-> repair).
"""

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[3] / "core"


def _graph(root: Path) -> dict[str, set[str]]:
    mods: dict[str, tuple[Path, bool]] = {}
    for f in root.rglob("*.py"):
        parts = list(f.relative_to(root.parent).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        mods[".".join(parts[:-1] if is_pkg else parts)] = (f, is_pkg)
    edges: dict[str, set[str]] = {m: set() for m in mods}
    for m, (f, is_pkg) in mods.items():
        base = m.split(".") if is_pkg else m.split(".")[:-1]
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                mod = ".".join([*base[:len(base) - node.level + 1], node.module or ""]).strip(".") \
                    if node.level else (node.module or "")
                targets = [mod, *(f"{mod}.{a.name}" for a in node.names)]
            else:
                continue
            for t in targets:
                while t and t not in mods:  # the module a name belongs to
                    t = t.rpartition(".")[0]
                if t and t != m and not m.startswith(t + "."):  # a package's own __init__ is no circle
                    edges[m].add(t)
    return edges


def _circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    for start in edges:
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


@pytest.fixture(scope="module")
def core_graph() -> dict[str, set[str]]:
    """The import graph of ``core``, parsed once for the tests of this module (they only read it)."""
    return _graph(CORE)


def test_the_checker_finds_a_circle(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .b import x\n")
    (pkg / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import y\n")
    (pkg / "c.py").write_text("def f():\n    from pkg import a\n")
    assert _circles(_graph(pkg)) == [["pkg.a", "pkg.b"]]


@pytest.mark.parametrize("pair", [("geometry.camera", "geometry.mayacam"), ("io.cine", "io.sequences"),
                                  ("study.study", "study.trial")])
def test_untied_circles(pair, core_graph):
    edges = core_graph
    a, b = (f"core.{p}" for p in pair)
    assert not (b in edges[a] and a in edges[b]), f"{a} and {b} import each other"


def test_no_import_circle_in_core(core_graph):
    circles = _circles(core_graph)
    assert circles == [], f"import circles: {circles}"
