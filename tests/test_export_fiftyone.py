"""The fiftyone export of a real composed dataset. FiftyOne itself cannot run here (its database,
MongoDB, is downloaded when fiftyone-db installs, and this machine has no network), so the COCO file
is round-tripped with pycocotools, whose mask decoding FiftyOne's COCO importer uses: every mask,
box, attribute and count must come back as the dataset holds it."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mixcount.export import export_dataset

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def test_fiftyone_coco_round_trip_with_masks_and_attributes(composed_dataset: Path, tmp_path: Path) -> None:
    from pycocotools.coco import COCO

    out = tmp_path / "fo"
    export_dataset(composed_dataset, "fiftyone", out, tier="short")
    src = COCO(str(composed_dataset / "annotations" / "instances_train.json"))
    exp = COCO(str(out / "labels_train.json"))
    assert sorted(exp.getImgIds()) == sorted(src.getImgIds())
    assert [c["name"] for c in exp.loadCats(exp.getCatIds())] == [c["short"] for c in src.loadCats(src.getCatIds())]
    for image_id in src.getImgIds():
        img = exp.loadImgs(image_id)[0]
        with Image.open(out / "data" / img["file_name"]) as im:
            assert im.size == (img["width"], img["height"])
        counts = Counter(a["category_id"] for a in src.loadAnns(src.getAnnIds(image_id)))
        for a in exp.loadAnns(exp.getAnnIds(image_id)):
            s = src.loadAnns(a["id"])[0]
            mask = exp.annToMask(a).astype(bool)
            assert np.array_equal(mask, src.annToMask(s).astype(bool)) and mask.sum() == s["area"]
            assert a["bbox"] == s["bbox"] and a["category_id"] == s["category_id"]
            assert a["visibility"] == s["visibility"] and a["is_distractor"] == s["is_distractor"]
            assert a["count"] == counts[a["category_id"]]
            x, y = a["point"]
            assert mask[int(y), int(x)]  # the point is a visible pixel of the object
            assert (a["exemplar_rank"] >= 0) == any(a["id"] in e["annotation_ids"] for e in
                                                     src.loadImgs(image_id)[0]["exemplars"])
            assert "instance_id" not in a  # a reserved attribute name of FiftyOne's Detection
    assert json.loads((out / "mixcount_export.json").read_text())["format"] == "fiftyone"
