"""External exemplars in the dataset: each category's canonical white-background render (``catalog
render``), copied once per catalog object to ``OUT/exemplars/external/obj_<object_id><suffix>``.

The scene's COCO categories reference the copy by ``external_exemplar``, a path relative to the dataset
root ``OUT`` like every image ``file_name``; size-qualified categories of the same object share its file.
Copies are atomic (temporary file + rename) and skipped when an identical file is already in place, so
parallel and resumed runs write each file once.
"""

from __future__ import annotations

import filecmp
import os
import shutil
from pathlib import Path
from typing import Iterable, Mapping, Optional

EXTERNAL_DIR = Path("exemplars") / "external"


def external_exemplar_name(object_id: int, source: str | Path) -> str:
    """The copy's path relative to OUT (posix separators)."""
    return (EXTERNAL_DIR / f"obj_{int(object_id)}{Path(source).suffix.lower() or '.png'}").as_posix()


def copy_external_exemplar(out_dir: Path, object_id: int, source: str | Path) -> Optional[str]:
    """Copy ``source`` into OUT; returns its relative path, or None when the source file is missing."""
    src = Path(source)
    if not src.is_file():
        return None
    rel = external_exemplar_name(object_id, src)
    dest = Path(out_dir) / rel
    if dest.is_file() and filecmp.cmp(src, dest, shallow=False):
        return rel
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.tmp")
    shutil.copyfile(src, tmp)
    os.replace(tmp, dest)
    return rel


def copy_external_exemplars(out_dir: Path, renders: Mapping[int, Optional[str]],
                            object_ids: Iterable[int]) -> dict[int, str]:
    """Copy the renders of ``object_ids`` that have one; object id -> path relative to OUT."""
    out: dict[int, str] = {}
    for oid in sorted(set(int(o) for o in object_ids)):
        src = renders.get(oid)
        if src:
            rel = copy_external_exemplar(out_dir, oid, src)
            if rel is not None:
                out[oid] = rel
    return out
