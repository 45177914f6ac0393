"""The worker's pure decisions and the worker contract, without Blender: settle verdicts, deep
interpenetration, frame check, visibility and the final status, pass conversions, JSON round-trip."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import mixcount.scene_decisions as D
from mixcount.annotate.raster import PinholeCamera
from mixcount.worker.canonical_contract import CanonicalRequest, CanonicalResult, CanonicalSettings, CanonicalView
from mixcount.worker.contract import (
    CameraView,
    MeshCacheRequest,
    MeshCacheResult,
    ObjectResult,
    SceneRequest,
    SceneResult,
    SettleResult,
)


def pose(x: float = 0.0, y: float = 0.0, z: float = 0.0, scale: float = 1.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] *= scale
    m[:3, 3] = (x, y, z)
    return m


FLOOR = dict(floor_shape="cube", half_extent=(2.0, 1.0), below_floor_fraction=0.1)


def test_settle_verdict_reasons() -> None:
    assert D.settle_verdict(pose(0, 0, 0.5), 0.0, 1.0, **FLOOR) is None
    assert D.settle_verdict(pose(0, 0, 0.5), -0.09, 1.0, **FLOOR) is None  # within 10 % of its size
    assert D.settle_verdict(pose(0, 0, 0.5), -0.11, 1.0, **FLOOR) == D.BELOW_FLOOR
    assert D.settle_verdict(pose(0, 0, -0.01), 0.0, 1.0, **FLOOR) == D.BELOW_FLOOR  # centre under z = 0
    assert D.settle_verdict(pose(1.9, 0.0, 0.5), 0.0, 1.0, **FLOOR) is None
    assert D.settle_verdict(pose(0.0, 1.1, 0.5), 0.0, 1.0, **FLOOR) == D.FLUNG_OUT  # rectangle: |y| > hy
    cyl = dict(FLOOR, floor_shape="cylinder")
    assert D.settle_verdict(pose(1.5, 1.5, 0.5), 0.0, 1.0, **cyl) == D.FLUNG_OUT  # radius 2.12 > 2
    assert D.settle_verdict(pose(1.2, 1.2, 0.5), 0.0, 1.0, **cyl) is None  # a cylinder ignores hy
    bad = pose(0, 0, 0.5)
    bad[0, 3] = np.nan
    assert D.settle_verdict(bad, float("nan"), 1.0, **FLOOR) == D.UNSTABLE


def cube_body(x: float, size: float = 1.0) -> D.SettledBody:
    local = np.array([[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)]) * size
    m = pose(x, 0.0, 0.5)
    world = local + m[:3, 3]
    return D.SettledBody(m, world.min(0), world.max(0), D.hull_equations(local), size)


def test_interpenetration_drops_the_later_body_once() -> None:
    bodies = [cube_body(0.0), cube_body(0.1), cube_body(0.15), cube_body(3.0)]
    drops = D.interpenetrations(bodies, 0.15)
    # body 1's centre is 0.4 m inside body 0 (> 0.15); body 2 overlaps both but body 1 is gone by then
    assert [(j, k) for j, k, _ in drops] == [(1, 0), (2, 0)]
    assert drops[0][2] == pytest.approx(0.4)
    assert D.interpenetrations([cube_body(0.0), cube_body(0.9)], 0.15) == []  # touching: 0.1 < 0.15
    assert D.penetration_depth(np.array([0.0, 0, 0.5]), pose(0, 0, 0.5, 2.0), cube_body(0).hull) == pytest.approx(1.0)


def camera() -> PinholeCamera:
    # looking down -Z from z = 10 over the origin, 100 x 80 px
    return PinholeCamera.from_physical(50.0, 36.0, 100, 80, pose(0, 0, 10), near=0.1)


def test_origin_in_frame() -> None:
    cam = camera()
    (x, y), inside = D.origin_in_frame(cam, pose(0, 0, 0))
    assert inside and (x, y) == pytest.approx((50.0, 40.0))
    _, inside = D.origin_in_frame(cam, pose(50, 0, 0))
    assert not inside
    _, inside = D.origin_in_frame(cam, pose(0, 0, 20))  # behind the camera
    assert not inside
    # the vectorised form (the physics early stop's) gives the same answer point by point
    pts = np.array([[0, 0, 0], [50, 0, 0], [0, 0, 20], [1.5, -1.0, 0.5], [-5.0, 2.5, 1.0]], dtype=float)
    px, inside_all = D.points_in_frame(cam, pts)
    for p, q, ins in zip(pts, px, inside_all):
        (x, y), one = D.origin_in_frame(cam, pose(*p))
        assert one == bool(ins) and (x, y) == pytest.approx(tuple(q))
    assert inside_all.tolist() == [True, False, False, True, False]


def test_may_still_be_kept_waits_for_bodies_falling_into_view() -> None:
    # a camera 10 m up and 10 m back, looking at the origin at 45 degrees: a body high above the origin
    # is outside the frame but falls into it
    eye = np.array([0.0, -10.0, 10.0])
    fwd = -eye / np.linalg.norm(eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, -fwd, eye
    cam = PinholeCamera.from_physical(50.0, 36.0, 100, 100, c2w, near=0.1)
    centres = np.array([[0.0, 0.0, 0.5],    # on the floor in view
                        [0.0, 0.0, 30.0],   # high above the view, falling into it
                        [25.0, 0.0, 0.5],   # rolled away over the floor
                        [0.0, 0.0, -0.2]])  # under the floor's top
    assert D.points_in_frame(cam, centres)[1].tolist() == [True, False, False, True]
    assert D.may_still_be_kept(cam, centres).tolist() == [True, True, False, False]


def test_visibility_occlusion_and_status() -> None:
    index = np.zeros((4, 5), dtype=np.int32)
    index[0, :4] = 1  # 4 px of object 1
    index[1, :1] = 2  # 1 px of object 2
    sil = {k: np.zeros((4, 5), bool) for k in (1, 2, 3, 4)}
    sil[1][0, :5] = True  # 5 px silhouette, 4 visible
    sil[2][1:3, :2] = True  # 4 px silhouette, 1 visible
    sil[4][3, :3] = True  # 3 px silhouette, none visible; object 3 has no silhouette at all
    vis = D.measure_visibility(index, sil)
    assert vis == {1: (4, 5, 0.8), 2: (1, 4, 0.25), 3: (0, 0, 0.0), 4: (0, 3, 0.0)}
    # a visible pixel the rasteriser missed (a silhouette edge) still counts in the amodal mask
    index[2, 4] = 1
    assert D.measure_visibility(index, {1: sil[1]})[1] == (5, 6, 5 / 6)
    # an id map with a negative value (no bincount) counts the same
    negative = index.copy()
    negative[3, 4] = -1
    assert D.measure_visibility(negative, sil) == D.measure_visibility(index, sil)
    assert D.measure_visibility(index.astype(np.float32), sil) == D.measure_visibility(index, sil)  # as read from EXR
    am = D.amodal_mask(sil[1], index, 1)
    assert am.sum() == 6 and am[2, 4] and (am >= (index == 1)).all()
    visibility = {k: v.visibility for k, v in vis.items()}
    assert D.occluded(visibility, 0.4) == [2, 3, 4]
    assert D.occluded({1: 0.6}, 0.4) == [1]  # occlusion 0.4 >= v_t: dropped ...
    assert D.scene_status({1: 0.6}, 0.4) == ("ok", [])  # ... but the re-check only rejects below 1 - v_t
    assert D.scene_status({1: 0.8, 2: 0.5}, 0.4) == ("rejected", [2])
    assert D.scene_status({1: 0.8}, 0.4, {7: 0.3}) == ("rejected", [7])  # distractors under the same rule
    assert D.scene_status({1: 0.8}, 0.4, {7: 0.9}) == ("ok", [])
    assert D.scene_status({}, 0.4, {7: 0.9}) == ("empty", [])


def test_pass_conversions() -> None:
    depth = np.array([[2.0, 1e10], [3.5, 1e10]], dtype=np.float32)
    d = D.planar_depth(depth)
    assert d.dtype == np.float32 and d.tolist() == [[2.0, 0.0], [3.5, 0.0]]
    c2w = np.eye(4)
    c2w[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # camera rotated 90 degrees about z
    normal = np.zeros((2, 2, 3), dtype=np.float32)
    normal[..., 0] = 1.0  # world +x
    n = D.camera_normals(normal, c2w, depth)
    assert n.dtype == np.float32
    assert n[0, 0].tolist() == [0.0, -1.0, 0.0] and n[0, 1].tolist() == [0.0, 0.0, 0.0]  # world +x = camera -y
    ids = D.instance_map(np.array([[0, 1], [2, 7]]), [1, 7])
    assert ids.dtype == np.int32 and ids.tolist() == [[0, 1], [0, 7]]


def test_contract_json_round_trip() -> None:
    req = SceneRequest(stage="/x/scene.usda", out_dir="/x", threads=2, oracle=True, passes=("instance", "depth"),
                       depth_format="exr32", normal_format="png8", mesh_cache="raw",
                       settled_poses_file="/x/settled.json",
                       more_views=None)
    assert SceneRequest.from_dict(json.loads(json.dumps(req.to_dict()))) == req
    with pytest.raises(ValueError, match=r"SceneRequest: missing fields \['mesh_cache'\]"):
        SceneRequest.from_dict({k: v for k, v in req.to_dict().items() if k != "mesh_cache"})
    settled = SettleResult(poses_file="/x/settled.json", frames_run=140, seconds={"import": 1.5, "physics": 8.25})
    assert SettleResult.from_dict(json.loads(json.dumps(settled.to_dict()))) == settled
    look = CanonicalSettings(resolution=64, samples=4, denoise=True, elevation_deg=30.0, azimuth_deg=10.0,
                             extra_views=2, margin=0.1, world_strength=0.5, sun_strength=2.0,
                             heavy_faces=300000, heavy_denoise_prefilter="FAST")
    canonical = CanonicalRequest(model_path="/m.glb", out_dir="/r", stem="obj_000001", threads=0, settings=look,
                                 up_axis="")
    assert CanonicalRequest.from_dict(json.loads(json.dumps(canonical.to_dict()))) == canonical
    assert canonical.views() == (("canonical", 10.0), ("view_1", 130.0), ("view_2", 250.0))
    rendered = CanonicalResult(views=(CanonicalView(view="canonical", path="/r/a.png", mask_path="/r/a_mask.png",
                                                    coverage=0.25, width=64, height=64),),
                               faces=1280, heavy=False)
    assert CanonicalResult.from_dict(json.loads(json.dumps(rendered.to_dict()))) == rendered
    warm = MeshCacheRequest(assets=("/a.usdc",), mode="zstd")
    assert MeshCacheRequest.from_dict(json.loads(json.dumps(warm.to_dict()))) == warm
    assert MeshCacheResult.from_dict(MeshCacheResult(assets={"a.usdc": "hit"}).to_dict()).assets == {"a.usdc": "hit"}
    m = tuple(tuple(float(v) for v in r) for r in pose(1, 2, 3))
    kept = ObjectResult(name="obj_0001", path="/World/Objects/obj_0001", role="counted", instance_id=1, object_id=5,
                        class_index=0, asset="/a.usdc", size_m=0.5, spawn_matrix=m, matrix_world=m, min_z=0.0,
                        origin_px=(10.5, 20.0), unoccluded_px=40, visible_px=30, amodal_px=40, visibility=0.75)
    dropped = ObjectResult(name="dist_01", path="/World/Distractors/dist_01", role="distractor", instance_id=2,
                           object_id=6, class_index=-1, asset="/b.usdc", size_m=0.7, spawn_matrix=m,
                           status="dropped", reason="flung_out")
    res = SceneResult(status="ok", stage="/x/scene.usda", scene_id="scene_000001", seed=1, visibility_threshold=0.4,
                      id_pass_rounds=1, physics={"substeps": 8}, camera={"width": 128}, lights={},
                      objects=(kept, dropped), diagnostics=({"kind": "dropped", "object": "dist_01"},),
                      timings={"rgb": 1.5},
                      views=(CameraView(name="cam_0", suffix="", camera={"width": 128}, framing={"framing": "fixed"},
                                        passes={"depth": {"file": "depth.png", "format": "png16"}}),))
    back = SceneResult.from_json(res.to_json())
    assert back == res
    assert back.objects[0].kept and not back.objects[1].kept
    with pytest.raises(ValueError, match="unknown ObjectResult fields"):
        ObjectResult.from_dict({**kept.to_dict(), "_aabb": 1})


def test_contract_and_decisions_import_no_engine() -> None:
    code = ("import sys, mixcount, mixcount.engine, mixcount.worker.contract, mixcount.scene_decisions; "
            "assert 'bpy' not in sys.modules and 'pxr' not in sys.modules, sorted(m for m in sys.modules if m in ('bpy', 'pxr'))")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_floor_collider_keeps_the_top_and_outline_and_goes_deep() -> None:
    from mixcount.usd.stage import floor_mesh

    pts, _counts, _idx, _st = floor_mesh("cylinder", 3.0, 3.0, 0.5, 1.0)
    pts = np.asarray(pts, dtype=np.float64)
    lift = np.eye(4)
    lift[:3, 3] = [0.2, -0.1, 0.0]
    deep = D.deepen_below_top(pts, lift, 5.0)
    assert deep is not None
    top = pts[:, 2] >= -1e-9
    np.testing.assert_allclose(deep[top], pts[top] + [0.2, -0.1, 0.0])  # top face untouched (moved with the floor)
    np.testing.assert_allclose(deep[~top, 2], -5.0)  # the bottom rim 5 m under the top
    np.testing.assert_allclose(deep[~top, :2], pts[~top, :2] + [0.2, -0.1])  # same outline
    assert D.deepen_below_top(pts, np.eye(4), 0.5) is None  # already that deep: the floor itself collides
    assert D.deepen_below_top(pts, np.eye(4), 0.0) is None


def test_world_bounds_equal_the_transformed_vertices_bounds() -> None:
    rng = np.random.default_rng(4)
    local = rng.normal(size=(5000, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    m = np.eye(4)
    m[:3, :3] = q * 1.7
    m[:3, 3] = [3.0, -2.0, 0.5]
    world = local @ m[:3, :3].T + m[:3, 3]
    lo, hi = D.world_bounds(np.ascontiguousarray(local.T), m)
    np.testing.assert_allclose(lo, world.min(0), atol=1e-12)
    np.testing.assert_allclose(hi, world.max(0), atol=1e-12)
    m[0, 3] = np.nan
    lo, hi = D.world_bounds(np.ascontiguousarray(local.T), m)
    assert np.isnan(lo).all() and np.isnan(hi).all()


def test_changed_region_is_the_box_of_the_dropped_objects_and_paste_keeps_the_rest() -> None:
    index = np.zeros((6, 8), dtype=np.int32)
    index[1:3, 2:4] = 5
    index[4, 6] = 5
    index[0:2, 0:2] = 7
    assert D.changed_region(index, [5]) == (1, 2, 4, 6)
    assert D.changed_region(index, [9]) is None  # never seen: removing it changes no pixel
    before = {"index": index, "depth": np.full((6, 8), 2.0, dtype=np.float32)}
    after = {"index": np.full((6, 8), 3, dtype=np.int32), "depth": np.full((6, 8), 9.0, dtype=np.float32)}
    pasted = D.paste_region(before, after, (1, 2, 4, 6))
    assert (pasted["index"][1:5, 2:7] == 3).all() and (pasted["depth"][1:5, 2:7] == 9.0).all()
    outside = np.ones((6, 8), dtype=bool)
    outside[1:5, 2:7] = False
    assert (pasted["index"][outside] == index[outside]).all() and (pasted["depth"][outside] == 2.0).all()
    assert before["index"][1, 2] == 5  # the earlier passes are not modified in place
