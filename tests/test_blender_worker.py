"""Real bpy: compose small scenes from a generated demo library and check every output against the
instance map and the one-render-per-object oracle; crash, timeout and resume behaviour of the workers.

Budget: a few 128 px, 4-sample scenes (quick config, 60 physics frames); bpy runs in worker processes.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

from mixcount.worker.processes import child_pids, pid_running
from tests.conftest import PROJECT_ROOT

pytestmark = [pytest.mark.blender, pytest.mark.slow]

V_T = 0.4


def _config(*extra: str):
    from mixcount.config import load_config

    return load_config([PROJECT_ROOT / "configs" / "quick.toml"],
                       ["compose.render_threads=2", "compose.resolution=128", "compose.samples=4", "compose.seed=1",
                        *extra])


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory):
    from mixcount.demo.demo_pools import pool_from_demo_library
    from mixcount.demo.library import generate_demo_library

    root = tmp_path_factory.mktemp("lib")
    generate_demo_library(root / "demo", seed=0, n_objects=8)
    return pool_from_demo_library(root / "demo"), root / "assets"


def _with_renders(pool, folder: Path):
    """The pool with a canonical-render file for every object but the first (external exemplars)."""
    from dataclasses import replace

    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    out = [pool[0]]
    for rec in pool[1:]:
        png = folder / f"obj_{rec.object_id}.png"
        im = Image.new("RGB", (32, 32), (255, 255, 255))
        im.paste((rec.object_id * 30 % 256, 40, 90), (12, 12, 20, 20))
        im.save(png)
        out.append(replace(rec, render_path=str(png)))
    return out


N_CAMERAS = 2  # every check below runs per camera: the paper's rules are written for several


@pytest.fixture(scope="module")
def fault_worker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """One bpy worker of tests/fault_worker.py (the real worker plus test ops: border_check, mesh_cache,
    rest_stop, scaled_drop, release_wave) for the module's tests that only send it requests: one bpy start
    instead of one per test. The entry module is patched while it starts only (a restart would run the real
    one: these tests expect none). Each op builds its own scene (a stage, or the factory settings)."""
    from mixcount.worker.client import BlenderWorker

    with BlenderWorker(name="fault", log_dir=tmp_path_factory.mktemp("fault_worker")) as w:
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr("mixcount.worker.client.WORKER_MODULE", "tests.fault_worker")
            w.start()
        yield w
        assert w.restarts == 0  # every test above ran on the fault worker


@pytest.fixture(scope="module")
def composed(library, tmp_path_factory: pytest.TempPathFactory):
    """Two scenes of two cameras each with 3-5 distractors (placed in view after physics, the default
    rule), the one-render-per-object reference on."""
    from mixcount.run.compose import compose_scenes

    pool, assets = library
    out = tmp_path_factory.mktemp("out")
    pool = _with_renders(pool, out.parent / (out.name + "_renders"))
    # the quick config's 6-14 objects get a ~3 m container that fills the paper's frame (1.2 x its diagonal)
    # in both (here near top-down) cameras, leaving no floor in both views: all distractors would be dropped
    # (no_spot_in_view) and this test checks their annotations. A wider frame leaves floor for them.
    summary = compose_scenes(pool=pool, config=_config("scene.n_distractors=[3, 5]", f"scene.n_cameras={N_CAMERAS}",
                                                       "scene.camera_distance_factor=1.8",
                                                       "compose.denoise_prefilter=FAST"), out_dir=out,
                             assets_dir=assets, n=2, progress=False, oracle=True)
    return out, summary, pool


def _suffixes() -> list[str]:
    from mixcount.worker.contract import view_suffix

    return [view_suffix(k) for k in range(N_CAMERAS)]


def _scenes(out: Path) -> list[Path]:
    return sorted(d for d in (out / "scenes").iterdir() if d.is_dir() and not d.name.startswith("."))


def test_compose_writes_n_complete_scenes(composed) -> None:
    out, summary, _ = composed
    assert summary.written == 2 and summary.failed == 0
    dirs = _scenes(out)
    assert len(dirs) == 2
    for d in dirs:
        for name in ("scene.usda", "settled.usda", "coco.json", "metadata.json"):
            assert (d / name).is_file(), name
        for suffix in _suffixes():  # every camera rendered: K RGB images and K sets of passes
            for name in ("rgb", "instance", "class", "depth", "normal"):
                assert (d / f"{name}{suffix}.png").is_file(), (name, suffix)
        meta = json.loads((d / "metadata.json").read_text())
        assert [c["name"] for c in meta["cameras"]] == [f"cam_{k}" for k in range(N_CAMERAS)]
        assert [i["file_name"] for i in meta["images"]] == [f"scenes/{d.name}/rgb{s}.png" for s in _suffixes()]
        for cam in meta["cameras"]:  # framed on the settled pile by the paper's rule, and said how
            assert cam["framing"]["framing"] == "paper" and "pile_centre" in cam["framing"]
        assert meta["complete"] and meta["n_counted"] >= 1
        assert {"stage", "worker", "annotate", "total", "worker.physics", "worker.rgb"} <= set(meta["timings"])
        assert meta["camera"]["K"][0][0] > 0 and len(meta["camera"]["cam_to_world"]) == 4
        scene_cfg = _config().scene  # the physics values used are the stage's, recorded as such
        assert meta["physics"]["substeps"] == scene_cfg.physics_substeps == meta["spec"]["physics"]["substeps"]
        assert meta["physics"]["frames"] == scene_cfg.physics_frames
        # the RGB render used the spec's render settings, as Cycles reports them back
        rgb = [x for x in meta["diagnostics"] if x["kind"] == "rgb"]
        assert len(rgb) == 1 and (rgb[0]["samples"], rgb[0]["use_denoising"], rgb[0]["denoiser"],
                                  rgb[0]["denoising_prefilter"]) == (4, True, "OPENIMAGEDENOISE", "FAST")
        assert meta["spec"]["render"]["denoise_prefilter"] == "FAST"
        cy = meta["spec"]["render"]["cycles"]  # every [cycles] value recorded in the spec, and used
        assert cy == _config().cycles.to_dict()
        assert rgb[0]["use_adaptive_sampling"] == (cy["adaptive_threshold"] > 0)
        for spec_key, blender_key in (("max_bounces", "max_bounces"), ("diffuse_bounces", "diffuse_bounces"),
                                      ("light_tree", "use_light_tree"), ("denoising_quality", "denoising_quality"),
                                      ("texture_limit", "texture_limit_render"), ("pixel_filter", "pixel_filter_type")):
            assert rgb[0][blender_key] == cy[spec_key], spec_key
        if cy["adaptive_threshold"] > 0:
            assert abs(rgb[0]["adaptive_threshold"] - cy["adaptive_threshold"]) < 1e-6
            assert rgb[0]["adaptive_min_samples"] == cy["adaptive_min_samples"]
        assert (d / "exemplars").is_dir() and any((d / "exemplars").iterdir())
    summary_json = json.loads((out / "dataset.json").read_text())
    assert summary_json["counts"]["scenes"] == 2
    assert (out / "preview.png").is_file()
    assert not list((out / "scenes").glob(".tmp-*"))


def test_coco_masks_equal_instance_map_and_counts(composed) -> None:
    from PIL import Image
    from pycocotools import mask as mask_util
    from pycocotools.coco import COCO

    out, _, _ = composed
    merged = COCO(str(out / "annotations" / "instances_train.json"))
    assert len(merged.getImgIds()) == 2 * N_CAMERAS  # one COCO image per camera
    for d in _scenes(out):
        coco = COCO(str(d / "coco.json"))
        meta = json.loads((d / "metadata.json").read_text())
        assert sorted(coco.getImgIds()) == list(range(1, N_CAMERAS + 1))
        for image_id, suffix in zip(range(1, N_CAMERAS + 1), _suffixes()):
            inst = np.array(Image.open(d / f"instance{suffix}.png"))
            cls = np.array(Image.open(d / f"class{suffix}.png"))
            rgb = Image.open(d / f"rgb{suffix}.png")
            assert coco.loadImgs(image_id)[0]["file_name"] == f"scenes/{d.name}/rgb{suffix}.png"
            assert inst.dtype == np.uint16 and cls.dtype == np.uint16
            assert inst.shape == cls.shape == (rgb.height, rgb.width)
            anns = coco.loadAnns(coco.getAnnIds(imgIds=[image_id]))
            assert anns
            for a in anns:
                m = mask_util.decode(a["segmentation"]).astype(bool)
                assert (m == (inst == a["instance_id"])).all()
                assert a["area"] == int(m.sum())
                assert (cls[m] == a["category_id"]).all()
                assert 0.0 <= a["exemplar_score"] <= 1.0 and 0.0 < a["visibility"] <= 1.0
            ids_in_map = set(np.unique(inst).tolist()) - {0}
            assert ids_in_map == {a["instance_id"] for a in anns}
            for cat in {a["category_id"] for a in anns if not a["is_distractor"]}:
                n_anns = sum(1 for a in anns if a["category_id"] == cat and not a["is_distractor"])
                assert n_anns == len(set(np.unique(inst[cls == cat]).tolist()) - {0})
            # every camera shows the same kept objects
            assert sum(meta["counts"].values()) == sum(1 for a in anns if not a["is_distractor"])


def test_counted_objects_visible_by_oracle_and_raster_agrees(composed) -> None:
    out, _, _ = composed
    n_checked = 0
    for d in _scenes(out):
        meta = json.loads((d / "metadata.json").read_text())
        for k, suffix in enumerate(_suffixes()):
            oracle = np.load(d / f"oracle_masks{suffix}.npz")
            h, w = oracle["shape"]
            for o in meta["objects"]:
                if o["status"] != "kept":
                    continue
                view = o["views"][k]
                assert view["camera"] == f"cam_{k}"
                om = np.unpackbits(oracle[f"oracle_{o['instance_id']}"])[: h * w].reshape(h, w).astype(bool)
                rm = np.unpackbits(oracle[f"raster_{o['instance_id']}"])[: h * w].reshape(h, w).astype(bool)
                iou = (om & rm).sum() / max(1, (om | rm).sum())
                # one edge pixel of an 80-pixel object at 128 px is already 1.25 % of IoU
                assert iou >= 0.99 or (om ^ rm).sum() <= 1, (d.name, k, o["name"], iou)
                assert view["visible_px"] / om.sum() >= 1.0 - V_T - 1e-9, (d.name, k, o["role"], o["name"])
                x, y = view["origin_px"]  # the origin lies in every camera's frame
                assert 0 <= x < w and 0 <= y < h
                n_checked += 1
            if k == 0:  # cam_0's fields on the object itself; visibility is the worst camera's
                for o in meta["objects"]:
                    if o["status"] == "kept":
                        assert o["visibility_min"] == pytest.approx(min(v["visibility"] for v in o["views"]))
    assert n_checked >= 2 * N_CAMERAS


def _decode(rle) -> np.ndarray:
    from pycocotools import mask as mask_util

    return mask_util.decode(rle).astype(bool)


def test_every_annotation_visible_points_amodal_and_ground_truth_agree(composed) -> None:
    """Counted objects and distractors alike: >= 1 - v_t visible by the one-render-per-object reference,
    points on their own instance pixels, amodal masks containing the visible ones; metadata.json, the
    merged COCO and ``evaluate`` agree on the (image, category, count) pairs."""
    from PIL import Image

    from mixcount.evaluate.metrics import evaluate, load_ground_truth, parse_predictions

    out, _, pool = composed
    distractor_vis, removed = [], []
    meta_pairs: dict[tuple[str, int], int] = {}
    for d in _scenes(out):
        meta = json.loads((d / "metadata.json").read_text())
        coco = json.loads((d / "coco.json").read_text())
        assert not (d / "amodal.npz").exists()
        for image_id, suffix in zip(range(1, N_CAMERAS + 1), _suffixes()):
            inst = np.array(Image.open(d / f"instance{suffix}.png"))
            oracle = np.load(d / f"oracle_masks{suffix}.npz")
            _check_annotations(d, [a for a in coco["annotations"] if a["image_id"] == image_id], inst, oracle,
                               distractor_vis)
            for p in meta["ground_truth"]:  # every camera shows the same kept objects
                meta_pairs[(f"scenes/{d.name}/rgb{suffix}.png", p["category_id"])] = p["count"]
        kept_distractors = [o for o in meta["objects"] if o["role"] == "distractor" and o["status"] == "kept"]
        first = [a for a in coco["annotations"] if a["image_id"] == 1]
        assert len(kept_distractors) == meta["n_distractors"] == sum(a["is_distractor"] for a in first)
        gone = [o for o in meta["objects"] if o["role"] == "distractor" and o["status"] != "kept"]
        removed += gone
        for o in gone:
            assert o["reason"] in ("below_floor", "flung_out", "interpenetration", "unstable",
                                   "origin_outside_frame", "occluded", "no_spot_in_view")
            for suffix in _suffixes():  # removed before the final passes
                assert not (np.array(Image.open(d / f"instance{suffix}.png")) == o["instance_id"]).any()
    assert distractor_vis, "the composed scenes must hold distractors"
    print(f"\ndistractors: {len(distractor_vis)} annotated, visibility (reference) min {min(distractor_vis):.3f} "
          f"mean {np.mean(distractor_vis):.3f}; removed {len(removed)}: {[o['reason'] for o in removed]}")

    gt_path = out / "annotations" / "instances_train.json"
    gt = load_ground_truth(gt_path, "train")
    coco_pairs = {(gt.images[i]["file_name"], c): n for (i, c), n in gt.counts.items()}
    assert coco_pairs == meta_pairs
    by_file = {img["file_name"]: img["id"] for img in gt.images.values()}
    rows = [{"image_id": by_file[f], "category_id": c, "count": n} for (f, c), n in meta_pairs.items()]
    res = evaluate(gt, parse_predictions(rows)).overall
    assert (res.mae, res.pairs, res.missing, res.extra) == (0.0, len(coco_pairs), 0, 0)
    _check_exemplars(gt_path, out, pool)


def _check_annotations(d: Path, anns: list, inst: np.ndarray, oracle, distractor_vis: list) -> None:
    """One image's annotations against its instance map and the one-render-per-object reference."""
    h, w = oracle["shape"]
    for a in anns:
        vis = _decode(a["segmentation"])
        om = np.unpackbits(oracle[f"oracle_{a['instance_id']}"])[: h * w].reshape(h, w).astype(bool)
        ref_visibility = vis.sum() / (om | vis).sum()
        assert ref_visibility >= 1.0 - V_T, (d.name, a["id"], a["is_distractor"], ref_visibility)
        if a["is_distractor"]:
            distractor_vis.append(float(ref_visibility))
        x, y = a["point"]
        assert inst[y, x] == a["instance_id"] and a["keypoints"] == [x, y, 2] and a["num_keypoints"] == 1
        am = _decode(a["segmentation_amodal"])
        assert (am >= vis).all() and a["area_amodal"] == int(am.sum())
        assert a["visibility"] == pytest.approx(a["area"] / a["area_amodal"], abs=1e-6)
        assert (om & am).sum() / (om | am).sum() >= 0.98  # the amodal mask is the reference's silhouette
        x0, y0, bw, bh = a["bbox_amodal"]
        assert (x0, y0, x0 + bw, y0 + bh) == (np.nonzero(am.any(0))[0][0], np.nonzero(am.any(1))[0][0],
                                              np.nonzero(am.any(0))[0][-1] + 1, np.nonzero(am.any(1))[0][-1] + 1)


def _check_exemplars(gt_path: Path, out: Path, pool) -> None:
    # external exemplars: every category's canonical render copied under OUT and referenced by path
    renders = {r.object_id: r.render_path for r in pool}
    doc = json.loads(gt_path.read_text())
    for c in doc["categories"]:
        src = renders.get(c["object_id"])
        assert c["keypoints"] == ["center"] and c["skeleton"] == []
        if src is None:
            assert c["external_exemplar"] is None
        else:
            assert c["external_exemplar"] == f"exemplars/external/obj_{c['object_id']}.png"
            assert (out / c["external_exemplar"]).read_bytes() == Path(src).read_bytes()
    for img in doc["images"]:  # internal exemplars best first
        anns = {a["id"]: a for a in doc["annotations"]}
        for e in img["exemplars"]:
            scores = [anns[i]["exemplar_score"] for i in e["annotation_ids"]]
            assert scores == sorted(scores, reverse=True)


def test_every_camera_exports_as_its_own_image(composed, tmp_path: Path) -> None:
    """Each camera's image is a sample of every export, read back the way the counting loaders read it."""
    from mixcount.export import export_dataset

    out, _, _ = composed
    n_images = 2 * N_CAMERAS
    fsc = export_dataset(out, "fsc147", tmp_path / "fsc147")
    annotation = json.loads((tmp_path / "fsc147" / "annotation_FSC147_384.json").read_text())
    keys = sorted(annotation)
    assert fsc["figures"]["samples"] == len(keys) >= n_images  # one sample per (image, class)
    assert any("_rgb_cam_1" in k for k in keys) and any("_rgb_cam_1" not in k for k in keys)
    for k in keys:  # LOCA / CounTR read the image file named by the key
        assert (tmp_path / "fsc147" / "images_384_VarV2" / k).is_file()
    export_dataset(out, "countgd", tmp_path / "countgd")
    odvg = [json.loads(line) for line in (tmp_path / "countgd" / "train_odvg.jsonl").read_text().splitlines()]
    assert len({r["filename"] for r in odvg}) == n_images


def test_depth_normals_and_settled_poses(composed) -> None:
    from pxr import Usd, UsdGeom

    from mixcount.usd.read import labelled_prims

    out, _, _ = composed
    for d in _scenes(out):
        meta = json.loads((d / "metadata.json").read_text())
        h, w = meta["image"]["height"], meta["image"]["width"]
        assert meta["passes"]["depth"]["format"] == "png16" and meta["files"]["normal"] == "normal.png"
        for k, suffix in enumerate(_suffixes()):
            files = meta["files"]["cameras"][f"cam_{k}"]
            assert files["depth"] == f"depth{suffix}.png" and files["normal"] == f"normal{suffix}.png"
            _check_depth_normals(d, meta["cameras"][k]["record"], files, h, w, suffix,
                                 meta["passes"]["depth"]["unit_m"] if k == 0 else None)
        kept = {o["name"]: o for o in meta["objects"] if o["status"] == "kept"}
        for o in kept.values():
            assert o["min_z"] >= -0.1 * o["size_m"], o  # nothing rests below the floor
        stage = Usd.Stage.Open(str(d / "settled.usda"))
        prims = {Path(p.path).name: p for p in labelled_prims(stage) if p.role in ("counted", "distractor")}
        assert set(prims) == set(kept)
        for name, p in prims.items():
            assert p.instance_id == kept[name]["instance_id"]
            t = stage.GetPrimAtPath(p.path).GetAttribute("xformOp:translate").Get()
            assert np.allclose(list(t), kept[name]["pose"]["translate"], atol=1e-5)
        for cam in meta["cameras"]:  # settled.usda holds the cameras as rendered, framed on the settled pile
            prim = stage.GetPrimAtPath(f"/World/Cameras/{cam['name']}")
            m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())).T
            assert np.allclose(m, np.array(cam["record"]["cam_to_world"]), atol=1e-4)
            assert json.loads(prim.GetCustomDataByKey("mixcount:framing"))["framing"] == "paper"
        dropped = [o for o in meta["objects"] if o["status"] != "kept"]
        for o in dropped:
            assert not stage.GetPrimAtPath(o["path"])
            assert o["reason"] in ("below_floor", "flung_out", "interpenetration", "unstable",
                                   "origin_outside_frame", "occluded", "no_spot_in_view")


def _check_depth_normals(d: Path, camera: dict, files: dict, h: int, w: int, suffix: str,
                         unit_m: float | None) -> None:
    """One camera's depth and normal passes: shapes, unit normals facing it, planar depth of the floor."""
    from PIL import Image

    from mixcount.dataset import read_depth, read_normals

    depth = read_depth(d / files["depth"])
    normal = read_normals(d / files["normal"])
    assert depth.shape == (h, w) and depth.dtype == np.float32
    assert normal.shape == (h, w, 3) and normal.dtype == np.float32
    surf = depth > 0
    assert surf.mean() > 0.5
    norms = np.linalg.norm(normal[surf], axis=1)
    assert np.median(np.abs(norms - 1.0)) < 1e-3
    if unit_m is not None:
        steps = depth[surf] / unit_m  # 16-bit PNG: whole steps of the stored unit
        assert np.abs(steps - np.rint(steps)).max() < 0.01
    assert np.median(normal[surf][:, 2]) > 0  # camera space: surfaces face the camera (+z)
    K, C = np.array(camera["K"]), np.array(camera["cam_to_world"])
    target_dist = np.linalg.norm(C[:3, 3])
    assert 0.1 * target_dist < np.median(depth[surf]) < 3.0 * target_dist
    # planar depth: floor pixels (top face z = 0) equal the ray-plane intersection along the optical axis
    inst = np.array(Image.open(d / f"instance{suffix}.png"))
    # (pixels along the image border, every 4th: the container, not in instance.png, may cover some)
    border = [(r, c) for r in (1, h - 2) for c in range(1, w - 1, 4)] + [(r, c) for c in (1, w - 2)
                                                                         for r in range(1, h - 1, 4)]
    matches = 0
    for r, c in border:
        ray = C[:3, :3] @ np.array([(c + 0.5 - K[0, 2]) / K[0, 0], -(r + 0.5 - K[1, 2]) / K[1, 1], -1.0])
        planar = -C[2, 3] / ray[2]
        if inst[r, c] == 0 and planar > 0:
            assert depth[r, c] <= planar * 1.01  # never farther than the floor
            if abs(depth[r, c] - planar) < 0.002 * planar:
                matches += 1
                assert np.allclose(normal[r, c], C[:3, :3].T @ [0.0, 0.0, 1.0], atol=0.05)
    assert matches >= 2


def test_border_rerender_of_dropped_objects_equals_a_full_render(composed, tmp_path: Path, fault_worker) -> None:
    """The visibility loop re-renders only where dropped objects were seen: pasted into the earlier id
    pass, that region must give exactly the full render's ids, depth and normals (both in an id-pass
    series, as the loop renders)."""
    out, _summary, _pool = composed
    w = fault_worker  # adds "border_check"
    for scene in _scenes(out):
        r = w.request({"op": "border_check", "stage": str(scene / "scene.usda"), "out_dir": str(tmp_path / scene.name),
                       "drop": 2}, timeout=300)
        assert r["ok"], r
        row0, col0, row1, col1 = r["region"]
        assert 0 < (row1 - row0 + 1) * (col1 - col0 + 1) < 128 * 128  # a part of the image, not all of it
        assert r["dropped_px"] > 0 and r["changed_px"] > 0  # the dropped objects were seen and are gone
        assert r["dropped_still_seen"] == 0
        assert r["equal"] == {"index": True, "depth": True, "normal": True}, r
        # single-user meshes (each distractor's) are instanced by a twin beyond the far clip for the
        # series only; the ids equal a render without twins, depth to float precision
        assert r["twins"] >= 1 and r["twins_left"] == 0, r
        assert r["plain_index_equal"] and r["plain_depth_rel"] < 1e-4, r


def test_mesh_cache_gives_the_same_scene_and_survives_a_broken_file(composed, library, tmp_path: Path,
                                                                     fault_worker) -> None:
    """Asset meshes appended from the .blend cache render exactly as imported from USD: same ids, depth,
    normals and RGB, cold (files written) and warm (files appended); a truncated file is a miss that is
    rewritten, and a file that cannot be written is reported and costs nothing else. The unlit id pass
    equals a lit one."""
    from mixcount.worker.contract import MeshCacheRequest, MeshCacheResult

    out, _summary, _pool = composed
    scene = _scenes(out)[0]
    w = fault_worker  # adds "mesh_cache"
    r = w.request({"op": "mesh_cache", "stage": str(scene / "scene.usda"), "out_dir": str(tmp_path / "mc")},
                  timeout=300)
    paths = [str(library[1] / name) for name in r.get("assets", [])]
    ahead = w.cache_meshes(MeshCacheRequest(assets=tuple(paths), mode="zstd"), timeout=300)
    off = w.cache_meshes(MeshCacheRequest(assets=tuple(paths), mode="off"), timeout=300)
    assert r["ok"], r
    # the bench's warm-up: every file there, the one that could not be written made now
    assert ahead == MeshCacheResult(assets={a: ("written" if a == r["blocked"] else "hit") for a in r["assets"]}), ahead
    assert off == MeshCacheResult(assets={})
    assets, events = r["assets"], r["events"]
    assert len(assets) >= 2
    assert events["off"] == {}
    assert events["cold"] == {a: "written" for a in assets}
    assert events["warm"] == {a: "hit" for a in assets}
    assert events["truncated"] == {a: ("written" if a == r["broken"] else "hit") for a in assets}
    assert events["after"] == {a: "hit" for a in assets}
    unwritable = events["unwritable"]  # the write fails and says why; the scene is the same
    assert unwritable.pop(r["blocked"]).startswith(("IsADirectoryError", "OSError", "PermissionError"))
    assert unwritable == {a: "hit" for a in assets if a != r["blocked"]}
    assert r["equal"] == {k: True for k in ("off", "cold", "warm", "truncated", "after", "unwritable")}, r["equal"]
    assert r["lit_equal"] is True
    # one file per asset (the blocked one's write failed) and no temporary or stale ones
    stems = sorted(f.rsplit("-", 1)[0] for f in r["files"])
    assert stems == sorted(a[:-len(".usdc")] for a in assets if a != r["blocked"]), r["files"]


def test_rest_stop_waits_only_for_bodies_that_can_be_kept(fault_worker) -> None:
    """The early stop ends once the waited-for bodies are calm: a body the scene job would drop anyway
    (here: one still falling far away) no longer keeps the simulation going."""
    r = fault_worker.request({"op": "rest_stop"}, timeout=300)  # a fault_worker op
    assert r["ok"], r
    every, near = r["all"], r["near"]
    assert every["waited_for"] == 5 and near["waited_for"] == 2
    # waiting for the falling cubes: they land (~2.5 s = 59 frames at 24 fps) and calm down first
    assert every["frames_run"] > 59 and every["falling_z"] < 1.0, every
    # waiting for the resting ones alone: two calm windows of 10 frames
    assert near["frames_run"] <= 30 and near["falling_z"] > 10.0, near


def test_large_scale_body_rests_on_the_floor(fault_worker) -> None:
    """A small real object scaled up (a 2.2 cm die at x51) collides through a proxy with the scale in its
    mesh: dropped 15 m it comes to rest on the floor at Bullet's margins, as a 1.12 m cube should."""
    r = fault_worker.request({"op": "scaled_drop"}, timeout=300)
    assert r["ok"], r
    baked = r["baked"]
    print(f"\n1.12 m cube from 15 m: baked scale lowest point {baked['lowest']:.3f} m; "
          f"object scale (Bullet's own) {r['object_scale']['lowest']:.3f} m")
    assert baked["size"] == pytest.approx(1.124, rel=1e-3)  # the render pose gets the scale back
    assert -0.01 <= baked["lowest"] <= 0.12, baked  # on the floor, within the two 0.04 m collision margins


def test_spawn_wave_body_is_held_then_falls_from_its_spot(fault_worker) -> None:
    """A body released at frame 40 takes no part before it (parked far away), then falls from rest at
    its spawn spot; the simulation runs on past the release and leaves no animation behind."""
    r = fault_worker.request({"op": "release_wave"}, timeout=300)
    assert r["ok"], r
    centres = r["centres"]  # at frames 11, 21, 31, 41, ...
    assert all(c[2] > 500 for c in centres[:3]), centres[:4]  # parked until the release
    x, y, z = centres[3]  # frame 41, one frame after the release: at its spot, barely moving yet
    assert abs(x - 5.0) < 1e-3 and abs(y) < 1e-3 and 9.9 < z <= 10.0, centres[3]
    assert r["last_release"] == 40 and r["frames_run"] >= 70
    sx, sy, sz = r["settled"]
    assert abs(sx - 5.0) < 0.3 and abs(sy) < 0.3 and 0.4 < sz < 0.7, r["settled"]  # about straight down, on the floor
    assert not r["animation_left"] and r["pose"] == pytest.approx(r["settled"], abs=1e-4)


def test_worker_timeout_and_restart(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mixcount.config import load_config
    from mixcount.errors import RenderError
    from mixcount.worker.client import BlenderWorker
    from mixcount.worker.contract import SceneOutputs, SceneRequest

    monkeypatch.setattr("mixcount.worker.client.WORKER_MODULE", "tests.fault_worker")  # adds op "sleep"
    with BlenderWorker(name="t", log_dir=tmp_path) as w:
        first = w.request({"op": "ping"}, timeout=120)["pid"]
        with pytest.raises(RenderError, match="timed out"):
            w.request({"op": "sleep", "seconds": 30}, timeout=1.0)
        assert not w.alive()
        second = w.request({"op": "ping"}, timeout=120)["pid"]
        assert second != first and w.restarts == 1
        with pytest.raises(RenderError, match="scene failed"):
            w.run_scene_job(SceneRequest.for_outputs(SceneOutputs.from_config(load_config().compose),
                                                    stage=str(tmp_path / "missing.usda"), out_dir=str(tmp_path / "x"),
                                                    threads=1, oracle=False), timeout=60)
        assert w.request({"op": "ping"}, timeout=60)["pid"] == second  # a failed scene keeps the worker
        assert (tmp_path / f"mixcount-t-{os.getpid()}-{first}-timeout.log").is_file()  # the hung worker's log, kept
        os.kill(second, signal.SIGSEGV)  # a crash between requests: its log is kept at the next start
        w.proc.wait(timeout=30)
        third = w.request({"op": "ping"}, timeout=120)["pid"]
        kept = tmp_path / f"mixcount-t-{os.getpid()}-{second}-SIGSEGV.log"
        assert third != second and "Fatal Python error: Segmentation fault" in kept.read_text()
        assert w.idle_deaths == [f"SIGSEGV, exit code -11; log kept as {kept}"]


def _kill_when_tmp_scene_appears(out: Path, kill, timeout: float = 120.0) -> threading.Thread:
    def watch() -> None:
        t0 = time.time()
        while time.time() - t0 < timeout:
            tmps = list((out / "scenes").glob(".tmp-*/scene.usda")) if (out / "scenes").exists() else []
            if tmps:
                time.sleep(0.3)  # the worker is importing / simulating now
                kill()
                return
            time.sleep(0.05)

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    return th


def test_worker_segfault_mid_scene_is_explained_and_the_next_scene_composed(library, tmp_path: Path) -> None:
    """A worker killed with SIGSEGV mid-scene: the failure note quotes the last lines of that worker's log,
    which is kept under its own name and holds faulthandler's report; the failure line in
    OUT/logs/failures.jsonl names the signal, the seed and the log; the batch goes on with the next seed."""
    from mixcount.progress import NullProgress
    from mixcount.run.compose import compose_scenes
    from mixcount.run.failures import failures_by_cause, read_failures
    from mixcount.run.local import LocalExecutor

    pool, assets = library
    out = tmp_path / "out"
    notes: list[str] = []

    class Notes(NullProgress):  # the run's notes (what a user sees on the terminal)
        def note(self, message: str) -> None:
            notes.append(message)

    with LocalExecutor(1, log_dir=out / "logs", recycle_after=0, settle_ahead=False) as ex:
        killed: list[int] = []

        def kill() -> None:
            for _ in range(1200):
                worker = ex.workers[0]
                if worker.pid and worker.ready:  # started: the scene is in its hands now
                    pid = worker.pid
                    time.sleep(0.5)
                    os.kill(pid, signal.SIGSEGV)
                    killed.append(pid)
                    return
                time.sleep(0.05)

        th = _kill_when_tmp_scene_appears(out, kill)
        summary = compose_scenes(pool=pool, config=_config(), out_dir=out, assets_dir=assets, n=1,
                                 executor=ex, progress=Notes())
        th.join(5)
    assert killed
    failure = summary.failures[0]
    assert summary.failed == 1 and "worker died (SIGSEGV, exit code -11)" in failure["error"]
    assert failure["cause"] == "worker SIGSEGV" and failure["exit_code"] == -signal.SIGSEGV
    kept = Path(failure["log"])
    assert kept.name.endswith(f"-{killed[0]}-SIGSEGV.log") and kept.parent == out / "logs"
    log = kept.read_text()
    assert "Fatal Python error: Segmentation fault" in log and "most recent call first" in log
    assert "Segmentation fault" in failure["log_tail"] and failure["log_tail"].splitlines()[-1] in log
    note = next(n for n in notes if "failed [worker SIGSEGV]" in n)
    assert "Segmentation fault" in note and "seed 1" in note
    assert summary.written == 1  # the batch went on with the next seed
    assert [d.name for d in _scenes(out)] == ["scene_000002"]
    assert not list((out / "scenes").glob(".tmp-*"))
    lines = read_failures(out)
    assert [(r["scene_id"], r["seed"], r["cause"], r["exit"]) for r in lines] == [
        ("scene_000001", 1, "worker SIGSEGV", "SIGSEGV, exit code -11")]
    assert lines[0]["reproduce"] == "mixcount compose --n 1 --seed 1 --split train"
    assert failures_by_cause(out)["by_cause"] == {"worker SIGSEGV": 1}


def test_killed_compose_process_takes_its_workers_and_the_rerun_completes(library, tmp_path: Path) -> None:
    """``kill -9`` of the compose process alone (not its process group): its render and settle-ahead workers
    are gone within 3 s, nothing half-written is a scene, the rerun completes and ``verify`` passes."""
    from mixcount.cli import main

    pool, assets = library
    out = tmp_path / "out"
    script = (
        "import sys; from pathlib import Path\n"
        "from tests.test_blender_worker import _config\n"
        "from mixcount.demo.demo_pools import pool_from_demo_library\n"
        "from mixcount.run.compose import compose_scenes\n"
        f"pool = pool_from_demo_library(Path({str(Path(pool[0].model_path).parent.parent)!r}))\n"
        f"compose_scenes(pool=pool, config=_config(), out_dir=Path({str(out)!r}), assets_dir=Path({str(assets)!r}),"
        " n=2, progress=False)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=PROJECT_ROOT, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers: list[int] = []

    def kill() -> None:
        workers.extend(child_pids(proc.pid))
        os.kill(proc.pid, signal.SIGKILL)

    th = _kill_when_tmp_scene_appears(out, kill)
    proc.wait(timeout=300)
    th.join(5)
    assert proc.returncode == -signal.SIGKILL and workers
    deadline = time.monotonic() + 3.0
    while any(pid_running(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = [p for p in workers if pid_running(p)]
    for p in left:  # do not leave them to the next tests
        os.kill(p, signal.SIGKILL)
    assert not left, f"workers {left} outlived their compose process by 3 s"
    assert _scenes(out) == []  # nothing half-written is visible as a scene
    from mixcount.run.compose import compose_scenes

    summary = compose_scenes(pool=pool, config=_config(), out_dir=out, assets_dir=assets, n=2,
                             progress=False)
    assert summary.written == 2 and summary.failed == 0
    assert [d.name for d in _scenes(out)] == ["scene_000001", "scene_000002"]
    assert not list((out / "scenes").glob(".tmp-*"))
    assert main(["verify", str(out)]) == 0
    again = compose_scenes(pool=pool, config=_config(), out_dir=out, assets_dir=assets, n=2,
                           progress=False)
    assert again.skipped == 2 and again.written == 2
    assert summary.outputs["dataset"] and again.outputs == {}  # nothing new: the resumed call does not re-merge


def test_compose_passes_choose_the_written_files(library, tmp_path: Path) -> None:
    from mixcount.dataset import read_depth
    from mixcount.run.compose import compose_scenes

    pool, assets = library
    out = tmp_path / "out"
    summary = compose_scenes(pool=pool, config=_config("compose.resolution=64", "compose.depth_format='exr32'"),
                             out_dir=out, assets_dir=assets, n=1, progress=False, passes="depth")
    assert summary.written == 1
    d = _scenes(out)[0]
    assert (d / "depth.exr").is_file() and (d / "rgb.png").is_file() and (d / "coco.json").is_file()
    for name in ("normal.png", "normal.npy", "instance.png", "class.png", "depth.png", "depth.npy"):
        assert not (d / name).exists(), name
    meta = json.loads((d / "metadata.json").read_text())
    assert set(meta["passes"]) == {"depth"} and meta["files"]["depth"] == "depth.exr"
    assert meta["render_device"] == {"used": "CPU", "backend": "NONE", "devices": []}  # compose.device = "cpu"
    depth = read_depth(d)
    assert depth.shape == (64, 64) and depth.dtype == np.float32 and (depth > 0).mean() > 0.5
