"""The layers of ``somtorch/`` point one way (STYLE.md, "Layout" and "Config at the bottom").

The import graph is read from the source (every ``import`` statement, at module level and inside
functions), not from a running interpreter, so a lazy import inside a function counts as much as
one at the top of a file; only ``if TYPE_CHECKING:`` blocks, which never run, are left out. Nodes
are modules; ``from pkg import name`` points at ``pkg.name`` when that is a module, else at ``pkg``.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "somtorch"


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _runtime_nodes(tree: ast.AST):
    """Every node of ``tree`` except those under ``if TYPE_CHECKING:``."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        if isinstance(node, ast.If) and getattr(node.test, "id", getattr(node.test, "attr", "")) == "TYPE_CHECKING":
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """``{module: {imported somtorch modules}}`` for every ``.py`` file under ``root``."""
    files = {_module_name(p, root): p for p in sorted(root.rglob("*.py"))}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets: set[str] = set()
        for node in _runtime_nodes(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                targets.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                for alias in node.names:
                    sub = f"{mod}.{alias.name}"
                    targets.add(sub if sub in files else mod)
        graph[name] = {t for t in targets if t in files and t != name}
    return graph


def tangles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan): each is a set of
    modules that all reach each other, i.e. one or more import cycles."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(u: str) -> None:
        index[u] = low[u] = len(index)
        stack.append(u)
        on.add(u)
        for v in sorted(graph[u]):
            if v not in index:
                visit(v)
                low[u] = min(low[u], low[v])
            elif v in on:
                low[u] = min(low[u], index[v])
        if low[u] == index[u]:
            comp = []
            while True:
                v = stack.pop()
                on.discard(v)
                comp.append(v)
                if v == u:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for u in sorted(graph):
        if u not in index:
            visit(u)
    return out


def _outside(graph: dict[str, set[str]], package: str, allowed: tuple[str, ...]) -> dict[str, set[str]]:
    def inside(m: str, p: str) -> bool:
        return m == p or m.startswith(p + ".")

    return {m: bad for m, deps in graph.items() if inside(m, package)
            if (bad := {d for d in deps if not any(inside(d, a) for a in allowed)})}


def test_graph_reader_sees_function_level_and_relative_imports(tmp_path):
    pkg = tmp_path / "somtorch"
    (pkg / "a").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a" / "__init__.py").write_text("from . import b\n")
    (pkg / "a" / "b.py").write_text("def f():\n    from ..c import g\n")
    (pkg / "c.py").write_text("import somtorch.a.b\ng = 1\n")
    (pkg / "d.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .c import g\n")
    graph = import_graph(pkg)
    assert graph["somtorch.a"] == {"somtorch.a.b"}
    assert graph["somtorch.a.b"] == {"somtorch.c"}
    assert graph["somtorch.c"] == {"somtorch.a.b"}
    assert graph["somtorch.d"] == set()
    assert tangles(graph) == [["somtorch.a.b", "somtorch.c"]]


def test_no_import_cycle():
    found = tangles(import_graph())
    assert not found, "modules in import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_config_is_the_bottom_layer():
    """``somtorch.config`` imports nothing of somtorch outside itself: option names live in it."""
    bad = _outside(import_graph(), "somtorch.config", ("somtorch.config",))
    assert not bad, f"somtorch.config reaches up: {bad}"


@pytest.mark.parametrize("above", ["somtorch.disparity", "somtorch.tasks", "somtorch.segmenters",
                                   "somtorch.pipeline", "somtorch.geometry"])
def test_core_does_not_import_layers_above(above):
    graph = import_graph()
    bad = {m: {d for d in deps if d == above or d.startswith(above + ".")}
           for m, deps in graph.items() if m.startswith("somtorch.core")}
    assert not any(bad.values()), f"somtorch.core imports {above}: {bad}"


def test_config_names_no_module_by_string():
    """Option names are not looked up through ``"somtorch.module:NAME"`` strings (a dependency
    the import graph cannot see)."""
    for path in (ROOT / "config").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                assert not re.fullmatch(r"somtorch(\.\w+)*:\w+", node.value), (path, node.value)
            if isinstance(node, ast.Name):
                assert node.id not in ("importlib", "__import__"), path


def test_library_never_imports_experiments():
    for path in ROOT.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            assert not any(n == "experiments" or n.startswith("experiments.") for n in names), path
