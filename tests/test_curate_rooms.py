"""curation/'s two sub-rooms (mixcount/curation/__init__.py): ``finding/`` (the automatic flags) and
``review/`` (a person's side) never import each other, lazy imports included; what both use lives in
``curation/`` itself (``renders.py``, ``flag_kinds.py``), which imports neither."""

from __future__ import annotations

import ast
from pathlib import Path

CURATION = Path(__file__).resolve().parent.parent / "mixcount" / "curation"
SIDES = ("mixcount.curation.finding", "mixcount.curation.review")


def _side(module: str) -> str | None:
    return next((s for s in SIDES if module == s or module.startswith(s + ".")), None)


def cross_imports() -> list[tuple[str, str]]:
    """(importer, imported) for every import from one side to the other, or from curation/'s shared
    modules into a side."""
    found = []
    for path in sorted(CURATION.rglob("*.py")):
        rel = path.relative_to(CURATION.parent.parent).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            for target in targets:
                there = _side(target)
                if there is not None and there != _side(name):
                    found.append((name, target))
    return sorted(set(found))


def test_finding_and_review_do_not_import_each_other():
    assert cross_imports() == []
