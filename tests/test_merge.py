"""The streaming merge: fields pass through untouched, the result loads with pycocotools, a resumed merge
reuses the index for unchanged scenes and re-reads changed ones, ``mixcount merge`` runs it alone."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np


def _scene(out: Path, k: int, split: str, n_ann: int, extra: dict | None = None) -> Path:
    from PIL import Image

    sid = f"scene_{k:06d}"
    d = out / "scenes" / sid
    d.mkdir(parents=True)
    anns = [{"id": i, "image_id": 1, "category_id": 40 + i % 2, "bbox": [i, i, 2, 2], "area": 4, "iscrowd": 0,
             "segmentation": {"size": [8, 8], "counts": "0"}, "instance_id": 10 + i,
             "keypoints": [1, 2, 2], "future_field": {"k": k}} for i in range(1, n_ann + 1)]
    coco = {"images": [{"id": 1, "file_name": f"scenes/{sid}/rgb.png", "width": 8, "height": 8, "scene_id": sid,
                        "exemplars": [{"category_id": 41, "annotation_ids": [1], "source": "internal"}]}],
            "annotations": anns,
            "categories": [{"id": 40, "name": "a", "keypoints": ["tip"], "external_exemplars": ["x.png"]},
                           {"id": 41, "name": "b"}]}
    (d / "coco.json").write_text(json.dumps(coco))
    Image.new("RGB", (8, 8), (k * 30 % 255, 0, 0)).save(d / "rgb.png")
    meta = {"scene_id": sid, "seed": k, "split": split, "n_counted": n_ann, "n_distractors": 0,
            "counts": {"40": n_ann}, "timings": {"total": float(k)}, "complete": True, **(extra or {})}
    (d / "metadata.json").write_text(json.dumps(meta))
    return d


def test_streaming_merge_passes_fields_through_and_loads(tmp_path: Path) -> None:
    from pycocotools.coco import COCO

    from mixcount.dataset.merge import finalize_dataset

    for k in range(5):
        _scene(tmp_path, k, "train" if k % 2 == 0 else "val", n_ann=k + 1)
    (tmp_path / "scenes" / "scene_000009").mkdir()  # incomplete: ignored
    res = finalize_dataset(tmp_path, config={"x": 1}, config_hash="h", preview_scenes=2)
    train = COCO(res["annotations"]["train"])
    assert len(train.getImgIds()) == 3 and len(train.getAnnIds()) == 1 + 3 + 5
    anns = train.dataset["annotations"]
    assert [a["id"] for a in anns] == list(range(1, 10))
    assert anns[0]["keypoints"] == [1, 2, 2] and anns[-1]["future_field"] == {"k": 4}
    assert anns[-1]["scene_id"] == "scene_000004" and anns[-1]["instance_id"] == 15
    cat40 = next(c for c in train.dataset["categories"] if c["id"] == 40)
    assert cat40["keypoints"] == ["tip"] and cat40["external_exemplars"] == ["x.png"]
    img3 = train.dataset["images"][2]
    assert img3["exemplars"] == [{"category_id": 41, "annotation_ids": [5], "source": "internal"}]
    summary = json.loads(Path(res["dataset"]).read_text())
    assert summary["counts"] == {"scenes": 5, "counted_objects": 15}
    assert summary["splits"]["val"]["scenes"] == 2 and summary["splits"]["train"]["class_count_max"] == 5
    assert summary["timings_mean_s"]["total"] == 2.0 and summary["config"] == {"x": 1}
    assert [s["scene_id"] for s in summary["scenes"]] == [f"scene_{k:06d}" for k in range(5)]
    assert Path(res["preview"]).is_file()


def test_resumed_merge_reads_only_changed_metadata(tmp_path: Path) -> None:
    from mixcount.dataset.merge import finalize_dataset

    dirs = [_scene(tmp_path, k, "train", n_ann=2) for k in range(3)]
    finalize_dataset(tmp_path, preview_scenes=4)
    # unchanged size and mtime: the index answers and the (now unparsable) metadata.json is not read
    meta = dirs[1] / "metadata.json"
    st = meta.stat()
    meta.write_text("x" * st.st_size)
    os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns))
    # a changed scene is re-read, a new one joins
    changed = json.loads((dirs[2] / "metadata.json").read_text())
    changed["n_counted"] = 7
    (dirs[2] / "metadata.json").write_text(json.dumps(changed))
    _scene(tmp_path, 3, "train", n_ann=1)
    res = finalize_dataset(tmp_path, preview_scenes=4)
    summary = json.loads(Path(res["dataset"]).read_text())
    assert summary["counts"] == {"scenes": 4, "counted_objects": 2 + 2 + 7 + 1}
    index = (tmp_path / "annotations" / ".merge_index.jsonl").read_text().splitlines()
    assert [json.loads(line)["scene_id"] for line in index] == [f"scene_{k:06d}" for k in range(4)]


def test_merge_command(tmp_path: Path, capsys) -> None:
    from mixcount.cli import main

    _scene(tmp_path / "out", 0, "test", n_ann=3)
    assert main(["merge", str(tmp_path / "out")]) == 0
    doc = json.loads((tmp_path / "out" / "annotations" / "instances_test.json").read_text())
    assert len(doc["annotations"]) == 3 and np.all([a["image_id"] == 1 for a in doc["annotations"]])
    capsys.readouterr()
    assert main(["merge", str(tmp_path / "nothing")]) == 2
    assert "nothing to merge" in capsys.readouterr().err.replace("\n", " ")
