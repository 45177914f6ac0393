"""Rigid-body settling with Blender's Bullet world, and the checks that the result holds (bpy).

Setup follows the stage's UsdPhysics schema: instances with RigidBodyAPI are active bodies with a
convex-hull shape (of their collision proxy when the asset has one: a hidden object of at most
``ingest.proxy_max_vertices`` vertices that the scene job moves in their place, see docs/performance.md);
the container is static: one passive convex hull per part of its convex decomposition (else its
decimated triangle mesh); the floor is a passive convex hull of a hidden copy reaching
``physics.floor_collider_depth`` under its top (a box or a cylinder: a hull does not let thin floors
tunnel like a triangle mesh can, and the depth holds fast bodies). Bodies with a later release frame
(spawn waves) join mid-run. Frames, substeps and solver iterations come from the PhysicsScene prim's
customData. After stepping the frames the evaluated world matrices are read back, the rigid-body world is
removed and the matrices are written onto the objects, so later renders see a static scene at frame 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np

SHAPES = {"convexHull": "CONVEX_HULL", "none": "MESH", "boundingCube": "BOX", "boundingSphere": "SPHERE",
          "convexDecomposition": "CONVEX_HULL"}


# Bullet's collision margin of a convex body (m, absolute; Blender's default): with use_margin on, Bullet grows
# the hull by it, so two hulls at rest on each other lie up to twice this apart (docs/blender.md)
HULL_MARGIN = 0.04


@dataclass
class Body:
    obj: Any
    kind: str  # "active" | "passive"
    shape: str  # Blender collision shape
    # collision margin (m); None: HULL_MARGIN for convex shapes (Blender's default), 0 for triangle meshes. A
    # container's convex parts take 0: static, and a margin would lift the pile off the container's floor
    collision_margin: Optional[float] = None


def _add_bodies(scene: Any, bodies: list[Body]) -> None:
    """Every body into the rigid-body world, without an operator per body.

    ``bpy.ops.rigidbody.object_add`` (like every operator called from Python) updates the view layer
    before and after it runs: ~20 ms each with 400 objects in the scene, i.e. 12 s of a 200-object
    scene's physics spent only on adding bodies. Linking the objects into the world's collection and
    updating once makes Blender create their rigid-body settings (type ACTIVE) in one pass.
    """
    import bpy

    coll = scene.rigidbody_world.collection
    for body in bodies:
        if body.obj.name not in coll.objects:
            coll.objects.link(body.obj)
    bpy.context.view_layer.update()
    for body in bodies:
        rb = body.obj.rigid_body
        if rb is None:
            raise RuntimeError(f"Blender created no rigid body for {body.obj.name}")
        rb.type = "ACTIVE" if body.kind == "active" else "PASSIVE"
        rb.collision_shape = body.shape
        rb.mesh_source = "BASE"
        rb.friction = 0.6
        rb.restitution = 0.0
        rb.use_margin = True
        rb.collision_margin = (body.collision_margin if body.collision_margin is not None
                               else 0.0 if body.shape == "MESH" else HULL_MARGIN)
        if body.kind == "active":
            rb.mass = 1.0
            rb.linear_damping = 0.1
            rb.angular_damping = 0.2
            rb.use_deactivation = True


def _hold_until_release(obj: Any, release: int, slot: int) -> None:
    """Keep a body out of the simulation until frame ``release``, then let it go from rest at its pose.

    Until then it is animated (kinematic) and parked far from everything (kinematic bodies do not
    collide with each other); three frames before its release it is moved to its spawn pose, and at
    ``release`` ``rigid_body.kinematic`` turns off, so Bullet takes it over with no velocity. Blender
    5.0 honours such keyframes mid-simulation without resetting the cache (docs/blender.md)."""
    at = obj.matrix_world.copy()
    obj.keyframe_insert("location", frame=release - 3)
    obj.location = (1000.0 + 10.0 * slot, 1000.0, 1000.0)
    obj.keyframe_insert("location", frame=1)
    obj.keyframe_insert("location", frame=release - 4)
    obj.rigid_body.kinematic = True
    obj.keyframe_insert("rigid_body.kinematic", frame=release - 1)
    obj.rigid_body.kinematic = False
    obj.keyframe_insert("rigid_body.kinematic", frame=release)
    obj.location = at.translation  # the current frame's pose stays the spawn pose for anything reading it


REST_WINDOW = 10  # frames between rest checks
REST_WINDOWS = 2  # consecutive calm windows before the simulation stops early
REST_ROLLING = 0.05  # fraction of bodies still allowed to move then: balls rolling away over the floor
REST_ROLLING_MIN = 2  # ... and at least this many (they are mostly dropped as outside the frame)


@dataclass(frozen=True)
class Settled:
    """What one simulation gave: the settled pose of every active body and how the run went."""

    matrices: dict[str, np.ndarray]  # active body name -> settled 4x4 world matrix
    speeds: dict[str, float]  # active body name -> its mean speed (m/s) over the last rest window
    frames_run: int  # frames actually simulated (fewer than asked when the pile came to rest)
    waited_for: int  # bodies the last rest check waited for
    last_release: int  # the latest release frame (1 without spawn waves)


def _setup_world(scene: Any, *, frames: int, substeps: int, iterations: int, gravity: float) -> None:
    """A rigid-body world over frames 1 .. ``frames`` + 1 with the stage's substeps, iterations, gravity."""
    import bpy

    if scene.rigidbody_world is None:
        with bpy.context.temp_override(scene=scene):
            bpy.ops.rigidbody.world_add()
    world = scene.rigidbody_world
    if world.collection is None:
        world.collection = bpy.data.collections.new("RigidBodyWorld")
    world.substeps_per_frame = max(1, int(substeps))
    world.solver_iterations = max(1, int(iterations))
    world.point_cache.frame_start = 1
    world.point_cache.frame_end = frames + 1
    scene.gravity = (0.0, 0.0, -abs(float(gravity)))
    scene.use_gravity = True
    scene.frame_start = 1
    scene.frame_end = frames + 1


def _freeze(scene: Any, bodies: list[Body], held_objs: list[Any]) -> dict[str, np.ndarray]:
    """The active bodies' evaluated poses, then the simulation dropped (one operator, not one per body)
    and those poses kept as plain transforms; the bodies keep inert rigid-body settings, which nothing
    reads without a world."""
    import bpy
    import mathutils

    depsgraph = bpy.context.evaluated_depsgraph_get()
    settled = {b.obj.name: np.array(b.obj.evaluated_get(depsgraph).matrix_world, dtype=np.float64)
               for b in bodies if b.kind == "active"}
    with bpy.context.temp_override(scene=scene):
        bpy.ops.rigidbody.world_remove()
    for obj in held_objs:  # the parking animation would put them back at frame 1
        obj.animation_data_clear()
    scene.frame_set(1)
    for body in bodies:
        if body.obj.name in settled:
            body.obj.matrix_world = mathutils.Matrix(settled[body.obj.name].tolist())
    return settled


def simulate(scene: Any, bodies: list[Body], *, frames: int, substeps: int, iterations: int,
             gravity: float, rest_speed: float,
             waited_for: Optional[Callable[[np.ndarray], np.ndarray]] = None,
             releases: Optional[dict[str, int]] = None) -> Settled:
    """Run the simulation for at most ``frames`` frames; returns the settled 4x4 world matrix per active
    body and how the run went (:class:`Settled`).

    Every :data:`REST_WINDOW` frames the active bodies' mean speeds over the window are measured; with
    ``rest_speed`` > 0 the run stops once all bodies but :data:`REST_ROLLING` of them, at least 2 (objects rolling
    away over the floor, which Bullet's damping stops only slowly) have been slower than it (m/s) for
    :data:`REST_WINDOWS` windows in a row: a settled pile costs no further frames. Only bodies that can
    still be kept are waited for: by default those whose centre is above the floor's top (z = 0);
    ``waited_for`` (active bodies' centres (N, 3) -> bool mask) replaces that rule, e.g. to add "origin
    in the camera frame" (the scene job's). ``releases`` (active body name -> frame > 1) holds bodies
    out until their frame (:func:`_hold_until_release`, spawn waves); ``frames`` then counts from the
    last release, and the run does not stop before every held body has been let go and has slowed
    below ``rest_speed`` once (or stopped being waited for)."""
    import bpy

    held = {name: int(f) for name, f in (releases or {}).items() if int(f) > 1}
    last_release = max(held.values(), default=1)
    frames = int(frames) + last_release - 1
    _setup_world(scene, frames=frames, substeps=substeps, iterations=iterations, gravity=gravity)
    _add_bodies(scene, bodies)
    held_objs = [b.obj for b in bodies if b.kind == "active" and b.obj.name in held]
    for slot, obj in enumerate(held_objs):
        _hold_until_release(obj, held[obj.name], slot)
    scene.frame_set(1)
    fps = scene.render.fps / scene.render.fps_base
    active = [b.obj for b in bodies if b.kind == "active"]

    def positions() -> np.ndarray:
        dg = bpy.context.evaluated_depsgraph_get()
        return np.array([o.evaluated_get(dg).matrix_world.translation for o in active],
                        dtype=np.float64).reshape(-1, 3)

    last, last_f, calm, ran = positions(), 1, 0, frames
    unlanded = {i for i, o in enumerate(active) if o.name in held}
    window_speed = waited = np.zeros(len(active))
    for f in range(2, frames + 2):
        scene.frame_set(f)
        if (f - 1) % REST_WINDOW and f != frames + 1:
            continue
        now = positions()
        window_speed = np.linalg.norm(now - last, axis=1) * fps / max(1, f - last_f)
        last, last_f = now, f
        # a body whose centre fell under the floor's top (z = 0) is dropped as below_floor anyway and
        # may fall forever: it does not hold the rest of the pile up
        waiting = np.asarray(waited_for(now) if waited_for is not None else now[:, 2] >= 0.0, dtype=bool)
        waited = window_speed[waiting]
        moving = int((waited >= rest_speed).sum())
        calm = calm + 1 if rest_speed > 0 and moving <= max(REST_ROLLING_MIN, REST_ROLLING * len(waited)) else 0
        # a held body counts as landed once, after its release, it is slower than rest_speed or no longer
        # waited for (fallen off the floor, rolling on outside the view); until every one has, the run
        # goes on (the rolling allowance must not freeze a late body in mid-air)
        unlanded = {i for i in unlanded
                    if f <= held[active[i].name] or (waiting[i] and window_speed[i] >= rest_speed)}
        if unlanded:
            calm = 0
        if calm >= REST_WINDOWS:
            ran = f - 1
            break
    speeds = {o.name: float(v) for o, v in zip(active, window_speed)}
    return Settled(matrices=_freeze(scene, bodies, held_objs), speeds=speeds, frames_run=ran,
                   waited_for=len(waited), last_release=last_release)
