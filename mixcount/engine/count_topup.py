"""Bringing a count-target scene to its target in the worker (issue 37; bpy): the reserve bodies held out
of the first settle, the top-up of a short class and the rest check after the take-out.

- :func:`set_reserves_aside` (right after the scene is loaded, before any settle): each class's reserve
  bodies (``count_target["reserve"]``, the class's highest instance ids) leave the scene and the
  simulation; they wait, marked ``count_reserve``.
- :func:`bring_to_target` (after the first visibility loop): take out the surplus
  (:func:`mixcount.engine.count_trim.remove_surplus`); while a class is short and holds reserves, drop
  reserve bodies of the short classes from above onto the settled pile, simulate the pile again, re-run the
  settle checks, the frame check, the silhouettes and the visibility loop, then take out the surplus again
  (at most ``topup_rounds``); then the rest check (:func:`rest_check`): the kept bodies simulated again
  for ``rest_frames``; a body that moved more than ``rest_tolerance`` x its size (held up by a body taken
  out or dropped as occluded) takes that pose and visibility is measured again. The largest displacement
  goes into the ``count_rest`` diagnostic.

The decisions are :mod:`mixcount.annotate.count_decisions`'; this module moves objects and runs Bullet.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from mixcount.annotate import count_decisions as C
from mixcount.annotate import scene_decisions as D
from mixcount.annotate.raster import PinholeCamera
from mixcount.engine.scene_build import SceneState, pose_with_scale, scaled_proxy_collider
from mixcount.worker.contract import DROPPED, KEPT

COUNT_TOPUP_STREAM = 43  # where reserve bodies drop: default_rng([scene seed, COUNT_TOPUP_STREAM, round])
TOPUP_FACTOR = 1.3  # reserve bodies dropped per missing object (+1): some land occluded or out of view


@dataclass
class Reserves:
    """Reserve bodies set aside: object index -> its render object (unlinked from the scene)."""

    objects: dict[int, Any] = field(default_factory=dict)


def set_reserves_aside(state: SceneState) -> Reserves:
    """Take each class's reserve bodies out of the scene and the simulation (see the module docstring)."""
    import bpy

    from mixcount.scene.count_targets import reserve_instances

    out = Reserves()
    target = state.spec.count_target
    if target is None or not any(target.get("reserve") or ()):
        return out
    counted = [i for i, o in enumerate(state.objects) if o.role == "counted"]
    ids = set(reserve_instances([state.objects[i].class_index for i in counted],
                                [state.objects[i].instance_id for i in counted], target["reserve"]))
    for i in counted:
        o = state.objects[i]
        if o.instance_id not in ids:
            continue
        obj = state.blender_objects.pop(o.path)
        proxy = state.proxies.pop(obj.name, None)
        state.proxy_scales.pop(obj.name, None)
        collider = proxy if proxy is not None else obj
        state.bodies = [b for b in state.bodies if b.obj is not collider]
        if proxy is not None:
            bpy.data.objects.remove(proxy, do_unlink=True)
        for coll in list(obj.users_collection):
            coll.objects.unlink(obj)
        state.update(i, status=DROPPED, reason=C.COUNT_RESERVE)
        out.objects[i] = obj
    return out


def _simulate(state: SceneState, indices: list[int], frames: int) -> dict[int, np.ndarray]:
    """The counted bodies ``indices`` (their current poses) simulated with the floor and the container for
    at most ``frames`` frames (the stage's physics, early stop when calm); returns each one's new pose."""
    import bpy
    import mathutils

    from mixcount.engine.physics import Body, simulate

    ph = state.spec.physics
    bodies = [b for b in state.bodies if b.kind == "passive"]
    back: dict[str, tuple[int, Optional[np.ndarray]]] = {}
    temporary = []
    for i in indices:
        o = state.objects[i]
        obj = state.blender_objects[o.path]
        mesh = state.cache.proxies.get(o.asset)
        if mesh is not None:
            pobj, scale = scaled_proxy_collider(state.scene, obj.name + "_again", mesh, np.array(obj.matrix_world))
            temporary.append(pobj)
            bodies.append(Body(pobj, "active", "CONVEX_HULL"))
            back[pobj.name] = (i, scale)
        else:
            bodies.append(Body(obj, "active", "CONVEX_HULL"))
            back[obj.name] = (i, None)
    waited_for = None
    if state.spec.placement is not None:
        import functools

        waited_for = functools.partial(D.near_the_pile, np.zeros(2), state.spec.placement.view_radius)
    run = simulate(state.scene, bodies, frames=int(frames), substeps=ph.substeps, iterations=ph.solver_iterations,
                   gravity=ph.gravity, rest_speed=ph.rest_speed, waited_for=waited_for)
    out: dict[int, np.ndarray] = {}
    for name, mat in run.matrices.items():
        i, scale = back[name]
        out[i] = mat if scale is None else pose_with_scale(mat, scale)
    for pobj in temporary:
        bpy.data.objects.remove(pobj, do_unlink=True)
    for i, mat in out.items():
        state.blender_objects[state.objects[i].path].matrix_world = mathutils.Matrix(np.asarray(mat).tolist())
    return out


def _kept_per_class(state: SceneState, n_classes: int) -> dict[int, int]:
    kept = {c: 0 for c in range(n_classes)}
    for i in state.kept("counted"):
        kept[int(state.objects[i].class_index)] += 1
    return kept


def top_up(state: SceneState, reserves: Reserves, short: dict[int, int], round_no: int) -> int:
    """Drop reserve bodies of the ``short`` classes (lacking objects per class) from above onto the settled
    pile and simulate it again; returns how many were dropped (0: no reserve left for them)."""
    from mixcount.annotate.count_decisions import drop_spots, topup_draw

    available: dict[int, list[int]] = {}
    for i in sorted(reserves.objects):
        available.setdefault(int(state.objects[i].class_index), []).append(i)
    draw = topup_draw(short, {c: len(v) for c, v in available.items()}, TOPUP_FACTOR)
    picks = [i for c in sorted(draw) for i in available[c][: draw[c]]]
    if not picks:
        return 0
    kept = state.kept("counted")
    boxes = [state.bounds.get(i) or D.world_bounds(state.cache.columns[state.objects[i].asset],
                                                    np.asarray(state.objects[i].matrix_world)) for i in kept]
    if boxes:
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
    else:
        lo = hi = np.zeros(3)
    rng = np.random.default_rng([int(state.spec.seed), COUNT_TOPUP_STREAM, int(round_no)])
    spots = drop_spots(lo[:2], hi[:2], float(hi[2]), [state.objects[i].size_m for i in picks], rng)
    for i, spot in zip(picks, spots):
        obj = reserves.objects.pop(i)
        state.scene.collection.objects.link(obj)
        m = np.asarray(state.objects[i].spawn_matrix, dtype=np.float64).copy()
        m[:3, 3] = spot
        import mathutils

        obj.matrix_world = mathutils.Matrix(m.tolist())
        state.blender_objects[state.objects[i].path] = obj
        state.update(i, status=KEPT, reason=None, matrix_world=tuple(tuple(float(v) for v in r) for r in m))
    _simulate(state, state.kept("counted"), int(state.spec.physics.frames))
    state.diagnostics.append({"kind": "count_topup", "round": int(round_no),
                              "dropped_per_class": {str(c): n for c, n in sorted(draw.items())},
                              "short_per_class": {str(c): n for c, n in sorted(short.items())}})
    return len(picks)


def rest_check(state: SceneState) -> tuple[float, int]:
    """The kept counted bodies simulated again (``rest_frames``): returns the largest displacement (x the
    body's size) and how many moved more than ``rest_tolerance`` x their size; when any did, every body
    keeps the pose of that run (else the poses stay exactly as they were)."""
    import mathutils

    target = state.spec.count_target
    assert target is not None
    kept = state.kept("counted")
    if not kept or int(target["rest_frames"]) <= 0:
        return 0.0, 0
    before = {i: np.array(state.blender_objects[state.objects[i].path].matrix_world) for i in kept}
    after = _simulate(state, kept, int(target["rest_frames"]))
    rows = [i for i in kept if i in after]
    disp = C.displacements(np.array([before[i] for i in rows]), np.array([after[i] for i in rows]))
    rel = disp / np.array([max(state.objects[i].size_m, 1e-9) for i in rows])
    moved = int((rel > float(target["rest_tolerance"])).sum())
    if not moved:  # nothing moved beyond the tolerance: the poses stay exactly the settled ones
        for i in rows:
            state.blender_objects[state.objects[i].path].matrix_world = mathutils.Matrix(before[i].tolist())
    return (float(rel.max()) if len(rel) else 0.0), moved


def _measure_again(state: SceneState, cameras: list[PinholeCamera], threads: int,
                   timer: Any) -> tuple[list[dict[int, np.ndarray]], list[dict[str, np.ndarray]], int]:
    """After bodies moved: settle checks, frame check, silhouettes and the visibility loop from fresh id passes."""
    from mixcount.engine.scene_job import check_frame, check_settled, silhouettes, visibility_loop

    with timer.stage("count_target"):
        check_settled(state, {}, ("counted",))
        check_frame(state, cameras)
    with timer.stage("silhouettes"):
        masks = [silhouettes(state, cam, threads, k) for k, cam in enumerate(cameras)]
    id_passes, renders = visibility_loop(state, masks, timer)
    return masks, id_passes, renders


def bring_to_target(state: SceneState, reserves: Reserves, cameras: list[PinholeCamera],
                    masks: list[dict[int, np.ndarray]], id_passes: list[dict[str, np.ndarray]], threads: int,
                    timer: Any) -> tuple[list[dict[int, np.ndarray]], list[dict[str, np.ndarray]], int, Optional[str]]:
    """Take-out, top-ups and the rest check (module docstring); returns the masks and id passes to write,
    the id-pass renders made and the count verdict (None: the scene may be kept)."""
    from mixcount.engine.count_trim import count_outcome, remove_surplus
    from mixcount.engine.scene_job import visibility_loop

    target = state.spec.count_target
    assert target is not None
    targets = {ci: int(n) for ci, n in enumerate(target["per_class"])}
    renders = removed = dropped = 0
    rounds = 0
    while True:
        with timer.stage("count_target"):
            out = remove_surplus(state)
        removed += out
        if out:  # measured again on id passes without them (visibility can only have grown)
            id_passes, more = visibility_loop(state, masks, timer)
            renders += more
        short = C.short_classes(targets, _kept_per_class(state, len(targets)))
        if not short or rounds >= int(target.get("topup_rounds", 0)):
            break
        with timer.stage("count_topup"):
            n = top_up(state, reserves, short, rounds)
        if not n:
            break
        dropped += n
        rounds += 1
        masks, id_passes, more = _measure_again(state, cameras, threads, timer)
        renders += more
    worst, moved_total = 0.0, 0
    for _ in range(2):  # a body that moved may have held another up: one more check after it
        with timer.stage("count_rest"):
            rel, moved = rest_check(state)
        worst = max(worst, rel)
        moved_total += moved
        if not moved:
            break
        masks, id_passes, more = _measure_again(state, cameras, threads, timer)
        renders += more
    state.diagnostics.append({"kind": "count_rest", "largest_displacement_x_size": round(worst, 4),
                              "moved": moved_total, "tolerance_x_size": float(target["rest_tolerance"])})
    unused = sorted(reserves.objects)
    verdict = count_outcome(state, removed, int(state.spec.render.resolution), topped_up=dropped,
                            topup_rounds=rounds, reserve_unused=len(unused))
    return masks, id_passes, renders, verdict
