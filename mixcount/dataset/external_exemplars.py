"""External exemplars in the dataset, the paper's two kinds: each category's canonical white-background
render (``catalog render``), copied once per catalog object to ``OUT/exemplars/external/obj_<object_id><suffix>``,
and crops of the same object from other scenes of the split (:class:`CrossSceneExemplars`, below).

The scene's COCO categories reference the copy by ``external_exemplar``, a path relative to the dataset
root ``OUT`` like every image ``file_name``; size-qualified categories of the same object share its file.
Copies are atomic (temporary file + rename) and skipped when an identical file is already in place, so
parallel and resumed runs write each file once.
"""

from __future__ import annotations

import filecmp
import shutil
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional

from mixcount.atomic import atomic_path

EXTERNAL_DIR = Path("exemplars") / "external"


def external_exemplar_name(object_id: int, source: str | Path) -> str:
    """The copy's path relative to OUT (posix separators)."""
    return (EXTERNAL_DIR / f"obj_{int(object_id)}{Path(source).suffix.lower() or '.png'}").as_posix()


def copy_external_exemplar(out_dir: Path, object_id: int, source: str | Path) -> Optional[str]:
    """Copy ``source`` into OUT; returns its relative path, or None when the source file is missing."""
    src = Path(source)
    if not src.is_file():
        return None
    rel = external_exemplar_name(object_id, src)
    dest = Path(out_dir) / rel
    if dest.is_file() and filecmp.cmp(src, dest, shallow=False):
        return rel
    dest.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(dest) as tmp:
        shutil.copyfile(src, tmp)
    return rel


def copy_external_exemplars(out_dir: Path, renders: Mapping[int, Optional[str]],
                            object_ids: Iterable[int]) -> dict[int, str]:
    """Copy the renders of ``object_ids`` that have one; object id -> path relative to OUT."""
    out: dict[int, str] = {}
    for oid in sorted(set(int(o) for o in object_ids)):
        src = renders.get(oid)
        if src:
            rel = copy_external_exemplar(out_dir, oid, src)
            if rel is not None:
                out[oid] = rel
    return out


# ------------------------------------------------------------------------------------ cross-scene exemplars
#
# The paper's second kind of external exemplar: "crops from different scenes of our dataset". Every
# scene already crops the internal exemplars of each image (``scenes/<id>/exemplars/<category>_<rank>.png``,
# listed as ``crops`` beside the image's ``exemplars`` in coco.json); the merge lists, on each category of
# a split's COCO, ``cross_scene_exemplars``: the best-scored such crops of the same catalog object from the
# scenes of that split (never another split's). A consumer takes, for an image, the first ones whose
# ``scene_id`` is not the image's own (:meth:`mixcount.export.reader.DatasetImage.cross_scene_exemplars`).

CROSS_SCENE_PER_SCENE = 3  # crops kept from one scene (its three internal exemplars)
CROSS_SCENE_KEPT = 12  # crops listed per category: enough that every image has three from other scenes
# unless the object is in fewer scenes of the split


def crop_name(image: Mapping[str, Any], category_id: int, rank: int) -> str:
    """A crop's path for scenes written before coco.json listed ``crops`` (scene_writer's naming)."""
    fn = Path(str(image["file_name"]))
    suffix = fn.stem[len("rgb"):] if fn.stem.startswith("rgb") else ""
    return (fn.parent / "exemplars" / f"{category_id}_{rank}{suffix}.png").as_posix()


class CrossSceneExemplars:
    """Collects, one scene at a time, each catalog object's best internal-exemplar crops of one split.

    Memory: at most ``CROSS_SCENE_KEPT`` candidates per object, whatever the number of scenes."""

    def __init__(self) -> None:
        self.by_object: dict[int, list[dict[str, Any]]] = {}

    def add_scene(self, scene_id: str, images: Iterable[Mapping[str, Any]], annotations: Mapping[int, Mapping[str, Any]],
                  categories: Mapping[int, Mapping[str, Any]]) -> None:
        """``images`` with merged ids and ``exemplars`` (merged annotation ids), ``annotations`` by merged id,
        the scene's ``categories`` by id (for the object id)."""
        found: dict[int, list[dict[str, Any]]] = {}
        for img in images:
            for ex in img.get("exemplars", []):
                cid = int(ex["category_id"])
                cat = categories.get(cid) or {}
                oid = int(cat.get("object_id", cid // 4))
                crops = ex.get("crops") or [crop_name(img, cid, r) for r in range(len(ex["annotation_ids"]))]
                for rank, (aid, crop) in enumerate(zip(ex["annotation_ids"], crops)):
                    a = annotations[int(aid)]
                    found.setdefault(oid, []).append({
                        "scene_id": scene_id, "image_id": int(img["id"]), "file_name": img["file_name"],
                        "annotation_id": int(aid), "category_id": cid, "rank": rank,
                        "bbox": [float(v) for v in a["bbox"]], "exemplar_score": float(a.get("exemplar_score", 0.0)),
                        "crop": crop})
        for oid, cands in found.items():
            best = sorted(cands, key=_order)[:CROSS_SCENE_PER_SCENE]
            self.by_object[oid] = sorted(self.by_object.get(oid, []) + best, key=_order)[:CROSS_SCENE_KEPT]

    def for_category(self, category: Mapping[str, Any]) -> list[dict[str, Any]]:
        oid = int(category.get("object_id", int(category["id"]) // 4))
        return [dict(c) for c in self.by_object.get(oid, [])]


def _order(c: Mapping[str, Any]) -> tuple[float, str, int, int]:
    return (-float(c["exemplar_score"]), str(c["scene_id"]), int(c["image_id"]), int(c["rank"]))


def cross_scene_for_image(category: Mapping[str, Any], scene_id: str, n: int) -> list[Mapping[str, Any]]:
    """The first ``n`` cross-scene exemplars of ``category`` that come from scenes other than ``scene_id``."""
    return [c for c in category.get("cross_scene_exemplars") or [] if c["scene_id"] != scene_id][:n]
