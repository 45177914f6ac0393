"""Count targets read from a benchmark's own annotation file (issue 48): ``--counts histogram:PATH``.

A user asks for counts to match the benchmark they evaluate on; the benchmark's annotation file already
holds them, so ``histogram:`` takes, besides a text file of ``count weight`` lines
(:func:`mixcount.counts.targets.read_histogram`), a JSON file of one of these kinds, told apart by
their keys:

- a COCO instances file (``images`` + ``annotations``): one count per image, the annotations whose
  ``image_id`` names it, without crowd regions (``iscrowd: 1``: one region for many objects, no count) and
  without mixcount's distractors (``is_distractor: true``, so a mixcount dataset's own
  ``annotations/instances_<split>.json`` gives its counted objects); per image and ``category_id`` too,
  so a two-class benchmark's file also gives its class ratios, and per category the mean ``area`` of one
  object (``bbox`` w x h when an annotation has no area), so the scene's larger class takes the count of the
  image's larger objects (:func:`mixcount.counts.targets.split_total`);
- FSC-147's annotation JSON (``annotation_FSC147_384.json``: image name -> ``{"points": [[x, y], ...],
  ...}``): ``len(points)`` per image, one class.

Images with no counted object (nothing to aim at) are left out; a file left with none is a ConfigError of
one line that names the file and what it lacked, never its text. The file is read whole by ``json``
(an FSC-147 or COCO val file is tens of MB; a merged mixcount file of tens of thousands of scenes holds
gigabytes of masks: give such a split as a text histogram instead, docs/scene.md, "Count targets").
"""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path
from typing import Any, Mapping, NamedTuple

import mixcount.json_input as json_input
from mixcount.errors import ConfigError

# The most visible objects one image may be asked for (and the largest imbalance): FSC-147's fullest image
# holds 3,731 and the paper spawns at most 200, so a larger number is a typo, and ranges past it would
# hold billions of support points (``uniform:1-99999999999999999999`` was an OverflowError).
MAX_COUNT = 10_000


class FileImage(NamedTuple):
    """One usable image of an annotation file: per category its count (largest first) and the mean area
    in pixels of one of its objects (0.0: unknown, e.g. FSC-147's points)."""

    counts: tuple[int, ...]
    areas: tuple[float, ...]


def looks_like_json(path: Path) -> bool:
    """True when the file's first non-blank character opens a JSON object or array."""
    with path.open("rb") as fh:
        head = fh.read(4096).lstrip()
    return head[:1] in (b"{", b"[")


def _load(path: Path) -> Any:
    """The file's JSON (:mod:`mixcount.json_input`: too deep, too large or a number past the digit limit
    is one ConfigError line, like malformed JSON)."""
    try:
        return json_input.read(path, max_bytes=json_input.COUNT_FILE_BYTES, max_depth=None)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"count target histogram {path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    except json_input.JsonInputError as exc:
        raise ConfigError(f"count target histogram {path}: not usable JSON: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"count target histogram {path}: cannot read it ({type(exc).__name__})") from None


def _object_area(ann: Mapping[str, Any]) -> float:
    """An annotation's area in pixels: its ``area``, else its ``bbox`` w x h, else 0 (unknown)."""
    area = _finite(ann.get("area"))
    if area is not None and area > 0:
        return area
    box = ann.get("bbox")
    if isinstance(box, list) and len(box) == 4:
        w, h = _finite(box[2]), _finite(box[3])
        if w is not None and h is not None:
            return _finite(max(w, 0.0) * max(h, 0.0)) or 0.0
    return 0.0


def _finite(value: Any) -> float | None:
    """``value`` as a finite float, None when it is not a number (a bool, a string, a 400-digit int)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        out = float(value)
    except OverflowError:
        return None
    return out if math.isfinite(out) else None


def _coco_images(doc: Mapping[str, Any], path: Path) -> list[FileImage]:
    """Per image with a counted annotation: its per-category counts, largest first, with each category's
    mean object area (0.0 where any of its annotations has none)."""
    images, annotations = doc.get("images"), doc.get("annotations")
    if not isinstance(images, list) or not isinstance(annotations, list):
        raise ConfigError(f"count target histogram {path}: a COCO file needs 'images' and 'annotations' lists")
    ids = {_key(img.get("id")) for img in images if isinstance(img, dict)} - {None}
    per_image: dict[Any, dict[Any, list[float]]] = {}
    for ann in annotations:
        if not isinstance(ann, dict) or _key(ann.get("image_id")) not in ids:
            continue
        if ann.get("is_distractor") or ann.get("iscrowd"):
            continue
        cats = per_image.setdefault(ann["image_id"], {})
        cats.setdefault(_key(ann.get("category_id")), []).append(_object_area(ann))
    out = []
    for image_id, cats in per_image.items():
        rows = sorted(((len(a), _mean(a)) for a in cats.values()), key=lambda r: -r[0])
        _check_total(path, f"image {image_id!r}", sum(r[0] for r in rows))
        out.append(FileImage(tuple(r[0] for r in rows), tuple(r[1] for r in rows)))
    return out


def _key(value: Any) -> Any:
    """An id as a key: an int or a string, else None (a list or an object id matches nothing)."""
    return value if isinstance(value, (int, str)) and not isinstance(value, bool) else None


def _mean(areas: list[float]) -> float:
    """The mean object area, 0.0 when one is unknown (0) or the sum leaves the float range."""
    if min(areas) <= 0:
        return 0.0
    mean = math.fsum(areas) / len(areas)
    return mean if math.isfinite(mean) else 0.0


def _check_total(path: Path, image: str, total: int) -> None:
    if total > MAX_COUNT:
        raise ConfigError(f"count target histogram {path}: {image} holds {total:,} objects, more than the "
                          f"{MAX_COUNT:,} one image may be asked for")


def _fsc147_images(doc: Mapping[str, Any], path: Path) -> list[FileImage]:
    """Per image with points: ``(len(points),)`` (FSC-147 names one class per image; no areas)."""
    out = []
    for name, v in doc.items():
        if isinstance(v, dict) and isinstance(v.get("points"), list) and v["points"]:
            _check_total(path, f"image {name!r}", len(v["points"]))
            out.append(FileImage((len(v["points"]),), (0.0,)))
    return out


def read_annotation_file(path: Path) -> list[FileImage]:
    """A benchmark's annotation JSON -> per usable image its per-category counts (largest first, each >= 1)
    and mean object areas. ConfigError (one line) when the file is neither kind or has no usable image."""
    doc = _load(path)
    if isinstance(doc, dict) and ("images" in doc or "annotations" in doc):
        kind, images = "COCO", _coco_images(doc, path)
        lacks = "no image with a counted annotation (crowd regions and distractors are not counted)"
    elif isinstance(doc, dict) and any(isinstance(v, dict) and "points" in v for v in doc.values()):
        kind, images = "FSC-147", _fsc147_images(doc, path)
        lacks = "no image with 'points'"
    else:
        raise ConfigError(f"count target histogram {path}: JSON, but neither a COCO instances file ('images' and "
                          "'annotations') nor FSC-147 annotations (image name -> 'points')")
    if not images:
        raise ConfigError(f"count target histogram {path}: a {kind} file with {lacks}")
    return images


def histogram_of(images: list[FileImage]) -> tuple[tuple[int, ...], tuple[float, ...]]:
    """Per-image totals -> sorted counts and their image counts as weights."""
    table = Counter(sum(img.counts) for img in images)
    keys = tuple(sorted(table))
    return keys, tuple(float(table[k]) for k in keys)
