"""The scene job's steps after the poses (bpy), shared by a composed scene
(:mod:`mixcount.engine.scene_job`), a count target's take-out and top-up (:mod:`mixcount.engine.count_topup`)
and a re-render (:mod:`mixcount.engine.rerender_job`): the frame check, the silhouettes, the id-pass
visibility loop, the final status, the passes and amodal masks, the RGB render, the reference check, and
the :class:`Timer` of named stages. Imports no other engine step but :mod:`mixcount.engine.cameras`,
:mod:`mixcount.engine.scene_build`, :mod:`mixcount.engine.visibility` and
:mod:`mixcount.engine.render_passes`, so the engine's files form no import circle (issue 48).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Optional

import numpy as np

import mixcount.scene_decisions as D
from mixcount.annotate.raster import PinholeCamera
from mixcount.engine.cameras import set_matrix
from mixcount.engine.scene_build import SceneState
from mixcount.worker.contract import SceneRequest, view_suffix


class Timer:
    """Seconds per named stage (``with timer.stage(name):``), summed over repeats."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}

    def stage(self, name: str) -> "_Stage":
        return _Stage(self, name)


class _Stage:
    def __init__(self, timer: Timer, name: str) -> None:
        self.timer, self.name = timer, name

    def __enter__(self) -> None:
        self.t0 = time.perf_counter()

    def __exit__(self, *exc: Any) -> None:
        self.timer.times[self.name] = round(self.timer.times.get(self.name, 0.0) + time.perf_counter() - self.t0, 4)


def place_poses(state: SceneState, poses: dict[str, np.ndarray]) -> None:
    """Matrices (by render object name) onto the objects; the collision proxies removed."""
    import bpy

    for name, mat in poses.items():
        set_matrix(bpy.data.objects[name], mat)
    proxy_objs = list(state.proxies.values())
    state.bodies = [b for b in state.bodies if b.obj not in proxy_objs]
    for pobj in proxy_objs:
        bpy.data.objects.remove(pobj, do_unlink=True)
    state.proxies.clear()


def check_frame(state: SceneState, cameras: list[PinholeCamera], indices: Optional[list[int]] = None,
                stage: str = "frame") -> None:
    """Drop objects whose origin projects outside any camera's image (or behind it): the paper keeps an
    object "only if their origin projects inside every camera frame". ``indices``: only those objects
    (default: every kept one); ``stage``: the step a drop is recorded under (a count target's rest check
    checks the bodies that moved, under ``count_rest``)."""
    for i in state.kept() if indices is None else indices:
        inside_all = True
        for k, camera in enumerate(cameras):
            origin, inside = D.origin_in_frame(camera, np.array(state.objects[i].matrix_world))
            state.view(i, k)["origin_px"] = list(origin)
            if k == 0:
                state.update(i, origin_px=origin)
            inside_all = inside_all and inside
        if not inside_all:
            state.drop(i, D.OUTSIDE_FRAME, stage)


def silhouettes(state: SceneState, camera: PinholeCamera, threads: int, k: int = 0) -> dict[int, np.ndarray]:
    """Each kept object's unoccluded mask in camera ``k`` (numpy rasteriser), by instance id.

    Objects are rasterised on ``threads`` threads: numpy releases the GIL in the large array
    operations that make up the rasteriser, and each mask depends on its object alone."""
    from concurrent.futures import ThreadPoolExecutor

    from mixcount.engine.visibility import unoccluded_mask

    kept = state.kept()

    def one(i: int) -> np.ndarray:
        o = state.objects[i]
        return unoccluded_mask(camera, state.cache.columns[o.asset], state.cache.corners[o.asset],
                               np.array(o.matrix_world))

    with ThreadPoolExecutor(max_workers=max(1, threads)) as pool:
        results = list(pool.map(one, kept))
    masks: dict[int, np.ndarray] = {}
    for i, mask in zip(kept, results):
        masks[state.objects[i].instance_id] = mask
        px = int(np.count_nonzero(mask))  # a bool sum() is ~10x slower at 1024² (0.1 s of 171 objects)
        state.view(i, k)["unoccluded_px"] = px
        if k == 0:
            state.update(i, unoccluded_px=px)
    return masks


def visibility_loop(state: SceneState, masks: list[dict[int, np.ndarray]], timer: Timer,
                    start: Optional[tuple[list[dict[str, np.ndarray]], list[Optional[tuple[int, int, int, int]]]]] = None,
                    deferred: Optional[list[int]] = None) -> tuple[list[dict[str, np.ndarray]], int]:
    """Render each camera's id pass, measure every kept object's visibility (visible / amodal pixels) in
    each, drop the occluded ones - counted objects and distractors under the same rule, occlusion the
    maximum over the cameras - and re-render (up to MAX_VISIBILITY_ROUNDS times); returns the last id
    passes per camera and the number of renders.

    Dropping an object removes it from the Blender scene, so the next id pass and the final RGB render
    no longer show it; the loop only ends on id passes that hold no dropped object. A re-render covers
    only the box of pixels where the dropped objects were seen (:func:`D.changed_region`; no render at
    all when they were seen nowhere) and is pasted into the previous passes: those are the only pixels
    that removing them changes, and a border render gives them exactly as a full one does.

    ``start`` (id passes per camera and the region each must re-render first, None: none) continues from
    earlier passes instead of full renders: a count target's rest check moves a few bodies
    (:mod:`mixcount.engine.count_topup`).

    ``deferred`` (a list, filled in): stop after the first round's drops without re-rendering; the instance
    ids dropped are appended to it and the passes returned still show them. A count target takes out its
    surplus and runs its rest check before the one re-render that covers all of it
    (:func:`mixcount.engine.count_topup.bring_to_target`): the drops only raise the others' visibility, so
    the objects kept by then are exactly those the re-render would keep."""
    from mixcount.engine import render_passes as P

    exrs = [state.out_dir / f"_ids{view_suffix(k)}.exr" for k in range(len(state.cam_objs))]
    with P.id_pass_series(state.scene):
        id_passes, renders = _visibility_rounds(state, masks, timer, exrs, start, deferred)
    for exr in exrs:
        P.remove_quiet(exr)
    return id_passes, renders


def _visibility_rounds(state: SceneState, masks: list[dict[int, np.ndarray]], timer: Timer, exrs: list[Path],
                       start: Optional[tuple[list[dict[str, np.ndarray]], list[Optional[tuple[int, int, int, int]]]]]
                       = None, deferred: Optional[list[int]] = None) -> tuple[list[dict[str, np.ndarray]], int]:
    """:func:`visibility_loop`'s rounds, rendering camera k's id pass into ``exrs[k]``."""
    from mixcount.engine import render_passes as P

    v_t = state.spec.render.visibility_threshold
    n_cams = len(state.cam_objs)
    rounds = renders = 0
    id_passes: list[Optional[dict[str, np.ndarray]]] = [None] * n_cams
    regions: list[Optional[tuple[int, int, int, int]]] = [None] * n_cams
    if start is not None:
        id_passes, regions = list(start[0]), list(start[1])
    while True:
        with timer.stage("id_pass"):
            for k in range(n_cams):
                state.scene.camera = state.cam_objs[k]
                before = id_passes[k]
                if before is None:
                    id_passes[k] = P.render_id_passes(state.scene, exrs[k])
                    renders += 1
                elif regions[k] is not None:
                    region = regions[k]
                    assert region is not None
                    id_passes[k] = D.paste_region(before, P.render_id_passes(state.scene, exrs[k], region), region)
                    renders += 1
            state.scene.camera = state.cam_objs[0]
        with timer.stage("visibility"):
            kept = state.kept()
            worst: dict[int, float] = {}
            by_inst = {}
            for k in range(n_cams):
                passes_k = id_passes[k]
                assert passes_k is not None
                vis = D.measure_visibility(passes_k["index"], {state.objects[i].instance_id:
                                                               masks[k][state.objects[i].instance_id] for i in kept})
                for i in kept:
                    o = state.objects[i]
                    m = vis[o.instance_id]
                    state.view(i, k).update(visible_px=m.visible_px, amodal_px=m.amodal_px, visibility=m.visibility)
                    if k == 0:
                        state.update(i, visible_px=m.visible_px, amodal_px=m.amodal_px)
                    worst[o.instance_id] = min(worst.get(o.instance_id, 1.0), m.visibility)
                    by_inst[o.instance_id] = i
            for inst, v in worst.items():
                state.update(by_inst[inst], visibility=v)
            low = D.occluded(worst, v_t)
            if not low or rounds >= D.MAX_VISIBILITY_ROUNDS:
                break
            for k in range(n_cams):
                passes_k = id_passes[k]
                assert passes_k is not None
                regions[k] = D.changed_region(passes_k["index"], low)
            for inst in low:
                state.drop(by_inst[inst], D.OCCLUDED, "visibility", visibility=round(worst[inst], 4))
            if deferred is not None:  # the caller re-renders once, after its own changes
                deferred.extend(sorted(low))
                break
            rounds += 1
    return [p for p in id_passes if p is not None], renders


def final_status(state: SceneState) -> str:
    """ok / empty / rejected by the final visibility re-check of every kept counted object and distractor
    (a diagnostic names the failing objects)."""
    def visibility(role: str) -> dict[int, float]:
        return {state.objects[i].instance_id: float(state.objects[i].visibility or 0.0) for i in state.kept(role)}

    status, failing = D.scene_status(visibility("counted"), state.spec.render.visibility_threshold,
                                     visibility("distractor"))
    if failing:
        names = {o.instance_id: o.name for o in state.objects}
        state.diagnostics.append({"kind": "recheck_failed", "objects": [names[i] for i in failing]})
    return status


def write_amodal_masks(state: SceneState, masks: dict[int, np.ndarray], id_passes: dict[str, np.ndarray],
                       k: int = 0) -> None:
    """``amodal<suffix>.npz``: each kept object's amodal mask in camera ``k`` (silhouette | visible pixels,
    packed bits under ``amodal_<instance id>``) and the image ``shape``; the scene writer turns them into RLE."""
    index = id_passes["index"]
    save = {f"amodal_{state.objects[i].instance_id}":
            np.packbits(D.amodal_mask(masks[state.objects[i].instance_id], index, state.objects[i].instance_id))
            for i in state.kept()}
    # a temporary file (the scene writer reads it into coco.json and removes it): not worth compressing
    np.savez(state.out_dir / f"amodal{view_suffix(k)}.npz", shape=np.array(index.shape[:2]), **save)


def write_passes(state: SceneState, id_passes: dict[str, np.ndarray], camera: PinholeCamera,
                 req: SceneRequest, k: int = 0) -> dict[str, Any]:
    """ids<suffix>.npy (kept objects only; the scene writer turns it into instance/class PNGs and
    annotations), and the requested depth (planar metres) and normal (camera space) passes of camera
    ``k`` in their compact formats (:mod:`mixcount.annotate.passes`); returns the written passes' records."""
    from mixcount.annotate.passes import write_depth, write_normals

    suffix = view_suffix(k)
    keep = [state.objects[i].instance_id for i in state.kept()]
    np.save(state.out_dir / f"ids{suffix}.npy", D.instance_map(id_passes["index"], keep))
    written: dict[str, Any] = {}
    if "normal" in req.passes:
        normals = D.camera_normals(id_passes["normal"], camera.cam_to_world, id_passes["depth"])
        written["normal"] = write_normals(state.out_dir, normals, req.normal_format, suffix)
    if "depth" in req.passes:
        written["depth"] = write_depth(state.out_dir, D.planar_depth(id_passes["depth"]), req.depth_format, suffix)
    return written


def render_rgb(state: SceneState) -> None:
    """The final image of every camera (``rgb.png``, ``rgb_cam_1.png``, ...) with the stage's samples and denoiser."""
    from mixcount.engine import render_passes as P

    applied = P.configure_rgb(state.scene, state.spec.render)
    # what Cycles was set to, read back (a diagnostic beside the spec's wish)
    state.diagnostics.append({"kind": "rgb", **applied})
    for k, cam_obj in enumerate(state.cam_objs):
        state.scene.camera = cam_obj
        P.render_to(state.scene, state.out_dir / f"rgb{view_suffix(k)}.png")
    state.scene.camera = state.cam_objs[0]


def reference_check(state: SceneState, masks: dict[int, np.ndarray], camera: PinholeCamera, k: int = 0) -> None:
    """The paper's one-render-per-object masks against the rasterised ones in camera ``k``: oracle_*
    fields on each kept object's view (and on the object for cam_0) and ``oracle_masks<suffix>.npz``
    (packed bits of both masks)."""
    from mixcount.engine.visibility import oracle_masks

    kept = state.kept()
    state.scene.camera = state.cam_objs[k]
    try:
        oracle = oracle_masks(state.scene, [state.blender_objects[state.objects[i].path] for i in kept], state.out_dir)
    finally:
        state.scene.camera = state.cam_objs[0]
    save = {}
    for i in kept:
        o = state.objects[i]
        view = state.view(i, k)
        om, rm = oracle[o.instance_id], masks[o.instance_id]
        union = int((om | rm).sum())
        fields = {"oracle_unoccluded_px": int(om.sum()), "oracle_iou": int((om & rm).sum()) / union if union else 1.0,
                  "oracle_visibility": (int(view["visible_px"]) / int(om.sum())) if om.any() else 0.0}
        view.update(fields)
        if k == 0:
            state.update(i, **fields)
        save[f"oracle_{o.instance_id}"] = np.packbits(om)
        save[f"raster_{o.instance_id}"] = np.packbits(rm)
    np.savez_compressed(state.out_dir / f"oracle_masks{view_suffix(k)}.npz",
                        shape=np.array([camera.height, camera.width]), **save)
