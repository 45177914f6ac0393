"""``--format fsc147``: the FSC-147 layout that LOCA, DAVE, GeCo, CounTR and FamNet load, with PairTally's
negative fields in the same entries (field by field in docs/export.md).

FSC-147 labels one class per image, so every (image, class) pair of the dataset becomes one sample
``<scene>_<category_id>.jpg``:

- ``images_384_VarV2/<sample>.jpg``: the render resized to height 384 (width in proportion, bicubic).
- ``annotation_FSC147_384.json``: ``{sample: {H, W, points, box_examples_coordinates, ratio_h, ratio_w,
  img_path, density_path, negative_points, negative_box_exemples_coordinates, positive_prompt,
  negative_prompt, cross_scene_exemplars, mixcount}}``; coordinates in the 384-high image.
- ``cross_scene_exemplars/<scene>_<crop>.png``: the paper's second kind of external exemplar, crops of the
  sample's object from other scenes of the same split; each sample lists up to three as
  ``cross_scene_exemplars`` ``[{file, scene_id, category_id, exemplar_score}]``.
- ``Train_Test_Val_FSC_147.json``: ``{"train": [...], "val": [...], "test": [...]}`` (+ any other split).
- ``ImageClasses_FSC147.txt``: ``sample<TAB>class text`` (the chosen caption tier).
- ``gt_density_map_adaptive_384_VarV2/<sample>.npy`` and ``gt_density_map_adaptive_512_512_object_VarV2/
  <sample>.npy``: the two density maps of :mod:`mixcount.export.density_maps`, each summing to the count.
- ``instances_<split>.json``: COCO boxes of each sample's class (file_name = sample), which DAVE and
  GeCo read for val / test box evaluation.

The negative class of a sample (PairTally) is another class of the same image: one of the same catalog
object at another size or of the same category when there is one (PairTally's INTRA pairs), else the
most numerous other class (INTER); ties go to the lower category id. A single-class image gets empty
negative lists and an empty negative prompt.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from mixcount.dataset.attribution import write_attribution
from mixcount.export.density_maps import adaptive_density_map, density_sum_error, loca_object_density_map
from mixcount.export.object_points import object_point
from mixcount.export.outputs import ExportFolder
from mixcount.export.reader import ComposedDataset, DatasetImage, caption, check_tier
from mixcount.progress import ProgressReporter

TARGET_HEIGHT = 384
JPEG_QUALITY = 95
IMAGES = "images_384_VarV2"
DENSITY_384 = "gt_density_map_adaptive_384_VarV2"
DENSITY_512 = "gt_density_map_adaptive_512_512_object_VarV2"
ANNOTATIONS = "annotation_FSC147_384.json"
SPLITS = "Train_Test_Val_FSC_147.json"
CLASSES = "ImageClasses_FSC147.txt"
CROSS_SCENE = "cross_scene_exemplars"  # crops of the class's object from other scenes of the split
STANDARD_SPLITS = ("train", "val", "test")


def resized_size(width: int, height: int, target_height: int = TARGET_HEIGHT) -> tuple[int, int]:
    """(width, height) of an image scaled to ``target_height`` rows, aspect kept."""
    return max(1, round(width * target_height / height)), target_height


def corners(box: Sequence[float]) -> list[list[float]]:
    """FSC-147's four corners of [x1, y1, x2, y2]: [[x1, y1], [x1, y2], [x2, y2], [x2, y1]]."""
    x1, y1, x2, y2 = box
    return [[x1, y1], [x1, y2], [x2, y2], [x2, y1]]


def _r(v: float) -> float:
    return round(float(v), 3)


def scaled_box(ann: Mapping[str, Any], sx: float, sy: float) -> list[float]:
    """[x1, y1, x2, y2] of the annotation's COCO box in the resized image."""
    x, y, w, h = (float(v) for v in ann["bbox"])
    return [_r(x * sx), _r(y * sy), _r((x + w) * sx), _r((y + h) * sy)]


def scaled_points(anns: Sequence[Mapping[str, Any]], sx: float, sy: float) -> list[list[float]]:
    return [[_r(x * sx), _r(y * sy)] for x, y in (object_point(a) for a in anns)]


def negative_class(img: DatasetImage, category_id: int) -> Optional[int]:
    """The PairTally negative of a class in its image (module docstring), or None for a single class."""
    others = [c for c in img.classes() if c != category_id]
    if not others:
        return None
    cat = img.categories[category_id]

    def rank(c: int) -> tuple[int, int, int]:
        o = img.categories[c]
        related = o.get("object_id") == cat.get("object_id") or (
            o.get("category") is not None and o.get("category") == cat.get("category"))
        return (0 if related else 1, -img.count(c), c)

    return min(others, key=rank)


def save_npy(path: Path, array: np.ndarray) -> None:
    """``np.save`` to exactly ``path`` (np.save itself appends .npy to other names)."""
    with open(path, "wb") as fh:
        np.save(fh, array)


def sample_name(img: DatasetImage, category_id: int) -> str:
    return f"{img.key}_{category_id}.jpg"


def _cross_scene(folder: ExportFolder, root: Path, img: DatasetImage, category_id: int, crops: set[str]
                 ) -> list[dict[str, Any]]:
    """The sample's cross-scene exemplars: crops of its object from other scenes of the split, copied to
    ``cross_scene_exemplars/<scene>_<crop>.png`` (CounTR-style external exemplars: images of the object
    that are not this image), each with its source scene and exemplar score."""
    out = []
    for c in img.cross_scene_exemplars(category_id):
        name = f"{c['scene_id']}_{Path(str(c['crop'])).name}"
        if name not in crops:
            folder.copy_if_stale(Path(root) / str(c["crop"]), f"{CROSS_SCENE}/{name}")
            crops.add(name)
        out.append({"file": f"{CROSS_SCENE}/{name}", "scene_id": c["scene_id"], "category_id": c["category_id"],
                    "exemplar_score": c["exemplar_score"]})
    return out


def export_fsc147(ds: ComposedDataset, out: Path | str, *, split: Optional[str] = None, tier: str = "concise",
                  progress: Optional[ProgressReporter] = None) -> dict[str, Any]:
    """Write the FSC-147 export of ``ds`` into ``out``; returns the manifest (figures included)."""
    from PIL import Image

    from mixcount.progress import as_reporter

    bar = as_reporter(progress)
    splits = ds.select_splits(split)
    folder = ExportFolder(out, ds.root, "fsc147")
    check_tier(tier)
    annotations: dict[str, Any] = {}
    split_lists: dict[str, list[str]] = {s: [] for s in STANDARD_SPLITS}
    class_lines: list[str] = []
    coco_by_split: dict[str, dict[str, Any]] = {}
    worst_384 = worst_512 = 0.0
    objects = 0
    crops: set[str] = set()
    bar.start("export fsc147", ds.count_samples(splits))
    try:
        for s in splits:
            split_lists.setdefault(s, [])
            coco = coco_by_split.setdefault(s, {"images": [], "annotations": [], "categories": {}})
            ann_file = ds.annotation_files[s]
            for img, cid in ds.samples(s):
                name = sample_name(img, cid)
                stem = Path(name).stem
                new_w, new_h = resized_size(img.width, img.height)
                sx, sy = new_w / img.width, new_h / img.height
                if not folder.fresh(f"{IMAGES}/{name}", [img.path]):
                    def save(tmp: Path, img: DatasetImage = img, size: tuple[int, int] = (new_w, new_h)) -> None:
                        with Image.open(img.path) as im:
                            im.convert("RGB").resize(size, Image.Resampling.BICUBIC).save(tmp, format="JPEG", quality=JPEG_QUALITY)
                    folder.write_with(f"{IMAGES}/{name}", save)
                    folder.produced()
                anns = img.of_category(cid)
                points = scaled_points(anns, sx, sy)
                exemplars = img.exemplars(cid)
                ex_boxes = [scaled_box(a, sx, sy) for a in exemplars]
                neg = negative_class(img, cid)
                neg_anns = img.of_category(neg) if neg is not None else []
                neg_boxes = [scaled_box(a, sx, sy) for a in img.exemplars(neg)] if neg is not None else []
                cat = img.categories[cid]
                text = caption(cat, tier)
                annotations[name] = {
                    "H": new_h, "W": new_w,
                    "points": points,
                    "box_examples_coordinates": [corners(b) for b in ex_boxes],
                    "ratio_h": new_h / img.height, "ratio_w": new_w / img.width,
                    "img_path": f"{IMAGES}/{name}",
                    "density_path": f"{DENSITY_384}/{stem}.npy",
                    "negative_points": scaled_points(neg_anns, sx, sy),
                    "negative_box_exemples_coordinates": [corners(b) for b in neg_boxes],
                    "positive_prompt": text,
                    "negative_prompt": caption(img.categories[neg], tier) if neg is not None else "",
                    "cross_scene_exemplars": _cross_scene(folder, ds.root, img, cid, crops),
                    "mixcount": {"split": s, "scene_id": img.scene_id, "image_id": img.id, "category_id": cid,
                                 "negative_category_id": neg, "count": len(anns),
                                 "exemplar_annotation_ids": [int(a["id"]) for a in exemplars]},
                }
                split_lists[s].append(name)
                class_lines.append(f"{name}\t{text}\n")
                objects += len(anns)
                d384, d512 = f"{DENSITY_384}/{stem}.npy", f"{DENSITY_512}/{stem}.npy"
                if folder.fresh(d384, [ann_file]) and folder.fresh(d512, [ann_file]):
                    m384, m512 = np.load(folder.root / d384), np.load(folder.root / d512)
                else:
                    window = float(np.mean([((b[2] - b[0]) + (b[3] - b[1])) / 2 for b in ex_boxes]))
                    m384 = adaptive_density_map(points, new_h, new_w, fallback_window=window)
                    m512 = loca_object_density_map(points, ex_boxes, new_h, new_w)
                    folder.write_with(d384, lambda tmp, m=m384: save_npy(tmp, m))
                    folder.write_with(d512, lambda tmp, m=m512: save_npy(tmp, m))
                    folder.produced(2)
                worst_384 = max(worst_384, density_sum_error(m384, len(anns)) or 0.0)
                worst_512 = max(worst_512, density_sum_error(m512, len(anns)) or 0.0)
                image_id = len(coco["images"]) + 1
                coco["images"].append({"id": image_id, "file_name": name, "width": new_w, "height": new_h,
                                       "scene_id": img.scene_id, "source_image_id": img.id})
                coco["categories"].setdefault(cid, {"id": cid, "name": text})
                for a in anns:
                    x1, y1, x2, y2 = scaled_box(a, sx, sy)
                    coco["annotations"].append({
                        "id": len(coco["annotations"]) + 1, "image_id": image_id, "category_id": cid,
                        "bbox": [x1, y1, _r(x2 - x1), _r(y2 - y1)], "area": _r((x2 - x1) * (y2 - y1)), "iscrowd": 0})
                bar.advance(info=name)
    finally:
        bar.stop()
    names = list(annotations)
    folder.prune(IMAGES, names)
    folder.prune(DENSITY_384, [f"{Path(n).stem}.npy" for n in names])
    folder.prune(DENSITY_512, [f"{Path(n).stem}.npy" for n in names])
    folder.prune(CROSS_SCENE, crops)
    folder.write_json(ANNOTATIONS, annotations)
    folder.write_json(SPLITS, split_lists, indent=1)
    folder.write_text(CLASSES, "".join(class_lines))
    folder.prune(".", [f"instances_{s}.json" for s in coco_by_split], "instances_*.json")
    for s, coco in coco_by_split.items():
        folder.write_json(f"instances_{s}.json", {
            "info": {"description": f"mixcount fsc147 export, {s}: boxes of each sample's class"},
            "images": coco["images"], "annotations": coco["annotations"],
            "categories": [coco["categories"][k] for k in sorted(coco["categories"])]})
    write_attribution(ds.root, folder.root, ds.scene_ids(splits))
    figures = {"samples": len(names), "objects": objects,
               "samples_per_split": {s: len(v) for s, v in split_lists.items() if v},
               "density_max_relative_error": {DENSITY_384: worst_384, DENSITY_512: worst_512}}
    return folder.finish(ds.root, {"split": split, "caption_tier": tier}, figures)
