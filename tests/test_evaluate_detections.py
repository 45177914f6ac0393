"""``mixcount evaluate`` on COCO detection results (image_id, category_id, bbox, score): counts are the
detections above ``--score-threshold``, read from real files through the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mixcount.cli import main
from mixcount.errors import PredictionError
from mixcount.evaluate.detections import detection_rows, is_detection_document, load_prediction_file


def _gt(tmp_path: Path) -> Path:
    anns = []
    for image_id, cat, n in ((1, 7, 4), (1, 9, 2), (2, 7, 10)):
        for k in range(n):
            anns.append({"id": len(anns) + 1, "image_id": image_id, "category_id": cat, "bbox": [k, k, 3, 3],
                         "is_distractor": False})
    doc = {"images": [{"id": 1}, {"id": 2}], "categories": [{"id": 7, "name": "a"}, {"id": 9, "name": "b"}],
           "annotations": anns}
    path = tmp_path / "gt.json"
    path.write_text(json.dumps(doc))
    return path


def _run(capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    capsys.readouterr()
    assert main(["evaluate", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_detections_are_counted_above_the_threshold(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt = _gt(tmp_path)
    dets = []
    for a in json.loads(gt.read_text())["annotations"]:  # every object found with a confident box
        dets.append({"image_id": a["image_id"], "category_id": a["category_id"], "bbox": a["bbox"], "score": 0.9})
    dets += [{"image_id": 2, "category_id": 7, "bbox": [50, 50, 3, 3], "score": s} for s in (0.3, 0.5)]  # weak ones
    pred = tmp_path / "results.json"
    pred.write_text(json.dumps(dets))
    res = _run(capsys, "--gt", str(gt), "--pred", str(pred))
    assert (res["mae"], res["acc10"], res["pairs"], res["missing"]) == (0.0, 1.0, 3, 0)  # 0.5 is not above 0.5
    res = _run(capsys, "--gt", str(gt), "--pred", str(pred), "--score-threshold", "0.2")
    assert res["mae"] == pytest.approx(2 / 3)  # image 2 / category 7 counts 12 for 10
    assert res["nae"] == pytest.approx(0.2 / 3)
    res = _run(capsys, "--gt", str(gt), "--pred", str(pred), "--score-threshold", "0.95")
    assert res["mae"] == pytest.approx((4 + 2 + 10) / 3) and res["missing"] == 0  # pairs seen, counted 0


def test_detection_files_are_checked(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert is_detection_document([{"image_id": 1, "category_id": 7, "bbox": [0, 0, 1, 1], "score": 0.4}])
    assert not is_detection_document([{"image_id": 1, "category_id": 7, "count": 3}])
    assert not is_detection_document([])
    with pytest.raises(PredictionError, match="detection 1: 'bbox' must be"):
        detection_rows([{"image_id": 1, "category_id": 7, "bbox": [0, 0, 1, 1], "score": 0.4},
                        {"image_id": 1, "category_id": 7, "bbox": [0, 0, 1], "score": 0.4}])
    with pytest.raises(PredictionError, match="'score' must be a finite number"):
        detection_rows([{"image_id": 1, "category_id": 7, "bbox": [0, 0, 1, 1], "score": "high"}])
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"image_id": "1", "category_id": 7, "bbox": [0, 0, 1, 1], "score": 0.9}]))
    assert main(["evaluate", "--gt", str(_gt(tmp_path)), "--pred", str(bad)]) == 2
    assert "needs integer 'image_id' and 'category_id'" in capsys.readouterr().err
    counts = tmp_path / "counts.json"
    counts.write_text(json.dumps([{"image_id": 1, "category_id": 7, "count": 4}]))
    assert [r.count for r in load_prediction_file(counts)] == [4.0]  # count files still read as before


@pytest.mark.blender
@pytest.mark.slow
def test_detections_on_a_composed_dataset(composed_dataset: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    doc = json.loads((composed_dataset / "annotations" / "instances_train.json").read_text())
    dets = [{"image_id": a["image_id"], "category_id": a["category_id"], "bbox": a["bbox"],
             "score": 0.8 if k % 2 == 0 else 0.6} for k, a in enumerate(doc["annotations"])]
    pred = tmp_path / "coco_results.json"
    pred.write_text(json.dumps(dets))
    res = _run(capsys, "--gt", str(composed_dataset), "--split", "train", "--pred", str(pred))
    assert (res["mae"], res["acc10"], res["missing"], res["extra"]) == (0.0, 1.0, 0, 0)
    res = _run(capsys, "--gt", str(composed_dataset), "--split", "train", "--pred", str(pred), "--score-threshold", "0.7")
    assert res["mae"] == pytest.approx(sum(1 for k in range(len(dets)) if k % 2) / res["pairs"])
