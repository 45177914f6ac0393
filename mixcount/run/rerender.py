"""``mixcount render``: every finished scene of a dataset rendered again into a new dataset, no physics.

For each complete scene of ``SRC/scenes/`` (in scene-id order): its ``settled.usda`` is copied into a
temporary folder of ``NEW/scenes/`` as the new scene's ``scene.usda`` (the stage it is rendered from),
with every scene-local file it names (the floor's ``textures/``: :func:`copy_scene_files`),
the poses and camera records of its ``metadata.json`` (float64, exactly what the original render used)
go into a :class:`~mixcount.worker.rerender_contract.RerenderRequest` with the new settings and any new views
(:mod:`mixcount.scene.views`), one bpy worker renders it (:mod:`mixcount.engine.rerender_job`), and the
scene writer finishes the folder exactly as compose does (``finalize_scene``: PNGs, coco.json, a new
settled.usda, metadata.json last). ``NEW/assets/`` holds relative links to ``SRC/assets/``'s entries, so
the copied stages resolve their ``../../assets/`` references. At the end ``NEW`` is merged like a composed
dataset. The source is only read.

Before anything is written every file each stage needs is checked (:func:`check_scene_files`): a
missing floor texture, environment map or asset is an AssetError naming it (exit 2), never a magenta
render. The device is asked for before anything is written too: ``[rerender] device = "gpu"`` on a machine without
one is a RenderError (one line naming what Cycles found; exit 2) and ``NEW`` is not created.
"""

from __future__ import annotations

import json
import os
import shutil
import time
import uuid
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Collection, Optional

import numpy as np

from mixcount.config import Config
from mixcount.errors import CompositionError, RenderError
from mixcount.scene.spec import SceneSpec
from mixcount.worker.client import Worker
from mixcount.worker.contract import STATUS_OK, SceneOutputs, SceneResult
from mixcount.worker.rerender_contract import DevicesRequest, DevicesResult, RenderView, RerenderRequest


@dataclass
class RerenderSummary:
    """What a ``mixcount render`` run did."""

    source: str
    out: str
    device: dict[str, Any]
    scenes: list[dict[str, Any]] = field(default_factory=list)  # scene_id, status, views, seconds, timings
    seconds: float = 0.0
    merged: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def probe_device(worker: Worker, device: str, timeout: float) -> DevicesResult:
    """The worker's answer to ``devices``: a RenderError (one line) when ``gpu`` was asked for and none exists."""
    answer = worker.request({"op": DevicesRequest.OP, "request": DevicesRequest(device).to_dict()}, timeout=timeout)
    if not answer.get("ok"):
        raise RenderError(f"device check failed: {answer.get('error')}")
    res = DevicesResult.from_dict(answer["result"])
    if res.error:
        raise RenderError(res.error + "; nothing was written")
    return res


def finished_scenes(src: Path) -> list[Path]:
    """The complete scene folders of ``src`` (metadata.json says complete), by scene id."""
    from mixcount.dataset.scene_writer import TMP_PREFIX, is_complete

    scenes = Path(src) / "scenes"
    if not scenes.is_dir():
        raise CompositionError(f"{src} holds no scenes/ folder: nothing to render")
    found = [d for d in sorted(scenes.iterdir()) if d.is_dir() and not d.name.startswith((TMP_PREFIX, "."))
             and is_complete(d) and (d / "settled.usda").is_file()]
    if not found:
        raise CompositionError(f"{src}/scenes holds no finished scene with a settled.usda: nothing to render")
    return found


def link_assets(src: Path, dst: Path) -> None:
    """``dst/assets/<entry>`` -> relative link to ``src/assets/<entry>`` (the stages' ``../../assets/``)."""
    assets = src / "assets"
    if not assets.is_dir():
        return
    (dst / "assets").mkdir(parents=True, exist_ok=True)
    for entry in sorted(assets.iterdir()):
        link = dst / "assets" / entry.name
        if not link.exists() and not link.is_symlink():
            os.symlink(os.path.relpath(entry, link.parent), link)


def copy_scene_files(scene_dir: Path, tmp: Path) -> list[str]:
    """Every file inside ``scene_dir`` that its settled.usda names (the procedural floor's
    ``./textures/floor_<pattern>.png``, any other scene-local texture) copied to the same place under
    ``tmp``, so the copied stage resolves them as the original did (issue 60: the new folders had no
    ``textures/`` and every floor rendered magenta). Returns the copied paths, relative."""
    from mixcount.usd.dependencies import dependencies

    root = Path(os.path.abspath(scene_dir))
    copied = []
    for dep in dependencies(scene_dir / "settled.usda"):
        try:
            rel = dep.path.relative_to(root)
        except ValueError:
            continue  # the dataset's assets/ (linked by link_assets) or an absolute path: used where it is
        if (tmp / rel).exists():
            continue
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(dep.path, tmp / rel)
        copied.append(str(rel))
    return copied


def check_scene_files(scenes: list[Path]) -> None:
    """Every file each scene's settled.usda needs (textures, environment maps, assets) can be read, or an
    AssetError naming the first missing one: checked for all scenes before anything is written."""
    from mixcount.usd.dependencies import require_files

    for scene_dir in scenes:
        require_files(scene_dir / "settled.usda",
                      f"scene {scene_dir.name} cannot be rendered again (nothing was written)")


def own_views(meta: dict[str, Any]) -> list[RenderView]:
    """The scene's cameras at the poses recorded in its metadata.json (as they rendered)."""
    views = []
    for cam in meta["cameras"]:
        rec = cam["record"]
        views.append(RenderView(name=str(cam["name"]), cam_to_world=tuple(tuple(float(v) for v in r) for r in rec["cam_to_world"]),
                                focal_length_mm=float(rec["focal_length_mm"]), sensor_width_mm=float(rec["sensor_width_mm"]),
                                clip_range=(float(rec["clip_range"][0]), float(rec["clip_range"][1])),
                                framing=dict(cam["framing"])))
    return views


def new_views(meta: dict[str, Any], spec: SceneSpec, config: Config) -> list[RenderView]:
    """``[rerender] views`` cameras by the paper's rule and/or an orbit of ``frames`` cameras, named after
    the scene's own (cam_<n>, cam_<n+1>, ...): :func:`mixcount.scene.views.plan_views` on the settled pile
    metadata.json records (the worker draws them the same way for ``compose --views``)."""
    from mixcount.scene.views import ViewPlan, plan_views

    kept = [o for o in meta["objects"] if o["status"] == "kept" and o["role"] == "counted"]
    centres = np.array([np.asarray(o["matrix_world"], dtype=np.float64)[:3, 3] for o in kept]).reshape(-1, 3)
    sizes = np.array([float(o["size_m"]) for o in kept])
    diag = float(np.linalg.norm(spec.container.extent_m)) if spec.container is not None else None
    drawn = plan_views(ViewPlan.from_config(config.rerender, config.scene), spec.cameras[0], diag, spec.seed,
                       centres, sizes, meta["cameras"][0]["record"]["cam_to_world"], len(meta["cameras"]))
    return [RenderView.of(v) for v in drawn]


def _captions_and_exemplars(meta: dict[str, Any]) -> tuple[dict[int, dict[str, str]], dict[int, str]]:
    """The source scene's category texts (distractor captions) and external exemplars, as compose had them."""
    captions: dict[int, dict[str, str]] = {}
    exemplars: dict[int, str] = {}
    for c in meta["categories"]:
        oid = int(c["object_id"])
        captions[oid] = {k: c[k] for k in ("short", "concise", "detailed")}
        if c.get("external_exemplar"):
            exemplars[oid] = str(c["external_exemplar"])
    return captions, exemplars


def rerender_scene(scene_dir: Path, dst: Path, config: Config, worker: Worker, *, oracle: bool) -> dict[str, Any]:
    """One finished scene rendered again into ``dst/scenes/<scene_id>`` (module docstring); its record."""
    from mixcount.dataset.manifest import record_scene_files
    from mixcount.dataset.scene_writer import finalize_scene, move_into_place, tmp_dir_for, write_metadata
    from mixcount.run.scene_task import render_fault_of

    t0 = time.perf_counter()
    meta = json.loads((scene_dir / "metadata.json").read_text())
    spec = SceneSpec.from_dict(meta["spec"])
    rr = config.rerender
    tmp = tmp_dir_for(dst, spec.scene_id, uuid.uuid4().hex[:8])
    tmp.mkdir(parents=True)
    try:
        shutil.copyfile(scene_dir / "settled.usda", tmp / "scene.usda")
        copy_scene_files(scene_dir, tmp)
        outputs = SceneOutputs.from_config(config.compose)
        views = own_views(meta) + new_views(meta, spec, config)
        req = RerenderRequest(
            stage=str(tmp / "scene.usda"), out_dir=str(tmp), threads=config.compose.render_threads, oracle=oracle,
            passes=outputs.passes, depth_format=outputs.depth_format, normal_format=outputs.normal_format,
            mesh_cache=outputs.mesh_cache,
            poses={o["path"]: tuple(tuple(float(v) for v in r) for r in o["matrix_world"])
                   for o in meta["objects"] if o["status"] == "kept"},
            views=tuple(views), resolution=rr.resolution, samples=rr.samples, denoise=rr.denoise,
            rule=rr.annotation_rule, device=rr.device, persistent_data=rr.persistent_data)
        t = time.perf_counter()
        answer = worker.request({"op": req.OP, "request": req.to_dict()}, timeout=rr.timeout_s)
        if not answer.get("ok"):
            raise RenderError(f"re-render of {spec.scene_id} failed: {answer.get('error')}")
        result = SceneResult.from_dict(answer["result"])
        timings = {"worker": round(time.perf_counter() - t, 4)}
        if result.status != STATUS_OK:
            return {"scene_id": spec.scene_id, "status": result.status, "views": len(views),
                    "seconds": round(time.perf_counter() - t0, 3)}
        fault = render_fault_of(tmp, result)
        if fault:  # black / magenta where the inputs are not: failed, never written (issue 68)
            raise RenderError(f"re-render of {spec.scene_id}: {fault}")
        render = spec.render
        changes: dict[str, Any] = {}
        if rr.resolution:
            changes["resolution"] = rr.resolution
        if rr.samples:
            changes["samples"] = rr.samples
        if rr.denoise != "scene":
            changes["denoise"] = rr.denoise == "on"
        spec = replace(spec, render=replace(render, **changes)) if changes else spec
        captions, exemplars = _captions_and_exemplars(meta)
        new_meta = finalize_scene(tmp, spec, result, captions=captions, timings=timings,
                                  external_exemplars=exemplars, passes=outputs.passes,
                                  extra={"rerender": {"source": str(scene_dir), "rule": rr.annotation_rule,
                                                      "views": len(views), "own_views": len(meta["cameras"])}})
        new_meta["timings"]["total"] = round(time.perf_counter() - t0, 4)
        write_metadata(tmp, new_meta)
        record_scene_files(tmp)
        move_into_place(tmp, dst / "scenes" / spec.scene_id)
        return {"scene_id": spec.scene_id, "status": "written", "views": len(views),
                "seconds": round(time.perf_counter() - t0, 3), "timings": dict(result.timings),
                "rgb_per_view": next((d["seconds"] for d in result.diagnostics if d.get("kind") == "rgb_per_view"), []),
                "device": next((d for d in result.diagnostics if d.get("kind") == "device"), {})}
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def rerender_dataset(src: Path, dst: Path, config: Config, worker: Worker, *, oracle: bool, merge: bool,
                     progress: Optional[Any], only: Optional[Collection[str]] = None) -> RerenderSummary:
    """Every finished scene of ``src`` (only those whose ids ``only`` names, when given) rendered again into
    the new dataset ``dst`` (module docstring).

    ``dst`` must not exist or be empty, and not be ``src``: the source is never written. The device is
    checked first; nothing is written when it is refused."""
    src, dst = Path(src).resolve(), Path(dst).resolve()
    if dst == src:
        raise CompositionError(f"--out {dst} is the source dataset: the re-render goes into a new folder")
    if dst.exists() and any(dst.iterdir()):
        raise CompositionError(f"--out {dst} exists and is not empty: the re-render goes into a new folder")
    scenes = finished_scenes(src)
    if only is not None:
        unknown = sorted(set(only) - {d.name for d in scenes})
        if unknown:
            raise CompositionError(f"{src} holds no finished scene {', '.join(unknown)}: nothing was written")
        scenes = [d for d in scenes if d.name in set(only)]
    check_scene_files(scenes)
    t0 = time.perf_counter()
    device = probe_device(worker, config.rerender.device, config.rerender.timeout_s)
    summary = RerenderSummary(source=str(src), out=str(dst), device=device.to_dict())
    (dst / "scenes").mkdir(parents=True, exist_ok=True)
    link_assets(src, dst)
    for k, scene_dir in enumerate(scenes):
        summary.scenes.append(rerender_scene(scene_dir, dst, config, worker, oracle=oracle))
        if progress is not None:
            progress(k + 1, len(scenes))
    if merge and any(s["status"] == "written" for s in summary.scenes):
        from mixcount.dataset.merge import finalize_dataset

        summary.merged = finalize_dataset(dst, config=config.to_dict(), config_hash=config.hash,
                                          preview_scenes=config.compose.preview_scenes)
    summary.seconds = round(time.perf_counter() - t0, 3)
    return summary
