"""Counting metrics on small hand-computed cases, y = 0 handling, missing/extra pairs, grouping and the CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from mixcount.cli import main
from mixcount.errors import GroundTruthError, PredictionError
from mixcount.evaluate.metrics import (
    evaluate,
    ground_truth_from_coco,
    load_ground_truth,
    load_predictions,
    parse_predictions,
    perfect_predictions,
    score_counts,
)

# (image_id, category_id) -> (counted annotations, distractor annotations)
LAYOUT = {(1, 10): (4, 0), (1, 11): (2, 0), (1, 12): (0, 1), (2, 10): (10, 0), (2, 11): (4, 1)}
CATEGORIES = {10: ("marker", None), 11: ("ball", "larger"), 12: ("plate", None), 13: ("mug", None)}


def make_coco(layout: dict = LAYOUT) -> dict:
    """A COCO document with the dataset writer's fields (docs: contracts, "Dataset output")."""
    images = [
        {"id": i, "file_name": f"scenes/scene_{i:06d}/rgb.png", "width": 96, "height": 96, "scene_id": f"scene_{i:06d}"}
        for i in sorted({i for i, _ in layout} | {1, 2})
    ]
    categories = [
        {"id": c, "name": n, "object_id": 100 + c, "short": f"a {n}", "concise": f"a small {n}",
         "detailed": f"a small {n} with a long description", "size_qualifier": q}
        for c, (n, q) in CATEGORIES.items()
    ]
    annotations = []
    for (img, cat), (n_counted, n_dist) in sorted(layout.items()):
        for k in range(n_counted + n_dist):
            annotations.append({
                "id": len(annotations) + 1, "image_id": img, "category_id": cat, "bbox": [k, k, 5, 5],
                "segmentation": {"size": [96, 96], "counts": "0"}, "area": 25, "iscrowd": 0,
                "visibility": 0.9, "is_distractor": k >= n_counted, "exemplar_score": 0.5,
            })
    return {"images": images, "categories": categories, "annotations": annotations}


GT = ground_truth_from_coco(make_coco(), "gt.json")

# Predictions: (1,10) 5 -> |e| 1, NAE .25; (1,11) 2 boxes -> 0; (1,12) missing -> |e| 1, NAE 1;
# (2,10) 11 points -> |e| 1, NAE .1 (counts as within 10 %); (2,11) 3 -> |e| 2, NAE .4.
ROWS = [
    {"image_id": 1, "category_id": 10, "count": 5},
    {"image_id": 1, "category_id": 11, "boxes": [[0, 0, 1, 1], [2, 2, 1, 1]]},
    {"image_id": 2, "category_id": 10, "points": [[float(k), 1.0] for k in range(11)]},
    {"image_id": 2, "category_id": 11, "count": 3.0},
    {"image_id": 3, "category_id": 10, "count": 7},  # unknown image: extra
    {"image_id": 1, "category_id": 13, "count": 2},  # known category absent from image 1: extra, or y = 0
]


def test_gt_counts_include_distractors() -> None:
    assert dict(GT.counts) == {(1, 10): 4, (1, 11): 2, (1, 12): 1, (2, 10): 10, (2, 11): 5}
    assert GT.role((1, 12)) == "distractor" and GT.role((2, 11)) == "counted" and GT.role((1, 13)) == "absent"


def test_hand_computed_metrics_missing_and_extra() -> None:
    res = evaluate(GT, parse_predictions(ROWS))
    o = res.overall
    assert o.pairs == 5 and o.missing == 1 and o.extra == 2 and o.zero_pairs == 0
    assert o.mae == pytest.approx(1.0)
    assert o.rmse == pytest.approx(math.sqrt(7 / 5))
    assert o.nae == pytest.approx((0.25 + 0 + 1 + 0.1 + 0.4) / 5)
    assert o.acc10 == pytest.approx(2 / 5)
    assert res.missing_examples == ((1, 12),)
    assert set(res.extra_examples) == {(3, 10), (1, 13)}
    assert res.as_dict()["zero_exact"] is None


def test_y_zero_pairs_count_in_mae_rmse_not_in_nae_acc10() -> None:
    o = evaluate(GT, parse_predictions(ROWS), score_absent=True).overall
    assert o.pairs == 6 and o.zero_pairs == 1 and o.extra == 1  # the unknown image stays extra
    assert o.mae == pytest.approx(7 / 6)  # |e| = 1, 0, 1, 1, 2 and 2 for the y = 0 pair
    assert o.rmse == pytest.approx(math.sqrt((7 + 4) / 6))
    assert o.nae == pytest.approx(0.35) and o.acc10 == pytest.approx(0.4)  # unchanged by the y = 0 pair
    assert o.zero_exact == 0.0
    s = score_counts([0, 0, 3], [0, 1, 3])
    assert (s.mae, s.nae, s.acc10, s.zero_pairs, s.zero_exact) == (pytest.approx(1 / 3), 0.0, 1.0, 2, 0.5)
    only_zero = score_counts([0], [0])
    assert only_zero.mae == 0.0 and only_zero.nae is None and only_zero.acc10 is None and only_zero.zero_exact == 1.0
    empty = score_counts([], [])
    assert empty.pairs == 0 and empty.mae is None


def test_acc10_threshold_is_inclusive_and_float_safe() -> None:
    s = score_counts([10, 30, 20, 7], [11, 33, 22.5, 7.7])
    assert s.acc10 == pytest.approx(3 / 4)  # 0.1, 0.1, 0.125, 0.1 (7.7 is 0.1 off only up to rounding)


def test_counted_only_drops_distractor_only_pairs() -> None:
    o = evaluate(GT, parse_predictions(ROWS), counted_only=True).overall
    assert o.pairs == 4 and o.missing == 0
    assert o.mae == pytest.approx(1.0) and o.nae == pytest.approx((0.25 + 0.1 + 0.4) / 4)


def test_perfect_predictions_score_zero() -> None:
    o = evaluate(GT, parse_predictions(perfect_predictions(GT))).overall
    assert (o.mae, o.rmse, o.nae, o.acc10, o.pairs, o.missing, o.extra) == (0.0, 0.0, 0.0, 1.0, 5, 0, 0)


def test_group_by_row_field_scores_each_group_on_all_pairs() -> None:
    rows = perfect_predictions(GT, prompt="text") + [{"image_id": 1, "category_id": 10, "count": 4, "prompt": "exemplars"}]
    res = evaluate(GT, parse_predictions(rows), by="prompt")
    assert list(res.groups) == ["exemplars", "text"]
    t, e = res.groups["text"], res.groups["exemplars"]
    assert t.mae == 0.0 and t.acc10 == 1.0 and t.missing == 0
    assert e.pairs == 5 and e.missing == 4
    assert e.mae == pytest.approx((0 + 2 + 1 + 10 + 5) / 5) and e.nae == pytest.approx(0.8) and e.acc10 == pytest.approx(0.2)
    assert res.overall.pairs == 10 and res.overall.missing == 4 and res.overall.mae == pytest.approx(1.8)
    # rows without the field form their own group
    res2 = evaluate(GT, parse_predictions(rows + [{"image_id": 2, "category_id": 10, "count": 0}]), by="prompt")
    assert "(none)" in res2.groups and res2.groups["(none)"].missing == 4


def test_group_by_gt_fields_partitions_pairs() -> None:
    res = evaluate(GT, parse_predictions(ROWS), by="name")
    assert set(res.groups) == {"marker", "ball", "plate"}
    assert res.groups["marker"].pairs == 2 and res.groups["marker"].mae == pytest.approx(1.0)
    assert res.groups["plate"].missing == 1 and res.groups["plate"].nae == pytest.approx(1.0)
    assert res.overall.pairs == 5 and res.overall.mae == pytest.approx(1.0)
    role = evaluate(GT, parse_predictions(ROWS), by="role", score_absent=True)
    assert {k: v.pairs for k, v in role.groups.items()} == {"counted": 4, "distractor": 1, "absent": 1}
    assert role.groups["absent"].zero_pairs == 1
    by_image = evaluate(GT, parse_predictions(ROWS), by="image_id")
    assert by_image.groups["2"].pairs == 2 and by_image.groups["2"].mae == pytest.approx(1.5)
    with pytest.raises(PredictionError, match="no prediction row"):
        evaluate(GT, parse_predictions(ROWS), by="nonexistent")


def test_duplicate_pairs_are_an_error_that_names_the_field() -> None:
    rows = [{"image_id": 1, "category_id": 10, "count": 4, "tier": t} for t in ("short", "detailed")]
    with pytest.raises(PredictionError, match="--by tier"):
        evaluate(GT, parse_predictions(rows))
    res = evaluate(GT, parse_predictions(rows), by="tier")
    assert set(res.groups) == {"short", "detailed"}


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"rows": []}, "'predictions' list"),
        ("text", "must be a list"),
        ([{"category_id": 1, "count": 1}], "row 0: needs integer 'image_id'"),
        ([{"image_id": 1, "category_id": 1}], "needs 'count', 'boxes' or 'points'"),
        ([{"image_id": 1, "category_id": 1, "count": -1}], "finite number >= 0"),
        ([{"image_id": 1, "category_id": 1, "count": True}], "finite number >= 0"),
        ([{"image_id": 1, "category_id": 1, "count": 2, "boxes": [[0, 0, 1, 1]]}], r"counts disagree \('count' 2 vs 1 box in 'boxes'\)"),
        ([{"image_id": 1, "category_id": 1, "points": "many"}], "'points' must be a list"),
        ([5], "row 0: must be an object"),
    ],
)
def test_malformed_predictions(doc: object, message: str) -> None:
    with pytest.raises(PredictionError, match=message):
        parse_predictions(doc, "p.json")


def test_wrapped_predictions_and_bad_gt(tmp_path: Path) -> None:
    p = tmp_path / "p.json"
    p.write_text(json.dumps({"model": "x", "predictions": ROWS[:2]}))
    rows = load_predictions(p)
    assert [r.count for r in rows] == [5.0, 2.0]
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(PredictionError, match="not valid JSON"):
        load_predictions(tmp_path / "bad.json")
    with pytest.raises(GroundTruthError, match="not valid JSON"):
        load_ground_truth(tmp_path / "bad.json")
    with pytest.raises(GroundTruthError, match="file not found"):
        load_ground_truth(tmp_path / "nope.json")
    with pytest.raises(GroundTruthError, match="'annotations' is missing"):
        ground_truth_from_coco({"images": [], "categories": []})
    doc = make_coco()
    doc["annotations"][0]["image_id"] = 99
    with pytest.raises(GroundTruthError, match="unknown image_id 99"):
        ground_truth_from_coco(doc)
    with pytest.raises(GroundTruthError, match="not found"):
        load_ground_truth(tmp_path, split="test")  # a folder without annotations/


def test_cli_json_table_and_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ds"
    (out / "annotations").mkdir(parents=True)
    (out / "annotations" / "instances_test.json").write_text(json.dumps(make_coco()))
    pred = tmp_path / "pred.json"
    pred.write_text(json.dumps([{**r, "prompt": "text"} for r in ROWS]))
    capsys.readouterr()
    assert main(["evaluate", "--gt", str(out / "annotations" / "instances_test.json"), "--pred", str(pred), "--json"]) == 0
    cap = capsys.readouterr()
    payload = json.loads(cap.out)
    assert {"mae", "rmse", "nae", "acc10", "pairs", "missing"} <= set(payload)
    assert payload["mae"] == pytest.approx(1.0) and payload["acc10"] == pytest.approx(0.4)
    assert payload["pairs"] == 5 and payload["missing"] == 1 and payload["extra"] == 2
    assert "scored as 0" in cap.err and "not scored" in cap.err
    # dataset folder as --gt, grouped
    assert main(["evaluate", "--gt", str(out), "--pred", str(pred), "--by", "prompt", "--json"]) == 0
    grouped = json.loads(capsys.readouterr().out)
    assert grouped["by"] == "prompt" and grouped["groups"]["text"]["nae"] == pytest.approx(0.35)
    # without --json the table is the result: on stdout; the warnings stay on stderr
    assert main(["evaluate", "--gt", str(out), "--pred", str(pred), "--by", "name"]) == 0
    cap = capsys.readouterr()
    assert "MAE" in cap.out and "marker" in cap.out and "MAE" not in cap.err and "scored as 0" in cap.err
    # malformed predictions: a clear message and exit code 2
    pred.write_text(json.dumps([{"image_id": "one", "category_id": 10, "count": 1}]))
    assert main(["evaluate", "--gt", str(out), "--pred", str(pred), "--json"]) == 2
    cap = capsys.readouterr()
    assert "row 0: needs integer 'image_id'" in cap.err and cap.out == ""


def test_baselines_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt = tmp_path / "gt.json"
    gt.write_text(json.dumps(make_coco()))
    ref = tmp_path / "train.json"  # one pair of 7 instances: the mean baseline predicts 7 everywhere
    ref.write_text(json.dumps(make_coco({(1, 10): (7, 0)})))
    mean, perfect = tmp_path / "mean.json", tmp_path / "perfect.json"
    assert main(["baseline", "--gt", str(gt), "--out", str(mean), "--reference", str(ref)]) == 0
    assert main(["baseline", "--gt", str(gt), "--out", str(perfect), "--kind", "perfect"]) == 0
    assert {r.count for r in load_predictions(mean)} == {7.0}
    capsys.readouterr()
    assert main(["evaluate", "--gt", str(gt), "--pred", str(mean), "--json"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["mae"] == pytest.approx((3 + 5 + 6 + 3 + 2) / 5) and m["acc10"] == 0.0
    assert main(["evaluate", "--gt", str(gt), "--pred", str(perfect), "--json"]) == 0
    p = json.loads(capsys.readouterr().out)
    assert (p["mae"], p["rmse"], p["nae"], p["acc10"], p["missing"]) == (0.0, 0.0, 0.0, 1.0, 0)
    assert main(["baseline", "--gt", str(gt), "--out", str(mean), "--kind", "median"]) == 2
