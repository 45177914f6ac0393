"""One scene in the worker as named steps: Blender scene -> settle -> visibility filter -> passes (bpy).

:func:`run_scene` runs the steps in order: :func:`~mixcount.engine.scene_build.load_scene` (stage ->
Blender scene, :mod:`mixcount.engine.scene_build`), :func:`settle` (physics), :func:`place_after_physics`
(:func:`check_settled`, then for specs with a placement :func:`frame_cameras` and
:func:`place_distractors_in_view`), :func:`check_frame`, :func:`silhouettes`, :func:`visibility_loop`,
:func:`final_status`, :func:`write_passes`, :func:`write_amodal_masks`, :func:`render_rgb` and, on
request, :func:`reference_check`. A request whose ``settled_poses_file`` names a file that :func:`settle_ahead` (the
``settle`` op, run by a companion process for the next scene) wrote applies those poses
(:func:`read_settled`) instead of running :func:`settle`; either way :func:`place_settled` puts them in. A request with ``more_views`` (``compose
--views``) whose own cameras came out ok goes on in this process to
:func:`mixcount.engine.rerender_job.render_more_views` (new cameras, then every view annotated and
rendered as ``mixcount render`` does). Every decision between them is a pure function of
:mod:`mixcount.annotate.scene_decisions`. What describes the scene (samples, denoise, visibility threshold,
physics) is read from the stage's SceneSpec only; the :class:`~mixcount.worker.contract.SceneRequest`
adds run-time settings (threads, oracle, passes and their formats, mesh cache).

Writes into ``out_dir`` per camera k (suffix "" for cam_0, ``_cam_<k>`` after): ``rgb<suffix>.png``,
``ids<suffix>.npy`` (int32 instance ids of kept counted objects and distractors, 0 elsewhere), the
requested depth pass (planar depth in metres along the optical axis, 0 = no surface) and normal pass
(unit normals in camera space: x right, y up, z towards the viewer; 0 = none) in the formats of
:mod:`mixcount.annotate.passes` (recorded in the result's :class:`~mixcount.worker.contract.CameraView`
``passes``), ``amodal<suffix>.npz`` (each kept object's amodal mask, see :func:`write_amodal_masks`); and returns
the :class:`~mixcount.worker.contract.SceneResult` (over the pipe; no file). Its ``status`` is "ok", "empty"
(no counted object survived: the caller regenerates from the next seed) or "rejected".
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from mixcount.annotate import scene_decisions as D
from mixcount.annotate.raster import PinholeCamera
from mixcount.engine.scene_build import SceneState, load_scene, pose_with_scale
from mixcount.worker.contract import (
    SETTLED_FILE,
    STATUS_OK,
    STATUS_REJECTED,
    CameraView,
    SceneRequest,
    SceneResult,
    SettleResult,
    view_suffix,
)


class Timer:
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


@dataclass(frozen=True)
class Settled:
    """What a settle gives (:func:`settle` here, or :func:`read_settled` from a ``settle`` op's file): the
    settled matrix of every simulated render object, by Blender name, and what happened (the ``rest``
    diagnostic, and ``settled_ahead`` when it was read). :func:`place_settled` puts it into the scene."""

    poses: dict[str, np.ndarray]
    diagnostics: tuple[dict[str, Any], ...]

    @property
    def rest(self) -> dict[str, Any]:
        return next(d for d in self.diagnostics if d.get("kind") == "rest")


def settle(state: SceneState, camera: Optional[PinholeCamera] = None) -> Settled:
    """Rigid-body simulation with exactly the stage's physics values; the settled matrix per active body
    (nothing is placed yet: :func:`place_settled`).

    The early stop waits only for bodies that can still be kept: with after-physics placement those
    above the floor's top within the placement's ``view_radius`` of the scene centre (the cameras are
    framed afterwards); for older specs, with ``camera``, those whose origin is in the camera frame or
    right above a point of the floor that is (a body still falling into view counts). Instances with
    a spec ``release_frame`` > 1 (spawn waves, docs/scene.md) join the simulation at that frame."""
    from mixcount.engine.physics import simulate

    ph = state.spec.physics
    # spawn waves: the body that collides for each instance (its proxy, else itself) -> release frame
    release = {p.instance_id: p.release_frame for p in (*state.spec.objects, *state.spec.distractors)}
    releases = {}
    for o in state.objects:
        obj = state.blender_objects.get(o.path)
        if obj is not None and release.get(o.instance_id, 1) > 1:
            releases[state.proxies.get(obj.name, obj).name] = release[o.instance_id]
    waited_for = None
    if state.spec.placement is not None:
        waited_for = functools.partial(D.near_the_pile, np.zeros(2), state.spec.placement.view_radius)
    elif camera is not None:
        waited_for = functools.partial(D.may_still_be_kept, camera)
    run = simulate(state.scene, state.bodies, frames=ph.frames, substeps=ph.substeps,
                   iterations=ph.solver_iterations, gravity=ph.gravity, rest_speed=ph.rest_speed,
                   waited_for=waited_for, releases=releases)
    poses = run.matrices
    names = {pobj.name: name for name, pobj in state.proxies.items()}
    rest = {"kind": "rest", "proxies": len(state.proxies), "frames_run": run.frames_run,
            "waited_for": run.waited_for, "released_later": len(releases), "last_release": run.last_release,
            "speed_m_s": {names.get(k, k): round(v, 5) for k, v in sorted(run.speeds.items())}}
    for name, pobj in state.proxies.items():  # proxy pose (x the scale baked into it) -> render object
        mat = poses.pop(pobj.name, None)
        if mat is not None:
            scale = state.proxy_scales.get(name)
            poses[name] = mat if scale is None else pose_with_scale(mat, scale)
    return Settled(poses, (rest,))


def place_settled(state: SceneState, settled: Settled) -> None:
    """The settled matrices (by render object name) onto the objects, the collision proxies removed, the
    settle's diagnostics recorded."""
    state.diagnostics.extend(settled.diagnostics)
    place_poses(state, settled.poses)


def place_poses(state: SceneState, poses: dict[str, np.ndarray]) -> None:
    """Matrices (by render object name) onto the objects; the collision proxies removed."""
    import bpy

    for name, mat in poses.items():
        _set_matrix(bpy.data.objects[name], mat)
    proxy_objs = list(state.proxies.values())
    state.bodies = [b for b in state.bodies if b.obj not in proxy_objs]
    for pobj in proxy_objs:
        bpy.data.objects.remove(pobj, do_unlink=True)
    state.proxies.clear()


def settle_ahead(req: SceneRequest) -> SettleResult:
    """The ``settle`` op: load the stage and settle it exactly as :func:`run_scene` would, then write the
    poses (by instance prim path) and the rest diagnostic to ``settled.json`` in ``req.out_dir``.

    A second bpy process runs this for the next scene while the first renders (``compose.settle_ahead``):
    Bullet steps on one thread, so a settle beside a render costs that render about half its own time
    instead of all of it. The poses travel as JSON floats (``repr`` round-trips a float64 exactly)."""
    import json

    from mixcount.engine.visibility import camera_model

    if not Path(req.out_dir).is_dir():  # its run is gone (interrupted, cleaned): do not make the folder again
        raise FileNotFoundError(f"the scene folder {req.out_dir} no longer exists")
    from mixcount.engine.count_topup import set_reserves_aside

    timer = Timer()
    with timer.stage("import"):
        state = load_scene(req)
        set_reserves_aside(state)  # as run_scene does: a count target's top-up bodies are not settled
    with timer.stage("physics"):
        settled = settle(state, camera_model(state.scene, state.cam_objs[0]))
    path_of = {obj.name: path for path, obj in state.blender_objects.items()}
    out = state.out_dir / SETTLED_FILE
    out.write_text(json.dumps({"stage": str(state.stage_path), "rest": settled.rest, "seconds": dict(timer.times),
                               "matrices": {path_of[name]: np.asarray(m).tolist() for name, m in settled.poses.items()}}))
    return SettleResult(poses_file=str(out), frames_run=int(settled.rest["frames_run"]), seconds=dict(timer.times))


def read_settled(state: SceneState, settled_json: str) -> Settled:
    """What :func:`settle` returns, read from a ``settle`` request's file instead of simulated here: the
    same matrices (by render object name), the same rest diagnostic (and a ``settled_ahead`` one). The
    file is removed (it is not part of the scene folder). A file for another stage is an error."""
    import json

    path = Path(settled_json)
    data = json.loads(path.read_text())
    if Path(data["stage"]) != state.stage_path:
        raise RuntimeError(f"{path} holds the settle of {data['stage']}, not of {state.stage_path}")
    poses = {state.blender_objects[p].name: np.array(m, dtype=np.float64) for p, m in data["matrices"].items()}
    path.unlink()
    return Settled(poses, (data["rest"], {"kind": "settled_ahead", "seconds": data["seconds"]}))


def check_settled(state: SceneState, settled_poses: dict[str, np.ndarray], roles: tuple[str, ...]) -> None:
    """Record settled poses of the objects of ``roles``; drop unstable / below-floor / flung-out bodies,
    then deep interpenetrations among them."""
    ph, floor = state.spec.physics, state.spec.floor
    live: list[int] = []
    bodies: list[D.SettledBody] = []
    for i, o in enumerate(state.objects):
        if o.role not in roles or not o.kept:
            continue
        obj = state.blender_objects[o.path]
        mat = settled_poses.get(obj.name, np.array(obj.matrix_world))
        lo, hi = D.world_bounds(state.cache.columns[o.asset], mat)
        state.bounds[i] = (lo, hi)
        min_z = float(lo[2])
        state.update(i, matrix_world=tuple(tuple(float(v) for v in row) for row in mat), min_z=min_z)
        reason = D.settle_verdict(mat, min_z, o.size_m, floor_shape=floor.shape,
                                  half_extent=(float(floor.half_extent[0]), float(floor.half_extent[1])),
                                  below_floor_fraction=ph.settle_below_floor_fraction)
        if reason is None:
            live.append(i)
            bodies.append(D.SettledBody(mat, lo, hi, state.cache.hull(o.asset), o.size_m))
        elif reason == D.BELOW_FLOOR:
            state.drop(i, reason, "settle", min_z=min_z)
        elif reason == D.FLUNG_OUT:
            state.drop(i, reason, "settle", position=mat[:3, 3].tolist())
        else:
            state.drop(i, reason, "settle")
    for j, k, depth in D.interpenetrations(bodies, ph.settle_penetration_fraction):
        state.drop(live[j], D.INTERPENETRATION, "settle", other=state.objects[live[k]].name, depth=round(depth, 4))


def _set_matrix(obj: Any, matrix: np.ndarray) -> None:
    import mathutils

    obj.matrix_world = mathutils.Matrix(np.asarray(matrix).tolist())


def frame_cameras(state: SceneState) -> list[dict[str, Any]]:
    """Every camera re-aimed at the settled counted objects by its framing rule
    (:func:`mixcount.scene.framing.frame_camera`); the Blender cameras move there. Returns how each
    camera was framed (its derivation and the framed camera)."""
    from mixcount.scene.framing import frame_camera, rotation_of

    kept = state.kept("counted")
    centres = np.array([np.asarray(state.objects[i].matrix_world)[:3, 3] for i in kept]).reshape(-1, 3)
    sizes = np.array([state.objects[i].size_m for i in kept])
    container = state.spec.container
    diag = float(np.linalg.norm(container.extent_m)) if container is not None else None
    margin = state.spec.placement.frame_margin if state.spec.placement is not None else 0.0
    framings = []
    for cam_obj, cam in zip(state.cam_objs, state.spec.cameras):
        framed = frame_camera(cam, centres, sizes, diag, margin=margin)
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = rotation_of(framed.camera), framed.camera.position
        _set_matrix(cam_obj, m)
        framings.append({**framed.derivation, "camera": framed.camera.to_dict()})
    return framings


def place_distractors_in_view(state: SceneState, cameras: list[PinholeCamera], framings: list[dict[str, Any]]) -> None:
    """Distractors on free floor where every camera sees them (:func:`mixcount.scene.framing.place_distractors`),
    resting on the floor at their drawn yaw and size; one without a spot is dropped (``no_spot_in_view``)."""
    from mixcount.scene.framing import DistractorShape, image_box, place_distractors

    placement = state.spec.placement
    assert placement is not None
    distractors = state.kept("distractor")
    if not distractors:
        return
    counted = state.kept("counted")
    bounds = [state.bounds[i] for i in counted]  # the settle checks' AABBs: the poses have not moved since
    occupied = [[lo[0], lo[1], hi[0], hi[1]] for lo, hi in bounds]
    if state.spec.container is not None:
        cobj = next(o for o in state.blender_objects.values() if o.pass_index == state.spec.container.instance_id)
        corners = np.array(cobj.matrix_world) @ np.c_[np.array([list(c) for c in cobj.bound_box]), np.ones(8)].T
        occupied.append([corners[0].min(), corners[1].min(), corners[0].max(), corners[1].max()])
    counted_boxes = []
    for cam in cameras:
        boxes = [image_box(cam, lo, hi) for lo, hi in bounds]
        counted_boxes.append(np.array([b for b in boxes if b is not None]).reshape(-1, 4))
    shapes, spawn = [], []
    for i in distractors:
        m = np.asarray(state.objects[i].spawn_matrix, dtype=np.float64).copy()
        m[:3, 3] = 0.0
        lo, hi = D.world_bounds(state.cache.columns[state.objects[i].asset], m)
        shapes.append(DistractorShape(tuple(lo.tolist()), tuple(hi.tolist())))  # type: ignore[arg-type]
        spawn.append(m)
    centres = np.array([np.asarray(state.objects[i].matrix_world)[:3, 3] for i in counted]).reshape(-1, 3)
    centre = np.median(centres[:, :2], axis=0) if len(centres) else np.zeros(2)
    # candidates within 1.5 x the farthest camera's distance of the pile (a low view sees floor far beyond it)
    reach = 1.5 * max(float(f["camera"]["distance"]) for f in framings)
    rng = np.random.default_rng([state.spec.seed, PLACEMENT_STREAM])
    spots = place_distractors(rng, shapes, cameras, state.spec.floor, np.array(occupied).reshape(-1, 4),
                              counted_boxes, centre=centre, max_radius=reach, margin=placement.distractor_margin,
                              frame_margin=placement.frame_margin, tries=placement.distractor_tries,
                              max_overlap=placement.distractor_max_overlap)
    for i, m, spot in zip(distractors, spawn, spots):
        if spot is None:
            state.drop(i, D.NO_SPOT_IN_VIEW, "placement")
            continue
        m[:3, 3] = spot
        obj = state.blender_objects[state.objects[i].path]
        _set_matrix(obj, m)
        lo, _ = D.world_bounds(state.cache.columns[state.objects[i].asset], m)
        state.update(i, matrix_world=tuple(tuple(float(v) for v in row) for row in m), min_z=float(lo[2]))


PLACEMENT_STREAM = 23  # the distractor placement's generator: default_rng([scene seed, PLACEMENT_STREAM])


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


def _camera_record(cam_obj: Any, camera: PinholeCamera) -> dict[str, Any]:
    return {
        "name": cam_obj.name, "width": camera.width, "height": camera.height, "K": camera.K.tolist(),
        "cam_to_world": camera.cam_to_world.tolist(), "focal_length_mm": float(cam_obj.data.lens),
        "sensor_width_mm": float(cam_obj.data.sensor_width),
        "clip_range": [float(cam_obj.data.clip_start), float(cam_obj.data.clip_end)],
        "convention": "camera looks down -Z, +Y up (Blender/USD); K maps to pixel x right, y down",
    }


@dataclass(frozen=True)
class Placement:
    """Where the cameras ended up after physics: each camera's pixel model and how it was framed (empty
    for a spec without after-physics placement: the stage's cameras, unmoved)."""

    cameras: list[PinholeCamera]
    framings: list[dict[str, Any]]

    def framing(self, k: int) -> dict[str, Any]:
        return self.framings[k] if self.framings else {"framing": "fixed"}


def place_after_physics(state: SceneState, settled_poses: dict[str, np.ndarray], timer: Timer) -> Placement:
    """Settle checks, then (specs with a placement) cameras framed on the settled pile and distractors
    placed in view; returns each camera's pixel model and framing."""
    from mixcount.engine.visibility import camera_model

    with timer.stage("settle_checks"):
        if state.placed_after_physics:
            check_settled(state, settled_poses, ("counted",))
        else:
            check_settled(state, settled_poses, ("counted", "distractor"))
    with timer.stage("placement"):
        framings = frame_cameras(state) if state.placed_after_physics else []
        cameras = [camera_model(state.scene, c) for c in state.cam_objs]
        if state.placed_after_physics:
            place_distractors_in_view(state, cameras, framings)
    return Placement(cameras, framings)


def run_scene(req: SceneRequest, render: Optional[Callable[[SceneState], None]] = None) -> SceneResult:
    """Handle one scene request (see module docstring); writes and returns the SceneResult.

    ``render`` replaces :func:`render_rgb` (``bench/render_quality.py`` renders the finished scene with
    several Cycles settings through :mod:`mixcount.engine.render_sweep`)."""
    from mixcount.engine.count_topup import set_reserves_aside
    from mixcount.engine.visibility import camera_model

    timer = Timer()
    with timer.stage("import"):
        state = load_scene(req)
        reserves = set_reserves_aside(state)  # a count target's top-up bodies wait outside the first settle
    with timer.stage("physics"):
        if req.settled_poses_file:  # settled ahead by another worker (settle_ahead)
            settled = read_settled(state, req.settled_poses_file)
        else:
            settled = settle(state, camera_model(state.scene, state.cam_objs[0]))
        place_settled(state, settled)
    placement = place_after_physics(state, settled.poses, timer)
    cameras = placement.cameras
    with timer.stage("frame_check"):
        check_frame(state, cameras)
    with timer.stage("silhouettes"):
        masks = [silhouettes(state, cam, req.threads, k) for k, cam in enumerate(cameras)]
    count_verdict = None
    if state.spec.count_target is None:
        id_passes, renders = visibility_loop(state, masks, timer)
    else:  # a visible-count target (issue 37): take-out, rest check and top-up before the first re-render
        from mixcount.engine import render_passes as P
        from mixcount.engine.count_topup import bring_to_target

        occluded: list[int] = []
        # one id-pass series for all of it: each loop opening its own re-synced the whole scene (the world
        # and lamps back, persistent data freed), 0.7-1.5 s a re-render on the capture-like pool
        with P.id_pass_series(state.scene):
            id_passes, renders = visibility_loop(state, masks, timer, deferred=occluded)
            masks, id_passes, more, count_verdict = bring_to_target(state, reserves, cameras, masks, id_passes,
                                                                    timer, occluded=tuple(occluded))
        renders += more
    status = final_status(state)
    if status == STATUS_OK and count_verdict is not None:
        status = STATUS_REJECTED  # cannot be brought to its target: the caller regenerates from the next seed
    if status == STATUS_OK and req.more_views is not None:  # compose --views: the new cameras, in this process
        from mixcount.engine.rerender_job import render_more_views

        return render_more_views(state, req, placement, renders, timer)
    view_passes: list[dict[str, Any]] = [{} for _ in cameras]
    if status == STATUS_OK:
        with timer.stage("write_passes"):
            for k, cam in enumerate(cameras):
                view_passes[k] = write_passes(state, id_passes[k], cam, req, k)
                write_amodal_masks(state, masks[k], id_passes[k], k)
        with timer.stage("rgb"):
            (render or render_rgb)(state)
        if req.oracle:
            with timer.stage("oracle"):
                for k, cam in enumerate(cameras):
                    reference_check(state, masks[k], cam, k)
    for i, views in state.views.items():
        state.update(i, views=tuple(views))
    spec = state.spec
    records = [_camera_record(c, cam) for c, cam in zip(state.cam_objs, cameras)]
    views = tuple(CameraView(name=c.name, suffix=view_suffix(k), camera=records[k],
                             framing=placement.framing(k), passes=view_passes[k]) for k, c in enumerate(state.cam_objs))
    result = SceneResult(
        status=status, stage=str(state.stage_path), scene_id=spec.scene_id, seed=spec.seed,
        visibility_threshold=spec.render.visibility_threshold, id_pass_rounds=renders,
        physics=spec.physics.to_dict(), camera=records[0], lights=state.lights,
        objects=tuple(state.objects), views=views, diagnostics=tuple(state.diagnostics), timings=dict(timer.times))
    return result  # over the pipe: the parent writes what it keeps into metadata.json
