"""Annotation and dataset code on synthetic arrays: no bpy, fast."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mixcount.annotate.coco import (
    bbox_of,
    build_scene_coco,
    category_id,
    class_map,
    counts_per_category,
    exemplar_score,
    mask_to_rle,
)
from mixcount.annotate.raster import PinholeCamera, placed_silhouette, rasterize_triangles, silhouette


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


def _centres_inside_brute_force(pts: np.ndarray, tris: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Every pixel centre in a triangle's box against the triangle (both windings, edges included): the
    rasteriser's rule (the box matters only for a degenerate triangle, whose edge functions are all 0)."""
    h, w = shape
    cy, cx = np.mgrid[0:h, 0:w] + 0.5
    mask = np.zeros(shape, dtype=bool)
    for t in tris:
        (ax, ay), (bx, by), (qx, qy) = pts[t]
        e0 = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        e1 = (qx - bx) * (cy - by) - (qy - by) * (cx - bx)
        e2 = (ax - qx) * (cy - qy) - (ay - qy) * (cx - qx)
        box = (cx >= min(ax, bx, qx)) & (cx <= max(ax, bx, qx)) & (cy >= min(ay, by, qy)) & (cy <= max(ay, by, qy))
        mask |= box & (((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0)))
    return mask


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dense_sub_pixel_mesh_marks_exactly_the_centres_a_brute_force_finds(seed: int) -> None:
    # a capture seen small: most triangles lie between pixel centres (culled by cell before the box
    # arithmetic); some corners sit exactly on centre lines, some triangles reach past the frame, a few
    # are large (the bucketed windows)
    rng = np.random.default_rng(seed)
    h, w = 23, 31
    base = rng.uniform([-4, -4], [w + 4, h + 4], size=(600, 2))
    pts = np.concatenate([base, base + rng.normal(scale=0.4, size=base.shape),
                          base + rng.normal(scale=0.4, size=base.shape)])
    on = rng.random(len(pts)) < 0.2
    pts[on] = np.floor(pts[on]) + 0.5  # corners exactly on a centre line in both axes
    tris = np.stack([np.arange(600), np.arange(600, 1200), np.arange(1200, 1800)], axis=1)
    big = rng.integers(0, len(pts), size=(6, 3))
    tris = np.concatenate([tris, big])
    got = rasterize_triangles(pts, tris, (h, w))
    assert got.sum() > 0
    assert (got == _centres_inside_brute_force(pts, tris, (h, w))).all()


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


def test_placed_silhouette_equals_silhouette_of_the_world_vertices() -> None:
    """The scene job's path (local rows + pose, one transform into camera space) gives the same mask as
    projecting world vertices, also for a mesh partly behind the camera and partly outside the frame."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    local = np.asarray(mesh.vertices, dtype=np.float64) * [1.0, 0.6, 0.4]
    tris = np.asarray(mesh.faces, dtype=np.int64)
    cam = PinholeCamera.from_physical(35.0, 36.0, 160, 120, _look_at(np.array([4.0, -3.0, 2.5]), np.zeros(3)))
    rng = np.random.default_rng(5)
    for k in range(6):
        q = rng.normal(size=4)
        pose = np.eye(4)
        pose[:3, :3] = trimesh.transformations.quaternion_matrix(q / np.linalg.norm(q))[:3, :3] * rng.uniform(0.5, 2.0)
        pose[:3, 3] = rng.uniform(-2.0, 2.0, size=3) if k < 5 else [4.0, -3.0, 2.5]  # the last one around the camera
        world = local @ pose[:3, :3].T + pose[:3, 3]
        expect = silhouette(cam, world, tris)
        got = placed_silhouette(cam, np.ascontiguousarray(local.T), np.ascontiguousarray(tris.T), pose)
        assert got.shape == (120, 160) and (k == 5 or expect.sum() > 0)
        assert np.array_equal(got, expect), (k, int((got != expect).sum()))


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


def test_interior_point_lies_deep_inside_the_visible_pixels() -> None:
    from mixcount.annotate.interior_points import interior_point

    ring = np.zeros((30, 30), bool)  # a ring: its centroid (15, 15) is not on the mask
    ring[5:25, 5:25] = True
    ring[9:21, 9:21] = False
    x, y = interior_point(ring)
    assert ring[y, x]
    ell = np.zeros((40, 40), bool)  # an L: thick vertical bar, thin foot
    ell[0:40, 0:12] = True
    ell[30:40, 0:40] = True
    x, y = interior_point(ell)
    assert ell[y, x] and 4 <= x <= 8  # centre of the thick bar (distance 6 from its edges)
    cut = np.zeros((20, 20), bool)  # cut by the left frame border: the border counts as an edge
    cut[5:15, 0:10] = True
    assert interior_point(cut) == [4, 9]  # not at column 0, 10 px from the mask's right edge
    single = np.zeros((5, 5), bool)
    single[3, 1] = True
    assert interior_point(single) == [1, 3]  # [x, y] = [column, row]
    with pytest.raises(ValueError):
        interior_point(np.zeros((3, 3), bool))


def test_scene_coco_points_keypoints_and_amodal_masks() -> None:
    from pycocotools import mask as mask_util

    from mixcount.annotate.coco import ground_truth_pairs

    ids = _synthetic_ids()
    amodal = {k: ids == k for k in (1, 2, 3, 4)}
    amodal[2] = amodal[2].copy()
    amodal[2][20:30, 9:14] = True  # object 2 is partly hidden: 40 visible of 90 amodal pixels
    amodal[3] = np.zeros_like(amodal[3])  # a silhouette that missed the visible pixels: united with them
    objects = [{"instance_id": k, "category_id": 40 if k != 3 else 12, "role": "counted" if k != 3 else "distractor",
                "visibility": 0.5} for k in (1, 2, 3, 4)]
    coco = build_scene_coco(ids, objects, [{"id": 12, "name": "d"}, {"id": 40, "name": "a"}], image_id=1,
                            file_name="x.png", scene_id="s", amodal=amodal)
    anns = {a["id"]: a for a in coco["annotations"]}
    for inst, a in anns.items():
        x, y = a["point"]
        assert isinstance(x, int) and ids[y, x] == inst
        assert a["keypoints"] == [x, y, 2] and a["num_keypoints"] == 1
        vis = mask_util.decode(a["segmentation"]).astype(bool)
        am = mask_util.decode(a["segmentation_amodal"]).astype(bool)
        assert (am >= vis).all() and a["area_amodal"] == int(am.sum()) >= a["area"]
        assert a["bbox_amodal"] == bbox_of(am)
        assert a["visibility"] == pytest.approx(a["area"] / a["area_amodal"], abs=1e-6)
    assert anns[2]["visibility"] == pytest.approx(40 / 90) and anns[2]["bbox_amodal"] == [5.0, 20.0, 9.0, 10.0]
    assert anns[1]["visibility"] == 1.0 and anns[3]["area_amodal"] == anns[3]["area"]
    assert all(c["keypoints"] == ["center"] and c["skeleton"] == [] for c in coco["categories"])
    # internal exemplars best first: object 2 (less visible) ranks after object 1
    ex = {e["category_id"]: e["annotation_ids"] for e in coco["images"][0]["exemplars"]}
    scores = [anns[i]["exemplar_score"] for i in ex[40]]
    assert scores == sorted(scores, reverse=True) and ex[40].index(1) < ex[40].index(2)
    assert ground_truth_pairs(coco) == {12: 1, 40: 3}  # distractors included


def test_pycocotools_reads_points_as_keypoints(tmp_path: Path) -> None:
    from pycocotools.coco import COCO

    ids = _synthetic_ids()
    coco = build_scene_coco(ids, [{"instance_id": 1, "category_id": 40, "role": "counted", "visibility": 1.0}],
                            [{"id": 40, "name": "a"}], image_id=1, file_name="x.png", scene_id="s")
    path = tmp_path / "c.json"
    path.write_text(json.dumps(coco))
    c = COCO(str(path))
    ann = c.loadAnns(c.getAnnIds(catIds=[40]))[0]
    assert c.loadCats(40)[0]["keypoints"] == ["center"] and ann["num_keypoints"] == 1
    assert ann["keypoints"][2] == 2 and ids[ann["keypoints"][1], ann["keypoints"][0]] == 1


def test_external_exemplars_are_copied_once_under_out(tmp_path: Path) -> None:
    from mixcount.dataset.external_exemplars import copy_external_exemplars

    src = tmp_path / "renders"
    src.mkdir()
    (src / "obj_3.png").write_bytes(b"png-3")
    out = tmp_path / "out"
    got = copy_external_exemplars(out, {3: str(src / "obj_3.png"), 4: None, 5: str(src / "gone.png")}, [3, 4, 5])
    assert got == {3: "exemplars/external/obj_3.png"}
    assert (out / got[3]).read_bytes() == b"png-3"
    mtime = (out / got[3]).stat().st_mtime_ns
    assert copy_external_exemplars(out, {3: str(src / "obj_3.png")}, [3]) == got
    assert (out / got[3]).stat().st_mtime_ns == mtime  # identical file: not rewritten
    (src / "obj_3.png").write_bytes(b"png-3 re-rendered")
    copy_external_exemplars(out, {3: str(src / "obj_3.png")}, [3])
    assert (out / got[3]).read_bytes() == b"png-3 re-rendered"
    assert not list((out / "exemplars" / "external").glob(".*tmp"))


def test_load_pool_carries_the_canonical_render_as_external_exemplar(catalog, tmp_path: Path) -> None:
    from mixcount.catalog.models import CatalogObject, Render, Split
    from mixcount.catalog.pool_loader import load_pool

    png = tmp_path / "obj.png"
    png.write_bytes(b"png")
    with catalog.session() as s:
        objs = []
        for k in range(4):
            o = CatalogObject(source="folder", source_id=f"o{k}", name=f"Mug_{k}", category="mug",
                              model_path=str(tmp_path / f"{k}.glb"), dim_x=0.1, dim_y=0.1, dim_z=0.1)
            s.add(o)
            s.flush()
            s.add(Split(object_id=o.id, split="train", method="random"))
            objs.append(o.id)
        s.add(Render(object_id=objs[0], view="canonical", path=str(png)))  # usable
        s.add(Render(object_id=objs[1], view="canonical", path=str(png), error="render failed"))
        s.add(Render(object_id=objs[2], view="canonical", path=str(tmp_path / "vanished.png")))
        s.add(Render(object_id=objs[3], view="view_1", path=str(png)))  # not the canonical view
        s.commit()
        pool = {r.object_id: r.render_path for r in load_pool(s)}
    assert pool == {objs[0]: str(png), objs[1]: None, objs[2]: None, objs[3]: None}
