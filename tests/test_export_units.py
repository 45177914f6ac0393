"""Engine-free parts of the exports: object points, density maps, exemplars, negatives, attribution,
the export folder's guards and the CLI's errors. A small synthetic dataset folder stands in for compose
(the real composed dataset is exercised in the other test_export_* files)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mixcount.annotate.coco import build_scene_coco, mask_to_rle
from mixcount.cli import main
from mixcount.dataset.attribution import collect_attribution, write_attribution
from mixcount.errors import ExportError
from mixcount.export.density_maps import adaptive_density_map, adaptive_sigmas, loca_object_density_map
from mixcount.export.fsc147 import corners, negative_class
from mixcount.export.object_points import decode_mask, object_point
from mixcount.export.outputs import ExportFolder
from mixcount.export.reader import ComposedDataset

# ------------------------------------------------------------------------------------------- points


def _ann(mask: np.ndarray, **extra) -> dict:
    rows, cols = np.nonzero(mask)
    bbox = [float(cols.min()), float(rows.min()), float(cols.max() - cols.min() + 1), float(rows.max() - rows.min() + 1)]
    return {"segmentation": mask_to_rle(mask), "bbox": bbox, **extra}


def test_point_is_deepest_visible_pixel_even_in_a_ring() -> None:
    yy, xx = np.mgrid[0:40, 0:50]
    r = np.hypot(xx - 25, yy - 20)
    ring = (r >= 8) & (r <= 14)  # the box centre (25, 20) lies in the hole
    x, y = object_point(_ann(ring))
    assert ring[int(y), int(x)]
    assert x % 1 == 0.5 and y % 1 == 0.5  # pixel centre
    assert 10 <= np.hypot(x - 25.5, y - 20.5) <= 13  # the middle of the band, not its edge


def test_point_of_a_square_is_its_centre_and_given_point_wins() -> None:
    sq = np.zeros((20, 20), bool)
    sq[4:11, 6:13] = True  # 7 x 7, centre pixel (9, 7)
    assert object_point(_ann(sq)) == (9.5, 7.5)
    assert object_point(_ann(sq, point=[6, 4])) == (6.5, 4.5)  # a given pixel index -> its centre
    assert decode_mask(mask_to_rle(sq)).sum() == 49


# ------------------------------------------------------------------------------------------- density


def test_adaptive_map_sums_to_count_at_the_border_and_follows_the_neighbour_rule() -> None:
    pts = [[0.2, 0.3], [63.9, 47.9], [30.5, 20.5], [34.5, 20.5]]
    dmap = adaptive_density_map(pts, 48, 64, fallback_window=10.0)
    assert dmap.dtype == np.float32 and dmap.shape == (48, 64)
    assert abs(float(dmap.sum()) - 4) < 1e-4
    # two dots 4 px apart, far from the rest: k-nearest mean distance (k = 3) / 4
    sig = adaptive_sigmas(np.array([[0.0, 0.0], [4.0, 0.0], [100.0, 0.0], [100.0, 8.0]]), 10.0)
    d1 = (4 + 100 + np.hypot(100, 8)) / 3
    assert sig[0] == pytest.approx(d1 / 4)
    assert adaptive_sigmas(np.array([[5.0, 5.0]]), 10.0)[0] == pytest.approx(2.5)  # lone dot: fallback / 4


def test_loca_map_uses_mean_exemplar_height_for_rows_and_width_for_cols() -> None:
    # a 384 x 384 image, one dot, exemplars 96 px wide and 24 px high -> in 512 px: 128 wide, 32 high
    boxes = [[10, 10, 106, 34]] * 3
    dmap = loca_object_density_map([[192.0, 192.0]], boxes, 384, 384)
    assert dmap.shape == (512, 512) and abs(float(dmap.sum()) - 1) < 1e-5
    rows, cols = np.mgrid[0:512, 0:512]
    mr, mc = (dmap * rows).sum(), (dmap * cols).sum()
    var_r, var_c = (dmap * (rows - mr) ** 2).sum(), (dmap * (cols - mc) ** 2).sum()
    assert np.sqrt(var_r) == pytest.approx(32 / 8, rel=0.05)
    assert np.sqrt(var_c) == pytest.approx(128 / 8, rel=0.05)
    assert (round(mr), round(mc)) == (256, 256)  # 192 * 512 / 384 = 256: the dot sits on pixel 256


def test_corners_are_fsc147_order() -> None:
    c = corners([1, 2, 30, 40])
    assert c == [[1, 2], [1, 40], [30, 40], [30, 2]]
    assert c[0] == [1, 2] and c[2] == [30, 40]  # what LOCA's [:, [0, 2], :] picks


# ------------------------------------------------------------------------------------ synthetic dataset


def _write_scene(root: Path, sid: str, ids: np.ndarray, objects: list[dict], cats: list[dict], split: str,
                 assets: list[dict]) -> None:
    d = root / "scenes" / sid
    d.mkdir(parents=True)
    coco = build_scene_coco(ids, objects, cats, image_id=1, file_name=f"scenes/{sid}/rgb.png", scene_id=sid)
    (d / "coco.json").write_text(json.dumps(coco))
    Image.new("RGB", (ids.shape[1], ids.shape[0]), (90, 120, 150)).save(d / "rgb.png")
    spec = {"classes": [{"object_id": c["object_id"]} for c in cats if not c.get("distractor")],
            "distractors": [{"object_id": c["object_id"]} for c in cats if c.get("distractor")],
            "container": None, "assets": assets, "environment": {"kind": "sky"}, "floor": {"material": {"kind": "procedural"}}}
    (d / "metadata.json").write_text(json.dumps({"scene_id": sid, "seed": 0, "split": split, "n_counted": 1,
                                                 "n_distractors": 0, "counts": {}, "spec": spec, "complete": True}))


@pytest.fixture
def synthetic(tmp_path: Path) -> Path:
    """Two scenes (train, test): class 40 with 2 instances, class 44 (same category) with 1, class 80 with
    4 (another category) and a distractor of category 12; one asset lacks a licence."""
    from mixcount.dataset.merge import finalize_dataset

    ids = np.zeros((60, 80), np.uint16)
    boxes = {1: (2, 2), 2: (20, 2), 3: (40, 2), 4: (2, 30), 5: (20, 30), 6: (40, 30), 7: (60, 30), 8: (60, 2)}
    for inst, (x, y) in boxes.items():
        ids[y:y + 10, x:x + 12] = inst
    cat_of = {1: 40, 2: 40, 3: 44, 4: 80, 5: 80, 6: 80, 7: 80, 8: 12}
    objects = [{"instance_id": i, "category_id": c, "role": "distractor" if c == 12 else "counted", "visibility": 0.9}
               for i, c in cat_of.items()]
    cats = [{"id": 12, "name": "mug", "object_id": 3, "category": "mug", "short": "mug", "concise": "white mug",
             "detailed": "white mug", "distractor": True},
            {"id": 40, "name": "red apple", "object_id": 10, "category": "apple", "short": "apple",
             "concise": "red apple", "detailed": "a red apple"},
            {"id": 44, "name": "green apple", "object_id": 11, "category": "apple", "short": "apple",
             "concise": "green apple", "detailed": "a green apple"},
            {"id": 80, "name": "pencil", "object_id": 20, "category": "pencil", "short": "pencil",
             "concise": "yellow pencil", "detailed": "a yellow pencil"}]
    lic = "CC-BY-SA-4.0 test licence"
    assets = [{"object_id": 3, "name": "Mug", "category": "mug", "source": "dtc", "source_id": "Mug_X", "license": lic},
              {"object_id": 10, "name": "Apple", "category": "apple", "source": "dtc", "source_id": "Apple_R", "license": lic},
              {"object_id": 11, "name": "Apple2", "category": "apple", "source": "folder", "source_id": "a2.glb", "license": None},
              {"object_id": 20, "name": "Pencil", "category": "pencil", "source": "dtc", "source_id": "Pencil_Y", "license": lic}]
    root = tmp_path / "ds"
    _write_scene(root, "scene_000000", ids, objects, cats, "train", assets)
    _write_scene(root, "scene_000001", ids, objects, cats, "test", assets)
    finalize_dataset(root, preview_scenes=0)
    return root


def test_exemplars_cycle_to_three_and_negative_prefers_same_category(synthetic: Path) -> None:
    ds = ComposedDataset(synthetic)
    img = next(ds.images("train"))
    assert img.classes() == [40, 44, 80]  # the distractor category is not a class
    ex = img.exemplars(44)
    assert len(ex) == 3 and len({a["id"] for a in ex}) == 1  # one instance, repeated
    assert [a["id"] for a in img.exemplars(40)][:2] == [a["id"] for a in img.exemplar_ranking(40)]
    assert negative_class(img, 40) == 44  # same category (INTRA) beats the more numerous pencil
    assert negative_class(img, 80) == 40  # no related class: the most numerous other, ties by id
    assert img.count(80) == 4


def test_attribution_lists_every_object_with_licence_and_flags_missing(synthetic: Path, tmp_path: Path) -> None:
    doc = collect_attribution(synthetic)
    assert [o["object_id"] for o in doc["objects"]] == [3, 10, 11, 20]
    by_id = {o["object_id"]: o for o in doc["objects"]}
    assert by_id[3]["roles"] == ["distractor"] and by_id[10]["roles"] == ["counted"]
    assert by_id[10]["source_id"] == "Apple_R" and by_id[10]["scenes"] == 2
    assert len(doc["licenses"]) == 1 and doc["licenses"][0]["objects"] == 3
    assert doc["missing_license"] == [11]
    only_one = collect_attribution(synthetic, ["scene_000001"])
    assert only_one["scenes"] == 1 and by_id[10]["license_id"] == only_one["objects"][1]["license_id"]
    write_attribution(synthetic, tmp_path / "attr")
    md = (tmp_path / "attr" / "ATTRIBUTION.md").read_text()
    assert "CC-BY-SA-4.0 test licence" in md and "Apple_R" in md and "No licence was recorded" in md
    assert json.loads((tmp_path / "attr" / "ATTRIBUTION.json").read_text()) == doc


def test_synthetic_fsc147_split_filter_and_prune(synthetic: Path, tmp_path: Path) -> None:
    out = tmp_path / "fsc"
    assert main(["export", str(synthetic), "--format", "fsc147", "--out", str(out)]) == 0
    splits = json.loads((out / "Train_Test_Val_FSC_147.json").read_text())
    assert len(splits["train"]) == 3 and len(splits["test"]) == 3 and splits["val"] == []
    ann = json.loads((out / "annotation_FSC147_384.json").read_text())
    assert ann["scene_000000_44.jpg"]["negative_prompt"] == "red apple"
    assert len(ann["scene_000000_44.jpg"]["box_examples_coordinates"]) == 3
    # exporting only test into the same folder leaves exactly a fresh test-only export
    assert main(["export", str(synthetic), "--format", "fsc147", "--out", str(out), "--split", "test"]) == 0
    assert sorted(p.name for p in (out / "images_384_VarV2").iterdir()) == sorted(
        json.loads((out / "Train_Test_Val_FSC_147.json").read_text())["test"])
    assert not (out / "instances_train.json").exists() and (out / "instances_test.json").exists()
    assert json.loads((out / "mixcount_export.json").read_text())["options"]["split"] == "test"


def test_export_guards(synthetic: Path, tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="inside the dataset"):
        ExportFolder(synthetic / "exports", synthetic, "fsc147")
    assert not (synthetic / "exports").exists()
    ExportFolder(tmp_path / "e", synthetic, "hf").finish(synthetic, {}, {})
    with pytest.raises(ExportError, match="holds a 'hf' export"):
        ExportFolder(tmp_path / "e", synthetic, "countgd")
    with pytest.raises(ExportError, match="not a composed mixcount dataset"):
        ComposedDataset(tmp_path)
    with pytest.raises(ExportError, match="no split 'val'"):
        ComposedDataset(synthetic).select_splits("val")


def test_cli_reports_errors_and_never_writes_into_the_dataset(synthetic: Path, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", str(synthetic), "--format", "yolo", "--out", str(tmp_path / "x")]) == 2
    assert "unknown export format 'yolo'" in capsys.readouterr().err
    assert main(["export", str(synthetic), "--format", "hf", "--caption-tier", "long", "--out", str(tmp_path / "x")]) == 2
    assert "unknown caption tier 'long'" in capsys.readouterr().err
    assert main(["export", str(synthetic), "--format", "countgd", "--out", str(synthetic / "cg")]) == 2
    assert not (synthetic / "cg").exists()
    (synthetic / "scenes" / "scene_000001" / "rgb.png").unlink()
    assert main(["export", str(synthetic), "--format", "countgd", "--out", str(tmp_path / "cg")]) == 2
    assert "rgb.png: image of instances_test.json image 1 is missing" in capsys.readouterr().err
