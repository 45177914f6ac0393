"""The engine's files form no import circle and import no private name from each other (issue 48): camera
records and poses live in ``engine/cameras.py``, the steps after the poses in ``engine/scene_steps.py``, so
``rerender_job`` and ``count_topup`` need nothing of ``scene_job``. Every import counts, lazy ones included
(read from the source with ``ast``, as tests/test_code_shape.py reads the rooms)."""

from __future__ import annotations

import ast
from pathlib import Path

import mixcount.engine

ENGINE = Path(mixcount.engine.__file__).parent


def _imports(path: Path) -> list[tuple[str, list[str]]]:
    """(engine module imported, names taken from it) for every import of ``path``, lazy ones included."""
    out: list[tuple[str, list[str]]] = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            if node.module == "mixcount.engine":  # from mixcount.engine import render_passes as P
                out += [(a.name, []) for a in node.names]
            elif node.module.startswith("mixcount.engine."):
                out.append((node.module.split(".")[2], [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            out += [(a.name.split(".")[2], []) for a in node.names if a.name.startswith("mixcount.engine.")]
    return out


def _graph() -> dict[str, set[str]]:
    return {p.stem: {m for m, _ in _imports(p) if m != p.stem} for p in ENGINE.glob("*.py") if p.stem != "__init__"}


def _cycle(graph: dict[str, set[str]]) -> list[str]:
    """One import circle as a path of module names ([] when none)."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str]:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == 1:
                return stack[stack.index(n):] + [n]
            if n not in state and (found := visit(n)):
                return found
        state[m] = 2
        stack.pop()
        return []

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return []


def test_the_check_finds_a_circle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) == []


def test_engine_files_form_no_import_circle() -> None:
    graph = _graph()
    assert {"cameras", "scene_steps", "scene_job", "rerender_job", "count_topup"} <= set(graph)
    assert _cycle(graph) == []
    assert "scene_job" not in graph["rerender_job"] | graph["count_topup"]


def test_no_private_name_crosses_engine_modules() -> None:
    private = [(p.name, m, n) for p in ENGINE.glob("*.py") for m, names in _imports(p) for n in names
               if n.startswith("_") and m != p.stem]
    assert private == []
