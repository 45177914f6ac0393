"""Count targets read from a benchmark's own annotation file (issue 48): ``--counts histogram:PATH``.

A user asks for counts to match the benchmark they evaluate on; the benchmark's annotation file already
holds them, so ``histogram:`` takes, besides a text file of ``count weight`` lines
(:func:`mixcount.scene.count_targets.read_histogram`), a JSON file of one of these kinds, told apart by
their keys:

- a COCO instances file (``images`` + ``annotations``): one count per image, the annotations whose
  ``image_id`` names it, without crowd regions (``iscrowd: 1``: one region for many objects, no count) and
  without mixcount's distractors (``is_distractor: true``, so a mixcount dataset's own
  ``annotations/instances_<split>.json`` gives its counted objects); per image and ``category_id`` too,
  so a two-class benchmark's file also gives its class ratios, and per category the mean ``area`` of one
  object (``bbox`` w x h when an annotation has no area), so the scene's larger class takes the count of the
  image's larger objects (:func:`mixcount.scene.count_targets.split_total`);
- FSC-147's annotation JSON (``annotation_FSC147_384.json``: image name -> ``{"points": [[x, y], ...],
  ...}``): ``len(points)`` per image, one class.

Images with no counted object (nothing to aim at) are left out; a file left with none is a ConfigError of
one line that names the file and what it lacked, never its text. The file is read whole by ``json``
(an FSC-147 or COCO val file is tens of MB; a merged mixcount file of tens of thousands of scenes holds
gigabytes of masks: give such a split as a text histogram instead, docs/scene.md, "Count targets").
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any, Mapping, NamedTuple

import numpy as np

from mixcount.errors import ConfigError


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
    try:
        with path.open(encoding="utf-8") as fh:
            return json.load(fh)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"count target histogram {path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"count target histogram {path}: cannot read it ({type(exc).__name__})") from None
    except ValueError:  # e.g. a number past int's digit limit: the decoder's message quotes no text
        raise ConfigError(f"count target histogram {path}: not valid JSON (a value it cannot decode)") from None


def _object_area(ann: Mapping[str, Any]) -> float:
    """An annotation's area in pixels: its ``area``, else its ``bbox`` w x h, else 0 (unknown)."""
    area = ann.get("area")
    if isinstance(area, (int, float)) and area > 0:
        return float(area)
    box = ann.get("bbox")
    if isinstance(box, list) and len(box) == 4 and all(isinstance(v, (int, float)) for v in box):
        return max(float(box[2]), 0.0) * max(float(box[3]), 0.0)
    return 0.0


def _coco_images(doc: Mapping[str, Any], path: Path) -> list[FileImage]:
    """Per image with a counted annotation: its per-category counts, largest first, with each category's
    mean object area (0.0 where any of its annotations has none)."""
    images, annotations = doc.get("images"), doc.get("annotations")
    if not isinstance(images, list) or not isinstance(annotations, list):
        raise ConfigError(f"count target histogram {path}: a COCO file needs 'images' and 'annotations' lists")
    ids = {img.get("id") for img in images if isinstance(img, dict)}
    per_image: dict[Any, dict[Any, list[float]]] = {}
    for ann in annotations:
        if not isinstance(ann, dict) or ann.get("image_id") not in ids:
            continue
        if ann.get("is_distractor") or ann.get("iscrowd"):
            continue
        per_image.setdefault(ann["image_id"], {}).setdefault(ann.get("category_id"), []).append(_object_area(ann))
    out = []
    for cats in per_image.values():
        rows = sorted(((len(a), float(np.mean(a)) if min(a) > 0 else 0.0) for a in cats.values()),
                      key=lambda r: -r[0])
        out.append(FileImage(tuple(r[0] for r in rows), tuple(r[1] for r in rows)))
    return out


def _fsc147_images(doc: Mapping[str, Any]) -> list[FileImage]:
    """Per image with points: ``(len(points),)`` (FSC-147 names one class per image; no areas)."""
    return [FileImage((len(v["points"]),), (0.0,)) for v in doc.values()
            if isinstance(v, dict) and isinstance(v.get("points"), list) and v["points"]]


def read_annotation_file(path: Path) -> list[FileImage]:
    """A benchmark's annotation JSON -> per usable image its per-category counts (largest first, each >= 1)
    and mean object areas. ConfigError (one line) when the file is neither kind or has no usable image."""
    doc = _load(path)
    if isinstance(doc, dict) and ("images" in doc or "annotations" in doc):
        kind, images = "COCO", _coco_images(doc, path)
        lacks = "no image with a counted annotation (crowd regions and distractors are not counted)"
    elif isinstance(doc, dict) and any(isinstance(v, dict) and "points" in v for v in doc.values()):
        kind, images = "FSC-147", _fsc147_images(doc)
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
