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

import numpy as np
import pytest

from tests.conftest import PROJECT_ROOT

pytestmark = [pytest.mark.blender, pytest.mark.slow]

V_T = 0.4


def _config(*extra: str):
    from mixcount.config import load_config

    return load_config([PROJECT_ROOT / "configs" / "quick.toml"],
                       ["compose.render_threads=2", "compose.resolution=128", "compose.samples=4", *extra])


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory):
    from mixcount.demo.library import generate_demo_library
    from mixcount.demo.pool import pool_from_demo_library

    root = tmp_path_factory.mktemp("lib")
    generate_demo_library(root / "demo", seed=0, n_objects=8)
    return pool_from_demo_library(root / "demo"), root / "assets"


@pytest.fixture(scope="module")
def composed(library, tmp_path_factory: pytest.TempPathFactory):
    from mixcount.run.compose import compose_scenes

    pool, assets = library
    out = tmp_path_factory.mktemp("out")
    summary = compose_scenes(pool=pool, config=_config(), out_dir=out, assets_dir=assets, n=2, seed=1,
                             progress=False, oracle=True)
    return out, summary


def _scenes(out: Path) -> list[Path]:
    return sorted(d for d in (out / "scenes").iterdir() if d.is_dir() and not d.name.startswith("."))


def test_compose_writes_n_complete_scenes(composed) -> None:
    out, summary = composed
    assert summary.written == 2 and summary.failed == 0
    dirs = _scenes(out)
    assert len(dirs) == 2
    for d in dirs:
        for name in ("rgb.png", "instance.png", "class.png", "depth.png", "normal.png", "scene.usda",
                     "settled.usda", "coco.json", "metadata.json"):
            assert (d / name).is_file(), name
        meta = json.loads((d / "metadata.json").read_text())
        assert meta["complete"] and meta["n_counted"] >= 1
        assert {"stage", "worker", "annotate", "total", "worker.physics", "worker.rgb"} <= set(meta["timings"])
        assert meta["camera"]["K"][0][0] > 0 and len(meta["camera"]["cam_to_world"]) == 4
        scene_cfg = _config()["scene"]  # the physics values used are the stage's, recorded as such
        assert meta["physics"]["substeps"] == scene_cfg["physics_substeps"] == meta["spec"]["physics"]["substeps"]
        assert meta["physics"]["frames"] == scene_cfg["physics_frames"]
        assert (d / "exemplars").is_dir() and any((d / "exemplars").iterdir())
    summary_json = json.loads((out / "dataset.json").read_text())
    assert summary_json["counts"]["scenes"] == 2
    assert (out / "preview.png").is_file()
    assert not list((out / "scenes").glob(".tmp-*"))


def test_coco_masks_equal_instance_map_and_counts(composed) -> None:
    from PIL import Image
    from pycocotools import mask as mask_util
    from pycocotools.coco import COCO

    out, _ = composed
    merged = COCO(str(out / "annotations" / "instances_train.json"))
    assert len(merged.getImgIds()) == 2
    for d in _scenes(out):
        inst = np.array(Image.open(d / "instance.png"))
        cls = np.array(Image.open(d / "class.png"))
        rgb = Image.open(d / "rgb.png")
        assert inst.dtype == np.uint16 and cls.dtype == np.uint16
        assert inst.shape == cls.shape == (rgb.height, rgb.width)
        coco = COCO(str(d / "coco.json"))
        anns = coco.loadAnns(coco.getAnnIds())
        assert anns
        for a in anns:
            m = mask_util.decode(a["segmentation"]).astype(bool)
            assert (m == (inst == a["id"])).all()
            assert a["area"] == int(m.sum())
            assert (cls[m] == a["category_id"]).all()
            assert 0.0 <= a["exemplar_score"] <= 1.0 and 0.0 < a["visibility"] <= 1.0
        ids_in_map = set(np.unique(inst).tolist()) - {0}
        assert ids_in_map == {a["id"] for a in anns}
        for cat in {a["category_id"] for a in anns if not a["is_distractor"]}:
            n_anns = sum(1 for a in anns if a["category_id"] == cat and not a["is_distractor"])
            assert n_anns == len(set(np.unique(inst[cls == cat]).tolist()) - {0})
        meta = json.loads((d / "metadata.json").read_text())
        assert sum(meta["counts"].values()) == sum(1 for a in anns if not a["is_distractor"])


def test_counted_objects_visible_by_oracle_and_raster_agrees(composed) -> None:
    out, _ = composed
    n_checked = 0
    for d in _scenes(out):
        meta = json.loads((d / "metadata.json").read_text())
        oracle = np.load(d / "oracle_masks.npz")
        h, w = oracle["shape"]
        for o in meta["objects"]:
            if o["status"] != "kept":
                continue
            om = np.unpackbits(oracle[f"oracle_{o['instance_id']}"])[: h * w].reshape(h, w).astype(bool)
            rm = np.unpackbits(oracle[f"raster_{o['instance_id']}"])[: h * w].reshape(h, w).astype(bool)
            iou = (om & rm).sum() / max(1, (om | rm).sum())
            assert iou >= 0.99, (d.name, o["name"], iou)
            if o["role"] == "counted":
                assert o["visible_px"] / om.sum() >= 1.0 - V_T - 1e-9, (d.name, o["name"])
                n_checked += 1
    assert n_checked >= 2


def test_depth_normals_and_settled_poses(composed) -> None:
    from pxr import Usd

    from mixcount.usd.read import labelled_prims

    out, _ = composed
    for d in _scenes(out):
        meta = json.loads((d / "metadata.json").read_text())
        h, w = meta["image"]["height"], meta["image"]["width"]
        from mixcount.dataset import read_depth, read_normals

        assert meta["passes"]["depth"]["format"] == "png16" and meta["files"]["normal"] == "normal.png"
        depth = read_depth(d / meta["files"]["depth"])
        normal = read_normals(d)
        assert depth.shape == (h, w) and depth.dtype == np.float32
        assert normal.shape == (h, w, 3) and normal.dtype == np.float32
        surf = depth > 0
        assert surf.mean() > 0.5
        norms = np.linalg.norm(normal[surf], axis=1)
        assert np.median(np.abs(norms - 1.0)) < 1e-3
        steps = depth[surf] / meta["passes"]["depth"]["unit_m"]  # 16-bit PNG: whole steps of the stored unit
        assert np.abs(steps - np.rint(steps)).max() < 0.01
        assert np.median(normal[surf][:, 2]) > 0  # camera space: surfaces face the camera (+z)
        dist = np.linalg.norm(np.array(meta["camera"]["cam_to_world"])[:3, 3])
        assert 0.2 * dist < np.median(depth[surf]) < 3.0 * dist
        # planar depth: floor pixels (top face z = 0) equal the ray-plane intersection along the optical axis
        from PIL import Image

        inst = np.array(Image.open(d / "instance.png"))
        K, C = np.array(meta["camera"]["K"]), np.array(meta["camera"]["cam_to_world"])
        matches = 0
        for r, c in ((1, 1), (1, w - 2), (h - 2, 1), (h - 2, w - 2)):
            ray = C[:3, :3] @ np.array([(c + 0.5 - K[0, 2]) / K[0, 0], -(r + 0.5 - K[1, 2]) / K[1, 1], -1.0])
            planar = -C[2, 3] / ray[2]
            if inst[r, c] == 0 and planar > 0:
                assert depth[r, c] <= planar * 1.01  # never farther than the floor
                if abs(depth[r, c] - planar) < 0.01 * planar:
                    matches += 1
                    assert np.allclose(normal[r, c], C[:3, :3].T @ [0.0, 0.0, 1.0], atol=0.05)
        assert matches >= 2
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
        dropped = [o for o in meta["objects"] if o["status"] != "kept"]
        for o in dropped:
            assert not stage.GetPrimAtPath(o["path"])
            assert o["reason"] in ("below_floor", "flung_out", "interpenetration", "unstable",
                                   "origin_outside_frame", "occluded")


def test_worker_timeout_and_restart(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mixcount.blender.contract import SceneRequest
    from mixcount.blender.worker import BlenderWorker
    from mixcount.errors import RenderError

    monkeypatch.setattr("mixcount.blender.worker.WORKER_MODULE", "tests.fault_worker")  # adds op "sleep"
    with BlenderWorker(name="t", log_dir=tmp_path) as w:
        first = w.request({"op": "ping"}, timeout=120)["pid"]
        with pytest.raises(RenderError, match="timed out"):
            w.request({"op": "sleep", "seconds": 30}, timeout=1.0)
        assert not w.alive()
        second = w.request({"op": "ping"}, timeout=120)["pid"]
        assert second != first and w.restarts == 1
        with pytest.raises(RenderError, match="scene failed"):
            w.render_scene(SceneRequest(stage=str(tmp_path / "missing.usda"), out_dir=str(tmp_path / "x"), threads=1,
                                        oracle=False), timeout=60)
        assert w.request({"op": "ping"}, timeout=60)["pid"] == second  # a failed scene keeps the worker


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


def test_worker_killed_mid_scene_fails_only_that_scene(library, tmp_path: Path) -> None:
    from mixcount.run.compose import compose_scenes
    from mixcount.run.local import LocalExecutor

    pool, assets = library
    out = tmp_path / "out"
    with LocalExecutor(1, log_dir=tmp_path) as ex:
        killed: list[int] = []

        def kill() -> None:
            for _ in range(200):
                pid = ex.workers[0].pid
                if pid:
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                    return
                time.sleep(0.05)

        th = _kill_when_tmp_scene_appears(out, kill)
        summary = compose_scenes(pool=pool, config=_config(), out_dir=out, assets_dir=assets, n=1, seed=1,
                                 executor=ex, progress=False)
        th.join(5)
    assert killed
    assert summary.failed == 1 and "worker died" in summary.failures[0]["error"]
    assert summary.written == 1  # the batch went on with the next seed
    assert [d.name for d in _scenes(out)] == ["scene_000002"]
    assert not list((out / "scenes").glob(".tmp-*"))


def test_killed_run_leaves_no_partial_scene_and_rerun_completes(library, tmp_path: Path) -> None:
    pool, assets = library
    out = tmp_path / "out"
    script = (
        "import sys; from pathlib import Path\n"
        "from tests.test_blender_worker import _config\n"
        "from mixcount.demo.pool import pool_from_demo_library\n"
        "from mixcount.run.compose import compose_scenes\n"
        f"pool = pool_from_demo_library(Path({str(Path(pool[0].model_path).parent.parent)!r}))\n"
        f"compose_scenes(pool=pool, config=_config(), out_dir=Path({str(out)!r}), assets_dir=Path({str(assets)!r}),"
        " n=2, seed=1, progress=False)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=PROJECT_ROOT, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    th = _kill_when_tmp_scene_appears(out, lambda: os.killpg(proc.pid, signal.SIGKILL))
    proc.wait(timeout=300)
    th.join(5)
    assert proc.returncode == -signal.SIGKILL
    assert _scenes(out) == []  # nothing half-written is visible as a scene
    from mixcount.run.compose import compose_scenes

    summary = compose_scenes(pool=pool, config=_config(), out_dir=out, assets_dir=assets, n=2, seed=1,
                             progress=False)
    assert summary.written == 2 and summary.failed == 0
    assert [d.name for d in _scenes(out)] == ["scene_000001", "scene_000002"]
    assert not list((out / "scenes").glob(".tmp-*"))
    again = compose_scenes(pool=pool, config=_config(), out_dir=out, assets_dir=assets, n=2, seed=1,
                           progress=False)
    assert again.skipped == 2 and again.written == 2
    assert summary.outputs["dataset"] and again.outputs == {}  # nothing new: the resumed call does not re-merge


def test_compose_passes_choose_the_written_files(library, tmp_path: Path) -> None:
    from mixcount.dataset import read_depth
    from mixcount.run.compose import compose_scenes

    pool, assets = library
    out = tmp_path / "out"
    summary = compose_scenes(pool=pool, config=_config("compose.resolution=64", "compose.depth_format='exr32'"),
                             out_dir=out, assets_dir=assets, n=1, seed=1, progress=False, passes="depth")
    assert summary.written == 1
    d = _scenes(out)[0]
    assert (d / "depth.exr").is_file() and (d / "rgb.png").is_file() and (d / "coco.json").is_file()
    for name in ("normal.png", "normal.npy", "instance.png", "class.png", "depth.png", "depth.npy"):
        assert not (d / name).exists(), name
    meta = json.loads((d / "metadata.json").read_text())
    assert set(meta["passes"]) == {"depth"} and meta["files"]["depth"] == "depth.exr"
    depth = read_depth(d)
    assert depth.shape == (64, 64) and depth.dtype == np.float32 and (depth > 0).mean() > 0.5
