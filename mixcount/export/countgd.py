"""``--format countgd``: what CountGD (and CountGD++) train and validate on (field by field in docs/export.md).

Training reads ODVG JSONL through ``datasets/odvg.py::ODVGDataset`` in OD mode, validation a COCO file
through ``datasets/coco.py::CocoDetection``. Written here:

- ``images/<scene>.png``: the renders, unchanged (CountGD resizes itself).
- ``label_map.json``: ``{"0": text, "1": text, ...}``, one label per distinct caption text (chosen tier)
  of every category in the exported splits, distractor categories included.
- ``<split>_odvg.jsonl``: one record per (image, class) sample: ``filename``, ``height``, ``width``,
  ``exemplars`` (three [x1, y1, x2, y2] integer boxes of the sample's class) and ``detection.instances``
  (``bbox`` [x1, y1, x2, y2], ``label``, ``category``), and ``external_exemplars``: the paper's crops of the
  same object from other scenes of the split, as boxes on those (exported) images
  ``[{filename, exemplar: [x1, y1, x2, y2], scene_id, exemplar_score}]`` (up to three). The instances are
  the sample's class first, then
  **every other annotation of the image** (other classes and distractors). ODVGDataset samples negative
  caption labels from the label map minus the labels of the record's instances, so listing every object
  of the image guarantees that a class present in the image is never offered as a negative for it; and
  CountGD inserts the exemplar tokens after the caption of the first instance's label (``labels[0]``),
  so the first instance ties the exemplars to the sample's class.
- ``<split>_coco_exemplars.json``: CountGD's validation COCO. One COCO image per sample (several may
  share a file); its annotations are the class's points as 2 x 2 boxes of area exactly 4, then its three
  exemplar boxes **last** (area w*h, never 4: CocoDetection counts ``area != 4`` and asserts 3, and takes
  ``boxes[-3:]`` as exemplars). Category ids are the label indices 0..N-1 in list order, because the
  evaluator indexes the category-name list with the label.
- ``datasets_countgd.json``: a CountGD dataset config (``--datasets``) pointing at the files above.

Labels follow captions, so two classes whose captions coincide at the chosen tier share a label: CountGD
cannot tell them apart by text, and the exemplar tokens of one then count both. The manifest reports
such collisions; ``--caption-tier concise`` or ``detailed`` keeps the classes apart.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Optional

from mixcount.dataset.attribution import write_attribution
from mixcount.export.object_points import object_point
from mixcount.export.outputs import ExportFolder
from mixcount.export.reader import ComposedDataset, DatasetImage, caption, check_tier, image_key
from mixcount.progress import ProgressReporter

IMAGES = "images"
LABEL_MAP = "label_map.json"
CONFIG = "datasets_countgd.json"
POINT_BOX = 2.0  # side of the box a point becomes in the COCO variant (area 4 marks a point)


def xyxy(ann: Mapping[str, Any]) -> list[float]:
    x, y, w, h = (float(v) for v in ann["bbox"])
    return [x, y, x + w, y + h]


def build_labels(ds: ComposedDataset, splits: list[str], tier: str) -> tuple[dict[str, str], dict[int, int], int]:
    """Label map (index -> text), category id -> label, and how many categories share a label with another."""
    texts: dict[int, str] = {}
    for s in splits:
        for cid, cat in ds.categories(s).items():
            texts.setdefault(cid, caption(cat, tier))
    label_of_text: dict[str, int] = {}
    cat_label: dict[int, int] = {}
    for cid in sorted(texts):
        cat_label[cid] = label_of_text.setdefault(texts[cid], len(label_of_text))
    shared = len(texts) - len(label_of_text)
    return {str(i): t for t, i in label_of_text.items()}, cat_label, shared


def cross_scene(img: DatasetImage, category_id: int) -> list[dict[str, Any]]:
    """The class's cross-scene exemplars as CountGD takes exemplars, boxes on an image: ``filename`` (an
    image of this export: same split), ``exemplar`` [x1, y1, x2, y2] integer box there, ``scene_id`` and
    ``exemplar_score``."""
    out = []
    for c in img.cross_scene_exemplars(category_id):
        x, y, w, h = (float(v) for v in c["bbox"])
        out.append({"filename": f"{image_key(str(c['scene_id']), str(c['file_name']))}{Path(str(c['file_name'])).suffix}",
                    "exemplar": [int(round(x)), int(round(y)), int(round(x + w)), int(round(y + h))],
                    "scene_id": c["scene_id"], "exemplar_score": c["exemplar_score"]})
    return out


def odvg_record(img: DatasetImage, category_id: int, filename: str, cat_label: Mapping[int, int],
                label_map: Mapping[str, str]) -> dict[str, Any]:
    own = img.of_category(category_id)
    own_ids = {int(a["id"]) for a in own}
    others = [a for a in img.annotations if int(a["id"]) not in own_ids]
    others.sort(key=lambda a: (bool(a.get("is_distractor", False)), int(a["category_id"]), int(a["id"])))
    instances = []
    for a in own + others:
        label = cat_label[int(a["category_id"])]
        instances.append({"bbox": xyxy(a), "label": label, "category": label_map[str(label)]})
    exemplars = [[int(round(v)) for v in xyxy(a)] for a in img.exemplars(category_id)]
    external = cross_scene(img, category_id)
    return {
        "filename": filename, "height": img.height, "width": img.width, "exemplars": exemplars,
        "external_exemplars": external,
        "detection": {"instances": instances},
        "mixcount": {"scene_id": img.scene_id, "image_id": img.id, "category_id": category_id,
                     "label": cat_label[category_id], "count": len(own)},
    }


def point_box(x: float, y: float, width: int, height: int) -> list[float]:
    """A POINT_BOX-sided box centred on (x, y), shifted to lie inside the image."""
    half = POINT_BOX / 2
    x0 = min(max(x - half, 0.0), width - POINT_BOX)
    y0 = min(max(y - half, 0.0), height - POINT_BOX)
    return [round(x0, 3), round(y0, 3), POINT_BOX, POINT_BOX]


def export_countgd(ds: ComposedDataset, out: Path | str, *, split: Optional[str] = None, tier: str = "concise",
                   progress: Optional[ProgressReporter] = None) -> dict[str, Any]:
    """Write the CountGD export of ``ds`` into ``out``; returns the manifest (figures included)."""
    from mixcount.progress import as_reporter

    check_tier(tier)
    bar = as_reporter(progress)
    splits = ds.select_splits(split)
    folder = ExportFolder(out, ds.root, "countgd")
    label_map, cat_label, shared = build_labels(ds, splits, tier)
    coco_categories = [{"id": int(i), "name": t} for i, t in sorted(label_map.items(), key=lambda kv: int(kv[0]))]
    image_files: list[str] = []
    records_per_split: dict[str, int] = {}
    bar.start("export countgd", ds.count_samples(splits))
    try:
        for s in splits:
            # spooled to temporary files: one record per (image, class) adds up to millions at 58,000 scenes
            with folder.spool(lines=True, ensure_ascii=True) as lines, folder.spool() as coco_images, folder.spool() as coco_anns:
                for img in ds.images(s):
                    filename = f"{img.key}{img.path.suffix}"
                    image_files.append(filename)
                    folder.copy_if_stale(img.path, f"{IMAGES}/{filename}")
                    for cid in img.classes():
                        lines.append(odvg_record(img, cid, filename, cat_label, label_map))
                        image_id = len(coco_images) + 1
                        coco_images.append({"id": image_id, "file_name": filename, "width": img.width,
                                            "height": img.height, "scene_id": img.scene_id, "source_image_id": img.id,
                                            "source_category_id": cid,
                                            "cross_scene_exemplars": cross_scene(img, cid)})
                        label = cat_label[cid]
                        for a in img.of_category(cid):
                            x, y = object_point(a)
                            coco_anns.append({"id": len(coco_anns) + 1, "image_id": image_id, "category_id": label,
                                              "bbox": point_box(x, y, img.width, img.height), "area": 4,
                                              "iscrowd": 0, "point": [round(x, 3), round(y, 3)]})
                        for a in img.exemplars(cid):
                            bx, by, bw, bh = (float(v) for v in a["bbox"])
                            area = bw * bh
                            coco_anns.append({"id": len(coco_anns) + 1, "image_id": image_id, "category_id": label,
                                              "bbox": [bx, by, bw, bh], "area": area + 0.01 if area == 4 else area,
                                              "iscrowd": 0, "exemplar": True})
                        bar.advance(info=f"{img.key} / {cid}")
                folder.write_spooled(f"{s}_odvg.jsonl", lines)
                folder.write_json_members(f"{s}_coco_exemplars.json", [
                    ("info", {"description": f"mixcount countgd export, {s}: points as {POINT_BOX:g}x{POINT_BOX:g} "
                                             "boxes, three exemplar boxes last per image"}),
                    ("images", coco_images), ("annotations", coco_anns), ("categories", coco_categories)])
                records_per_split[s] = len(lines)
    finally:
        bar.stop()
    folder.prune(IMAGES, image_files)
    folder.prune(".", [f"{s}_odvg.jsonl" for s in splits], "*_odvg.jsonl")
    folder.prune(".", [f"{s}_coco_exemplars.json" for s in splits], "*_coco_exemplars.json")
    folder.write_json(LABEL_MAP, label_map, indent=1)
    train = "train" if "train" in splits else splits[0]
    val = next((s for s in ("val", "test", "test_objects", "test_categories") if s in splits and s != train), train)
    root = str(folder.root)
    folder.write_json(CONFIG, {
        "train": [{"root": f"{root}/{IMAGES}", "anno": f"{root}/{train}_odvg.jsonl", "label_map": f"{root}/{LABEL_MAP}",
                   "dataset_mode": "odvg"}],
        "val": [{"root": f"{root}/{IMAGES}", "anno": f"{root}/{val}_coco_exemplars.json", "label_map": None,
                 "dataset_mode": "coco"}],
    }, indent=1)
    write_attribution(ds.root, folder.root, ds.scene_ids(splits))
    figures = {"records_per_split": records_per_split, "images": len(image_files), "labels": len(label_map),
               "categories_sharing_a_label": shared}
    return folder.finish(ds.root, {"split": split, "caption_tier": tier}, figures)
