"""The import graph of mixcount (every ``import`` and ``from ... import`` between its modules, lazy and
TYPE_CHECKING imports included) and its circles, shared by tests/test_code_shape.py (no circle) and
bench/house.py (the house's figures)."""

from __future__ import annotations

import ast
import sys
from pathlib import Path


def module_name(path: Path, root: Path) -> str:
    """``mixcount.catalog.layouts`` for ``root/mixcount/catalog/layouts/__init__.py``."""
    rel = path.relative_to(root).with_suffix("")
    return ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)


def package_modules(package: Path) -> dict[str, tuple[Path, ast.Module]]:
    """Every module of ``package`` (a folder) by its dotted name, with its path and parsed source."""
    return {module_name(p, package.parent): (p, ast.parse(p.read_text(), filename=str(p)))
            for p in sorted(package.rglob("*.py"))}


def resolve_import(importer: str, node: ast.ImportFrom, is_pkg: bool) -> str:
    """The absolute module a ``from ... import`` in ``importer`` reads from (relative levels resolved)."""
    if node.level == 0:
        return node.module or ""
    base = importer.split(".") if is_pkg else importer.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def import_graph(mods: dict[str, tuple[Path, ast.Module]]) -> dict[str, set[str]]:
    """Module -> the modules of ``mods`` it imports (a name imported from a package counts as the
    submodule of that name where there is one, else the package)."""
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, (path, tree) in mods.items():
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.ImportFrom):
                target = resolve_import(name, node, path.name == "__init__.py")
                targets = [f"{target}.{a.name}" if f"{target}.{a.name}" in mods else target for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            for t in targets:
                while t and t not in mods:
                    t = t.rpartition(".")[0]
                if t and t != name and t.startswith("mixcount."):
                    graph[name].add(t)
    return graph


def import_circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan), lazy imports included."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in graph:
        if v not in index:
            visit(v)
    return out
