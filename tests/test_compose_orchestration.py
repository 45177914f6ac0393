"""Compose orchestration without Blender: a fake worker stands in for bpy behind the real scene task.

Everything but the render is real: the sampler, the USD stage writer, ``run_scene_task`` (temporary
folder, rejected markers, atomic rename), ``finalize_scene`` and the dataset merge. The fake worker
answers "empty", "rejected", crashes or draws every object as a square in the id pass, chosen per seed.
The real bpy worker is tested in test_blender_worker.py.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import trimesh
from PIL import Image

from mixcount.config import load_config
from mixcount.dataset.scene_writer import REJECTED_DIR
from mixcount.run.compose import compose_scenes
from mixcount.run.local import LocalExecutor
from mixcount.run.scene_task import SceneTask, run_scene_task
from mixcount.scene.object_records import ObjectRecord, fallback_captions
from mixcount.scene.spec import SceneSpec
from mixcount.worker.contract import (
    STATUS_EMPTY,
    STATUS_OK,
    STATUS_REJECTED,
    CameraView,
    ObjectResult,
    SceneOutputs,
    SceneResult,
)

SIDE = 96


class FakeWorker:
    """Answers ``run_scene_job`` like the bpy worker: ids.npy + rgb.png in the request's folder and a
    SceneResult. ``plan(seed)`` picks "ok", "empty", "rejected" or "crash"."""

    def __init__(self, spec: SceneSpec, plan: Callable[[int], str], calls: list[int]) -> None:
        self.spec, self.plan, self.calls = spec, plan, calls

    def run_scene_job(self, request, timeout=None):  # noqa: ANN001 - the BlenderWorker signature
        spec = self.spec
        self.calls.append(spec.seed)
        what = self.plan(spec.seed)
        if what == "crash":
            raise RuntimeError("worker died (exit code -9)")
        placed = list(spec.objects) + list(spec.distractors)
        ids = np.zeros((SIDE, SIDE), dtype=np.int32)
        cols = math.ceil(math.sqrt(len(placed)))
        cell = SIDE // cols
        objects = []
        paths = [f"/World/Objects/obj_{p.instance_id:04d}" for p in spec.objects]
        paths += [f"/World/Distractors/dist_{k:02d}" for k in range(1, len(spec.distractors) + 1)]
        for k, (p, prim_path) in enumerate(zip(placed, paths)):
            r, c = divmod(k, cols)
            ids[r * cell + 1:(r + 1) * cell - 1, c * cell + 1:(c + 1) * cell - 1] = p.instance_id
            px = int(np.count_nonzero(ids == p.instance_id))
            objects.append(ObjectResult(
                name=prim_path.rsplit("/", 1)[-1], path=prim_path, role=p.role,
                instance_id=p.instance_id, object_id=p.object_id, class_index=p.class_index, asset="a.usda",
                size_m=p.size_m, spawn_matrix=tuple(tuple(float(i == j) for j in range(4)) for i in range(4)),
                matrix_world=tuple(tuple(float(i == j) for j in range(4)) for i in range(4)), min_z=0.0,
                origin_px=((c + 0.5) * cell, (r + 0.5) * cell), unoccluded_px=px, visible_px=px, visibility=1.0))
        out = Path(request.out_dir)
        np.save(out / "ids.npy", ids)
        Image.fromarray(((ids % 7) * 36).astype(np.uint8)).convert("RGB").save(out / "rgb.png")
        diagnostics: tuple = ()
        if what in ("occluded", "fell"):  # every counted object dropped: out of frame / fallen off the floor
            objects = [replace(o, status="dropped", reason="occluded", visibility=0.0, visible_px=0, unoccluded_px=0)
                       if o.role == "counted" and what == "occluded" else
                       replace(o, status="dropped", reason="below_floor", min_z=-1.25 - 0.01 * k)
                       if o.role == "counted" else o for k, o in enumerate(objects)]
        if what == "outside":  # every counted origin projected right of the frame
            objects = [replace(o, status="dropped", reason="origin_outside_frame", origin_px=(SIDE + 10.0 + k, 5.0))
                       if o.role == "counted" else o for k, o in enumerate(objects)]
        if what == "rejected":
            objects[0] = replace(objects[0], visibility=0.3)
            diagnostics = ({"kind": "recheck_failed", "objects": [objects[0].name]},)
        status = {"ok": STATUS_OK, "empty": STATUS_EMPTY, "rejected": STATUS_REJECTED, "occluded": STATUS_EMPTY,
                  "fell": STATUS_EMPTY, "outside": STATUS_EMPTY}[what]
        view = CameraView(name="cam_0", suffix="", camera={}, framing={"framing": "fixed"}, passes={})
        return SceneResult(status=status, stage=request.stage, scene_id=spec.scene_id, seed=spec.seed,
                           visibility_threshold=spec.render.visibility_threshold, id_pass_rounds=1,
                           physics=spec.physics.to_dict(), camera={"width": SIDE, "height": SIDE} if what == "outside"
                           else {}, lights={}, objects=tuple(objects), views=(view,), diagnostics=diagnostics, timings={})


def _pool(root: Path) -> list[ObjectRecord]:
    shapes = {"cube": trimesh.creation.box((0.06, 0.05, 0.04)),
              "ball": trimesh.creation.icosphere(subdivisions=2, radius=0.03),
              "can": trimesh.creation.cylinder(radius=0.02, height=0.08),
              "cone": trimesh.creation.cone(radius=0.03, height=0.05),
              "tray": trimesh.creation.box((0.3, 0.2, 0.02))}
    pool = []
    for k, (name, mesh) in enumerate(shapes.items(), start=1):
        path = root / f"{name}.glb"
        mesh.export(path)
        dims = tuple(float(v) for v in np.sort(mesh.extents)[::-1])
        pool.append(ObjectRecord(object_id=k, name=name, category=name, dims=dims,
                                 captions=fallback_captions(f"red {name}", name), split="train",
                                 model_path=str(path), content_hash=f"hash{k}"))
    return pool


@pytest.fixture()
def setup(tmp_path: Path):
    config = load_config(["quick"], values={"compose.seed": 100, "compose.split": "train"})
    return config, _pool(tmp_path), tmp_path / "out", tmp_path / "assets"


def _run(setup, plan: Callable[[int], str], n: int, calls: list[int]):
    config, pool, out, assets = setup
    runner = lambda task, _worker: run_scene_task(task, FakeWorker(task.spec, plan, calls))  # noqa: E731
    with LocalExecutor(1, runner=runner, recycle_after=0, settle_ahead=False) as executor:
        return compose_scenes(pool=pool, config=config, out_dir=out, assets_dir=assets, n=n,
                              executor=executor)


def test_empty_rejected_and_failed_seeds_are_replaced_and_finalized(setup) -> None:
    plan = {100: "empty", 101: "rejected", 102: "crash"}
    calls: list[int] = []
    summary = _run(setup, lambda s: plan.get(s, "ok"), 3, calls)
    out = setup[2]
    assert (summary.written, summary.empty, summary.rejected, summary.failed) == (3, 1, 1, 1)
    assert calls == [100, 101, 102, 103, 104, 105]
    assert sorted(p.name for p in (out / "scenes" / REJECTED_DIR).iterdir()) == ["scene_000100.json",
                                                                               "scene_000101.json"]
    assert json.loads((out / "scenes" / REJECTED_DIR / "scene_000101.json").read_text())["status"] == "rejected"
    assert summary.failures[0]["scene_id"] == "scene_000102" and "worker died" in summary.failures[0]["error"]
    scenes = sorted(p.name for p in (out / "scenes").iterdir() if not p.name.startswith("."))
    assert scenes == ["scene_000103", "scene_000104", "scene_000105"]
    assert not list((out / "scenes").glob(".tmp-*")), "a failed scene must not leave a half folder"
    merged = json.loads((out / "annotations" / "instances_train.json").read_text())
    assert len(merged["images"]) == 3
    n_counted = sum(json.loads((out / "scenes" / s / "metadata.json").read_text())["n_counted"] for s in scenes)
    assert n_counted == sum(1 for a in merged["annotations"] if not a["is_distractor"]) > 0
    summary_json = json.loads((out / "dataset.json").read_text())
    assert summary_json["splits"]["train"]["scenes"] == 3
    metas = [json.loads((out / "scenes" / s / "metadata.json").read_text()) for s in scenes]
    split = summary_json["splits"]["train"]  # spawned objects and empty classes summed from every scene
    assert split["counted_spawned"] == sum(m["spawned"]["counted"] for m in metas) >= n_counted
    assert split["classes_without_instances"] == sum(len(m["classes_without_instances"]) for m in metas)
    assert summary_json["counts"] == {"scenes": 3, "counted_objects": n_counted}
    assert (out / "preview.png").is_file()

    # A rerun: the failed seed is retried first (it left nothing behind), rejected seeds stay rejected,
    # finished scenes are skipped, nothing is rendered twice.
    again: list[int] = []
    summary2 = _run(setup, lambda s: "ok", 3, again)
    assert again == [102]
    assert (summary2.written, summary2.skipped) == (3, 2)
    scenes = sorted(p.name for p in (out / "scenes").iterdir() if not p.name.startswith("."))
    assert scenes == ["scene_000102", "scene_000103", "scene_000104", "scene_000105"]
    merged = json.loads((out / "annotations" / "instances_train.json").read_text())
    assert len(merged["images"]) == len({img["file_name"] for img in merged["images"]}) == 4


def test_every_thrown_away_scene_says_which_rule_with_its_figures(setup) -> None:
    """scenes/.rejected/ records name the rule and its numbers (issue 52), and ``mixcount stats`` counts them
    with the failure log's causes (issue 51)."""
    from mixcount.evaluate.stats import compute_stats, summary_lines

    plan = {100: "occluded", 101: "fell", 102: "rejected", 103: "crash", 104: "outside"}
    summary = _run(setup, lambda s: plan.get(s, "ok"), 1, [])
    out = setup[2]
    assert (summary.written, summary.empty, summary.rejected, summary.failed) == (1, 3, 1, 1)
    outside = json.loads((out / "scenes" / REJECTED_DIR / "scene_000104.json").read_text())
    assert outside["rule"] == "empty: origin_outside_frame"
    assert f"origin outside the frame of a camera (cam_0 {SIDE}x{SIDE} px: origins at x {SIDE + 10}-" in outside["why"]
    assert outside["figures"]["origin_outside_frame"]["inside_cam_0"] == 0
    rec = {s: json.loads((out / "scenes" / REJECTED_DIR / f"scene_000{s}.json").read_text()) for s in (100, 101, 102)}
    occluded = rec[100]
    n = occluded["figures"]["counted"]
    assert occluded["rule"] == "empty: occluded" and n > 0
    assert occluded["why"].startswith(f"no counted object kept: all {n} dropped: {n} occluded (visibility 0.00, "
                                      "0.60 needed)")
    assert f"{n} with no pixel in view ({n} with no silhouette in the frame: out of frame" in occluded["why"]
    assert occluded["figures"]["occluded"]["no_silhouette_in_frame"] == n
    assert [o["reason"] for o in occluded["objects"]] == ["occluded"] * n
    fell = rec[101]
    assert fell["rule"] == "empty: fell" and fell["why"].startswith("all ")
    assert "below floor (lowest settled point -1." in fell["why"] and fell["figures"]["below_floor"]["min_z_m"][0] < -1.2
    assert rec[102]["rule"] == "rejected: recheck" and "below 0.60 visible" in rec[102]["why"] and "0.30" in rec[102]["why"]
    stats = compute_stats(out)
    assert stats["thrown_away"]["regenerated"]["by_rule"] == {"empty: fell": 1, "empty: occluded": 1,
                                                               "empty: origin_outside_frame": 1, "rejected: recheck": 1}
    assert stats["thrown_away"]["failures"]["by_cause"] == {"error: RuntimeError": 1}
    text = "\n".join(summary_lines(stats))
    assert "scenes regenerated (scenes/.rejected): 4" in text and "scene failures (logs/failures.jsonl): 1" in text


def test_max_attempts_bounds_a_split_that_never_yields_a_scene(setup) -> None:
    config = setup[0]
    calls: list[int] = []
    summary = _run(setup, lambda s: "empty", 2, calls)
    limit = math.ceil(2 * config.compose.max_attempts_factor) + 4
    assert summary.written == 0 and summary.empty == limit and len(calls) == limit
    assert len(list((setup[2] / "scenes" / REJECTED_DIR).iterdir())) == limit


def test_compose_of_a_split_without_objects_makes_nothing_on_disk(tmp_path: Path) -> None:
    """Through the Python API too (the CLI checks first on its own): no OUT, no empty scenes/ left behind."""
    from types import SimpleNamespace

    from mixcount.errors import CompositionError

    out = tmp_path / "out"
    config = load_config(["quick"], values={"compose.split": "val"})
    with pytest.raises(CompositionError, match="no active objects in split 'val'.*nothing was written"):
        compose_scenes(pool=[SimpleNamespace(split="train")], config=config, out_dir=out, assets_dir=tmp_path, n=1)
    assert not out.exists()


def test_scene_task_is_picklable_plain_data(setup) -> None:
    import pickle

    from mixcount.scene.sampler import sample_scene

    config, pool = setup[0], setup[1]
    spec = sample_scene(7, "train", config, pool)
    task = SceneTask(spec=spec, out_dir="o", assets_dir="a", timeout_s=5.0, threads=1,
                     outputs=SceneOutputs.from_config(load_config().compose))
    assert pickle.loads(pickle.dumps(task)) == task


def test_the_dry_run_plan_names_the_scenes_the_run_writes(setup) -> None:
    """Issue 56: a dry run listed scene_000000/1 while the run wrote scene_000004/5 (seeds 0-3 thrown away
    by an earlier run). The dry run's walk (``dry_plan``, what `compose --dry-run --out OUT` prints) reads OUT
    as the run does; the run then writes exactly the planned ids, kept scenes counting towards n in both."""
    from mixcount.run.seed_plan import dry_plan
    from mixcount.scene.sampler import sample_scene

    config, pool, out, _assets = setup

    def plan(n: int) -> list[str]:
        return [s.scene_id for s in dry_plan(out, "train", 100, n, lambda seed: sample_scene(seed, "train", config, pool),
                                             10).specs]

    assert plan(2) == ["scene_000100", "scene_000101"]  # nothing there yet
    first = _run(setup, lambda s: {100: "empty", 102: "rejected"}.get(s, "ok"), 2, [])
    assert [o["scene_id"] for o in first.outcomes if o["status"] == "written"] == ["scene_000101", "scene_000103"]
    assert plan(2) == []  # the two finished scenes make n = 2
    planned = plan(4)
    assert planned == ["scene_000104", "scene_000105"]
    calls: list[int] = []
    again = _run(setup, lambda s: "ok", 4, calls)
    assert [o["scene_id"] for o in again.outcomes if o["status"] == "written"] == planned
    assert calls == [104, 105] and (again.written, again.skipped) == (4, 2)
    walked = dry_plan(out, "train", 100, 5, lambda seed: seed, 10)
    assert [(s.seed, s.state) for s in walked.passed] == [(100, "rejected"), (101, "kept"), (102, "rejected"),
                                                         (103, "kept"), (104, "kept"), (105, "kept")]
    assert walked.specs == [106] and walked.kept == 4


def test_a_run_says_once_what_its_objects_were_never_given(setup) -> None:
    """Objects never captioned (prompts from file names) or rendered (no external exemplar): one line each,
    with the command that fixes it, in the run's warnings; captioned and rendered objects: no line."""
    config, pool, out, assets = setup
    pool[0] = replace(pool[0], captions=fallback_captions(pool[0].name, pool[0].category))
    summary = compose_scenes(pool=pool, config=config, out_dir=out, assets_dir=assets, n=1,
                             executor=LocalExecutor(1, runner=lambda task, _w: run_scene_task(
                                 task, FakeWorker(task.spec, lambda s: "ok", [])), recycle_after=0, settle_ahead=False))
    caption_lines = [w for w in summary.warnings if "never captioned" in w]
    render_lines = [w for w in summary.warnings if "no canonical render" in w]
    assert len(caption_lines) == 1 and "1 of 5 objects" in caption_lines[0] and "'cube'" in caption_lines[0]
    assert "mixcount catalog caption" in caption_lines[0]
    assert len(render_lines) == 1 and "5 of 5 objects" in render_lines[0] and "mixcount catalog render" in render_lines[0]
    from mixcount.run.readiness import missing_steps

    ready = [replace(o, render_path=str(assets / "r.png")) for o in pool[1:]]  # pool[0]: uncaptioned above
    assert missing_steps(ready, "train") == [] and missing_steps(ready, "val") == []
