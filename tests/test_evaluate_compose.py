"""Evaluation and statistics on a real composed dataset (real ingest, real bpy renders at 96 px).

A perfect prediction file must score MAE 0 and Acc10 1.0 on the composed test split, and the dataset
statistics must agree with the COCO file they are computed from.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest
from PIL import Image

from mixcount.cli import main
from mixcount.evaluate.metrics import evaluate, load_ground_truth, parse_predictions, perfect_predictions
from mixcount.evaluate.plots import PLOT_FILES

pytestmark = [pytest.mark.blender, pytest.mark.slow]


@pytest.fixture(scope="module")
def composed(tmp_path_factory: pytest.TempPathFactory, demo_catalog_copy) -> Path:
    """Two scenes of the test split at 96 px (configs/quick.toml), from a small real demo catalog (a copy
    of the session's 12-object one)."""
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import Split

    root = demo_catalog_copy(tmp_path_factory.mktemp("eval_compose"), 12)
    cat = open_catalog(f"sqlite:///{root / 'catalog.db'}", data_dir="")  # every active object is in train ...
    with cat.session() as session:
        for row in session.query(Split):
            row.split = "test"  # ... so move them all to test: the split evaluation reads
        session.commit()
    cat.close()
    out = root / "out"
    rc = main([
        "--db", str(root / "catalog.db"), "--config", "quick", "compose", "--n", "2", "--split", "test",
        "--resolution", "96", "--out", str(out),
    ])
    assert rc == 0
    return out


def test_perfect_predictions_score_perfectly(composed: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt_path = composed / "annotations" / "instances_test.json"
    doc = json.loads(gt_path.read_text())
    assert len({img["scene_id"] for img in doc["images"]}) == 2
    # the protocol's counts, recomputed here from the raw annotations (distractors included)
    expected = Counter((a["image_id"], a["category_id"]) for a in doc["annotations"])
    gt = load_ground_truth(gt_path)
    assert dict(gt.counts) == dict(expected) and sum(expected.values()) == len(doc["annotations"])
    assert any(not a["is_distractor"] for a in doc["annotations"])

    pred = tmp_path / "perfect.json"
    assert main(["baseline", "--gt", str(composed), "--out", str(pred), "--kind", "perfect"]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--gt", str(gt_path), "--pred", str(pred), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert (res["mae"], res["rmse"], res["nae"], res["acc10"]) == (0.0, 0.0, 0.0, 1.0)
    assert res["pairs"] == len(expected) and res["missing"] == 0 and res["extra"] == 0

    # one wrong count out of all pairs moves the metrics by exactly that pair's error
    rows = perfect_predictions(gt)
    y0 = rows[0]["count"]
    rows[0]["count"] = y0 + 1
    off = evaluate(gt, parse_predictions(rows)).overall
    assert off.mae == pytest.approx(1 / len(rows)) and off.nae == pytest.approx(1 / y0 / len(rows))
    assert off.acc10 == pytest.approx(1.0 if y0 >= 10 else 1 - 1 / len(rows))


def test_stats_on_composed_dataset(composed: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["stats", str(composed), "--json"]) == 0
    cap = capsys.readouterr()
    stats = json.loads(cap.out)
    doc = json.loads((composed / "annotations" / "instances_test.json").read_text())
    counted = [a for a in doc["annotations"] if not a["is_distractor"]]
    assert stats["splits"]["test"]["scenes"] == 2
    assert stats["splits"]["test"]["objects"] == len(counted)
    assert stats["objects_per_scene"]["count"] == len(doc["images"])
    assert stats["visibility"]["counted"]["count"] == len(counted)
    # every counted object kept by the compose filter is at least 1 - v_t = 60 % visible
    assert stats["visibility"]["counted"]["min"] >= 0.6 - 1e-6
    assert "objects per scene" in cap.err
    for name in PLOT_FILES:
        with Image.open(composed / "stats" / name) as im:
            assert im.format == "PNG"
