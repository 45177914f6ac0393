"""The hf export of a real composed dataset, loaded with the real ``datasets`` library (folder with its
README card, and the Parquet shards directly); per-class counts equal the COCO counts."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest
import yaml

from mixcount.export import export_dataset

pytestmark = [pytest.mark.blender, pytest.mark.slow]


@pytest.fixture(scope="module")
def hf(composed_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("hf") / "export"
    return out, export_dataset(composed_dataset, "hf", out, tier="detailed")


def test_load_dataset_folder_and_counts_match_coco(hf, composed_dataset: Path, tmp_path: Path) -> None:
    import datasets

    out, manifest = hf
    doc = json.loads((composed_dataset / "annotations" / "instances_train.json").read_text())
    counts = Counter((a["image_id"], a["category_id"]) for a in doc["annotations"])
    counted = {(a["image_id"], a["category_id"]) for a in doc["annotations"] if not a["is_distractor"]}
    cats = {c["id"]: c for c in doc["categories"]}
    dd = datasets.load_dataset(str(out), cache_dir=str(tmp_path / "cache"))
    assert list(dd) == ["train"]
    ds = dd["train"]
    assert ds.num_rows == len(doc["images"]) == manifest["figures"]["rows_per_split"]["train"]
    assert isinstance(ds.features["image"], datasets.Image)
    seen_pairs = set()
    for row in ds:
        image_id = row["image_id"]
        img = next(i for i in doc["images"] if i["id"] == image_id)
        assert row["image"].size == (img["width"], img["height"]) == (row["width"], row["height"])
        classes = row["classes"]
        for cid, n, cap, det in zip(classes["category_id"], classes["count"], classes["caption"], classes["detailed"]):
            assert n == counts[(image_id, cid)]
            assert cap == det == cats[cid]["detailed"]
            seen_pairs.add((image_id, cid))
        objs = row["objects"]
        assert sorted(objs["id"]) == sorted(a["id"] for a in doc["annotations"] if a["image_id"] == image_id)
        for (x, y), (bx, by, bw, bh) in zip(objs["point"], objs["bbox"]):
            assert bx <= x <= bx + bw and by <= y <= by + bh
    assert seen_pairs == counted


def test_parquet_shards_and_dataset_card(hf, tmp_path: Path) -> None:
    import datasets

    out, _ = hf
    shards = sorted((out / "data").glob("train-*.parquet"))
    assert shards and shards[0].name == "train-00000-of-00001.parquet"
    ds = datasets.load_dataset("parquet", data_files={"train": [str(p) for p in shards]}, split="train",
                               cache_dir=str(tmp_path / "cache"))
    assert isinstance(ds.features["image"], datasets.Image)  # the features travel in the Parquet schema
    card = (out / "README.md").read_text()
    assert card.startswith("---\n")
    meta = yaml.safe_load(card.split("---\n")[1])
    assert meta["license"] == "cc-by-sa-4.0" and "object-detection" in meta["task_categories"]
    assert meta["size_categories"] == ["n<1K"]
    assert meta["configs"][0]["data_files"][0] == {"split": "train", "path": "data/train-*.parquet"}
    assert meta["dataset_info"]["splits"][0]["num_examples"] == ds.num_rows
    assert {f["name"] for f in meta["dataset_info"]["features"]} == set(ds.features)
    assert (out / "ATTRIBUTION.md").is_file()
