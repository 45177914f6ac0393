"""COCO annotations from an instance-id map (pure numpy + pycocotools; no bpy).

Category ids are deterministic so per-scene files merge without a lookup table:
``category_id = 4 * object_id + q`` with q = 0 (no size qualifier), 1 ("larger"), 2 ("smaller"). A class
that is a resized copy of the same catalog object is a different category; the same catalog object at
its one size has the same id in every scene. The class map stores these ids in 16 bits (object ids up to
16383).

Exemplar score (documented in docs/blender.md):
``s = v * sqrt(min(1, a / a_ref)) * (0.5 if the box touches the image border else 1)`` where ``v`` is
the object's visibility (visible / amodal pixels), ``a`` its visible area in pixels and ``a_ref`` the
median visible area of its class in the scene. Fully visible, typical-sized, untruncated instances score
1; occluded, unusually small or cut-off ones less. The three best counted instances per class (ties by
instance id) are the scene's internal exemplars, listed best first in ``images[].exemplars`` (a
model that takes the first N exemplar boxes of a category gets the N best).
"""

from __future__ import annotations

from typing import Any, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

QUALIFIER_CODE = {None: 0, "larger": 1, "smaller": 2}
MAX_CATEGORY_ID = 65535
N_EXEMPLARS = 3


def category_id(object_id: int, size_qualifier: Optional[str] = None) -> int:
    """Deterministic COCO category id of a catalog object at a size qualifier."""
    try:
        q = QUALIFIER_CODE[size_qualifier]
    except KeyError:
        raise ValueError(f"unknown size qualifier {size_qualifier!r}") from None
    cid = 4 * int(object_id) + q
    if not 0 < cid <= MAX_CATEGORY_ID:
        raise ValueError(f"object id {object_id} gives category id {cid} outside 1..{MAX_CATEGORY_ID}")
    return cid


def mask_to_rle(mask: NDArray[Any]) -> dict[str, Any]:
    """COCO compressed RLE (counts as str) of a boolean (H, W) mask."""
    from pycocotools import mask as mask_util

    # a mask that is already column-major (see build_scene_coco) is not copied here at all: a boolean
    # mask is read as the uint8 0 / 1 pycocotools wants (same bytes); anything else is converted
    arr = np.asfortranarray(mask)
    arr = arr.view(np.uint8) if arr.dtype == np.bool_ else (arr != 0).astype(np.uint8, order="F")
    rle = mask_util.encode(arr)
    rle["counts"] = rle["counts"].decode("ascii")
    return {"size": [int(v) for v in rle["size"]], "counts": rle["counts"]}


def bbox_of(mask: NDArray[Any]) -> list[float]:
    """[x, y, w, h] of the pixels of a boolean mask (pixel edges: a single pixel is 1 x 1)."""
    rows = np.nonzero(mask.any(axis=1))[0]
    cols = np.nonzero(mask.any(axis=0))[0]
    if len(rows) == 0:
        return [0.0, 0.0, 0.0, 0.0]
    return [float(cols[0]), float(rows[0]), float(cols[-1] - cols[0] + 1), float(rows[-1] - rows[0] + 1)]


def touches_border(bbox: Sequence[float], width: int, height: int) -> bool:
    x, y, w, h = bbox
    return x <= 0 or y <= 0 or x + w >= width or y + h >= height


def exemplar_score(visibility: float, area: float, ref_area: float, border: bool) -> float:
    """s in [0, 1] (see module docstring)."""
    v = float(np.clip(visibility, 0.0, 1.0))
    size = 1.0 if ref_area <= 0 else float(np.sqrt(min(1.0, area / ref_area)))
    return round(v * size * (0.5 if border else 1.0), 6)


def class_map(ids: NDArray[Any], inst_to_category: Mapping[int, int]) -> NDArray[Any]:
    """uint16 map of the COCO category id of each pixel's object (0 = none)."""
    lut_size = int(max([int(ids.max()) if ids.size else 0] + list(inst_to_category))) + 1
    lut = np.zeros(lut_size, dtype=np.uint16)
    for inst, cat in inst_to_category.items():
        lut[int(inst)] = int(cat)
    return np.asarray(lut[ids])


KEYPOINT_NAMES = ["center"]  # one keypoint per annotation: its point (see mixcount.annotate.interior_points)


def build_scene_coco(ids: NDArray[Any], objects: Sequence[Mapping[str, Any]], categories: Sequence[Mapping[str, Any]],
                     *, image_id: int, file_name: str, scene_id: str,
                     amodal: Optional[Mapping[int, NDArray[Any]]] = None) -> dict[str, Any]:
    """One scene's COCO dict.

    ``objects``: records with ``instance_id``, ``category_id``, ``role`` ("counted" | "distractor") and
    ``visibility``; objects without visible pixels get no annotation. Each annotation's mask is exactly
    the pixels of its id in ``ids``; its ``point`` / ``keypoints`` the visible pixel farthest from the
    mask edge. With ``amodal`` (instance id -> the object's unoccluded mask in the frame) each annotation
    also gets ``segmentation_amodal`` (that mask united with the visible one), ``bbox_amodal``,
    ``area_amodal`` and ``visibility`` = area / area_amodal; without it ``visibility`` is the record's.
    Annotation ids are the instance ids (unique within the scene). Field conventions: docs/annotations.md.
    """
    from scipy.ndimage import find_objects

    from mixcount.annotate.interior_points import interior_point

    h, w = ids.shape
    anns: list[dict[str, Any]] = []
    areas_by_cat: dict[int, list[int]] = {}
    masks, crops = {}, {}
    ids_f = np.asfortranarray(ids)  # COCO RLE runs down columns: masks compared on it come out column-major
    # each id's tight box in one pass over the map: an object's mask is compared within its box only
    # (a full-image comparison per object was ~0.3 s of a 100-object 1024² scene)
    boxes = find_objects(ids_f) if ids_f.size and int(ids_f.max()) > 0 else []
    for obj in objects:
        inst = int(obj["instance_id"])
        sl = boxes[inst - 1] if 0 < inst <= len(boxes) else None
        if sl is None:
            continue
        crop = ids_f[sl] == inst
        m = np.zeros((h, w), dtype=bool, order="F")
        m[sl] = crop
        masks[inst], crops[inst] = m, (crop, sl)
        if obj["role"] == "counted":
            areas_by_cat.setdefault(int(obj["category_id"]), []).append(int(crop.sum()))
    ref = {c: float(np.median(a)) for c, a in areas_by_cat.items()}
    for obj in objects:
        inst = int(obj["instance_id"])
        if inst not in masks:
            continue
        m = masks[inst]
        crop, (rows, cols) = crops[inst]
        box = [float(cols.start), float(rows.start), float(cols.stop - cols.start), float(rows.stop - rows.start)]
        area = int(crop.sum())
        cat = int(obj["category_id"])
        vis = float(obj.get("visibility", 1.0))
        amodal_fields: dict[str, Any] = {}
        if amodal is not None:
            am = np.logical_or(np.asarray(amodal[inst], dtype=bool), m, order="F")
            area_amodal = int(np.count_nonzero(am))
            vis = area / area_amodal
            amodal_fields = {"segmentation_amodal": mask_to_rle(am), "bbox_amodal": bbox_of(am),
                             "area_amodal": area_amodal}
        cx, cy = interior_point(crop)
        x, y = cols.start + cx, rows.start + cy
        anns.append({
            "id": inst, "image_id": image_id, "category_id": cat, "bbox": box, "segmentation": mask_to_rle(m),
            "area": area, "iscrowd": 0, "point": [x, y], "keypoints": [x, y, 2], "num_keypoints": 1,
            **amodal_fields, "visibility": round(vis, 6), "is_distractor": obj["role"] != "counted",
            "instance_id": inst,
            "exemplar_score": exemplar_score(vis, area, ref.get(cat, float(area)), touches_border(box, w, h)),
        })
    exemplars = []
    for cat in sorted({a["category_id"] for a in anns if not a["is_distractor"]}):
        ranked = sorted((a for a in anns if a["category_id"] == cat and not a["is_distractor"]),
                        key=lambda a: (-a["exemplar_score"], a["id"]))
        exemplars.append({"category_id": cat, "annotation_ids": [a["id"] for a in ranked[:N_EXEMPLARS]]})
    image = {"id": image_id, "file_name": file_name, "width": int(w), "height": int(h), "scene_id": scene_id,
             "exemplars": exemplars}
    cats = [{**c, "keypoints": list(KEYPOINT_NAMES), "skeleton": []} for c in categories]
    return {"images": [image], "annotations": anns, "categories": cats}


def ground_truth_pairs(coco: Mapping[str, Any]) -> dict[int, int]:
    """The evaluation protocol's ground truth of one scene: annotations per category id, distractors
    included (what ``mixcount evaluate`` counts per (image, category) pair)."""
    out: dict[int, int] = {}
    for a in coco["annotations"]:
        out[int(a["category_id"])] = out.get(int(a["category_id"]), 0) + 1
    return dict(sorted(out.items()))


def counts_per_category(coco: Mapping[str, Any]) -> dict[int, int]:
    """Counted (non-distractor) annotations per category id."""
    out: dict[int, int] = {}
    for a in coco["annotations"]:
        if not a["is_distractor"]:
            out[a["category_id"]] = out.get(a["category_id"], 0) + 1
    return out
