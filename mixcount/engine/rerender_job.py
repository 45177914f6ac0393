"""A settled scene rendered again (bpy): the ``rerender`` op and the ``devices`` op.

:func:`run_rerender` loads a settled stage (``settled.usda`` of a finished scene) with the scene job's own
loader (:func:`~mixcount.engine.scene_build.load_scene`), then, instead of physics and after-physics
placement, puts every body at the matrix the source scene's metadata.json recorded (``req.poses``,
float64: exactly what the original render used) and every camera at the pose of ``req.views`` (the scene's
own cameras at their recorded ``cam_to_world`` first, then any new ones). From there it runs the scene
job's steps unchanged: frame check, silhouettes, the id-pass visibility loop, passes, amodal masks, RGB,
and on request the one-render-per-object reference. Nothing is simulated, placed or drawn at random here.

Two annotation rules (``req.rule``): ``all_cameras`` (the paper's: an object whose origin leaves a frame
or whose occlusion reaches v_t in any view is removed from the scene and the views re-rendered, as a
composed scene does with its own cameras) and ``per_view`` (nothing removed; view k's id map and
annotations hold the objects whose origin is in its frame and that are more than 1 - v_t visible in it).

The import, the floor and the lights are paid once for all views; with ``req.persistent_data`` Cycles
keeps its scene data (BVH, images) between the RGB renders of the views (``render.use_persistent_data``).
:func:`select_device` enables CUDA / OptiX devices through Cycles' add-on preferences (:mod:`mixcount.engine.devices`).

:func:`render_views` (every step after the poses) is shared with ``compose --views``:
:func:`render_more_views` runs it inside the ``scene`` request on the pile that request has just settled,
with the new cameras drawn as ``mixcount render`` draws them (:func:`mixcount.scene.views.plan_views`).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, Sequence

import numpy as np

import mixcount.scene_decisions as D
from mixcount.engine import devices
from mixcount.engine.cameras import Placement, camera_record, set_matrix
from mixcount.engine.scene_build import SceneState, load_scene
from mixcount.engine.scene_steps import (
    Timer,
    check_frame,
    final_status,
    place_poses,
    reference_check,
    silhouettes,
    visibility_loop,
    write_amodal_masks,
    write_passes,
)
from mixcount.scene_config import RULE_ALL_CAMERAS, RULE_PER_VIEW
from mixcount.worker.contract import STATUS_EMPTY, STATUS_OK, CameraView, SceneRequest, SceneResult, view_suffix
from mixcount.worker.rerender_contract import DevicesRequest, DevicesResult, RenderView, RerenderRequest

# an occlusion threshold no object reaches (D.occluded drops visibility <= 1 - threshold = -1): the
# per-view rule measures every view with the visibility loop and drops nothing
NEVER_OCCLUDED = 2.0
def select_device(device: str, scene: Any = None) -> DevicesResult:
    """Cycles' devices for a re-render's ``device`` (cpu | gpu | auto): :func:`mixcount.engine.devices.select`,
    whose ``gpu`` error line names ``rerender.device``."""
    return devices.select(device, scene, key="rerender.device")


def probe_devices(req: DevicesRequest) -> DevicesResult:
    """The ``devices`` op: what ``req.device`` would render on in this process (nothing is rendered)."""
    return select_device(req.device)


def _place_cameras(state: SceneState, views: tuple[RenderView, ...]) -> list[dict[str, Any]]:
    """One Blender camera per view: the stage's cameras reused in order, copies of the first for more
    (same camera data settings), each at its view's pose and lens; stage cameras beyond the views removed.
    Returns each view's framing record."""
    import bpy

    template = state.cam_objs[0]
    objs = []
    for k, view in enumerate(views):
        if k < len(state.cam_objs):
            obj = state.cam_objs[k]
        else:
            obj = template.copy()
            obj.data = template.data.copy()
            obj.name = obj.data.name = view.name
            state.scene.collection.objects.link(obj)
        obj.data.lens = view.focal_length_mm
        obj.data.sensor_width = view.sensor_width_mm
        obj.data.clip_start, obj.data.clip_end = view.clip_range
        set_matrix(obj, np.asarray(view.cam_to_world, dtype=np.float64))
        objs.append(obj)
    for extra in state.cam_objs[len(views):]:
        bpy.data.objects.remove(extra, do_unlink=True)
    state.cam_objs = objs
    state.scene.camera = objs[0]
    for recs in state.views.values():  # records of the scene's own cameras (compose --views): one per new camera
        recs.extend({"camera": c.name} for c in objs[len(recs):])
    return [dict(v.framing) for v in views]


def _apply_settings(state: SceneState, req: RerenderRequest) -> None:
    """New resolution / samples / denoiser where the request asks (0 / "scene" keep the stage's)."""
    render = state.spec.render
    changes: dict[str, Any] = {}
    if req.resolution:
        changes["resolution"] = req.resolution
        state.scene.render.resolution_x = state.scene.render.resolution_y = req.resolution
    if req.samples:
        changes["samples"] = req.samples
    if req.denoise != "scene":
        changes["denoise"] = req.denoise == "on"
    if changes:
        state.spec = replace(state.spec, render=replace(render, **changes))


def _apply_poses(state: SceneState, req: RerenderRequest) -> None:
    """Every body at its recorded matrix (the collision proxies removed): exactly the original's poses."""
    by_name = {}
    for i, o in enumerate(state.objects):
        m = req.poses.get(o.path)
        if m is None:
            raise RuntimeError(f"no recorded pose for {o.path} (the source metadata.json and settled.usda disagree)")
        mat = np.asarray(m, dtype=np.float64)
        by_name[state.blender_objects[o.path].name] = mat
        lo, _ = D.world_bounds(state.cache.columns[o.asset], mat)
        state.update(i, matrix_world=tuple(tuple(float(v) for v in row) for row in mat), min_z=float(lo[2]))
    place_poses(state, by_name)


def _per_view_keep(state: SceneState, k: int) -> list[int]:
    """Instance ids annotated in view ``k`` by the per-view rule: origin in its frame and kept by compose's
    visibility rule in that view alone (more than 1 - v_t visible, :func:`D.occluded`'s complement)."""
    v_t = state.spec.render.visibility_threshold
    keep = []
    for i in state.kept():
        view = state.view(i, k)
        if view["in_frame"] and not D.occluded({0: float(view["visibility"])}, v_t):
            keep.append(state.objects[i].instance_id)
    return keep


def _origins_per_view(state: SceneState, cameras: list[Any]) -> None:
    """Per-view rule: each object's origin position and in-frame flag per view (nothing dropped)."""
    for i in state.kept():
        for k, camera in enumerate(cameras):
            origin, inside = D.origin_in_frame(camera, np.array(state.objects[i].matrix_world))
            state.view(i, k).update(origin_px=list(origin), in_frame=bool(inside))
            if k == 0:
                state.update(i, origin_px=origin)


def run_rerender(req: RerenderRequest) -> SceneResult:
    """Handle one ``rerender`` request (module docstring); returns the SceneResult like the ``scene`` op."""
    timer = Timer()
    with timer.stage("device"):
        device = devices.use(req.device, key="rerender.device")  # kept for every render setting made later
    with timer.stage("import"):
        state = load_scene(req.scene_request())
        state.scene.cycles.device = device.used
        state.diagnostics.append({"kind": "device", **device.to_dict()})
    with timer.stage("poses"):
        _apply_poses(state, req)
        _apply_settings(state, req)
    return render_views(state, req.views, rule=req.rule, persistent_data=req.persistent_data,
                        req=req.scene_request(), timer=timer)


def render_more_views(state: SceneState, req: SceneRequest, placement: Placement, renders: int,
                      timer: Timer) -> SceneResult:
    """``compose --views``: a scene whose own cameras the scene job has just settled, placed and checked
    (status ok) gets ``req.more_views``' cameras in the same process, then every view is annotated and
    rendered by :func:`render_views` exactly as ``mixcount render`` does from the finished scene: the own
    cameras at the poses they rendered from, the new ones drawn by :func:`~mixcount.scene.views.plan_views`
    from the same settled pile. No second import, no physics."""
    from mixcount.scene.views import plan_views

    more = req.more_views
    assert more is not None
    own = [RenderView(name=c.name, cam_to_world=tuple(tuple(float(v) for v in row) for row in cam.cam_to_world),
                      focal_length_mm=float(c.data.lens), sensor_width_mm=float(c.data.sensor_width),
                      clip_range=(float(c.data.clip_start), float(c.data.clip_end)),
                      framing=placement.framing(k))
           for k, (c, cam) in enumerate(zip(state.cam_objs, placement.cameras))]
    spec = state.spec
    counted = state.kept("counted")
    centres = np.array([np.asarray(state.objects[i].matrix_world)[:3, 3] for i in counted]).reshape(-1, 3)
    sizes = np.array([state.objects[i].size_m for i in counted])
    diag = float(np.linalg.norm(spec.container.extent_m)) if spec.container is not None else None
    drawn = plan_views(more.plan, spec.cameras[0], diag, spec.seed, centres, sizes, own[0].cam_to_world, len(own))
    state.diagnostics.append({"kind": "more_views", "own": len(own), "new": len(drawn), "rule": more.rule})
    return render_views(state, own + [RenderView.of(v) for v in drawn], rule=more.rule,
                        persistent_data=more.persistent_data, req=req, timer=timer, renders=renders)


def render_views(state: SceneState, views: Sequence[RenderView], *, rule: str, persistent_data: bool,
                 req: SceneRequest, timer: Timer, renders: int = 0) -> SceneResult:
    """Every view of a settled scene (bodies at their final poses, proxies gone): one Blender camera per
    view, then the scene job's steps under ``rule`` (module docstring): frame check, silhouettes, the
    id-pass visibility loop, passes and amodal masks of ``req``, RGB per view (each timed), the reference
    check on ``req.oracle``; ``renders`` id passes were rendered before (the SceneResult counts them all)."""
    from mixcount.engine.visibility import camera_model

    with timer.stage("poses"):
        framings = _place_cameras(state, tuple(views))
        cameras = [camera_model(state.scene, c) for c in state.cam_objs]
    with timer.stage("frame_check"):
        if rule == RULE_ALL_CAMERAS:
            check_frame(state, cameras)
        else:
            _origins_per_view(state, cameras)
    with timer.stage("silhouettes"):
        masks = [silhouettes(state, cam, req.threads, k) for k, cam in enumerate(cameras)]
    if rule == RULE_PER_VIEW:  # measure every view, drop nothing: the loop's threshold set out of reach
        spec = state.spec
        state.spec = replace(spec, render=replace(spec.render, visibility_threshold=NEVER_OCCLUDED))
        id_passes, more = visibility_loop(state, masks, timer)
        state.spec = spec
        keeps = [_per_view_keep(state, k) for k in range(len(cameras))]
        counted = {o.instance_id for o in state.objects if o.role == "counted" and o.kept}
        status = STATUS_OK if any(counted & set(k) for k in keeps) else STATUS_EMPTY
    else:
        id_passes, more = visibility_loop(state, masks, timer)
        status = final_status(state)
        keeps = []
    view_passes: list[dict[str, Any]] = [{} for _ in cameras]
    if status == STATUS_OK:
        with timer.stage("write_passes"):
            for k, cam in enumerate(cameras):
                view_passes[k] = write_passes(state, id_passes[k], cam, req, k)
                if keeps:  # per view: only this view's objects in its id map and amodal file
                    np.save(state.out_dir / f"ids{view_suffix(k)}.npy", D.instance_map(id_passes[k]["index"], keeps[k]))
                write_amodal_masks(state, masks[k], id_passes[k], k)
        with timer.stage("rgb"):
            _render_all(state, persistent_data)
        if req.oracle:
            with timer.stage("oracle"):
                for k, cam in enumerate(cameras):
                    reference_check(state, masks[k], cam, k)
    for i, recs in state.views.items():
        state.update(i, views=tuple({k: v for k, v in view.items() if k != "in_frame"} for view in recs))
    spec = state.spec
    records = [camera_record(c, cam) for c, cam in zip(state.cam_objs, cameras)]
    out_views = tuple(CameraView(name=c.name, suffix=view_suffix(k), camera=records[k], framing=framings[k],
                                 passes=view_passes[k]) for k, c in enumerate(state.cam_objs))
    return SceneResult(
        status=status, stage=str(state.stage_path), scene_id=spec.scene_id, seed=spec.seed,
        visibility_threshold=spec.render.visibility_threshold, id_pass_rounds=renders + more,
        physics=spec.physics.to_dict(), camera=records[0], lights=state.lights, objects=tuple(state.objects),
        views=out_views, diagnostics=tuple(state.diagnostics), timings=dict(timer.times))


def _render_all(state: SceneState, persistent_data: bool) -> None:
    """Every view's RGB image, each timed (wall and this process's CPU: the ``rgb_per_view`` diagnostic)."""
    state.scene.render.use_persistent_data = persistent_data
    rgb_times, rgb_cpu = [], []
    for k in range(len(state.cam_objs)):
        t, c = time.perf_counter(), time.process_time()
        _render_one(state, k)
        rgb_times.append(round(time.perf_counter() - t, 4))
        rgb_cpu.append(round(time.process_time() - c, 4))
    state.diagnostics.append({"kind": "rgb_per_view", "seconds": rgb_times, "cpu_seconds": rgb_cpu,
                              "persistent_data": persistent_data})


def _render_one(state: SceneState, k: int) -> None:
    """View ``k``'s RGB image with the stage's (or the request's) samples and denoiser."""
    from mixcount.engine import render_passes as P

    if k == 0:
        applied = P.configure_rgb(state.scene, state.spec.render)
        state.diagnostics.append({"kind": "rgb", **applied})
    state.scene.camera = state.cam_objs[k]
    P.render_to(state.scene, state.out_dir / f"rgb{view_suffix(k)}.png")
    state.scene.camera = state.cam_objs[0]
