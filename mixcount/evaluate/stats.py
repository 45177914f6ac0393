"""Dataset statistics of a mixcount dataset folder: the numbers behind the paper's histograms.

Reads every ``OUT/annotations/instances_<split>.json`` (COCO, see docs/contracts) and computes, per image
(one image per scene and camera; ``scenes`` counts distinct ``scene_id``):
  objects_per_scene      counted (non-distractor) annotations per image; the paper's range is 1-200
  distractors_per_scene  distractor annotations per image
  classes_per_scene      distinct counted categories per image
  class_imbalance        instances of the most common counted class / of the least common one, per image
                         (the paper's definition; 1.0 for a single-class image)
  visibility             visibility of every counted annotation (and of distractors, apart)
  splits                 images, scenes, objects, distractors and categories per split
  caption_length         words per caption tier (short / concise / detailed) over the distinct categories
  density                what each scene kept of what it spawned, read from ``OUT/scenes/<id>/metadata.json``
                         (None without scene folders, e.g. an export): per scene (``scenes``) spawned and kept
                         counted objects and distractors, drop reasons by role and the counted classes that
                         ended with no visible instance (with their objects' drop reasons); in ``summary``
                         the same pooled (retention overall and in container / no-container scenes, share
                         lost off the floor, ...; :func:`mixcount.evaluate.scene_density.summarise_density`);
                         ``kept_per_scene`` / ``spawned_per_scene`` / ``retention_per_scene`` summaries and
                         histograms (bins of 10 objects)
Engine-free; plotting lives in mixcount.evaluate.plots.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.errors import GroundTruthError
from mixcount.evaluate.count_stats import count_lines, dataset_count_stats
from mixcount.evaluate.metrics import read_coco
from mixcount.evaluate.scene_density import scene_density, summarise_density
from mixcount.scene.spec import TIERS

SPLIT_ORDER = ("train", "val", "test")
_INSTANCES = re.compile(r"^instances_(.+)\.json$")


def find_annotation_files(dataset: Path) -> dict[str, Path]:
    """``{split: path}`` of the COCO files under ``dataset/annotations`` (train, val, test first)."""
    ann_dir = Path(dataset) / "annotations"
    if not Path(dataset).is_dir():
        raise GroundTruthError(f"{dataset}: not a folder")
    found = {}
    for p in sorted(ann_dir.glob("instances_*.json")) if ann_dir.is_dir() else []:
        m = _INSTANCES.match(p.name)
        if m:
            found[m.group(1)] = p
    if not found:
        raise GroundTruthError(f"{dataset}: no annotations/instances_<split>.json (is this a mixcount dataset folder?)")
    order = {s: i for i, s in enumerate(SPLIT_ORDER)}
    return dict(sorted(found.items(), key=lambda kv: (order.get(kv[0], len(order)), kv[0])))


def summarise(values: Sequence[float] | NDArray[Any]) -> dict[str, float | int | None]:
    """count, min, max, mean, median, p5 and p95 of ``values`` (None when empty)."""
    a = np.asarray(values, dtype=np.float64)
    if a.size == 0:
        return {"count": 0, "min": None, "max": None, "mean": None, "median": None, "p5": None, "p95": None}
    return {
        "count": int(a.size), "min": float(a.min()), "max": float(a.max()), "mean": float(a.mean()),
        "median": float(np.median(a)), "p5": float(np.percentile(a, 5)), "p95": float(np.percentile(a, 95)),
    }


def int_histogram(values: Sequence[int]) -> dict[str, list[int]]:
    """Counts of each integer value from min to max: ``{"values": [...], "counts": [...]}``."""
    if len(values) == 0:
        return {"values": [], "counts": []}
    c = Counter(int(v) for v in values)
    xs = list(range(min(c), max(c) + 1))
    return {"values": xs, "counts": [c.get(x, 0) for x in xs]}


def bin_histogram(values: Sequence[float], edges: Sequence[float]) -> dict[str, list[float] | list[int]]:
    """Counts of ``values`` in the bins of ``edges`` (the last bin closed): ``{"edges", "counts"}``."""
    counts, _ = np.histogram(np.asarray(values, dtype=np.float64), bins=np.asarray(edges, dtype=np.float64))
    return {"edges": [float(e) for e in edges], "counts": [int(c) for c in counts]}


def _words(text: Any) -> int | None:
    return len(str(text).split()) if isinstance(text, str) and text.strip() else None


def _check_coco(doc: Any, path: Path) -> dict[str, list[dict[str, Any]]]:
    if not isinstance(doc, dict):
        raise GroundTruthError(f"{path}: a COCO file must hold a JSON object")
    for key in ("images", "annotations", "categories"):
        if not isinstance(doc.get(key), list) or not all(isinstance(x, dict) for x in doc[key]):
            raise GroundTruthError(f"{path}: COCO key {key!r} is missing or not a list of objects")
    for i, ann in enumerate(doc["annotations"]):
        if "image_id" not in ann or "category_id" not in ann:
            raise GroundTruthError(f"{path}: annotations[{i}] needs 'image_id' and 'category_id'")
    return doc


def compute_stats(dataset: str | Path) -> dict[str, Any]:
    """All statistics of a dataset folder as one JSON-ready dict (module doc lists the keys)."""
    dataset = Path(dataset)
    files = find_annotation_files(dataset)
    objects: list[int] = []
    distractors: list[int] = []
    classes: list[int] = []
    imbalance: list[float] = []
    vis_counted: list[float] = []
    vis_distractor: list[float] = []
    splits: dict[str, dict[str, int]] = {}
    captions: dict[tuple[Any, ...], dict[str, Any]] = {}
    scene_splits: dict[str, str] = {}
    for split, path in files.items():
        doc = _check_coco(read_coco(path, GroundTruthError,
                                    keep=("image_id", "category_id", "is_distractor", "visibility")), path)
        per_image: dict[Any, Counter[Any]] = {img.get("id"): Counter() for img in doc["images"]}
        n_dist: Counter[Any] = Counter()
        for ann in doc["annotations"]:
            if ann.get("is_distractor", False):
                n_dist[ann["image_id"]] += 1
                target = vis_distractor
            else:
                per_image.setdefault(ann["image_id"], Counter())[ann["category_id"]] += 1
                target = vis_counted
            if isinstance(ann.get("visibility"), (int, float)):
                target.append(float(ann["visibility"]))
        for img_id, per_class in per_image.items():
            objects.append(sum(per_class.values()))
            distractors.append(n_dist.get(img_id, 0))
            classes.append(len(per_class))
            if per_class:
                imbalance.append(max(per_class.values()) / min(per_class.values()))
        scene_ids = {img.get("scene_id", img.get("id")) for img in doc["images"]}
        scene_splits.update({str(sid): split for sid in scene_ids})
        counted_cats = {a["category_id"] for a in doc["annotations"] if not a.get("is_distractor", False)}
        splits[split] = {
            "images": len(doc["images"]), "scenes": len(scene_ids),
            "objects": sum(not a.get("is_distractor", False) for a in doc["annotations"]),
            "distractors": sum(bool(a.get("is_distractor", False)) for a in doc["annotations"]),
            "categories": len(counted_cats),
        }
        for cat in doc["categories"]:
            key = (cat.get("object_id", cat.get("name")), cat.get("size_qualifier"), *(cat.get(t) for t in TIERS))
            captions[key] = cat
    caption_words = {t: [w for c in captions.values() if (w := _words(c.get(t))) is not None] for t in TIERS}
    vis_edges = [round(0.05 * i, 2) for i in range(21)]
    totals = {k: sum(s[k] for s in splits.values()) for k in ("images", "scenes", "objects", "distractors")}
    return {
        "dataset": str(dataset),
        "files": {s: str(p) for s, p in files.items()},
        "splits": splits,
        "totals": totals,
        "objects_per_scene": {**summarise(objects), "histogram": int_histogram(objects)},
        "distractors_per_scene": {**summarise(distractors), "histogram": int_histogram(distractors)},
        "classes_per_scene": {**summarise(classes), "histogram": int_histogram(classes)},
        "class_imbalance": {**summarise(imbalance), "histogram": bin_histogram(imbalance, _ratio_edges(imbalance))},
        "visibility": {
            "counted": {**summarise(vis_counted), "histogram": bin_histogram(vis_counted, vis_edges)},
            "distractor": {**summarise(vis_distractor), "histogram": bin_histogram(vis_distractor, vis_edges)},
        },
        "caption_length": {
            t: {**summarise(caption_words[t]), "histogram": int_histogram(caption_words[t])} for t in TIERS
        },
        "distinct_categories": len(captions),
        "density": density_stats(dataset, scene_splits),
        "count_target": dataset_count_stats(Path(dataset)),  # issue 37: None without count targets
    }


def density_stats(dataset: Path, scene_splits: dict[str, str]) -> dict[str, Any] | None:
    """The ``density`` key: :func:`~mixcount.evaluate.scene_density.scene_density` of every scene the COCO
    files name (``scene_splits``: scene id -> split) whose ``scenes/<id>/metadata.json`` is there, pooled;
    None when the dataset has no ``scenes`` folder (an export). One metadata.json is read at a time."""
    scenes_dir = Path(dataset) / "scenes"
    if not scenes_dir.is_dir():
        return None
    rows, missing = [], []
    for sid in sorted(scene_splits):
        meta_path = scenes_dir / sid / "metadata.json"
        if not meta_path.is_file():
            missing.append(sid)
            continue
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
            rows.append({"split": scene_splits[sid], **scene_density(meta)})
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise GroundTruthError(f"{meta_path}: not a scene's metadata.json ({type(exc).__name__}: {exc})") from None
    kept = [r["counted_kept"] for r in rows]
    spawned = [r["counted_spawned"] for r in rows]
    top = max([10, *spawned])
    edges = [float(10 * i) for i in range(int(np.ceil(top / 10)) + 1)]  # the last bin is closed: holds top
    return {
        "scenes": rows, "scenes_without_metadata": missing, "summary": summarise_density(rows),
        "kept_per_scene": {**summarise(kept), "histogram": bin_histogram(kept, edges)},
        "spawned_per_scene": {**summarise(spawned), "histogram": bin_histogram(spawned, edges)},
        "retention_per_scene": summarise([k / n for k, n in zip(kept, spawned) if n]),
    }


def _ratio_edges(ratios: Sequence[float]) -> list[float]:
    """Bins of width 0.5 from 1 up to past the largest imbalance ratio."""
    top = max([1.0, *ratios])
    n = int(np.ceil((top - 1.0) / 0.5)) + 1
    return [1.0 + 0.5 * i for i in range(n + 1)]


def write_stats(stats: dict[str, Any], path: str | Path) -> Path:
    """Write ``stats`` as indented JSON to ``path`` (parents created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(stats, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return path


def summary_lines(stats: dict[str, Any]) -> list[str]:
    """A short human summary of ``stats``, one line per topic."""

    def rng(d: dict[str, Any], fmt: str = "{:.1f}") -> str:
        if not d.get("count"):
            return "n/a"
        return f"mean {fmt.format(d['mean'])}, median {fmt.format(d['median'])}, range {d['min']:g}-{d['max']:g}"

    t = stats["totals"]
    lines = [
        f"{t['images']} images of {t['scenes']} scenes, {t['objects']} counted objects, "
        f"{t['distractors']} distractors, {stats['distinct_categories']} categories",
        f"objects per scene: {rng(stats['objects_per_scene'])}",
        f"classes per scene: {rng(stats['classes_per_scene'])}",
        f"class imbalance (most/least common): {rng(stats['class_imbalance'], '{:.2f}')}",
        f"visibility of counted objects: {rng(stats['visibility']['counted'], '{:.2f}')}",
        "caption words: " + "; ".join(
            f"{tier} {stats['caption_length'][tier]['mean']:.1f}" if stats["caption_length"][tier]["count"] else f"{tier} n/a"
            for tier in TIERS
        ),
    ]
    return lines + density_lines(stats.get("density")) + count_lines(stats.get("count_target"))


def _top(reasons: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0]))) or "none"


def density_lines(density: dict[str, Any] | None, max_classes: int = 10) -> list[str]:
    """Summary lines of the ``density`` key: retention, distractors, drop reasons and the classes that
    ended with no visible instance (the first ``max_classes`` of them by scene, with their reasons)."""
    if density is None:
        return ["kept vs spawned: n/a (no scenes/ folder with metadata.json)"]
    d = density["summary"]
    if not d["scenes"]:
        return ["kept vs spawned: n/a (no scene metadata.json found)"]

    def pct(x: float | None) -> str:
        return "n/a" if x is None else f"{100 * x:.0f} %"

    c, nc = d["container"], d["no_container"]
    lines = [
        f"kept vs spawned counted objects: {d['counted_kept']} of {d['counted_spawned']} ({pct(d['retention'])}), "
        f"mean {d['mean_counted_kept']:.1f} kept per scene; container scenes {pct(c['retention'])} "
        f"({c['scenes']}), without {pct(nc['retention'])} ({nc['scenes']})",
        f"distractors: {d['distractors_kept']} of {d['distractors_spawned']} kept, mean {d['mean_distractors_kept']:.2f} "
        f"per scene",
        f"drop reasons (counted): {_top(d['counted_drops'])}; (distractors): {_top(d['distractor_drops'])}; "
        f"lost off the floor {d['lost_off_floor']} ({pct(d['lost_off_floor_share'])} of spawned bodies)",
        f"classes with no visible instance: {d['classes_without_instances']} of {d['classes']}"
        + (f" (their objects: {_top(d['classes_without_instances_reasons'])})" if d["classes_without_instances"] else ""),
    ]
    empty = [(r["scene_id"], c) for r in density["scenes"] for c in r["classes_without_instances"]]
    for sid, cls in empty[:max_classes]:
        lines.append(f"  {sid}: class {cls['class_index']} {cls['name']!r} (category {cls['category_id']}), "
                     f"{cls['spawned']} spawned, none kept: {_top(cls['reasons'])}")
    if len(empty) > max_classes:
        lines.append(f"  ... {len(empty) - max_classes} more in stats.json (density.scenes)")
    if density["scenes_without_metadata"]:
        lines.append(f"{len(density['scenes_without_metadata'])} scene(s) of the COCO files have no metadata.json")
    return lines


def per_split_table(stats: dict[str, Any]) -> list[tuple[str, int, int, int, int, int]]:
    """Rows (split, images, scenes, objects, distractors, categories) for a terminal table."""
    return [(s, v["images"], v["scenes"], v["objects"], v["distractors"], v["categories"]) for s, v in stats["splits"].items()]


__all__ = [
    "compute_stats", "find_annotation_files", "per_split_table", "summarise", "summary_lines", "write_stats",
    "int_histogram", "bin_histogram", "TIERS", "density_stats", "density_lines",
]
