"""The fsc147 export of a real composed dataset, read the way LOCA / DAVE / CounTR / PairTally read it.

LOCA ``utils/data.py::FSC147Dataset``: split JSON -> names, ``annotation_FSC147_384.json`` ->
``box_examples_coordinates[:3, [0, 2], :]`` as (x1, y1), (x2, y2), image from ``images_384_VarV2``,
``gt_density_map_adaptive_512_512_object_VarV2/<stem>.npy`` (512 x 512). CounTR / DAVE: class file split
on whitespace. DAVE / GeCo: ``instances_<split>.json`` through pycocotools. PairTally: its verifier's
required keys. Counts are checked against the dataset's COCO, the density maps against the counts.
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mixcount.cli import main
from mixcount.export import export_dataset

pytestmark = [pytest.mark.blender, pytest.mark.slow]

PAIRTALLY_KEYS = ["points", "negative_points", "box_examples_coordinates", "negative_box_exemples_coordinates",
                  "positive_prompt", "negative_prompt"]


def tree_digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


class Recorder:
    """A ProgressReporter that remembers what it was told."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def start(self, label: str, total: int) -> None:
        self.calls.append(("start", label, total))

    def advance(self, n: int = 1, *, info=None) -> None:
        self.calls.append(("advance", n))

    def update(self, *, completed=None, info=None) -> None:
        self.calls.append(("update", completed))

    def note(self, message: str) -> None:
        self.calls.append(("note", message))

    def stop(self) -> None:
        self.calls.append(("stop",))


@pytest.fixture(scope="module")
def fsc(composed_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, Recorder]:
    out = tmp_path_factory.mktemp("fsc147") / "export"
    rec = Recorder()
    before = tree_digest(composed_dataset)
    manifest = export_dataset(composed_dataset, "fsc147", out, tier="concise", progress=rec)
    assert tree_digest(composed_dataset) == before  # the dataset is never modified
    return out, manifest, rec


def coco_counts(dataset: Path) -> dict[tuple[str, int], int]:
    """(scene_id, category_id) -> annotations, for categories with a counted annotation in the image."""
    doc = json.loads((dataset / "annotations" / "instances_train.json").read_text())
    scene = {img["id"]: img["scene_id"] for img in doc["images"]}
    counts = Counter((scene[a["image_id"]], a["category_id"]) for a in doc["annotations"])
    counted = {(scene[a["image_id"]], a["category_id"]) for a in doc["annotations"] if not a["is_distractor"]}
    return {k: v for k, v in counts.items() if k in counted}


def test_fsc147_trio_reads_like_loca_and_counts_match_coco(fsc, composed_dataset: Path) -> None:
    out, manifest, rec = fsc
    splits = json.loads((out / "Train_Test_Val_FSC_147.json").read_text())
    annotations = json.loads((out / "annotation_FSC147_384.json").read_text())
    classes = dict(line.split("\t") for line in (out / "ImageClasses_FSC147.txt").read_text().splitlines())
    expected = coco_counts(composed_dataset)
    assert set(splits) >= {"train", "val", "test"} and splits["val"] == [] and splits["test"] == []
    assert len(splits["train"]) == len(expected) == manifest["figures"]["samples"] > 0
    assert set(classes) == set(annotations) == set(splits["train"])
    cats = {c["id"]: c for c in json.loads((composed_dataset / "annotations" / "instances_train.json").read_text())["categories"]}
    for name in splits["train"]:
        ann = annotations[name]
        meta = ann["mixcount"]
        assert len(ann["points"]) == meta["count"] == expected[(meta["scene_id"], meta["category_id"])]
        assert classes[name] == cats[meta["category_id"]]["concise"]
        with Image.open(out / "images_384_VarV2" / name) as im:
            w, h = im.size
            assert im.format == "JPEG" and h == 384 and (ann["H"], ann["W"]) == (h, w)
        # LOCA: torch.tensor(box_examples_coordinates)[:3, [0, 2], :].reshape(-1, 4) -> x1, y1, x2, y2
        boxes = np.asarray(ann["box_examples_coordinates"], dtype=np.float32)[:3, [0, 2], :].reshape(-1, 4)
        assert boxes.shape == (3, 4)
        assert (boxes[:, 2] > boxes[:, 0]).all() and (boxes[:, 3] > boxes[:, 1]).all()
        assert (boxes >= 0).all() and (boxes[:, [0, 2]] <= w).all() and (boxes[:, [1, 3]] <= h).all()
        pts = np.asarray(ann["points"])
        assert ((pts >= 0) & (pts <= [w, h])).all()
        # each exemplar box contains a dot of its own class (the exemplars are instances of the class)
        assert all(((pts[:, 0] >= b[0]) & (pts[:, 0] <= b[2]) & (pts[:, 1] >= b[1]) & (pts[:, 1] <= b[3])).any()
                   for b in boxes)
        d384 = np.load(out / ann["density_path"])
        d512 = np.load(out / "gt_density_map_adaptive_512_512_object_VarV2" / (Path(name).stem + ".npy"))
        assert d384.shape == (h, w) and d512.shape == (512, 512) and d512.dtype == np.float32
        for dmap in (d384, d512):
            assert abs(float(dmap.sum()) - meta["count"]) <= 0.01 * meta["count"]
        assert all(k in ann for k in PAIRTALLY_KEYS)
    errors = manifest["figures"]["density_max_relative_error"]
    assert max(errors.values()) < 0.01
    assert rec.calls[0] == ("start", "export fsc147", len(expected)) and rec.calls[-1] == ("stop",)
    assert sum(c[1] for c in rec.calls if c[0] == "advance") == len(expected)


def test_pairtally_negatives_come_from_another_class_of_the_image(fsc, composed_dataset: Path) -> None:
    out, _, _ = fsc
    annotations = json.loads((out / "annotation_FSC147_384.json").read_text())
    expected = coco_counts(composed_dataset)
    multi = [a for a in annotations.values() if a["mixcount"]["negative_category_id"] is not None]
    assert multi, "the fixture dataset must have an image with two classes"
    for ann in annotations.values():
        meta = ann["mixcount"]
        neg = meta["negative_category_id"]
        if neg is None:
            assert ann["negative_points"] == [] and ann["negative_prompt"] == ""
            continue
        assert neg != meta["category_id"]
        assert len(ann["negative_points"]) == expected[(meta["scene_id"], neg)]
        assert len(ann["negative_box_exemples_coordinates"]) == 3
        other = annotations[f"{meta['scene_id']}_{neg}.jpg"]
        assert ann["negative_points"] == other["points"] and ann["negative_prompt"] == other["positive_prompt"]


def test_dave_instances_file_loads_with_pycocotools(fsc) -> None:
    from pycocotools.coco import COCO

    out, _, _ = fsc
    annotations = json.loads((out / "annotation_FSC147_384.json").read_text())
    coco = COCO(str(out / "instances_train.json"))
    name_to_id = {img["file_name"]: img["id"] for img in coco.imgs.values()}  # DAVE's map_img_name_to_ori_id
    for name, ann in annotations.items():
        boxes = coco.loadAnns(coco.getAnnIds([name_to_id[name]]))
        assert len(boxes) == len(ann["points"])
        assert {b["category_id"] for b in boxes} == {ann["mixcount"]["category_id"]}


def test_rerun_is_idempotent_and_resumes(fsc, composed_dataset: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, manifest, _ = fsc
    before = tree_digest(out)
    name = sorted((out / "images_384_VarV2").iterdir())[0].name
    (out / "images_384_VarV2" / name).unlink()  # an interrupted run that lost one image
    (out / "images_384_VarV2" / "stale.jpg").write_bytes(b"x")  # a file no sample names
    capsys.readouterr()
    assert main(["export", str(composed_dataset), "--format", "fsc147", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "export fsc147" in captured.err  # the progress bar, on stderr
    assert "1 file(s) written" in captured.out  # the result, on stdout
    after = tree_digest(out)
    changed = {k for k in set(before) | set(after) if before.get(k) != after.get(k)}
    assert changed == {"mixcount_export.json"}  # same files, same bytes; only the run's figures differ


def test_compose_and_export_carry_attribution_for_every_object(fsc, composed_dataset: Path) -> None:
    out, _, _ = fsc
    doc = json.loads((composed_dataset / "ATTRIBUTION.json").read_text())
    used = set()
    for meta_path in (composed_dataset / "scenes").glob("*/metadata.json"):
        used |= {a["object_id"] for a in json.loads(meta_path.read_text())["spec"]["assets"]}
    assert {o["object_id"] for o in doc["objects"]} == used and doc["scenes"] == 2
    texts = {lic["id"]: lic["text"] for lic in doc["licenses"]}
    for o in doc["objects"]:
        if o["source"] == "folder":  # the demo's plain-folder scans (unit traps): keyed by their file, portably
            assert o["source_id"].startswith("source:") and "/" not in o["source_id"]
        else:  # the rest of the demo library: DTC-style folders
            assert o["source"] == "dtc" and o["source_id"] == o["name"]
        assert "CC-BY-4.0" in texts[o["license_id"]]  # the LICENSE file found at ingest
    assert doc["missing_license"] == []
    assert json.loads((out / "ATTRIBUTION.json").read_text()) == doc  # the export covers the same scenes
    md = (composed_dataset / "ATTRIBUTION.md").read_text()
    assert all(o["source_id"] in md for o in doc["objects"])
