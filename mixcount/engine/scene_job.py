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
rendered as ``mixcount render`` does). The steps after the poses live in :mod:`mixcount.engine.scene_steps`
and the camera code in :mod:`mixcount.engine.cameras` (shared with the count target's steps and the re-render,
so the engine's files import each other in no circle). Every decision between them is a pure function of
:mod:`mixcount.scene_decisions`. What describes the scene (samples, denoise, visibility threshold,
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

import mixcount.scene_decisions as D
from mixcount.annotate.raster import PinholeCamera
from mixcount.engine.cameras import Placement, camera_record, frame_cameras, set_matrix
from mixcount.engine.scene_build import SceneState, load_scene, pose_with_scale
from mixcount.engine.scene_steps import (
    Timer,
    check_frame,
    final_status,
    place_poses,
    reference_check,
    render_rgb,
    silhouettes,
    visibility_loop,
    write_amodal_masks,
    write_passes,
)
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
        set_matrix(obj, m)
        lo, _ = D.world_bounds(state.cache.columns[state.objects[i].asset], m)
        state.update(i, matrix_world=tuple(tuple(float(v) for v in row) for row in m), min_z=float(lo[2]))


PLACEMENT_STREAM = 23  # the distractor placement's generator: default_rng([scene seed, PLACEMENT_STREAM])



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
    records = [camera_record(c, cam) for c, cam in zip(state.cam_objs, cameras)]
    views = tuple(CameraView(name=c.name, suffix=view_suffix(k), camera=records[k],
                             framing=placement.framing(k), passes=view_passes[k]) for k, c in enumerate(state.cam_objs))
    result = SceneResult(
        status=status, stage=str(state.stage_path), scene_id=spec.scene_id, seed=spec.seed,
        visibility_threshold=spec.render.visibility_threshold, id_pass_rounds=renders,
        physics=spec.physics.to_dict(), camera=records[0], lights=state.lights,
        objects=tuple(state.objects), views=views, diagnostics=tuple(state.diagnostics), timings=dict(timer.times))
    return result  # over the pipe: the parent writes what it keeps into metadata.json
