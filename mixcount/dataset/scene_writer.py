"""Per-scene folder writer: worker outputs -> the files of ``OUT/scenes/<scene_id>/`` (no bpy).

A scene is built in a temporary sibling folder ``OUT/scenes/.tmp-<scene_id>-<pid>-<n>`` and renamed into
place only when every file is written; ``metadata.json`` (written last, ``"complete": true``) marks a
finished scene, so a folder holding only ``scene.usda`` (``compose --stage-only``) is redone by a rerun.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from mixcount.annotate.coco import build_scene_coco, category_id, class_map, ground_truth_pairs
from mixcount.counts.targets import per_category
from mixcount.scene.spec import SceneSpec
from mixcount.usd.settled_stage import decompose, write_settled_stage
from mixcount.worker.contract import KEPT, SceneResult

TMP_PREFIX = ".tmp-"
REJECTED_DIR = ".rejected"


def is_complete(scene_dir: Path) -> bool:
    meta = Path(scene_dir) / "metadata.json"
    if not meta.is_file():
        return False
    try:
        return bool(json.loads(meta.read_text()).get("complete"))
    except (OSError, ValueError):
        return False


def tmp_dir_for(out_dir: Path, scene_id: str, token: str) -> Path:
    return Path(out_dir) / "scenes" / f"{TMP_PREFIX}{scene_id}-{os.getpid()}-{token}"


def clean_stale_tmp(out_dir: Path) -> list[Path]:
    """Remove temporary scene folders left by dead processes (a killed run)."""
    removed = []
    scenes = Path(out_dir) / "scenes"
    if not scenes.is_dir():
        return removed
    for d in scenes.glob(f"{TMP_PREFIX}*"):
        parts = d.name[len(TMP_PREFIX):].split("-")
        try:
            pid = int(parts[-2])
        except (IndexError, ValueError):
            pid = -1
        alive = False
        if pid > 0 and pid != os.getpid():
            try:
                os.kill(pid, 0)
                alive = True
            except OSError:
                alive = False
        if not alive or pid == os.getpid():
            shutil.rmtree(d, ignore_errors=True)
            removed.append(d)
    return removed


def move_into_place(tmp: Path, final: Path) -> None:
    """Atomic rename of a finished temporary folder (an incomplete folder in the way is replaced)."""
    if final.exists():
        if is_complete(final):
            shutil.rmtree(tmp, ignore_errors=True)
            return
        shutil.rmtree(final)
    os.rename(tmp, final)


def scene_categories(spec: SceneSpec, captions: Mapping[int, Mapping[str, str]],
                     external_exemplars: Optional[Mapping[int, str]] = None) -> tuple[list[dict[str, Any]], dict[int, int]]:
    """COCO categories of a scene (counted classes, then distractor objects) and class_index -> category id.

    ``external_exemplars`` (object id -> path relative to OUT of its canonical render) fills each
    category's ``external_exemplar`` (None when the object has no render)."""
    ext = external_exemplars or {}
    cats: dict[int, dict[str, Any]] = {}
    class_cat: dict[int, int] = {}
    for c in spec.classes:
        cid = category_id(c.object_id, c.size_qualifier)
        class_cat[c.class_index] = cid
        name = c.name if c.size_qualifier is None else f"{c.name} ({c.size_qualifier})"
        cats[cid] = {"id": cid, "name": name, "object_id": c.object_id, "category": c.category,
                     "short": c.captions.short, "concise": c.captions.concise, "detailed": c.captions.detailed,
                     "size_qualifier": c.size_qualifier, "supercategory": c.category,
                     "external_exemplar": ext.get(c.object_id)}
    for d in spec.distractors:
        cid = category_id(d.object_id, None)
        if cid in cats:
            continue
        a = spec.asset(d.object_id)
        cap = captions.get(d.object_id) or {}
        cats[cid] = {"id": cid, "name": a.name, "object_id": a.object_id, "category": a.category,
                     "short": cap.get("short", a.category), "concise": cap.get("concise", a.name),
                     "detailed": cap.get("detailed", a.name), "size_qualifier": None, "supercategory": a.category,
                     "external_exemplar": ext.get(a.object_id)}
    return [cats[k] for k in sorted(cats)], class_cat


def _png16(arr: np.ndarray, path: Path) -> None:
    from PIL import Image

    Image.fromarray(arr.astype(np.uint16)).save(path)


def write_exemplar_crops(rgb_path: Path, coco: Mapping[str, Any], out: Path, margin: float = 0.1,
                         suffix: str = "") -> list[dict[str, Any]]:
    """Crops of the internal exemplars of one camera's image (``coco`` holds that image alone):
    ``exemplars/<category_id>_<rank><suffix>.png``."""
    from PIL import Image

    out.mkdir(exist_ok=True)
    im = Image.open(rgb_path).convert("RGB")
    (image,) = coco["images"]
    anns = {a["id"]: a for a in coco["annotations"]}
    written = []
    for ex in image["exemplars"]:
        for rank, aid in enumerate(ex["annotation_ids"]):
            x, y, w, h = anns[aid]["bbox"]
            mx, my = margin * w, margin * h
            box = (max(0, int(x - mx)), max(0, int(y - my)), min(im.width, int(np.ceil(x + w + mx))),
                   min(im.height, int(np.ceil(y + h + my))))
            name = f"{ex['category_id']}_{rank}{suffix}.png"
            im.crop(box).save(out / name)
            # the crop beside the exemplar in coco.json, relative to OUT like file_name (the merge lists
            # other scenes' crops as each category's cross-scene exemplars: mixcount.dataset.external_exemplars)
            ex.setdefault("crops", []).append((Path(str(image["file_name"])).parent / "exemplars" / name).as_posix())
            written.append({"category_id": ex["category_id"], "annotation_id": aid, "rank": rank,
                            "image_id": image["id"], "file": f"exemplars/{name}",
                            "exemplar_score": anns[aid]["exemplar_score"]})
    return written


def read_amodal_masks(path: Path) -> Optional[dict[int, np.ndarray]]:
    """The worker's ``amodal.npz`` -> instance id -> boolean mask (None when the file is absent)."""
    if not path.is_file():
        return None
    with np.load(path) as z:
        h, w = (int(v) for v in z["shape"])
        # unpacked bits are 0 / 1 bytes: read as bool in place, not copied
        return {int(k[len("amodal_"):]): np.unpackbits(z[k])[: h * w].reshape(h, w).view(bool)
                for k in z.files if k.startswith("amodal_")}


ANNOTATION_ID_STRIDE = 100_000  # camera k's annotation ids in a scene's coco.json: k * stride + instance id


def _offset_annotation_ids(coco: dict[str, Any], offset: int) -> dict[str, Any]:
    if offset:
        for a in coco["annotations"]:
            a["id"] = int(a["id"]) + offset
        for img in coco["images"]:
            img["exemplars"] = [{**e, "annotation_ids": [int(i) + offset for i in e["annotation_ids"]]}
                                for e in img["exemplars"]]
    return coco


def classes_without_instances(spec: SceneSpec, objects: Sequence[Mapping[str, Any]],
                              class_cat: Mapping[int, int]) -> list[dict[str, Any]]:
    """Counted classes of the spec that end with no kept instance, with how many were spawned and why
    each was dropped (a class that leaves the ground truth is recorded, never silently)."""
    out = []
    for c in spec.classes:
        mine = [r for r in objects if r["role"] == "counted" and int(r["class_index"]) == c.class_index]
        if any(r["status"] == KEPT for r in mine):
            continue
        reasons: dict[str, int] = {}
        for r in mine:
            reasons[str(r.get("reason"))] = reasons.get(str(r.get("reason")), 0) + 1
        out.append({"class_index": c.class_index, "category_id": class_cat[c.class_index],
                    "name": c.name if c.size_qualifier is None else f"{c.name} ({c.size_qualifier})",
                    "spawned": len(mine), "reasons": dict(sorted(reasons.items()))})
    return out


def _write_view(tmp: Path, spec: SceneSpec, k: int, view: Any, objects: list[dict[str, Any]],
                cats: list[dict[str, Any]], passes: Sequence[str]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Camera ``k``'s files (instance / class PNGs from its id map, exemplar crops) and its COCO part;
    annotation fields go onto ``objects`` (cam_0's on the record itself, every camera's in its ``views``).
    Returns the COCO part and the exemplar records; the worker's ids / amodal files are removed."""
    suffix = view.suffix
    kept = [r for r in objects if r["status"] == KEPT]
    ids = np.load(tmp / f"ids{suffix}.npy")
    amodal = read_amodal_masks(tmp / f"amodal{suffix}.npz")
    if "instance" in passes:
        _png16(ids.astype(np.uint16), tmp / f"instance{suffix}.png")
    if "class" in passes:
        _png16(class_map(ids, {int(r["instance_id"]): int(r["category_id"]) for r in kept}), tmp / f"class{suffix}.png")
    file_name = f"scenes/{spec.scene_id}/rgb{suffix}.png"
    one = _offset_annotation_ids(build_scene_coco(ids, kept, cats, image_id=k + 1, file_name=file_name,
                                                  scene_id=spec.scene_id, amodal=amodal), k * ANNOTATION_ID_STRIDE)
    one["images"][0]["camera"] = view.name
    by_inst = {a["instance_id"]: a for a in one["annotations"]}
    for r in objects:
        a = by_inst.get(int(r["instance_id"]))
        if a is None:
            continue
        fields = dict(bbox=a["bbox"], area=a["area"], point=a["point"], visibility=a["visibility"],
                      exemplar_score=a["exemplar_score"], annotation_id=a["id"])
        if "bbox_amodal" in a:
            fields.update(bbox_amodal=a["bbox_amodal"], area_amodal=a["area_amodal"])
        if k == 0:
            r.update(fields)
        if k < len(r.get("views") or []):
            r["views"][k].update(fields)
    exemplars = write_exemplar_crops(tmp / f"rgb{suffix}.png", one, tmp / "exemplars", suffix=suffix)
    os.remove(tmp / f"ids{suffix}.npy")
    if amodal is not None:
        os.remove(tmp / f"amodal{suffix}.npz")  # the masks are in coco.json as segmentation_amodal
    one["image_record"] = {"file_name": file_name, "width": int(ids.shape[1]), "height": int(ids.shape[0]),
                           "camera": view.name, "image_id": k + 1}
    one["files"] = {"rgb": f"rgb{suffix}.png", **{p: f"{p}{suffix}.png" for p in ("instance", "class") if p in passes},
                    **{name: rec["file"] for name, rec in view.passes.items()}}
    return one, exemplars


CONVENTIONS = {
    "instance.png": "uint16 instance id of counted objects and distractors; 0 = floor, container, background",
    "class.png": "uint16 COCO category id (4 * object_id + q; q 0 none, 1 larger, 2 smaller); 0 = none",
    "depth": "planar depth along the optical axis, metres; 0 = no surface (mixcount.dataset.read_depth)",
    "normal": "unit normals in camera space (x right, y up, z toward the camera); 0 = none "
              "(mixcount.dataset.read_normals)",
    "cameras": "camera k > 0 writes rgb_cam_<k>.png, instance_cam_<k>.png, ...; coco.json holds one image per camera",
}


def finalize_scene(tmp: Path, spec: SceneSpec, worker: SceneResult, *, captions: Mapping[int, Mapping[str, str]],
                   timings: dict[str, float], extra: Optional[dict[str, Any]] = None,
                   external_exemplars: Optional[Mapping[int, str]] = None,
                   passes: Sequence[str]) -> dict[str, Any]:
    """Turn the worker's raw outputs in ``tmp`` and its SceneResult into the scene's files; returns
    metadata.json's dict, for the caller to complete (timings) and write once with :func:`write_metadata` (its ``objects`` are the ObjectResult fields plus category, box, point, amodal
    box, pose of cam_0's image, and per camera the same under ``views``; its ``ground_truth`` the
    evaluation pairs of cam_0's image, distractors included: every camera shows the same kept objects).

    One COCO image per camera (:func:`_write_view`): cam_0's is ``rgb.png`` (image id 1, annotation ids =
    instance ids), camera k's ``rgb_cam_<k>.png`` (image id k + 1, annotation ids k * ANNOTATION_ID_STRIDE
    + instance id)."""
    views = worker.views
    cats, class_cat = scene_categories(spec, captions, external_exemplars)
    objects = [{**rec.to_dict(), "category_id": class_cat[rec.class_index] if rec.role == "counted"
                else category_id(rec.object_id, None)} for rec in worker.objects]
    parts = [_write_view(tmp, spec, k, view, objects, cats, passes) for k, view in enumerate(views)]
    coco = {"images": [img for one, _ in parts for img in one["images"]],
            "annotations": [a for one, _ in parts for a in one["annotations"]], "categories": parts[0][0]["categories"]}
    for r in objects:
        if r["status"] == KEPT:
            r["pose"] = decompose(r["matrix_world"])
            if len(views) > 1:  # the rule's value: the worst camera's visibility (the paper's max occlusion)
                r["visibility_min"] = min(float(v.get("visibility", 1.0)) for v in r["views"])
    (tmp / "coco.json").write_text(json.dumps(coco))
    write_settled_stage(tmp / "scene.usda", tmp / "settled.usda", worker.objects, views)
    counts: dict[str, int] = {}
    for r in objects:
        if r["status"] == KEPT and r["role"] == "counted":
            counts[str(r["category_id"])] = counts.get(str(r["category_id"]), 0) + 1
    first = parts[0][0]["annotations"]
    files = {v.name: one["files"] for v, (one, _) in zip(views, parts)}
    meta = {
        "scene_id": spec.scene_id, "seed": spec.seed, "split": spec.split, "config_hash": spec.config_hash,
        "image": {k: v for k, v in parts[0][0]["image_record"].items() if k in ("file_name", "width", "height")},
        "images": [one["image_record"] for one, _ in parts],
        "camera": worker.camera, "lights": worker.lights, "physics": worker.physics,
        "cameras": [{"name": v.name, "record": v.camera, "framing": v.framing} for v in views],
        "visibility_threshold": worker.visibility_threshold,
        "counts": counts, "n_counted": sum(counts.values()),
        # the visible counts asked for (issue 37), by category id, beside "counts" (what was kept)
        **({} if spec.count_target is None else {"count_target": per_category(spec.count_target, class_cat)}),
        "n_distractors": sum(1 for a in first if a["is_distractor"]),
        "ground_truth": [{"category_id": c, "count": n}
                         for c, n in ground_truth_pairs({"annotations": first}).items()],
        "n_dropped": sum(1 for r in objects if r["status"] != KEPT),
        "spawned": {"counted": sum(1 for r in objects if r["role"] == "counted"),
                    "distractors": sum(1 for r in objects if r["role"] == "distractor")},
        "classes_without_instances": classes_without_instances(spec, objects, class_cat),
        "categories": cats, "objects": objects, "exemplars": [e for _, ex in parts for e in ex],
        "diagnostics": list(worker.diagnostics),
        "timings": {**timings, **{f"worker.{k}": v for k, v in worker.timings.items()}},
        "spec": spec.to_dict(),
        "files": {**files[views[0].name], "stage": "scene.usda", "settled": "settled.usda", "coco": "coco.json",
                  **({"cameras": files} if len(views) > 1 else {})},
        "passes": {name: dict(rec) for name, rec in views[0].passes.items()},
        "conventions": CONVENTIONS,
        **(extra or {}),
        "complete": True,
    }
    # no absolute path leaves the machine (docs/usd.md, "Portable datasets"): the worker's resolved asset
    # paths (into the catalog), the dome's map, the spec's source files
    from mixcount.usd.portable import PathRoots, portable_paths

    asset_dirs = tuple(sorted({Path(r.asset).parent for r in worker.objects if r.asset}))
    return portable_paths(meta, PathRoots(tmp.parent.parent, asset_dirs))


def write_metadata(scene_dir: Path, meta: Mapping[str, Any]) -> None:
    """metadata.json, written once, last (its ``"complete": true`` marks a finished scene)."""
    (scene_dir / "metadata.json").write_text(json.dumps(meta, indent=1))
