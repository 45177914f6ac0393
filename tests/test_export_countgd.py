"""The countgd export of a real composed dataset, read the way CountGD reads it.

Training: ``datasets/odvg.py::ODVGDataset`` in OD mode (label map keys, ``str(label)``, negatives =
label map minus the record's labels, exemplars as an int64 tensor, image from ``root/filename``).
Validation: ``datasets/coco.py::CocoDetection`` (pycocotools order of each image's annotations; exactly
three annotations with ``area != 4``, the last three; category ids index the category-name list).
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mixcount.export import export_dataset

pytestmark = [pytest.mark.blender, pytest.mark.slow]


@pytest.fixture(scope="module")
def cg(composed_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("countgd") / "export"
    return out, export_dataset(composed_dataset, "countgd", out, tier="concise")


def gt(dataset: Path) -> tuple[dict, dict]:
    doc = json.loads((dataset / "annotations" / "instances_train.json").read_text())
    scene = {img["id"]: img["scene_id"] for img in doc["images"]}
    counts = Counter((scene[a["image_id"]], a["category_id"]) for a in doc["annotations"])
    present: dict[str, set[int]] = {}
    for a in doc["annotations"]:
        present.setdefault(scene[a["image_id"]], set()).add(a["category_id"])
    return counts, present


def test_odvg_records_read_like_odvgdataset(cg, composed_dataset: Path) -> None:
    out, manifest = cg
    label_map = json.loads((out / "label_map.json").read_text())
    label_index = set(label_map.keys())
    cats = {c["id"]: c for c in json.loads((composed_dataset / "annotations" / "instances_train.json").read_text())["categories"]}
    counts, present = gt(composed_dataset)
    metas = [json.loads(line) for line in (out / "train_odvg.jsonl").read_text().splitlines()]
    counted_pairs = {(m["mixcount"]["scene_id"], m["mixcount"]["category_id"]) for m in metas}
    assert len(metas) == manifest["figures"]["records_per_split"]["train"] == len(counted_pairs) > 0
    for meta in metas:
        with Image.open(out / "images" / meta["filename"]) as im:
            assert im.size == (meta["width"], meta["height"])
        exemplars = np.asarray(meta["exemplars"], dtype=np.int64)
        assert exemplars.shape == (3, 4) and (exemplars[:, 2] > exemplars[:, 0]).all()
        instances = meta["detection"]["instances"]
        pos_labels = {str(obj["label"]) for obj in instances}
        assert pos_labels <= label_index
        neg_labels = label_index.difference(pos_labels)
        scene, cid = meta["mixcount"]["scene_id"], meta["mixcount"]["category_id"]
        # no category of the image (class or distractor) can be drawn as a negative label
        assert not {str(meta["mixcount"]["label"])} & neg_labels
        image_labels = {m["label"] for m in instances}
        assert all(str(label) not in neg_labels for label in image_labels)
        assert len(instances) == sum(v for (s, _), v in counts.items() if s == scene)
        assert {label_map[str(i["label"])] for i in instances} == {cats[c]["concise"] for c in present[scene]}
        # the first instance (labels[0], where CountGD inserts the exemplar tokens) is of the class
        assert instances[0]["label"] == meta["mixcount"]["label"]
        assert instances[0]["category"] == cats[cid]["concise"] == label_map[str(meta["mixcount"]["label"])]
        assert sum(1 for i in instances if i["label"] == meta["mixcount"]["label"]) == counts[(scene, cid)]
        boxes = np.asarray([i["bbox"] for i in instances])
        assert (boxes[:, 2] > boxes[:, 0]).all() and (boxes[:, [0, 2]] <= meta["width"]).all()
        # each exemplar box is one of the class's instance boxes
        own = {tuple(int(round(v)) for v in i["bbox"]) for i in instances if i["label"] == meta["mixcount"]["label"]}
        assert {tuple(e) for e in meta["exemplars"]} <= own
    assert manifest["figures"]["categories_sharing_a_label"] == 0


def test_coco_exemplar_file_reads_like_countgd_cocodetection(cg, composed_dataset: Path) -> None:
    from pycocotools.coco import COCO

    out, _ = cg
    coco = COCO(str(out / "train_coco_exemplars.json"))
    cat_list = [c["name"] for c in coco.loadCats(coco.getCatIds())]  # CountGD's evaluate(): caption list
    label_map = json.loads((out / "label_map.json").read_text())
    assert cat_list == [label_map[str(i)] for i in range(len(label_map))]
    counts, _ = gt(composed_dataset)
    cats = {c["id"]: c for c in json.loads((composed_dataset / "annotations" / "instances_train.json").read_text())["categories"]}
    for image_id in coco.getImgIds():
        img = coco.loadImgs(image_id)[0]
        anns = coco.loadAnns(coco.getAnnIds(image_id))
        assert sum(1 for a in anns if a["area"] != 4) == 3  # CocoDetection's assert
        assert all(a["area"] != 4 for a in anns[-3:]) and all(a["area"] == 4 for a in anns[:-3])
        w, h = img["width"], img["height"]
        boxes = np.asarray([a["bbox"] for a in anns], dtype=np.float32)
        boxes[:, 2:] += boxes[:, :2]
        boxes[:, 0::2] = boxes[:, 0::2].clip(0, w)
        boxes[:, 1::2] = boxes[:, 1::2].clip(0, h)
        assert ((boxes[:, 3] > boxes[:, 1]) & (boxes[:, 2] > boxes[:, 0])).all()  # ConvertCocoPolysToMask's assert
        gt_count = len(anns) - 3  # labels_uncropped after dropping the exemplars
        assert gt_count == counts[(img["scene_id"], img["source_category_id"])]
        labels = {a["category_id"] for a in anns}
        assert len(labels) == 1  # the caption CountGD prompts with: cat_list[labels[0]]
        assert cat_list[labels.pop()] == cats[img["source_category_id"]]["concise"]
        with Image.open(out / "images" / img["file_name"]) as im:
            assert im.size == (w, h)


def test_dataset_config_points_at_the_files(cg) -> None:
    out, _ = cg
    config = json.loads((out / "datasets_countgd.json").read_text())
    train, val = config["train"][0], config["val"][0]
    assert train["dataset_mode"] == "odvg" and Path(train["anno"]).is_file() and Path(train["label_map"]).is_file()
    assert val["dataset_mode"] == "coco" and Path(val["anno"]).is_file() and val["label_map"] is None
    assert Path(train["root"]).is_dir()
    assert (out / "ATTRIBUTION.json").is_file() and (out / "ATTRIBUTION.md").is_file()
