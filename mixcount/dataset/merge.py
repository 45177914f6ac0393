"""Dataset-level outputs from the finished scene folders (no bpy): merged COCO per split,
``OUT/dataset.json``, the ``OUT/preview.png`` grid and ``OUT/ATTRIBUTION.json`` / ``.md``.

Merging renumbers images (1.. in scene-id order) and annotations (1.. in image order) so the merged file
is a valid COCO set; category ids need no renumbering (they are deterministic, see
:mod:`mixcount.annotate.coco`). The scene id and the per-scene instance id stay on every record.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Optional

import numpy as np

from mixcount.dataset.attribution import JSON_NAME, write_attribution
from mixcount.dataset.scene_writer import is_complete


def complete_scenes(out_dir: Path) -> list[Path]:
    scenes = Path(out_dir) / "scenes"
    if not scenes.is_dir():
        return []
    return sorted(d for d in scenes.iterdir() if d.is_dir() and not d.name.startswith(".") and is_complete(d))


def _write_json(path: Path, obj: Any, indent: Optional[int] = None) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(obj, indent=indent))
    os.replace(tmp, path)


def merge_annotations(out_dir: Path) -> dict[str, Path]:
    """Write ``OUT/annotations/instances_<split>.json`` for every split present; returns split -> path."""
    out_dir = Path(out_dir)
    by_split: dict[str, list[Path]] = {}
    for d in complete_scenes(out_dir):
        meta = json.loads((d / "metadata.json").read_text())
        by_split.setdefault(meta["split"], []).append(d)
    (out_dir / "annotations").mkdir(parents=True, exist_ok=True)
    written = {}
    for split, dirs in sorted(by_split.items()):
        images, anns, cats = [], [], {}
        ann_id = 1
        for image_id, d in enumerate(dirs, start=1):
            coco = json.loads((d / "coco.json").read_text())
            old_to_new = {}
            for a in coco["annotations"]:
                b = dict(a)
                old_to_new[a["id"]] = ann_id
                b["id"], b["image_id"] = ann_id, image_id
                b["scene_id"] = d.name
                anns.append(b)
                ann_id += 1
            img = dict(coco["images"][0])
            img["id"] = image_id
            img["exemplars"] = [{"category_id": e["category_id"],
                                 "annotation_ids": [old_to_new[i] for i in e["annotation_ids"]]}
                                for e in img.get("exemplars", [])]
            images.append(img)
            for c in coco["categories"]:
                cats.setdefault(c["id"], c)
        path = out_dir / "annotations" / f"instances_{split}.json"
        _write_json(path, {
            "info": {"description": f"mixcount {split}", "version": "1"},
            "images": images, "annotations": anns, "categories": [cats[k] for k in sorted(cats)],
        })
        written[split] = path
    return written


def write_preview(out_dir: Path, *, max_scenes: int = 16, cell: int = 256, columns: int = 4) -> Optional[Path]:
    """A grid of the first ``max_scenes`` finished scenes with their counted totals."""
    from PIL import Image, ImageDraw

    dirs = complete_scenes(out_dir)[:max_scenes]
    if not dirs:
        return None
    cols = min(columns, len(dirs))
    rows = (len(dirs) + cols - 1) // cols
    grid = Image.new("RGB", (cols * cell, rows * cell), (255, 255, 255))
    draw = ImageDraw.Draw(grid)
    for k, d in enumerate(dirs):
        im = Image.open(d / "rgb.png").convert("RGB").resize((cell, cell), Image.BILINEAR)
        x, y = (k % cols) * cell, (k // cols) * cell
        grid.paste(im, (x, y))
        meta = json.loads((d / "metadata.json").read_text())
        label = f"{d.name}  n={meta['n_counted']}"
        draw.rectangle([x, y, x + cell, y + 14], fill=(0, 0, 0))
        draw.text((x + 3, y + 1), label, fill=(255, 255, 255))
    path = Path(out_dir) / "preview.png"
    grid.save(path)
    return path


def write_dataset_summary(out_dir: Path, *, config: Optional[dict[str, Any]] = None, config_hash: str = "",
                          run: Optional[dict[str, Any]] = None) -> Path:
    """``OUT/dataset.json``: config, counts, per-split numbers and mean timings of the finished scenes."""
    out_dir = Path(out_dir)
    splits: dict[str, dict[str, Any]] = {}
    timings: dict[str, list[float]] = {}
    scenes = []
    for d in complete_scenes(out_dir):
        meta = json.loads((d / "metadata.json").read_text())
        s = splits.setdefault(meta["split"], {"scenes": 0, "counted": 0, "distractors": 0, "categories": set(),
                                              "counts": []})
        s["scenes"] += 1
        s["counted"] += meta["n_counted"]
        s["distractors"] += meta["n_distractors"]
        s["categories"].update(meta["counts"])
        s["counts"].extend(meta["counts"].values())
        for k, v in meta.get("timings", {}).items():
            timings.setdefault(k, []).append(float(v))
        scenes.append({"scene_id": meta["scene_id"], "seed": meta["seed"], "split": meta["split"],
                       "n_counted": meta["n_counted"], "counts": meta["counts"]})
    per_split = {}
    for name, s in sorted(splits.items()):
        counts = np.array(s["counts"] or [0])
        per_split[name] = {"scenes": s["scenes"], "counted_objects": s["counted"], "distractors": s["distractors"],
                           "categories": len(s["categories"]), "class_count_mean": round(float(counts.mean()), 3),
                           "class_count_min": int(counts.min()), "class_count_max": int(counts.max()),
                           "annotations": f"annotations/instances_{name}.json"}
    summary = {
        "config_hash": config_hash, "config": config or {},
        "counts": {"scenes": len(scenes), "counted_objects": sum(s["n_counted"] for s in scenes)},
        "splits": per_split,
        "timings_mean_s": {k: round(float(np.mean(v)), 4) for k, v in sorted(timings.items())},
        "scenes": scenes, "preview": "preview.png", "run": run or {},
    }
    path = out_dir / "dataset.json"
    _write_json(path, summary, indent=1)
    return path


def finalize_dataset(out_dir: Path, *, config: Optional[dict[str, Any]] = None, config_hash: str = "",
                     run: Optional[dict[str, Any]] = None, preview_scenes: int) -> dict[str, Any]:
    ann = merge_annotations(out_dir)
    preview = write_preview(out_dir, max_scenes=preview_scenes)
    summary = write_dataset_summary(out_dir, config=config, config_hash=config_hash, run=run)
    write_attribution(out_dir, out_dir)  # ATTRIBUTION.json / .md: every object shown, its source and licence
    return {"annotations": {k: str(v) for k, v in ann.items()}, "preview": str(preview) if preview else None,
            "dataset": str(summary), "attribution": str(Path(out_dir) / JSON_NAME)}
