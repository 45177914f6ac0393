"""Dataset-level outputs from the finished scene folders (no bpy): merged COCO per split,
``OUT/dataset.json``, the ``OUT/preview.png`` grid and ``OUT/ATTRIBUTION.json`` / ``.md``, built in ONE
streaming pass.

Merging renumbers images (1.. in scene-id order) and annotations (1.. in image order) so the merged file
is a valid COCO set; category ids need no renumbering (they are deterministic, see
:mod:`mixcount.annotate.coco`). The scene id and the per-scene instance id stay on every record; every
other field of a scene's images, annotations and categories passes through unchanged.

Scaling (58,000 scenes, see docs/performance.md):

* one pass over the scene folders in scene-id order; each scene's ``coco.json`` is read once, and its
  images / annotations are written straight to per-split temporary files that are concatenated into
  ``annotations/instances_<split>.json`` at the end: memory holds one scene, the categories and a few
  counters, never the whole dataset;
* the summary numbers of a scene (split, counts, timings) come from ``annotations/.merge_index.jsonl``,
  a sorted index keyed by each ``metadata.json``'s size and modification time: ``metadata.json`` is
  parsed once per scene ever, and a resumed run re-reads only the scenes that changed. The index is read
  alongside the sorted folder listing (a merge join), so it is not held in memory either.

``mixcount merge OUT`` runs this on its own; ``compose`` runs it at its end when it wrote scenes.

A damaged scene (a recorded file missing or of another size, a ``coco.json`` that cannot be read; see
:mod:`mixcount.dataset.manifest`) is left out by name - the result's ``damaged`` lines - and the merge
goes on with the rest; what the split had written for it is cut back first, so the merged files never
hold part of a scene.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Optional, TextIO

from mixcount.atomic import atomic_path
from mixcount.dataset.attribution import (
    JSON_NAME,
    AttributionCollector,
    attribution_extract,
    write_attribution_document,
)
from mixcount.dataset.external_exemplars import CrossSceneExemplars
from mixcount.dataset.manifest import finished_but_unlisted, merge_problem
from mixcount.dataset.settings import variant_of_hash, variants_summary

INDEX_NAME = ".merge_index.jsonl"
RECORD_KEYS = ("scene_id", "seed", "split", "n_counted", "n_distractors", "counts", "timings", "spawned",
               "classes_without_instances", "config_hash")


# ------------------------------------------------------------------------------------ the scene index


def _read_index(path: Path) -> Iterator[dict[str, Any]]:
    if not path.is_file():
        return
    with open(path) as fh:
        for line in fh:
            try:
                yield json.loads(line)
            except ValueError:
                continue  # a torn last line of a killed merge: that scene is simply re-read


def scan_scenes(out_dir: Path, index_out: Optional[TextIO] = None
                ) -> Iterator[tuple[Path, dict[str, Any], Optional[dict[str, Any]]]]:
    """(folder, summary record, spec) of every complete scene in scene-id order. The record comes from
    the index where a scene's metadata.json is unchanged (same size and mtime; ``spec`` is then None),
    else from metadata.json (``spec`` is its parsed spec, so nobody reads the file again); each record
    is also written to ``index_out`` (the new index)."""
    out_dir = Path(out_dir)
    scenes = out_dir / "scenes"
    if not scenes.is_dir():
        return
    names = sorted(e.name for e in os.scandir(scenes) if e.is_dir() and not e.name.startswith("."))
    cached = _read_index(out_dir / "annotations" / INDEX_NAME)
    head = next(cached, None)
    for name in names:
        while head is not None and str(head.get("scene_id", "")) < name:
            head = next(cached, None)
        meta_path = scenes / name / "metadata.json"
        try:
            st = meta_path.stat()
        except OSError:
            continue
        key = [st.st_mtime_ns, st.st_size]
        spec: Optional[dict[str, Any]] = None
        # a cached record is reused only when it holds every key this version records (an index written by
        # an older version is re-read scene by scene, once)
        if (head is not None and head.get("scene_id") == name and head.get("key") == key and "attribution" in head
                and all(k in head for k in RECORD_KEYS)):
            rec = head
        else:
            try:
                meta = json.loads(meta_path.read_text())
            except (OSError, ValueError):
                continue
            if not meta.get("complete"):
                continue
            rec = {k: meta.get(k) for k in RECORD_KEYS}
            rec["scene_id"], rec["key"] = name, key
            spec = meta.get("spec") or {}
            rec["attribution"] = attribution_extract(spec)
            rec["timings"] = {k: float(v) for k, v in (rec.get("timings") or {}).items()
                              if isinstance(v, (int, float))}
        if index_out is not None:
            index_out.write(json.dumps(rec, separators=(",", ":")) + "\n")
        yield scenes / name, rec, spec


# ------------------------------------------------------------------------------------ one split's COCO


@dataclass
class _SplitWriter:
    """Streams one split's images and annotations into temporary files; keeps counters and categories."""

    split: str
    tmp: Path
    images: int = 0
    annotations: int = 0
    categories: dict[int, dict[str, Any]] = field(default_factory=dict)
    scenes: int = 0
    counted: int = 0
    distractors: int = 0
    spawned_counted: int = 0
    spawned_distractors: int = 0
    empty_classes: int = 0  # counted classes that ended with no visible instance
    category_ids: set[str] = field(default_factory=set)
    count_sum: int = 0
    count_n: int = 0
    count_min: Optional[int] = None
    count_max: Optional[int] = None
    cross_scene: CrossSceneExemplars = field(default_factory=CrossSceneExemplars)

    def __post_init__(self) -> None:
        self.img_fh = open(self.tmp / f"{self.split}.images", "w")
        self.ann_fh = open(self.tmp / f"{self.split}.annotations", "w")

    def add(self, scene_dir: Path, rec: dict[str, Any]) -> None:
        coco = json.loads((scene_dir / "coco.json").read_text())
        # one image per camera (scene-local image ids 1..K), annotations in image order
        new_image = {}
        for img in coco["images"]:
            self.images += 1
            new_image[int(img["id"])] = self.images
        old_to_new = {}
        merged_anns: dict[int, dict[str, Any]] = {}
        for a in sorted(coco["annotations"], key=lambda a: int(a.get("image_id", 1))):
            self.annotations += 1
            b = dict(a)
            old_to_new[a["id"]] = self.annotations
            b["id"], b["image_id"] = self.annotations, new_image[int(a.get("image_id", 1))]
            b["scene_id"] = scene_dir.name
            merged_anns[self.annotations] = b
            self.ann_fh.write(("," if self.annotations > 1 else "") + json.dumps(b))
        merged_images = []
        for src in coco["images"]:
            img = dict(src)
            img["id"] = new_image[int(src["id"])]
            img["exemplars"] = [{**e, "annotation_ids": [old_to_new[i] for i in e["annotation_ids"]]}
                                for e in img.get("exemplars", [])]
            merged_images.append(img)
            self.img_fh.write(("," if img["id"] > 1 else "") + json.dumps(img))
        for c in coco["categories"]:
            known = self.categories.setdefault(c["id"], c)
            if known is not c and known.get("external_exemplar") is None and c.get("external_exemplar"):
                self.categories[c["id"]] = c  # a scene composed after the render was made names it
        self.scenes += 1
        self.counted += int(rec.get("n_counted") or 0)
        self.distractors += int(rec.get("n_distractors") or 0)
        spawned = rec.get("spawned") or {}
        self.spawned_counted += int(spawned.get("counted") or 0)
        self.spawned_distractors += int(spawned.get("distractors") or 0)
        self.empty_classes += len(rec.get("classes_without_instances") or [])
        counts = rec.get("counts") or {}
        self.category_ids.update(counts)
        for v in counts.values():
            v = int(v)
            self.count_sum += v
            self.count_n += 1
            self.count_min = v if self.count_min is None else min(self.count_min, v)
            self.count_max = v if self.count_max is None else max(self.count_max, v)
        # last: nothing after it can fail, so an undone scene never leaves a candidate behind
        self.cross_scene.add_scene(scene_dir.name, merged_images, merged_anns,
                                   {int(c["id"]): c for c in coco["categories"]})

    def finish(self, out_dir: Path) -> Path:
        """Concatenate header, images, annotations and categories into the split's COCO file."""
        self.img_fh.close()
        self.ann_fh.close()
        path = out_dir / "annotations" / f"instances_{self.split}.json"
        info = json.dumps({"description": f"mixcount {self.split}", "version": "1"})
        with atomic_path(path) as tmp, open(tmp, "w") as out:
            out.write('{"info": ' + info + ', "images": [')
            with open(self.tmp / f"{self.split}.images") as fh:
                shutil.copyfileobj(fh, out, 1 << 20)
            out.write('], "annotations": [')
            with open(self.tmp / f"{self.split}.annotations") as fh:
                shutil.copyfileobj(fh, out, 1 << 20)
            cats = [{**self.categories[k], "cross_scene_exemplars": self.cross_scene.for_category(self.categories[k])}
                    for k in sorted(self.categories)]
            out.write('], "categories": ' + json.dumps(cats) + "}")
        return path

    def summary(self) -> dict[str, Any]:
        n = max(1, self.count_n)
        return {"scenes": self.scenes, "counted_objects": self.counted, "distractors": self.distractors,
                "counted_spawned": self.spawned_counted, "distractors_spawned": self.spawned_distractors,
                "classes_without_instances": self.empty_classes,
                "categories": len(self.category_ids), "class_count_mean": round(self.count_sum / n, 3),
                "class_count_min": int(self.count_min or 0), "class_count_max": int(self.count_max or 0),
                "annotations": f"annotations/instances_{self.split}.json"}


def _add_or_undo(writer: _SplitWriter, scene_dir: Path, rec: dict[str, Any]) -> Optional[str]:
    """``writer.add`` the scene; when its files cannot be read as a scene, undo what it wrote (the
    split's temporary files cut back, its counters and collections restored) and return why."""
    state = vars(writer)
    positions = {k: v.tell() for k, v in state.items() if hasattr(v, "truncate")}
    saved = {k: (copy.copy(v) if isinstance(v, (dict, set, list)) else v) for k, v in state.items()
             if k not in positions}
    try:
        writer.add(scene_dir, rec)
        return None
    except (OSError, ValueError, KeyError, TypeError, IndexError, AttributeError) as exc:
        for k, pos in positions.items():
            state[k].seek(pos)
            state[k].truncate()
        state.update(saved)
        return f"coco.json cannot be merged ({type(exc).__name__}: {str(exc)[:200]})"


# ------------------------------------------------------------------------------------ preview, the pass


def write_preview(out_dir: Path, scenes: list[tuple[Path, int]], *, cell: int = 256,
                  columns: int = 4) -> Optional[Path]:
    """A grid of the given (scene folder, counted total) pairs."""
    from PIL import Image, ImageDraw

    if not scenes:
        return None
    cols = min(columns, len(scenes))
    rows = (len(scenes) + cols - 1) // cols
    grid = Image.new("RGB", (cols * cell, rows * cell), (255, 255, 255))
    draw = ImageDraw.Draw(grid)
    for k, (d, n_counted) in enumerate(scenes):
        try:
            with Image.open(d / "rgb.png") as src:
                im = src.convert("RGB").resize((cell, cell), Image.BILINEAR)
        except (OSError, ValueError, SyntaxError):  # a damaged image: its cell stays empty
            im = Image.new("RGB", (cell, cell), (200, 200, 200))
        x, y = (k % cols) * cell, (k // cols) * cell
        grid.paste(im, (x, y))
        draw.rectangle([x, y, x + cell, y + 14], fill=(0, 0, 0))
        draw.text((x + 3, y + 1), f"{d.name}  n={n_counted}", fill=(255, 255, 255))
    path = Path(out_dir) / "preview.png"
    grid.save(path)
    return path


def finalize_dataset(out_dir: Path, *, config: Optional[dict[str, Any]] = None, config_hash: str = "",
                     run: Optional[dict[str, Any]] = None, preview_scenes: int) -> dict[str, Any]:
    """Merged COCO per split, ``dataset.json`` and ``preview.png`` in one pass (see the module docstring)."""
    out_dir = Path(out_dir)
    ann_dir = out_dir / "annotations"
    ann_dir.mkdir(parents=True, exist_ok=True)
    index_path = ann_dir / INDEX_NAME
    splits: dict[str, _SplitWriter] = {}
    timing_sum: dict[str, float] = {}
    timing_n: dict[str, int] = {}
    preview: list[tuple[Path, int]] = []
    n_scenes = n_counted = 0
    attribution = AttributionCollector()
    listed: set[str] = set()
    damaged: list[str] = []  # "<scene_id>: <what is wrong>" of scenes left out
    variant_of = variant_of_hash(out_dir)  # config hash -> settings variant (OUT/settings.json)
    with tempfile.TemporaryDirectory(prefix=".merge-", dir=ann_dir) as tmpdir:
        tmp = Path(tmpdir)
        scenes_fh = open(tmp / "scenes.json", "w")
        try:
            with atomic_path(index_path) as index_tmp, open(index_tmp, "w") as index_out:
                for d, rec, spec in scan_scenes(out_dir, index_out):
                    listed.add(d.name)
                    split = str(rec.get("split"))
                    if split not in splits:
                        splits[split] = _SplitWriter(split, tmp)
                    problem = merge_problem(d) or _add_or_undo(splits[split], d, rec)
                    if problem:
                        damaged.append(f"{d.name}: {problem}")
                        continue
                    attribution.add(d, rec["attribution"], spec)
                    for k, v in rec.get("timings", {}).items():
                        timing_sum[k] = timing_sum.get(k, 0.0) + float(v)
                        timing_n[k] = timing_n.get(k, 0) + 1
                    entry = {"scene_id": rec["scene_id"], "seed": rec.get("seed"), "split": split,
                             "n_counted": rec.get("n_counted"), "counts": rec.get("counts"),
                             "settings_id": variant_of.get(str(rec.get("config_hash")))}
                    scenes_fh.write(("," if n_scenes else "") + "\n  " + json.dumps(entry))
                    n_scenes += 1
                    n_counted += int(rec.get("n_counted") or 0)
                    if len(preview) < preview_scenes:
                        preview.append((d, int(rec.get("n_counted") or 0)))
            damaged += finished_but_unlisted(out_dir / "scenes", listed)
        finally:
            scenes_fh.close()
        written = {name: w.finish(out_dir) for name, w in sorted(splits.items())}
        head = {
            "config_hash": config_hash, "config": config or {},
            "counts": {"scenes": n_scenes, "counted_objects": n_counted},
            "splits": {name: w.summary() for name, w in sorted(splits.items())},
            "timings_mean_s": {k: round(timing_sum[k] / timing_n[k], 4) for k in sorted(timing_sum)},
            "preview": "preview.png", "run": run or {},
            # every settings variant of the scenes (one unless composed with --mixed-settings); each scene's
            # settings_id names its variant
            "settings_variants": variants_summary(out_dir),
        }
        path = out_dir / "dataset.json"
        with atomic_path(path) as part, open(part, "w") as out:
            text = json.dumps(head, indent=1)
            out.write(text[:-2] + ',\n "scenes": [')  # the head without its closing brace, then the list
            with open(tmp / "scenes.json") as fh:
                shutil.copyfileobj(fh, out, 1 << 20)
            out.write("\n ]\n}\n")
    preview_path = write_preview(out_dir, preview)
    write_attribution_document(attribution.document(), out_dir)  # every object shown, its source and licence
    return {"annotations": {k: str(v) for k, v in written.items()},
            "preview": str(preview_path) if preview_path else None, "dataset": str(path),
            "attribution": str(out_dir / JSON_NAME), "damaged": damaged}
