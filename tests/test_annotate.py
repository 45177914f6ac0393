"""Annotation and dataset code on synthetic arrays: no bpy, fast."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mixcount.annotate.coco import (bbox_of, build_scene_coco, category_id, class_map, counts_per_category,
                                    exemplar_score, mask_to_rle)
from mixcount.annotate.raster import PinholeCamera, rasterize_triangles, silhouette


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    f = target - eye
    f /= np.linalg.norm(f)
    right = np.cross(f, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, -f, eye
    return m


def test_rasterize_square_covers_exact_pixel_centres() -> None:
    # square from (2.2, 3.1) to (7.6, 6.9): centres x in {2.5..7.5} (6), y in {3.5..6.5} (4)
    pts = np.array([[2.2, 3.1], [7.6, 3.1], [7.6, 6.9], [2.2, 6.9]])
    mask = rasterize_triangles(pts, np.array([[0, 1, 2], [0, 2, 3]]), (10, 12))
    assert mask.sum() == 24
    assert mask[3:7, 2:8].all()


def test_rasterize_large_and_clipped_triangles() -> None:
    pts = np.array([[-50.0, -50.0], [300.0, -50.0], [-50.0, 300.0]])
    mask = rasterize_triangles(pts, np.array([[0, 1, 2]]), (100, 120))
    # the triangle covers x + y < 250 in pixel-centre coordinates
    yy, xx = np.mgrid[0:100, 0:120]
    expect = (xx + 0.5) + (yy + 0.5) < 250.0
    assert (mask == expect).all()


def test_silhouette_of_a_cube_matches_convex_hull_of_its_projection() -> None:
    from matplotlib.path import Path as MplPath
    from scipy.spatial import ConvexHull

    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    rot = np.array([[0.8, -0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    verts = corners @ rot.T + [0.3, -0.2, 1.0]
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    tris = np.array([[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads])
    cam = PinholeCamera.from_physical(35.0, 36.0, 96, 80, _look_at(np.array([6.0, 4.0, 5.0]), np.array([0.3, -0.2, 1.0])))
    mask = silhouette(cam, verts, tris)
    pix, depth = cam.project(verts)
    assert (depth > 0).all()
    hull = pix[ConvexHull(pix).vertices]
    yy, xx = np.mgrid[0:80, 0:96]
    centres = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], axis=1)
    expect = MplPath(hull).contains_points(centres).reshape(80, 96)
    assert mask.sum() > 200
    assert (mask != expect).sum() <= 2  # only centres lying on the hull boundary may differ


def test_category_ids_are_deterministic_and_distinct() -> None:
    assert category_id(7) == 28 and category_id(7, "larger") == 29 and category_id(7, "smaller") == 30
    assert len({category_id(o, q) for o in range(1, 50) for q in (None, "larger", "smaller")}) == 147
    with pytest.raises(ValueError):
        category_id(1, "huge")
    with pytest.raises(ValueError):
        category_id(20000)


def test_exemplar_score_formula() -> None:
    assert exemplar_score(1.0, 100, 100, False) == 1.0
    assert exemplar_score(0.8, 100, 100, False) == pytest.approx(0.8)
    assert exemplar_score(1.0, 25, 100, False) == pytest.approx(0.5)
    assert exemplar_score(1.0, 400, 100, True) == pytest.approx(0.5)
    assert 0.0 <= exemplar_score(1.7, 1, 1e9, True) <= 1.0


def _synthetic_ids() -> np.ndarray:
    ids = np.zeros((40, 50), dtype=np.int32)
    ids[2:10, 3:12] = 1
    ids[20:30, 5:9] = 2
    ids[12:18, 30:49] = 3  # distractor
    ids[35:40, 45:50] = 4  # counted, touches the border
    return ids


def test_scene_coco_masks_boxes_and_counts() -> None:
    from pycocotools import mask as mask_util

    ids = _synthetic_ids()
    objects = [
        {"instance_id": 1, "category_id": 40, "role": "counted", "visibility": 1.0},
        {"instance_id": 2, "category_id": 40, "role": "counted", "visibility": 0.7},
        {"instance_id": 3, "category_id": 12, "role": "distractor", "visibility": 0.9},
        {"instance_id": 4, "category_id": 41, "role": "counted", "visibility": 1.0},
        {"instance_id": 9, "category_id": 41, "role": "counted", "visibility": 0.0},  # not visible: no annotation
    ]
    cats = [{"id": 12, "name": "d"}, {"id": 40, "name": "a"}, {"id": 41, "name": "b"}]
    coco = build_scene_coco(ids, objects, cats, image_id=5, file_name="scenes/s/rgb.png", scene_id="s")
    anns = {a["id"]: a for a in coco["annotations"]}
    assert sorted(anns) == [1, 2, 3, 4]
    for inst, a in anns.items():
        m = mask_util.decode(a["segmentation"]).astype(bool)
        assert (m == (ids == inst)).all()
        assert a["area"] == int((ids == inst).sum())
        assert a["image_id"] == 5 and a["iscrowd"] == 0
    assert anns[1]["bbox"] == [3.0, 2.0, 9.0, 8.0]
    assert anns[3]["is_distractor"] and not anns[1]["is_distractor"]
    assert anns[4]["exemplar_score"] == pytest.approx(0.5)  # border-touching
    assert counts_per_category(coco) == {40: 2, 41: 1}
    ex = {e["category_id"]: e["annotation_ids"] for e in coco["images"][0]["exemplars"]}
    assert ex[40][0] == 1 and set(ex) == {40, 41}
    cm = class_map(ids, {1: 40, 2: 40, 3: 12, 4: 41})
    assert cm.dtype == np.uint16 and cm[5, 5] == 40 and cm[15, 40] == 12 and cm[0, 0] == 0
    assert bbox_of(np.zeros((3, 3), bool)) == [0.0, 0.0, 0.0, 0.0]
    rle = mask_to_rle(ids == 2)
    assert isinstance(rle["counts"], str) and rle["size"] == [40, 50]


def test_merge_renumbers_and_loads_with_pycocotools(tmp_path: Path) -> None:
    from pycocotools.coco import COCO

    from mixcount.dataset.merge import finalize_dataset

    ids = _synthetic_ids()
    objects = [{"instance_id": 1, "category_id": 40, "role": "counted", "visibility": 1.0},
               {"instance_id": 3, "category_id": 12, "role": "distractor", "visibility": 1.0}]
    cats = [{"id": 12, "name": "d"}, {"id": 40, "name": "a"}]
    from PIL import Image

    for k in range(2):
        sid = f"scene_{k:06d}"
        d = tmp_path / "scenes" / sid
        d.mkdir(parents=True)
        coco = build_scene_coco(ids, objects, cats, image_id=1, file_name=f"scenes/{sid}/rgb.png", scene_id=sid)
        (d / "coco.json").write_text(json.dumps(coco))
        Image.new("RGB", (50, 40), (k * 100, 0, 0)).save(d / "rgb.png")
        (d / "metadata.json").write_text(json.dumps({"scene_id": sid, "seed": k, "split": "val", "n_counted": 1,
                                                     "n_distractors": 1, "counts": {"40": 1},
                                                     "timings": {"total": 1.0 + k}, "complete": True}))
    (tmp_path / "scenes" / "scene_000009").mkdir()  # incomplete: ignored
    res = finalize_dataset(tmp_path, config={"x": 1}, config_hash="abc", preview_scenes=16)
    coco = COCO(res["annotations"]["val"])
    assert len(coco.getImgIds()) == 2 and len(coco.getAnnIds()) == 4
    assert sorted(a["id"] for a in coco.dataset["annotations"]) == [1, 2, 3, 4]
    assert {a["image_id"] for a in coco.dataset["annotations"]} == {1, 2}
    assert coco.dataset["images"][1]["exemplars"][0]["annotation_ids"] == [3]
    summary = json.loads((tmp_path / "dataset.json").read_text())
    assert summary["counts"]["scenes"] == 2 and summary["splits"]["val"]["counted_objects"] == 2
    assert summary["timings_mean_s"]["total"] == 1.5
    assert (tmp_path / "preview.png").exists()
