"""Bringing a count-target scene to its target in the worker (issue 37; bpy): the reserve bodies held out
of the first settle, the top-up of a short class and the rest check after the take-out.

- :func:`set_reserves_aside` (right after the scene is loaded, before any settle): each class's reserve
  bodies (``count_target["reserve"]``, the class's highest instance ids) leave the scene and the
  simulation; they wait, marked ``count_reserve``.
- :func:`bring_to_target` (after the first visibility round, before its re-render): take out the surplus
  (:func:`mixcount.engine.count_trim.remove_surplus`), then the rest check (:func:`rest_check`): the kept
  bodies simulated again for ``rest_frames`` at most (the settle's early stop); a body that fell more
  than ``rest_tolerance`` x its size (held up by a body taken out or dropped as occluded) takes that pose;
  later checks wake only the bodies near what changed (:func:`near_boxes`); then one re-render of the boxes
  where anything changed. While a class is short, bodies of the short classes (the reserve, then the
  class's bodies dropped so far) drop from above onto the settled pile (which holds still), are checked and
  measured, and the round repeats (at most ``topup_rounds``). The largest displacement goes into the
  ``count_rest`` diagnostic; :func:`verify_rest` (benches) checks the finished pile once more, whole.

The decisions are :mod:`mixcount.counts.worker_decisions`'; this module moves objects and runs Bullet.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

import mixcount.scene_decisions as D
from mixcount.annotate.raster import PinholeCamera
from mixcount.counts import worker_decisions as C
from mixcount.engine.scene_build import SceneState, pose_with_scale, scaled_proxy_collider
from mixcount.worker.contract import DROPPED, KEPT

COUNT_TOPUP_STREAM = 43  # where reserve bodies drop: default_rng([scene seed, COUNT_TOPUP_STREAM, round])
REST_CHECKS = 3  # rest checks in a row at most while bodies fall (60 scenes: 7 still fell at the 2nd)
NOT_AT_REST = "count_not_at_rest"  # verdict: the last rest check still saw a body fall more than the tolerance
TOPUP_FACTOR = 1.5  # reserve bodies dropped per missing object (+1) at least: some land occluded or out of view
TOPUP_FACTOR_MOST = 4.0  # ... and at most, when the class's yield so far was lower (topup_factors)


@dataclass
class Reserves:
    """Reserve bodies set aside: object index -> its render object (unlinked from the scene)."""

    objects: dict[int, Any] = field(default_factory=dict)


def set_reserves_aside(state: SceneState) -> Reserves:
    """Take each class's reserve bodies out of the scene and the simulation (see the module docstring)."""
    import bpy

    from mixcount.counts.targets import reserve_instances

    out = Reserves()
    target = state.spec.count_target
    if target is None:
        return out
    state.set_aside = {}  # bodies dropped later wait there too: a top-up may use them
    if not any(target.get("reserve") or ()):
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


def _simulate(state: SceneState, indices: list[int], frames: int, still: tuple[int, ...] = ()
              ) -> tuple[dict[int, np.ndarray], int]:
    """The counted bodies ``indices`` (their current poses) simulated with the floor and the container for
    at most ``frames`` frames (the stage's physics, early stop when calm); returns each one's new pose.
    The counted bodies ``still`` take part as static colliders where they are (a top-up's bodies land on
    the settled pile, which keeps its poses). Also returns the frames run."""
    import bpy
    import mathutils

    from mixcount.engine.physics import Body, simulate

    ph = state.spec.physics
    bodies = [b for b in state.bodies if b.kind == "passive"]
    back: dict[str, tuple[int, Optional[np.ndarray]]] = {}
    temporary = []
    for i, kind in [(i, "active") for i in indices] + [(i, "passive") for i in still]:
        o = state.objects[i]
        obj = state.blender_objects[o.path]
        mesh = state.cache.proxies.get(o.asset)
        if mesh is not None:
            pobj, scale = scaled_proxy_collider(state.scene, obj.name + "_again", mesh, np.array(obj.matrix_world))
            temporary.append(pobj)
            bodies.append(Body(pobj, kind, "CONVEX_HULL"))
            if kind == "active":
                back[pobj.name] = (i, scale)
        else:
            bodies.append(Body(obj, kind, "CONVEX_HULL"))
            if kind == "active":
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
    for pobj in temporary:  # the collider and its own scaled copy of the proxy mesh
        data = pobj.data
        bpy.data.objects.remove(pobj, do_unlink=True)
        bpy.data.meshes.remove(data)
    for i, mat in out.items():
        state.blender_objects[state.objects[i].path].matrix_world = mathutils.Matrix(np.asarray(mat).tolist())
    return out, int(run.frames_run)


def container_room(state: SceneState) -> Optional[tuple[NDArray[Any], NDArray[Any]]]:
    """The XY square a top-up's bodies may be dropped over inside the container's walls, whatever its yaw:
    half-side 0.35 x its shorter side about its centre (a square that fits in the rotated box); None on
    the floor."""
    container = state.spec.container
    if container is None:
        return None
    centre = np.asarray(container.position[:2], dtype=np.float64)
    half = 0.35 * float(min(container.extent_m[0], container.extent_m[1]))
    return centre - half, centre + half


def top_up(state: SceneState, reserves: Reserves, short: dict[int, int], round_no: int,
           factors: Optional[dict[int, float]] = None) -> list[int]:
    """Drop bodies of the ``short`` classes (lacking objects per class: the class's reserve, then its bodies
    dropped so far) from above onto the settled pile, which holds still (static colliders at its settled
    poses: the bodies landing on it are light and the rest check after the top-up wakes the bodies near
    them); returns the bodies dropped (none: no body of those classes left out of the scene).
    ``factors``: bodies per lacking object, per class (default :data:`TOPUP_FACTOR`)."""
    from mixcount.counts.worker_decisions import drop_spots, topup_draw

    available: dict[int, list[int]] = {}
    # the reserve first, then the class's bodies dropped so far (occluded, out of view, taken out): a class
    # whose reserve is used up (small bodies that land in the gaps) is not left short for want of bodies
    aside = state.set_aside if state.set_aside is not None else {}
    for i in [*sorted(reserves.objects), *sorted(aside)]:
        available.setdefault(int(state.objects[i].class_index), []).append(i)
    draw = topup_draw(short, {c: len(v) for c, v in available.items()}, TOPUP_FACTOR if factors is None else factors)
    picks = [i for c in sorted(draw) for i in available[c][: draw[c]]]
    if not picks:
        return []
    recycled = [i for i in picks if i not in reserves.objects]
    kept = state.kept("counted")
    boxes = [state.bounds.get(i) or D.world_bounds(state.cache.columns[state.objects[i].asset],
                                                    np.asarray(state.objects[i].matrix_world)) for i in kept]
    if boxes:
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
    else:
        lo = hi = np.zeros(3)
    rng = np.random.default_rng([int(state.spec.seed), COUNT_TOPUP_STREAM, int(round_no)])
    spots = drop_spots(lo[:2], hi[:2], float(hi[2]), [state.objects[i].size_m for i in picks], rng,
                       room=container_room(state))
    for i, spot in zip(picks, spots):
        obj = reserves.objects.pop(i) if i in reserves.objects else aside.pop(i)
        state.scene.collection.objects.link(obj)
        m = np.asarray(state.objects[i].spawn_matrix, dtype=np.float64).copy()
        m[:3, 3] = spot
        import mathutils

        obj.matrix_world = mathutils.Matrix(m.tolist())
        state.blender_objects[state.objects[i].path] = obj
        state.update(i, status=KEPT, reason=None, matrix_world=tuple(tuple(float(v) for v in r) for r in m))
    # _simulate leaves the new poses on the Blender objects; its returned poses and frames are not needed here
    _simulate(state, picks, int(state.spec.physics.frames), still=tuple(kept))
    state.diagnostics.append({"kind": "count_topup", "round": int(round_no),
                              "dropped_per_class": {str(c): n for c, n in sorted(draw.items())},
                              "short_per_class": {str(c): n for c, n in sorted(short.items())},
                              "dropped_again": [state.objects[i].instance_id for i in recycled],
                              "factor_per_class": {str(c): round(f, 3) for c, f in sorted((factors or {}).items())}})
    return picks


Box = tuple[np.ndarray, np.ndarray, float]  # world AABB (lo, hi) and a margin (m) around it
NEAR_MARGIN = 0.5  # x a changed body's size: a local rest check wakes the bodies within this of its boxes
VERIFY_FRAMES = 40  # verify_rest's whole re-simulation: frames at most (the settle's early stop), whatever
                   # rest_frames is, so checks of different lengths are measured by one rule


def changed_boxes(state: SceneState, indices: Any) -> list[Box]:
    """The boxes (settle-check AABBs, :attr:`SceneState.bounds`) of bodies that changed: taken out,
    dropped, fallen or dropped in; a local rest check (:func:`rest_check` ``near``) wakes what is near them."""
    return [(*state.bounds[i], NEAR_MARGIN * float(state.objects[i].size_m)) for i in indices if i in state.bounds]


def near_boxes(state: SceneState, indices: list[int], boxes: list[Box]) -> list[int]:
    """The bodies of ``indices`` whose AABB (:attr:`SceneState.bounds`) overlaps one of ``boxes`` grown by
    its margin: touching a changed body, leaning on it from beside or lying under or over it."""
    rows = [i for i in indices if i in state.bounds]
    if not rows or not boxes:
        return []
    lo = np.array([state.bounds[i][0] for i in rows])
    hi = np.array([state.bounds[i][1] for i in rows])
    hit = np.zeros(len(rows), dtype=bool)
    for blo, bhi, margin in boxes:
        hit |= np.all(lo <= np.asarray(bhi) + margin, axis=1) & np.all(hi >= np.asarray(blo) - margin, axis=1)
    return [i for i, h in zip(rows, hit) if h]


@dataclass
class _Rerun:
    """The bodies ``rows`` simulated again: their poses after, and how far each moved and fell (centre
    drop), both x the body's size; the frames run (the work: frames x bodies awake)."""

    rows: list[int]
    after: dict[int, np.ndarray]
    moved_by: np.ndarray
    fell_by: np.ndarray
    frames: int


def _rerun(state: SceneState, awake: list[int], still: tuple[int, ...], frames: int) -> _Rerun:
    """``awake`` simulated again (``still`` static) and every one of them put back at its pose before: the
    caller decides which keep the new pose (:func:`rest_check`) or none (:func:`verify_rest`)."""
    import mathutils

    before = {i: np.array(state.blender_objects[state.objects[i].path].matrix_world) for i in awake}
    after, ran = _simulate(state, awake, frames, still=still)
    for i in awake:
        state.blender_objects[state.objects[i].path].matrix_world = mathutils.Matrix(before[i].tolist())
    rows = [i for i in awake if i in after]
    b = np.array([before[i] for i in rows]).reshape(-1, 4, 4)
    a = np.array([after[i] for i in rows]).reshape(-1, 4, 4)
    size = np.array([max(state.objects[i].size_m, 1e-9) for i in rows])
    return _Rerun(rows, after, C.displacements(b, a) / size, (b[:, 2, 3] - a[:, 2, 3]) / size, ran)


def rest_check(state: SceneState, near: Optional[list[Box]] = None, work: Optional[dict[str, Any]] = None
               ) -> tuple[float, float, list[int], list[Box]]:
    """The kept counted bodies simulated again (``rest_frames`` at most, the settle's early stop): returns
    the largest displacement and the largest drop (each x the body's size), the bodies whose centre fell
    more than ``rest_tolerance`` x their size (they were not held up: a body under them was taken out or
    dropped as occluded) and the boxes where those were and are; they keep the pose of that run, every
    other body goes back exactly to its settled pose. A body rolling on over the floor (the settle's early
    stop lets up to 5 % of them roll on, as in every scene) moves without falling and is not one.

    ``near`` (boxes, None: every kept body): a local check after a few bodies changed (fell in the check
    before, were taken out or dropped in): only the kept bodies near those boxes (:func:`near_boxes`) move,
    the rest of the pile takes part as static colliders at its poses. The check before had the whole pile
    move; what changed since is only at those boxes. ``work`` (a record) adds up the frames run and the
    body-frames (bodies awake x frames): the checks' cost, free of the machine's load."""
    import mathutils

    target = state.spec.count_target
    assert target is not None
    kept = state.kept("counted")
    if not kept or int(target["rest_frames"]) <= 0:
        return 0.0, 0.0, [], []
    awake = kept if near is None else near_boxes(state, kept, near)
    if not awake:
        return 0.0, 0.0, [], []
    still = () if near is None else tuple(sorted(set(kept) - set(awake)))
    run = _rerun(state, awake, still, int(target["rest_frames"]))
    if work is not None:
        work["check_frames"] = work.get("check_frames", 0) + run.frames
        work["body_frames"] = work.get("body_frames", 0) + run.frames * len(awake)
    fell = [i for i, f in zip(run.rows, run.fell_by) if f > float(target["rest_tolerance"])]
    boxes = changed_boxes(state, fell)  # where they were ...
    for i in fell:  # ... and where they are: the pose of that run
        state.blender_objects[state.objects[i].path].matrix_world = mathutils.Matrix(run.after[i].tolist())
        state.bounds[i] = D.world_bounds(state.cache.columns[state.objects[i].asset], run.after[i])
    boxes += changed_boxes(state, fell)
    return float(run.moved_by.max(initial=0.0)), float(run.fell_by.max(initial=0.0)), fell, boxes


def verify_rest(state: SceneState) -> dict[str, Any]:
    """What a bench asks for (``count_target["rest_verify"]``): the whole kept pile simulated once more
    (every body awake) for :data:`VERIFY_FRAMES` at most, then every body put back: nothing in the scene changes.
    Returns the ``count_rest_verify`` diagnostic: the bodies whose centre would fall more than
    ``rest_tolerance`` x their size, and the largest drop, so the rest check's shortcut (local checks after
    the first) can be measured against a whole one."""
    target = state.spec.count_target
    assert target is not None
    kept = state.kept("counted")
    record: dict[str, Any] = {"kind": "count_rest_verify", "bodies": len(kept), "fell": 0, "largest_drop_x_size": 0.0}
    if not kept:
        return record
    drops = _rerun(state, kept, (), VERIFY_FRAMES).fell_by
    record.update(fell=int((drops > float(target["rest_tolerance"])).sum()),
                  largest_drop_x_size=round(float(drops.max(initial=0.0)), 4),
                  fell_over_half_size=int((drops > 0.5).sum()))
    return record


def _union(a: Optional[tuple[int, int, int, int]], b: Optional[tuple[int, int, int, int]]
           ) -> Optional[tuple[int, int, int, int]]:
    if a is None or b is None:
        return a if b is None else b
    return min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])


def _measure_again(state: SceneState, cameras: list[PinholeCamera], timer: Any,
                   masks: list[dict[int, np.ndarray]], id_passes: list[dict[str, np.ndarray]],
                   moved: list[int], removed_ids: tuple[int, ...] = ()
                   ) -> tuple[list[dict[int, np.ndarray]], list[dict[str, np.ndarray]], int]:
    """After bodies moved (fell in a rest check, or were dropped in by a top-up) or were taken out: the
    moved bodies' settle verdict and frame check, their silhouettes drawn again, and each camera re-renders
    only the box where they (and the bodies ``removed_ids`` taken out since ``id_passes``) were seen and
    where they are now; then the visibility loop goes on from there."""
    from mixcount.engine.scene_steps import visibility_loop
    from mixcount.engine.visibility import unoccluded_mask
    from mixcount.scene.framing import image_box

    before = set(state.kept())
    if moved:
        with timer.stage("count_target"):
            _check_moved(state, moved, cameras)
    gone = before - set(state.kept())
    still = [i for i in moved if state.objects[i].kept]  # (dropped ones are in gone)
    ids = [state.objects[i].instance_id for i in (*moved, *gone)] + list(removed_ids)
    regions: list[Optional[tuple[int, int, int, int]]] = []
    with timer.stage("silhouettes"):
        for k, cam in enumerate(cameras):
            region = D.changed_region(id_passes[k]["index"], ids)
            for i in still:
                o = state.objects[i]
                masks[k][o.instance_id] = mask = unoccluded_mask(cam, state.cache.columns[o.asset],
                                                                 state.cache.corners[o.asset], np.array(o.matrix_world))
                state.view(i, k)["unoccluded_px"] = px = int(np.count_nonzero(mask))
                if k == 0:
                    state.update(i, unoccluded_px=px)
                lo, hi = state.bounds[i]
                box = image_box(cam, lo, hi)
                if box is None:  # behind the camera or out of the image: the whole image
                    region = (0, 0, cam.height - 1, cam.width - 1)
                    continue
                x0, y0, x1, y1 = (int(np.floor(box[0])), int(np.floor(box[1])), int(np.ceil(box[2])),
                                  int(np.ceil(box[3])))
                region = _union(region, (max(0, y0 - 1), max(0, x0 - 1), min(cam.height - 1, y1 + 1),
                                         min(cam.width - 1, x1 + 1)))
            regions.append(region)
    passes, renders = visibility_loop(state, masks, timer, start=(id_passes, regions))
    return masks, passes, renders


def _check_moved(state: SceneState, moved: list[int], cameras: list[PinholeCamera]) -> None:
    """The settle verdict (unstable, below the floor, flung out) and the frame check of the bodies that
    fell in a rest check or were dropped in by a top-up, at their new poses (the others did not move:
    their checks stand). The simulation that moved them resolved their contacts, so no interpenetration
    check is run again."""
    from mixcount.engine.scene_steps import check_frame

    floor, ph = state.spec.floor, state.spec.physics
    for i in moved:
        o = state.objects[i]
        mat = np.array(state.blender_objects[o.path].matrix_world)
        lo, hi = D.world_bounds(state.cache.columns[o.asset], mat)
        state.bounds[i] = (lo, hi)
        state.update(i, matrix_world=tuple(tuple(float(v) for v in row) for row in mat), min_z=float(lo[2]))
        reason = D.settle_verdict(mat, float(lo[2]), o.size_m, floor_shape=floor.shape,
                                  half_extent=(float(floor.half_extent[0]), float(floor.half_extent[1])),
                                  below_floor_fraction=ph.settle_below_floor_fraction)
        if reason is not None:
            state.drop(i, reason, "count_rest")
            continue
        check_frame(state, cameras, [i], "count_rest")


def _rest(state: SceneState, timer: Any, record: dict[str, Any], near: Optional[list[Box]] = None) -> list[int]:
    """The rest check, three times at most (a body that fell may have held another up, or still slide);
    returns the bodies that fell. The first check wakes every kept body, or with ``near`` those near the
    bodies that changed since the last check; each later one those near the bodies that fell in the one
    before. ``record`` collects the checks (whole and local), their frames and body-frames, the largest
    displacement and drop and how many fell."""
    fallen: list[int] = []
    for _ in range(REST_CHECKS):
        with timer.stage("count_rest"):
            moved_by, fell_by, fell, boxes = rest_check(state, near, record)
        key = "checks" if near is None else "local_checks"
        record[key] = record.get(key, 0) + 1
        record["largest_displacement_x_size"] = round(max(record.get("largest_displacement_x_size", 0.0), moved_by), 4)
        record["largest_drop_x_size"] = round(max(record.get("largest_drop_x_size", 0.0), fell_by), 4)
        record["last_drop_x_size"] = round(fell_by, 4)
        record["fell"] = record.get("fell", 0) + len(fell)
        fallen.extend(i for i in fell if i not in fallen)
        if not fell:
            break
        near = boxes
    return fallen


def bring_to_target(state: SceneState, reserves: Reserves, cameras: list[PinholeCamera],
                    masks: list[dict[int, np.ndarray]], id_passes: list[dict[str, np.ndarray]],
                    timer: Any, occluded: tuple[int, ...] = ()
                    ) -> tuple[list[dict[int, np.ndarray]], list[dict[str, np.ndarray]], int, Optional[str]]:
    """Take-out, rest check, top-ups (module docstring); returns the masks and id passes to write, the
    id-pass renders made and the count verdict (None: the scene may be kept).

    ``id_passes`` may still show the bodies ``occluded`` (instance ids) that the first visibility round
    dropped without re-rendering (``visibility_loop(deferred=...)``): their pixels join the first
    re-render's region, so one re-render covers the occluded, the surplus and the fallen bodies.

    Each round: the surplus is taken out (bodies nothing rests on), then the rest check (bodies dropped as
    occluded, taken out or still settling may have left one unsupported; one that fell takes its new pose:
    the first check simulates every kept body again, each later one only those near what changed since),
    then one visibility loop re-renders only the boxes where the bodies taken out were seen and where the
    fallen ones were and are. If that loop drops a body (a fallen one now occluded), the rest check runs
    again. Then a class still short is topped up (its reserve, then its bodies dropped so far, at a factor
    from its yield so far: :func:`mixcount.counts.worker_decisions.topup_factors`): its bodies land on the
    pile, only they are measured (their silhouettes, the boxes where they are) and the round repeats, at
    most ``topup_rounds`` times."""
    from mixcount.engine.count_trim import count_outcome, kept_per_class, remove_surplus

    target = state.spec.count_target
    assert target is not None
    targets = {ci: int(n) for ci, n in enumerate(target["per_class"])}
    renders = removed = dropped = 0
    rounds = 0
    record: dict[str, Any] = {"kind": "count_rest", "tolerance_x_size": float(target["rest_tolerance"])}
    pending = set(occluded)  # seen in id_passes, gone from the scene
    checked: Optional[set[int]] = None  # the kept bodies at the last rest check (None: none yet)
    # objects kept per body that entered the pile, per class: the first settle's, then each top-up's
    entered = {c: 0 for c in targets}
    for i, o in enumerate(state.objects):
        if o.role == "counted" and i not in reserves.objects:
            entered[int(o.class_index)] += 1
    kept_now = kept_per_class(state, len(targets))
    gained = {c: kept_now[c] / max(entered[c], 1) for c in targets}
    last: dict[int, tuple[int, int]] = {}  # class -> (lacking before the last top-up, bodies it dropped in)
    while True:
        before = {state.objects[i].instance_id for i in state.kept()} | pending
        pending = set()
        with timer.stage("count_target"):
            removed += len(remove_surplus(state))
        for _ in range(2):
            out_ids = tuple(sorted(before - {state.objects[i].instance_id for i in state.kept()}))
            # the first check wakes the whole pile; later ones only what is near the bodies taken out,
            # dropped or dropped in since the last (the pile around them passed that check)
            near = None if checked is None else changed_boxes(state, sorted(checked ^ set(state.kept())))
            fell = _rest(state, timer, record, near)
            checked = set(state.kept())
            kept_before = len(state.kept())
            masks, id_passes, more = _measure_again(state, cameras, timer, masks, id_passes, fell, out_ids)
            renders += more
            before = {state.objects[i].instance_id for i in state.kept()}
            if len(state.kept()) == kept_before or not fell:  # nothing dropped after a fall: all rest
                break
        short = C.short_classes(targets, kept_per_class(state, len(targets)))
        for c, (lacking, n) in last.items():
            gained[c] = max(0, lacking - short.get(c, 0)) / n
        if not (short and rounds < int(target["topup_rounds"])):
            break
        with timer.stage("count_topup"):
            picks = top_up(state, reserves, short, rounds,
                           C.topup_factors(short, gained, TOPUP_FACTOR, TOPUP_FACTOR_MOST))
        if not picks:
            break
        per_class = Counter(int(state.objects[i].class_index) for i in picks)
        last = {c: (short[c], n) for c, n in per_class.items()}
        dropped += len(picks)
        rounds += 1
        masks, id_passes, more = _measure_again(state, cameras, timer, masks, id_passes, picks)
        renders += more
    state.diagnostics.append(record)
    if target.get("rest_verify"):
        with timer.stage("count_rest_verify"):
            state.diagnostics.append(verify_rest(state))
    verdict = count_outcome(state, removed, int(state.spec.render.resolution), topped_up=dropped,
                            topup_rounds=rounds, reserve_unused=len(reserves.objects))
    if verdict is None and float(record.get("last_drop_x_size", 0.0)) > float(target["rest_tolerance"]):
        # the last rest check still saw a body fall (still sliding after its checks): not shipped
        verdict = NOT_AT_REST
        state.diagnostics[-1]["verdict"] = verdict
    return masks, id_passes, renders, verdict
