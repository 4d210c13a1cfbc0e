"""No two modules of a3d (or of bench/) import each other, directly or round a longer loop.

A cycle makes import order matter (a half-initialised module hands out missing names) and ties
two modules that should stand apart: what both need belongs in a third. The graph is read from the
source (every import statement, also inside functions and ``TYPE_CHECKING``, and the literal names
given to ``importlib.import_module``), so a lazy import that closes a loop counts too.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"runtime": "a3d.runtime", "train": "a3d.train", "export": "a3d.export", "synth": "a3d.synth",
            "bench": "bench"}  # fmt: skip


def _modules() -> dict[str, Path]:
    found = {}
    for folder, package in PACKAGES.items():
        for path in (ROOT / folder).rglob("*.py"):
            parts = [p for p in path.relative_to(ROOT / folder).with_suffix("").parts if p != "__init__"]
            found[".".join([package, *parts])] = path
    return found


def _imported(node: ast.AST, modules: dict[str, Path]) -> list[str]:
    """The a3d modules one AST node imports (``from PKG import submodule`` names the submodule)."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom) and node.module:
        return [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules else node.module
                for a in node.names]  # fmt: skip
    name = getattr(node, "func", None)
    if isinstance(node, ast.Call) and getattr(name, "attr", getattr(name, "id", "")) == "import_module":
        first = node.args[0] if node.args else None
        if isinstance(first, ast.Constant) and isinstance(first.value, str):
            return [first.value]
    return []


def import_graph() -> dict[str, set[str]]:
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        targets = {t for node in ast.walk(ast.parse(path.read_text())) for t in _imported(node, modules)}
        graph[name] = {t for t in targets if t in modules and t != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = stack[stack.index(v) :]
            del stack[stack.index(v) :]
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_loop() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_module_imports_itself_round_a_loop() -> None:
    graph = import_graph()
    assert "a3d.runtime.viewer.view" in graph["a3d.runtime.viewer.options"]  # the lazy import is seen
    assert cycles(graph) == []
