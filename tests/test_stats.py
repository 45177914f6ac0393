"""Dataset statistics on a synthetic dataset folder: hand-computed numbers, stats.json, PNGs that open."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from PIL import Image

from mixcount.cli import main
from mixcount.evaluate.errors import GroundTruthError
from mixcount.evaluate.plots import PLOT_FILES, write_plots
from mixcount.evaluate.stats import compute_stats

# category id -> (name, short, concise, detailed): 2, 3 and 6 words per tier
CATS = {c: (f"thing{c}", f"a thing{c}", f"a small red thing{c}", f"a small red thing{c} with a handle") for c in range(1, 7)}
# split -> [(image_id, scene_id, [(category_id, n, visibility, is_distractor), ...])]
LAYOUT = {
    "train": [
        (1, "scene_000000", [(1, 6, 0.7, False), (2, 2, 0.9, False), (3, 1, 0.3, True)]),
        (2, "scene_000001", [(1, 3, 0.8, False), (2, 3, 0.8, False), (4, 2, 0.8, False)]),
    ],
    "test": [  # one scene seen by two cameras
        (10, "scene_000002", [(5, 1, 1.0, False), (6, 2, 0.5, True)]),
        (11, "scene_000002", [(5, 1, 1.0, False)]),
    ],
}


def write_dataset(root: Path, layout: dict = LAYOUT) -> Path:
    (root / "annotations").mkdir(parents=True)
    for split, images in layout.items():
        cats = sorted({c for _, _, anns in images for c, *_ in anns} | {1})  # category 1 repeated in test
        doc = {
            "images": [{"id": i, "file_name": f"scenes/{s}/rgb.png", "width": 96, "height": 96, "scene_id": s} for i, s, _ in images],
            "categories": [
                {"id": c, "name": CATS[c][0], "object_id": 100 + c, "short": CATS[c][1], "concise": CATS[c][2],
                 "detailed": CATS[c][3], "size_qualifier": None} for c in cats
            ],
            "annotations": [],
        }
        for img, _, anns in images:
            for cat, n, vis, dist in anns:
                for _ in range(n):
                    doc["annotations"].append({
                        "id": len(doc["annotations"]) + 1, "image_id": img, "category_id": cat, "bbox": [0, 0, 4, 4],
                        "segmentation": {"size": [96, 96], "counts": "0"}, "area": 16, "iscrowd": 0,
                        "visibility": vis, "is_distractor": dist, "exemplar_score": 0.5,
                    })
        (root / "annotations" / f"instances_{split}.json").write_text(json.dumps(doc))
    return root


def test_stats_numbers(tmp_path: Path) -> None:
    s = compute_stats(write_dataset(tmp_path / "ds"))
    assert list(s["splits"]) == ["train", "test"]
    assert s["splits"]["train"] == {"images": 2, "scenes": 2, "objects": 16, "distractors": 1, "categories": 3}
    assert s["splits"]["test"] == {"images": 2, "scenes": 1, "objects": 2, "distractors": 2, "categories": 1}
    assert s["totals"] == {"images": 4, "scenes": 3, "objects": 18, "distractors": 3}
    ops = s["objects_per_scene"]
    assert (ops["min"], ops["max"], ops["mean"], ops["count"]) == (1.0, 8.0, 4.5, 4)
    assert ops["histogram"] == {"values": list(range(1, 9)), "counts": [2, 0, 0, 0, 0, 0, 0, 2]}
    assert s["classes_per_scene"]["histogram"] == {"values": [1, 2, 3], "counts": [2, 1, 1]}
    assert s["distractors_per_scene"]["mean"] == pytest.approx(3 / 4)
    imb = s["class_imbalance"]  # 6/2 = 3, 3/2 = 1.5, 1, 1
    assert (imb["min"], imb["max"], imb["mean"]) == (1.0, 3.0, pytest.approx(6.5 / 4))
    assert imb["histogram"]["edges"][0] == 1.0 and sum(imb["histogram"]["counts"]) == 4
    vis = s["visibility"]
    assert vis["counted"]["count"] == 18 and vis["distractor"]["count"] == 3
    assert vis["counted"]["mean"] == pytest.approx((6 * 0.7 + 2 * 0.9 + 8 * 0.8 + 2 * 1.0) / 18)
    assert vis["distractor"]["histogram"]["counts"][6] == 1 and vis["distractor"]["histogram"]["counts"][10] == 2
    assert sum(vis["counted"]["histogram"]["counts"]) == 18  # 1.0 falls in the last, closed bin
    assert s["distinct_categories"] == 6  # category 1 appears in both files once
    assert {t: s["caption_length"][t]["mean"] for t in ("short", "concise", "detailed")} == {"short": 2, "concise": 4, "detailed": 7}


def test_plots_are_real_pngs(tmp_path: Path) -> None:
    stats = compute_stats(write_dataset(tmp_path / "ds"))
    paths = write_plots(stats, tmp_path / "plots")
    assert sorted(p.name for p in paths) == sorted(PLOT_FILES)
    for p in paths:
        with Image.open(p) as im:
            assert im.format == "PNG" and im.width >= 300 and im.height >= 200
            assert len(set(im.convert("L").getdata())) > 2  # something was drawn


def test_empty_split_and_missing_folder(tmp_path: Path) -> None:
    root = write_dataset(tmp_path / "ds", {"val": []})
    s = compute_stats(root)
    assert s["splits"]["val"]["images"] == 0 and s["objects_per_scene"]["mean"] is None
    assert len(write_plots(s, tmp_path / "plots")) == len(PLOT_FILES)  # "no data" plots, no crash
    with pytest.raises(GroundTruthError, match="no annotations"):
        compute_stats(tmp_path)
    (root / "annotations" / "instances_val.json").write_text('{"images": {}}')
    with pytest.raises(GroundTruthError, match="'images' is missing or not a list"):
        compute_stats(root)


def test_cli_stats(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = write_dataset(tmp_path / "ds")
    capsys.readouterr()
    assert main(["stats", str(root), "--json"]) == 0
    cap = capsys.readouterr()
    printed = json.loads(cap.out)
    on_disk = json.loads((root / "stats" / "stats.json").read_text())
    assert printed == on_disk and printed["totals"]["objects"] == 18
    assert "objects per scene: mean 4.5" in cap.err and "class imbalance" in cap.err
    assert all((root / "stats" / name).is_file() for name in PLOT_FILES)
    assert main(["stats", str(root), "--plots-dir", str(tmp_path / "p"), "--no-plots"]) == 0
    assert (tmp_path / "p" / "stats.json").is_file() and not (tmp_path / "p" / "visibility.png").exists()
    assert capsys.readouterr().out == ""
    assert main(["stats", str(tmp_path / "nothing")]) == 2
    assert "not a folder" in capsys.readouterr().err
