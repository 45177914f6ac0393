"""One folder, one object: are a folder's model files the parts of one object, or separate models?

A person's folder named after an object (``hammer/``: ``hammerhandle.stl``, ``hammerhead.stl``;
``basketball/``: ``basketballinner.stl``, ``basketballouter.stl``) holds the parts one exporter wrote
in one frame; a folder of a package's shapes (``bunny.stl``, ``torus.stl``, ``box.stl``) holds separate
models. The rule (recorded with the object as ``parts_rule``):

1. the user's word: ``parts`` in the folder's ``metadata.json`` or ``catalog ingest --parts``
   (``merge``: one object of all the files; ``separate``: one object per file; ``auto``: this rule);
2. a description beside them (MJCF) that places several visual meshes in one body: one object, each
   part where the description puts it;
3. otherwise the files are parts when both hold: their boxes, in the files' own common frame, touch or
   nest (one connected group, within 2 % of the group's size), and their names say so (at least two
   thirds of the file stems start with the folder's name or share a prefix of four or more letters).
   Boxes alone do not tell: separate models exported one by one all sit at the origin. Names alone do
   not either: ``chair_1.obj`` ... ``chair_9.obj`` may be nine chairs side by side.

The same stem in several formats (``nut.step`` + ``nut.stl``) is one model exported twice, never two
parts: the preferred format is kept (:data:`mixcount.catalog.layouts.candidates.MODEL_PREFERENCE`).
The folder given to ``catalog ingest`` itself is a folder of loose files: rule 3 does not apply there.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mixcount.errors import IngestError
from mixcount.frame import load_model, quiet_native_output

PARTS_CHOICES = ("auto", "merge", "separate")
MAX_PARTS = 64  # more model files than this in one folder: a library, not an object
TOUCH_TOLERANCE = 0.02
MIN_PREFIX = 4


def check_parts(value: str | None) -> str:
    """``--parts`` / a metadata ``parts`` entry checked: auto, merge or separate (IngestError otherwise)."""
    choice = (value or "auto").strip().lower()
    if choice not in PARTS_CHOICES:
        raise IngestError(f"unknown parts rule {value!r}: give merge, separate or auto")
    return choice


def _key(text: str) -> str:
    return re.sub(r"[^a-z0-9]", "", text.lower())


def names_say_parts(folder_name: str, stems: list[str]) -> bool:
    """At least two thirds of ``stems`` (two or more) start with the folder's name or share a prefix of
    :data:`MIN_PREFIX` or more letters."""
    keys = [_key(s) for s in stems]
    need = max(2, -(-2 * len(keys) // 3))
    folder = _key(folder_name)
    if len(folder) >= MIN_PREFIX and sum(k.startswith(folder) for k in keys) >= need:
        return True
    prefixes = {k[:n] for k in keys for n in range(MIN_PREFIX, len(k) + 1)}
    return any(sum(k.startswith(p) for k in keys) >= need for p in prefixes)


def _bounds(path: Path) -> np.ndarray | None:

    try:
        with quiet_native_output():  # a STEP part: OpenCASCADE prints its complaints past Python
            scene = load_model(path, force="scene")
        bounds = scene.bounds
    except Exception:  # a file that does not load is judged (and reported) by its own analysis
        return None
    return None if bounds is None else np.asarray(bounds, dtype=np.float64)


def boxes_connected(boxes: list[np.ndarray]) -> bool:
    """True when the boxes form one group in which each touches or overlaps another (within
    :data:`TOUCH_TOLERANCE` of the whole group's largest side)."""
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    tol = TOUCH_TOLERANCE * float(np.max(hi - lo))
    seen, todo = {0}, [0]
    while todo:
        i = todo.pop()
        for j in range(len(boxes)):
            if j not in seen and np.all(boxes[i][0] - tol <= boxes[j][1]) and np.all(boxes[j][0] - tol <= boxes[i][1]):
                seen.add(j)
                todo.append(j)
    return len(seen) == len(boxes)


def same_model_formats(models: list[Path], preference: tuple[str, ...]) -> tuple[list[Path], list[Path]]:
    """(one file per stem: the preferred format, the other formats' files) of a folder's model files."""
    keep: dict[str, Path] = {}
    for path in sorted(models, key=lambda p: (preference.index(p.suffix.lower()), p.name)):
        keep.setdefault(path.stem.lower(), path)
    kept = sorted(keep.values())
    return kept, sorted(p for p in models if p not in kept)


def auto_parts(folder: Path, models: list[Path]) -> tuple[bool, str]:
    """Rule 3: (parts of one object?, why) for two or more model files of one folder."""
    if len(models) > MAX_PARTS:
        return False, f"{len(models)} model files: a library folder, one object per file"
    if not names_say_parts(folder.name, [m.stem for m in models]):
        return False, "separate models: the file names share no stem with each other or the folder"
    boxes = [_bounds(m) for m in models]
    if any(b is None for b in boxes):
        return False, "separate models: a file did not load to measure"
    if not boxes_connected([b for b in boxes if b is not None]):
        return False, "separate models: the files' boxes lie apart"
    return True, (f"parts of one object: {len(models)} files named alike whose boxes touch or nest in one "
                  "frame (catalog ingest --parts separate, or \"parts\": \"separate\" in metadata.json, to split)")
