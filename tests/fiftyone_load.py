"""Run by tests/test_export_fiftyone.py in its own process (FiftyOne reads its database settings from the
environment at import): load one split of a ``--format fiftyone`` export into FiftyOne, backed by the
MongoDB that FIFTYONE_DATABASE_URI names, and write what came back as JSON (``OUT.json``) and each
detection's mask as FiftyOne holds it (the instance mask cropped to its box) in ``OUT.npz``.

    python fiftyone_load.py EXPORT_DIR SPLIT OUT
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def main(export_dir: str, split: str, out: str) -> None:
    import fiftyone as fo

    ds = fo.Dataset.from_dir(dataset_dir=export_dir, dataset_type=fo.types.COCODetectionDataset,
                             labels_path=f"labels_{split}.json", label_types=["detections", "segmentations"],
                             name=f"mixcount-{split}")
    samples, masks = [], {}
    for sample in ds.iter_samples():
        w, h = sample.metadata.width if sample.metadata else None, sample.metadata.height if sample.metadata else None
        dets = []
        field = sample["segmentations"] if sample.has_field("segmentations") and sample["segmentations"] else sample["detections"]
        for k, det in enumerate(field.detections if field else []):
            key = f"{Path(sample.filepath).name}:{k}"
            if det.mask is not None:
                masks[key] = np.asarray(det.mask).astype(bool)  # as FiftyOne stores it: cropped to the box
            dets.append({"label": det.label, "bounding_box": list(det.bounding_box), "mask": key if det.mask is not None else None,
                         **{a: det[a] for a in ("visibility", "is_distractor", "exemplar_score", "exemplar_rank", "point",
                                               "scene_instance_id", "count") if det.has_field(a)}})
        samples.append({"file": Path(sample.filepath).name, "width": w, "height": h, "detections": dets,
                        "fields": sorted(sample.field_names)})
    Path(f"{out}.json").write_text(json.dumps({"samples": samples, "count": ds.count(),
                                               "fiftyone": fo.__version__}, default=str))
    np.savez_compressed(f"{out}.npz", **masks)
    ds.delete()


if __name__ == "__main__":
    main(*sys.argv[1:4])
