"""Count targets read from a benchmark's own annotation file (issue 48): a COCO instances file (per image, and
per image and category for the class split; crowd regions and distractors not counted), FSC-147's annotation
JSON (``points`` per image), a real mixcount dataset's own ``instances_train.json``, and files refused in one
line that never echoes them, before compose writes anything."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest

from mixcount.cli import main
from mixcount.counts.targets import draw_total, parse_count_target, split_total
from mixcount.errors import ConfigError


def _coco(path: Path) -> Path:
    """Image 1: 5 of category 1 and 2 of category 2 counted (+ a distractor, a crowd region); image 2: none
    counted (only a distractor); image 3: 10 of category 1; an annotation of an image the file does not list."""
    anns = [{"image_id": 1, "category_id": 1} for _ in range(5)]
    anns += [{"image_id": 1, "category_id": 2} for _ in range(2)]
    anns += [{"image_id": 1, "category_id": 3, "is_distractor": True},
             {"image_id": 1, "category_id": 1, "iscrowd": 1},
             {"image_id": 2, "category_id": 3, "is_distractor": True},
             {"image_id": 99, "category_id": 1}]
    anns += [{"image_id": 3, "category_id": 1} for _ in range(10)]
    doc = {"images": [{"id": 1}, {"id": 2}, {"id": 3}], "categories": [{"id": c} for c in (1, 2, 3)],
           "annotations": [{**a, "id": k + 1} for k, a in enumerate(anns)]}
    path.write_text(json.dumps(doc))
    return path


def test_coco_file_gives_counts_and_class_ratios(tmp_path: Path) -> None:
    dist = parse_count_target(f"histogram:{_coco(tmp_path / 'instances_val.json')}")
    assert dist.kind == "histogram" and dist.counts == (7, 10) and dist.weights == (1.0, 1.0)
    assert sorted(img.counts for img in dist.images) == [(5, 2), (10,)]
    assert {draw_total(dist, s) for s in range(100)} == {7, 10}
    # two classes: the image's own per-category counts, in either order; its ratio recorded
    splits = {tuple(split_total(dist, s, 7, 2)[0]) for s in range(60)}
    assert splits == {(5, 2), (2, 5)}
    assert split_total(dist, 0, 7, 2)[1] == pytest.approx(2.5)
    # three classes: the image's ratio (largest / smallest) over a geometric split
    counts, ratio = split_total(dist, 4, 7, 3)
    assert sum(counts) == 7 and min(counts) >= 1 and ratio == pytest.approx(2.5)
    # the single-category image's total: stars-and-bars, no ratio
    counts, ratio = split_total(dist, 4, 10, 2)
    assert sum(counts) == 10 and ratio is None
    # an explicit imbalance outranks the file's ratios
    counts, ratio = split_total(parse_count_target(f"histogram:{tmp_path / 'instances_val.json'},imbalance:1-1"),
                                4, 7, 2)
    assert ratio == 1.0 and sorted(counts) == [3, 4]


def test_a_coco_files_counts_go_to_classes_by_object_size(tmp_path: Path) -> None:
    """Image 1 holds 30 small objects (area 40 px, no area key: bbox) and 10 large ones (area 900): the
    scene's class of the largest objects takes 10, whatever the class order; the smaller class 30."""
    anns = [{"image_id": 1, "category_id": 1, "bbox": [0, 0, 5, 8]} for _ in range(30)]
    anns += [{"image_id": 1, "category_id": 2, "area": 900.0, "bbox": [0, 0, 30, 30]} for _ in range(10)]
    path = tmp_path / "instances_val.json"
    path.write_text(json.dumps({"images": [{"id": 1}], "categories": [{"id": 1}, {"id": 2}],
                                "annotations": [{**a, "id": k + 1} for k, a in enumerate(anns)]}))
    dist = parse_count_target(f"histogram:{path}")
    assert dist.images[0].areas == (40.0, 900.0)
    for seed in range(20):
        assert split_total(dist, seed, 40, 2, [0.5, 0.05])[0] == [10, 30]
        assert split_total(dist, seed, 40, 2, [0.05, 0.5])[0] == [30, 10]
    # without the classes' areas (or in a file without areas) either order, as before
    assert {tuple(split_total(dist, s, 40, 2)[0]) for s in range(40)} == {(10, 30), (30, 10)}


def test_fsc147_file_gives_points_per_image(tmp_path: Path) -> None:
    doc = {f"{i}.jpg": {"H": 384, "W": 576, "box_examples_coordinates": [[[0, 0], [0, 9], [9, 9], [9, 0]]] * 3,
                        "points": [[float(k), 2.0 * k] for k in range(n)], "ratio_h": 1.0, "ratio_w": 1.0}
           for i, n in enumerate([12, 12, 7, 3731, 0])}
    path = tmp_path / "annotation_FSC147_384.json"
    path.write_text(json.dumps(doc, indent=1))  # written over many lines, as the benchmark's file is
    dist = parse_count_target(f"histogram:{path}")
    assert dist.counts == (7, 12, 3731) and dist.weights == (1.0, 2.0, 1.0)  # the empty image left out
    assert all(len(img.counts) == 1 for img in dist.images)
    assert split_total(dist, 1, 12, 3)[1] is None  # one class per image: stars-and-bars


@pytest.mark.parametrize("content, message", [
    ('{"images": [{"id": 1}], "annotations": [{"image_id": 1, "category_id": 1, "is_distractor": true}], '
     '"categories": [], "MARKER": "' + "x" * 5000 + '"}', "a COCO file with no image with a counted annotation"),
    ('{"a.jpg": {"points": [], "MARKER": "' + "x" * 5000 + '"}}', "a FSC-147 file with no image with 'points'"),
    ('{"images": {"MARKER": 1}, "annotations": []}', "needs 'images' and 'annotations' lists"),
    ('[{"MARKER": "' + "x" * 5000 + '"}]', "neither a COCO instances file"),
    ('{"MARKER": ' + "1" * 5000, "not (valid|usable) JSON"),
])
def test_bad_json_refused_in_one_line(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(ConfigError, match=message) as err:
        parse_count_target(f"histogram:{path}")
    text = str(err.value)
    assert "\n" not in text and "MARKER" not in text and len(text) < 300 and str(path) in text


def test_long_bad_text_line_is_cut(tmp_path: Path) -> None:
    path = tmp_path / "counts.txt"
    path.write_text("MARKER " + "y" * 600_000 + "\n")
    with pytest.raises(ConfigError, match=r"counts.txt:1: expected 'count weight'") as err:
        parse_count_target(f"histogram:{path}")
    assert len(str(err.value)) < 300 and "600007 characters" in str(err.value)


@pytest.fixture(scope="module")
def demo_db(tmp_path_factory, demo_catalog_copy):
    return demo_catalog_copy(tmp_path_factory.mktemp("count_files"), 12)


def test_compose_refuses_a_file_with_no_usable_image_before_writing(demo_db, capsys, tmp_path: Path) -> None:
    bad = tmp_path / "empty_coco.json"
    bad.write_text(json.dumps({"images": [{"id": 1, "file_name": "MARKER.jpg"}], "annotations": [],
                               "categories": [{"id": 1, "name": "MARKER"}]}))
    rc = main(["--db", str(demo_db / "catalog.db"), "--config", "quick", "compose", "--n", "1",
               "--counts", f"histogram:{bad}", "--out", str(tmp_path / "out")])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert "no image with a counted annotation" in err and "MARKER" not in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_compose_plans_from_a_coco_file(demo_db, capsys, tmp_path: Path) -> None:
    path = _coco(tmp_path / "instances_val.json")
    rc = main(["--db", str(demo_db / "catalog.db"), "--config", "quick", "--set", "scene.n_classes=[2,2]",
               "compose", "--n", "6", "--dry-run", "--json", "--counts", f"histogram:{path}",
               "--out", str(tmp_path / "out")])
    assert rc == 0, capsys.readouterr().err
    planned = json.loads(capsys.readouterr().out)
    assert len(planned) == 6 and not (tmp_path / "out").exists()
    dist = parse_count_target(f"histogram:{path}")
    for scene in planned:  # spawned for a drawn total of the file's (plus the margin and the reserve)
        assert draw_total(dist, scene["seed"]) in (7, 10) and scene["n_counted"] >= draw_total(dist, scene["seed"])


@pytest.mark.blender
def test_a_mixcount_dataset_file_gives_its_counted_objects(composed_dataset: Path) -> None:
    path = composed_dataset / "annotations" / "instances_train.json"
    doc = json.loads(path.read_text())
    per_image = Counter(a["image_id"] for a in doc["annotations"] if not a.get("is_distractor", False))
    assert any(a.get("is_distractor") for a in doc["annotations"])  # the file does hold distractors
    dist = parse_count_target(f"histogram:{path}")
    assert Counter(dict(zip(dist.counts, dist.weights))) == Counter(Counter(per_image.values()))
    metas = [json.loads(p.read_text()) for p in sorted((composed_dataset / "scenes").glob("scene_*/metadata.json"))]
    assert sorted(sum(img.counts) for img in dist.images) == sorted(m["n_counted"] for m in metas)


def test_stats_compare_the_kept_counts_with_the_files_histogram(tmp_path: Path) -> None:
    """`mixcount stats` reads the file the run named again: KS distance against its histogram, per bin."""
    from mixcount.evaluate.count_stats import count_lines, dataset_count_stats

    path = _coco(tmp_path / "instances_val.json")  # totals 7 and 10, one image each
    text = f"histogram:{path}"
    for i, (target, kept) in enumerate([(7, 7), (10, 10), (10, 9), (7, 7)]):
        d = tmp_path / "ds" / "scenes" / f"scene_{i:06d}"
        d.mkdir(parents=True)
        meta = {"scene_id": d.name, "seed": i, "counts": {"4": kept}, "diagnostics": [],
                "objects": [{"role": "counted", "status": "kept"}] * kept,
                "count_target": {"total": target, "per_class": {"4": target}, "distribution": text, "imbalance": None}}
        (d / "metadata.json").write_text(json.dumps(meta))
    stats = dataset_count_stats(tmp_path / "ds")
    assert stats is not None and stats["ks_against"] == "distribution" and stats["distributions"] == [text]
    # kept 7, 7, 9, 10 against half 7, half 10: the largest CDF gap is at 9 (0.75 against 0.5)
    assert stats["ks_distance"] == pytest.approx(0.25)
    assert stats["exact"] == 3 and sum(stats["bins"]["kept"]) == 4
    assert any("KS distance 0.25" in line for line in count_lines(stats))
    path.unlink()  # the file gone: against the drawn targets instead
    assert dataset_count_stats(tmp_path / "ds")["ks_against"] != "distribution"
