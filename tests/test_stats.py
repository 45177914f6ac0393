"""Dataset statistics on a synthetic dataset folder: hand-computed numbers, stats.json, PNGs that open."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from PIL import Image

from mixcount.cli import main
from mixcount.errors import GroundTruthError
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
    # one class count: category ids with a counted annotation (1, 2, 4 in train; 5 in test), not the 6 the
    # COCO files list (3 and 6 are distractors only)
    assert s["totals"] == {"images": 4, "scenes": 3, "objects": 18, "distractors": 3, "categories": 4}
    assert s["distinct_categories"] == 6
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
    out = capsys.readouterr().out  # without --json the readable summary is the result, on stdout
    assert "objects per scene: mean 4.5" in out and not out.lstrip().startswith("{")
    assert main(["stats", str(tmp_path / "nothing")]) == 2
    assert "not a folder" in capsys.readouterr().err


def _obj(role: str, class_index: int, category_id: int, reason: str | None = None) -> dict:
    return {"role": role, "class_index": class_index, "category_id": category_id,
            "status": "kept" if reason is None else "dropped", "reason": reason}


def write_scene_meta(root: Path, scene_id: str, *, container: bool, classes: list[tuple[int, str, int]],
                     objects: list[dict], **extra: object) -> None:
    """A scene's metadata.json as the scene writer lays it out (only the keys density reads)."""
    d = root / "scenes" / scene_id
    d.mkdir(parents=True)
    meta = {"scene_id": scene_id, "seed": int(scene_id[-6:]), "objects": objects,
            "categories": [{"id": cid, "name": name} for _, name, cid in classes],
            "spec": {"container": {"object_id": 9} if container else None,
                     "classes": [{"class_index": ci, "name": name, "size_qualifier": None,
                                  "count": sum(o["class_index"] == ci and o["role"] == "counted" for o in objects)}
                                 for ci, name, _ in classes]},
            **extra}
    (d / "metadata.json").write_text(json.dumps(meta))


def write_density_dataset(root: Path) -> Path:
    """LAYOUT's COCO files plus metadata for scene_000000 (container) and scene_000001 (none); scene_000002
    has none. scene_000000: class 0 keeps 2 of 3 (1 occluded), class 1 keeps 0 of 2 (origin_outside_frame,
    below_floor), 1 of 2 distractors kept (1 flung_out). scene_000001: class 0 keeps 4 of 4, class 1 loses
    its one instance (occluded); its metadata carries the scene writer's classes_without_instances."""
    write_dataset(root)
    write_scene_meta(root, "scene_000000", container=True, classes=[(0, "cup", 4), (1, "die", 8)], objects=[
        _obj("counted", 0, 4), _obj("counted", 0, 4), _obj("counted", 0, 4, "occluded"),
        _obj("counted", 1, 8, "origin_outside_frame"), _obj("counted", 1, 8, "below_floor"),
        _obj("distractor", -1, 12), _obj("distractor", -1, 16, "flung_out")])
    written = [{"class_index": 1, "category_id": 20, "name": "pen (from the writer)", "spawned": 1,
                "reasons": {"occluded": 1}}]
    write_scene_meta(root, "scene_000001", container=False, classes=[(0, "key", 24), (1, "pen", 20)],
                     objects=[_obj("counted", 0, 24) for _ in range(4)] + [_obj("counted", 1, 20, "occluded")],
                     classes_without_instances=written)
    return root


def test_density_kept_vs_spawned_from_scene_metadata(tmp_path: Path) -> None:
    d = compute_stats(write_density_dataset(tmp_path / "ds"))["density"]
    assert d["scenes_without_metadata"] == ["scene_000002"]
    s0, s1 = d["scenes"]
    assert (s0["split"], s0["container"], s0["counted_spawned"], s0["counted_kept"]) == ("train", True, 5, 2)
    assert (s0["distractors_spawned"], s0["distractors_kept"]) == (2, 1)
    assert s0["counted_drops"] == {"below_floor": 1, "occluded": 1, "origin_outside_frame": 1}
    assert s0["distractor_drops"] == {"flung_out": 1}
    assert s0["classes_without_instances"] == [{"class_index": 1, "category_id": 8, "name": "die", "spawned": 2,
                                                "reasons": {"below_floor": 1, "origin_outside_frame": 1}}]
    assert s1["classes_without_instances"][0]["name"] == "pen (from the writer)"  # the writer's key is preferred
    t = d["summary"]
    assert (t["scenes"], t["counted_spawned"], t["counted_kept"], t["retention"]) == (2, 10, 6, 0.6)
    assert t["mean_counted_kept"] == 3.0
    assert t["container"] == {"scenes": 1, "counted_spawned": 5, "counted_kept": 2, "retention": 0.4, "mean_counted_kept": 2.0}
    assert t["no_container"]["retention"] == 0.8
    assert (t["distractors_spawned"], t["distractors_kept"], t["mean_distractors_kept"]) == (2, 1, 0.5)
    assert t["counted_drops"] == {"below_floor": 1, "occluded": 2, "origin_outside_frame": 1}
    assert (t["lost_off_floor"], t["lost_off_floor_share"]) == (2, round(2 / 12, 4))  # of 12 spawned bodies
    assert (t["classes"], t["classes_without_instances"]) == (4, 2)
    assert t["classes_without_instances_reasons"] == {"below_floor": 1, "occluded": 1, "origin_outside_frame": 1}
    assert d["kept_per_scene"]["histogram"] == {"edges": [0.0, 10.0], "counts": [2]}
    assert d["retention_per_scene"]["mean"] == pytest.approx((0.4 + 0.8) / 2)


def test_density_without_scenes_folder_and_broken_metadata(tmp_path: Path) -> None:
    root = write_dataset(tmp_path / "ds")
    s = compute_stats(root)
    assert s["density"] is None
    paths = write_plots(s, tmp_path / "plots")  # a "no data" kept_vs_spawned.png
    assert (tmp_path / "plots" / "kept_vs_spawned.png") in paths
    (root / "scenes" / "scene_000000").mkdir(parents=True)
    (root / "scenes" / "scene_000000" / "metadata.json").write_text('{"scene_id": "scene_000000"}')
    with pytest.raises(GroundTruthError, match="scene_000000/metadata.json: not a scene's metadata.json"):
        compute_stats(root)


def test_cli_stats_reports_kept_vs_spawned_and_empty_classes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = write_density_dataset(tmp_path / "ds")
    capsys.readouterr()
    assert main(["stats", str(root)]) == 0
    err = capsys.readouterr().out  # the summary is the result: stdout
    assert "kept vs spawned counted objects: 6 of 10 (60 %), mean 3.0 kept per scene" in err
    assert "container scenes 40 % (1), without 80 % (1)" in err
    assert "distractors: 1 of 2 kept" in err and "lost off the floor 2 (17 % of spawned bodies)" in err
    assert "classes with no visible instance: 2 of 4" in err
    assert "scene_000000: class 1 'die' (category 8), 2 spawned, none kept: below_floor 1, origin_outside_frame 1" in err
    assert "1 scene(s) of the COCO files have no metadata.json" in err
    with Image.open(root / "stats" / "kept_vs_spawned.png") as im:
        assert im.format == "PNG" and len(set(im.convert("L").getdata())) > 2
    on_disk = json.loads((root / "stats" / "stats.json").read_text())
    assert on_disk["density"]["summary"]["counted_kept"] == 6


@pytest.mark.blender
@pytest.mark.slow
def test_density_of_a_real_composed_dataset_agrees_with_its_coco(composed_dataset: Path) -> None:
    """Independent of the objects list: kept counts equal the merged COCO's annotations per scene,
    spawned counts the spec's class counts, and a class is empty exactly when COCO has none of it."""
    from collections import Counter

    stats = compute_stats(composed_dataset)
    d = stats["density"]
    coco = json.loads((composed_dataset / "annotations" / "instances_train.json").read_text())
    summary = json.loads((composed_dataset / "dataset.json").read_text())
    # one class count: stats and dataset.json's summary say the same number of the same thing
    assert {k: v["categories"] for k, v in stats["splits"].items()} == {
        k: v["categories"] for k, v in summary["splits"].items()}
    assert stats["totals"]["categories"] == len({a["category_id"] for a in coco["annotations"] if not a["is_distractor"]})
    scene_of = {img["id"]: img["scene_id"] for img in coco["images"]}
    counted = Counter(scene_of[a["image_id"]] for a in coco["annotations"] if not a["is_distractor"])
    dist = Counter(scene_of[a["image_id"]] for a in coco["annotations"] if a["is_distractor"])
    cats = {(scene_of[a["image_id"]], a["category_id"]) for a in coco["annotations"] if not a["is_distractor"]}
    assert len(d["scenes"]) == 2 and d["scenes_without_metadata"] == []
    for row in d["scenes"]:
        meta = json.loads((composed_dataset / "scenes" / row["scene_id"] / "metadata.json").read_text())
        assert row["counted_kept"] == counted[row["scene_id"]] == meta["n_counted"]
        assert row["distractors_kept"] == dist[row["scene_id"]]
        assert row["counted_spawned"] == sum(c["count"] for c in meta["spec"]["classes"])
        assert row["distractors_spawned"] == len(meta["spec"]["distractors"])
        assert sum(row["counted_drops"].values()) == row["counted_spawned"] - row["counted_kept"]
        class_cat = {o["class_index"]: o["category_id"] for o in meta["objects"] if o["role"] == "counted"}
        empty = {c["class_index"] for c in row["classes_without_instances"]}
        assert empty == {ci for ci, cid in class_cat.items() if (row["scene_id"], cid) not in cats}
    assert d["summary"]["counted_kept"] == sum(counted.values())


def test_cli_stats_counts_regenerated_scenes_by_rule_and_failures_by_cause(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = write_dataset(tmp_path / "ds")
    rejected = root / "scenes" / ".rejected"
    rejected.mkdir(parents=True)
    why = "no counted object kept: all 12 dropped: 12 occluded (visibility 0.00, 0.60 needed)"
    (rejected / "scene_000007.json").write_text(json.dumps({"scene_id": "scene_000007", "seed": 7, "status": "empty",
                                                            "rule": "empty: occluded", "why": why}))
    (rejected / "scene_000008.json").write_text(json.dumps({"scene_id": "scene_000008", "seed": 8, "status": "empty",
                                                            "rule": "empty: occluded", "why": why}))
    (rejected / "scene_000009.json").write_text(json.dumps({"scene_id": "scene_000009", "status": "rejected"}))  # old
    (root / "logs").mkdir()
    lines = [{"scene_id": "scene_000003", "seed": 3, "cause": "worker SIGSEGV"},
             {"scene_id": "scene_000004", "seed": 4, "cause": "worker SIGSEGV"},
             {"scene_id": "scene_000005", "seed": 5, "cause": "timeout"}]
    (root / "logs" / "failures.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines) + '{"cut by a kill')
    capsys.readouterr()
    assert main(["stats", str(root), "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "scenes regenerated (scenes/.rejected): 3 (empty: occluded 2, rejected: no reason recorded 1)" in out
    assert f"scene_000007: {why}" in out
    assert "scene failures (logs/failures.jsonl): 3 (worker SIGSEGV 2, timeout 1)" in out
    assert "4 categories (category ids with a counted object; the COCO files list 6 category entries" in out
    health = json.loads((root / "stats" / "stats.json").read_text())["thrown_away"]
    assert health["failures"]["by_cause"] == {"worker SIGSEGV": 2, "timeout": 1}
    assert health["regenerated"]["by_rule"] == {"empty: occluded": 2, "rejected: no reason recorded": 1}
