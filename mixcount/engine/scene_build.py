"""Building one scene in Blender from its USD stage (bpy; runs only inside the worker process).

Chosen over ``wm.usd_import`` of the whole stage (see docs/blender.md): the stage is read with pxr; each
referenced asset's mesh comes from the scene's :class:`~mixcount.engine.asset_meshes.AssetCache` (imported
once, or appended from its .blend cache: :mod:`mixcount.engine.asset_meshes`), and every instance prim
becomes a linked duplicate (a new object sharing that mesh) placed by the prim's world matrix. Objects keep
the prim's name, so mapping back to prims is by name; ``pass_index`` is the instance id. The floor (with its
material) is imported through ``prim_path_mask``; camera and lights are built from their prims; physics
bodies (collision proxies, the container's convex parts, the floor's deep collider) are set up for
:func:`mixcount.engine.scene_job.settle`.

:func:`load_scene` returns the :class:`SceneState` the steps of :mod:`mixcount.engine.scene_job` refine.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

import mixcount.scene_decisions as D
from mixcount.engine.asset_meshes import AssetCache
from mixcount.scene.spec import SceneSpec
from mixcount.worker.contract import DROPPED, ObjectResult, SceneRequest


def _np_matrix(gf_matrix: Any) -> np.ndarray:
    """Gf.Matrix4d (row vectors, translation in the last row) -> 4x4 column-vector convention."""
    return np.array(gf_matrix, dtype=np.float64).T


def _reference_path(prim: Any, stage_dir: Path) -> Optional[Path]:
    op = prim.GetMetadata("references")
    if op is None:
        return None
    items = list(op.prependedItems) + list(op.appendedItems) + list(op.explicitItems)
    for ref in items:
        if ref.assetPath:
            p = Path(ref.assetPath)
            return p if p.is_absolute() else (stage_dir / p).resolve()
    return None


def _import_floor(stage_path: Path) -> Any:
    import bpy

    before = set(bpy.data.objects)
    bpy.ops.wm.usd_import(filepath=str(stage_path), prim_path_mask="/World/Floor,/World/Looks",
                          import_lights=False, import_cameras=False, create_collection=False)
    floor = None
    for o in list(bpy.data.objects):
        if o in before:
            continue
        if o.type == "MESH" and o.name.startswith("Floor"):
            floor = o
        elif o.type != "MESH":
            if o.children:
                for ch in o.children:
                    mw = ch.matrix_world.copy()
                    ch.parent = None
                    ch.matrix_world = mw
            bpy.data.objects.remove(o, do_unlink=True)
    if floor is None:
        raise RuntimeError("stage has no /World/Floor mesh")
    floor.pass_index = 0
    # the stage's floor carries no normals and Blender imports it smooth-shaded: the top face's normals
    # would be averaged with the side faces (a 45-degree tilt at the rim); a box/cylinder floor is flat
    floor.data.shade_flat()
    return floor


def _floor_collider(scene: Any, floor: Any, depth: float) -> Any:
    """The floor as physics sees it: a hidden copy whose bottom lies ``depth`` metres under its top.

    The rendered floor is a thin slab (box or cylinder); at the paper's 2 substeps a body dropped from
    1.5·s falls ~0.35 m per Bullet step (~0.09 m at the default 8) and can pass through it between steps. The collider keeps
    the floor's outline and top face (so the pile rests exactly where it renders) but is a deep solid:
    a body that reaches it is pushed back up. ``depth`` <= the floor's own thickness: the floor itself.
    """
    import bpy
    import mathutils

    data = floor.data.copy()
    co = np.empty(len(data.vertices) * 3, dtype=np.float32)
    data.attributes["position"].data.foreach_get("vector", co)
    world = D.deepen_below_top(co.reshape(-1, 3).astype(np.float64), np.array(floor.matrix_world), depth)
    if world is None:
        bpy.data.meshes.remove(data)
        return floor
    data.vertices.foreach_set("co", world.astype(np.float32).ravel())
    data.update()
    obj = bpy.data.objects.new("Floor_collider", data)
    scene.collection.objects.link(obj)
    obj.matrix_world = mathutils.Matrix.Identity(4)
    obj.hide_render = True
    return obj


def _hidden_collider(scene: Any, name: str, data: Any, matrix: np.ndarray) -> Any:
    """An object of mesh ``data`` at ``matrix`` (4x4) that only collides: linked, hidden from renders."""
    import bpy
    import mathutils

    obj = bpy.data.objects.new(name, data)
    scene.collection.objects.link(obj)
    obj.matrix_world = mathutils.Matrix(matrix.tolist())
    obj.hide_render = True
    return obj


def _build_camera(scene: Any, prim: Any) -> Any:
    import bpy
    import mathutils
    from pxr import Usd, UsdGeom

    ucam = UsdGeom.Camera(prim)
    data = bpy.data.cameras.new(prim.GetName())
    data.lens = float(ucam.GetFocalLengthAttr().Get())
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = float(ucam.GetHorizontalApertureAttr().Get())
    data.sensor_height = float(ucam.GetVerticalApertureAttr().Get())
    near, far = ucam.GetClippingRangeAttr().Get()
    data.clip_start, data.clip_end = float(near), float(far)
    obj = bpy.data.objects.new(prim.GetName(), data)
    scene.collection.objects.link(obj)
    m = _np_matrix(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    obj.matrix_world = mathutils.Matrix(m.tolist())
    scene.camera = obj
    res = prim.GetCustomDataByKey("mixcount:resolution")
    if res is not None:
        scene.render.resolution_x, scene.render.resolution_y = int(res[0]), int(res[1])
    return obj


def _build_lights(scene: Any, stage: Any, stage_dir: Path) -> dict[str, Any]:
    """World from the dome light (HDRI texture, or uniform sky colour) and a sun lamp if present."""
    import math

    import bpy
    import mathutils
    from pxr import Usd, UsdGeom, UsdLux

    world = bpy.data.worlds.new("World")
    scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    bg = nt.nodes.get("Background") or nt.nodes.new("ShaderNodeBackground")
    info: dict[str, Any] = {}
    dome_prim = stage.GetPrimAtPath("/World/Lights/Dome")
    if dome_prim and dome_prim.IsValid():
        dome = UsdLux.DomeLight(dome_prim)
        strength = float(dome.GetIntensityAttr().Get() or 1.0)
        bg.inputs["Strength"].default_value = strength
        tex_attr = dome.GetTextureFileAttr().Get()
        tex = tex_attr.resolvedPath or tex_attr.path if tex_attr is not None else ""
        rot = float(dome_prim.GetCustomDataByKey("mixcount:rotation_deg") or 0.0)
        if tex:
            path = Path(tex)
            if not path.is_absolute():
                path = (stage_dir / path).resolve()
            env = nt.nodes.new("ShaderNodeTexEnvironment")
            env.image = bpy.data.images.load(str(path), check_existing=True)
            mapping = nt.nodes.new("ShaderNodeMapping")
            coord = nt.nodes.new("ShaderNodeTexCoord")
            mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(rot))
            nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
            nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
            nt.links.new(env.outputs["Color"], bg.inputs["Color"])
            info["dome"] = {"kind": "hdri", "path": str(path), "strength": strength, "rotation_deg": rot}
        else:
            col = dome.GetColorAttr().Get()
            col = (1.0, 1.0, 1.0) if col is None else tuple(float(c) for c in col)
            bg.inputs["Color"].default_value = (*col, 1.0)
            info["dome"] = {"kind": "uniform", "color": list(col), "strength": strength}
    out = nt.nodes.get("World Output") or nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    sun_prim = stage.GetPrimAtPath("/World/Lights/Sun")
    if sun_prim and sun_prim.IsValid():
        sun = UsdLux.DistantLight(sun_prim)
        data = bpy.data.lights.new("Sun", type="SUN")
        data.energy = float(sun.GetIntensityAttr().Get() or 1.0)
        data.angle = math.radians(float(sun.GetAngleAttr().Get() or 0.53))
        obj = bpy.data.objects.new("Sun", data)
        scene.collection.objects.link(obj)
        m = _np_matrix(UsdGeom.Xformable(sun_prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
        obj.matrix_world = mathutils.Matrix(m.tolist())
        info["sun"] = {"strength": data.energy}
    return info


@dataclass
class SceneState:
    """One job's Blender scene as :func:`load_scene` built it (scene, spec, cameras, lights, asset cache,
    bodies and proxies) and the per-object record the steps write (``objects``, their per-camera
    ``views``, the settle checks' ``bounds``, ``diagnostics``). What a step makes besides that record is
    its return value (``scene_job.Settled``, ``scene_job.Placement``, id passes, masks, status)."""

    scene: Any
    spec: SceneSpec
    stage_path: Path
    out_dir: Path
    cam_objs: list[Any]  # one Blender camera per stage camera, in stage order
    lights: dict[str, Any]
    cache: AssetCache
    bodies: list[Any]  # mixcount.engine.physics.Body, floor and container included
    objects: list[ObjectResult]  # counted objects and distractors, in stage order
    blender_objects: dict[str, Any]  # prim path -> bpy object (removed from the scene when dropped)
    diagnostics: list[dict[str, Any]] = field(default_factory=list)
    proxies: dict[str, Any] = field(default_factory=dict)  # render object name -> its hidden collision proxy
    proxy_scales: dict[str, np.ndarray] = field(default_factory=dict)  # render object name -> scale baked in its proxy
    views: dict[int, list[dict[str, Any]]] = field(default_factory=dict)  # object index -> per-camera records
    bounds: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # object index -> settled world AABB
    # object index -> render object of a counted body dropped (unlinked, not removed): a count target's
    # top-up may drop it in again once its class's reserve is used up (None: dropped bodies are removed)
    set_aside: Optional[dict[int, Any]] = None

    @property
    def placed_after_physics(self) -> bool:
        """Cameras framed on the settled pile and distractors placed in view (specs with a placement)."""
        return self.spec.placement is not None

    def kept(self, role: Optional[str] = None) -> list[int]:
        return [i for i, o in enumerate(self.objects) if o.kept and (role is None or o.role == role)]

    def update(self, i: int, **changes: Any) -> None:
        self.objects[i] = replace(self.objects[i], **changes)

    def view(self, i: int, k: int) -> dict[str, Any]:
        """Object ``i``'s record for camera ``k`` (created on first use)."""
        views = self.views.setdefault(i, [{"camera": c.name} for c in self.cam_objs])
        return views[k]

    def drop(self, i: int, reason: str, step: str, **extra: Any) -> None:
        """Mark object ``i`` dropped (with a diagnostic) and remove it from the Blender scene (a counted
        body only unlinked into :attr:`set_aside` when that is kept)."""
        import bpy

        o = self.objects[i]
        self.update(i, status=DROPPED, reason=reason)
        self.diagnostics.append({"kind": "dropped", "object": o.name, "instance_id": o.instance_id,
                                 "role": o.role, "reason": reason, "stage": step, **extra})
        obj = self.blender_objects.pop(o.path, None)
        if obj is None:
            return
        if self.set_aside is not None and o.role == "counted":
            for coll in list(obj.users_collection):
                coll.objects.unlink(obj)
            self.set_aside[i] = obj
        else:
            bpy.data.objects.remove(obj, do_unlink=True)


def load_scene(req: SceneRequest) -> SceneState:
    """Factory-empty Blender -> floor, one linked duplicate per instance prim, cameras and lights."""
    import bpy
    from pxr import Usd, UsdGeom

    from mixcount.engine import render_passes as P

    stage_path = Path(req.stage).resolve()
    out_dir = Path(req.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    P.configure_common(scene, threads=req.threads)
    stage = Usd.Stage.Open(str(stage_path))
    if stage is None:
        raise RuntimeError(f"cannot open stage {stage_path}")
    spec = SceneSpec.from_json(stage.GetRootLayer().customLayerData["mixcount"]["spec"])
    state = SceneState(scene=scene, spec=spec, stage_path=stage_path, out_dir=out_dir, cam_objs=[], lights={},
                       cache=AssetCache(req.mesh_cache), bodies=[], objects=[], blender_objects={})
    _add_instances(state, stage)
    cam_prims = [p for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]
    if not cam_prims:
        raise RuntimeError("stage has no camera")
    state.cam_objs = [_build_camera(scene, prim) for prim in cam_prims]
    scene.camera = state.cam_objs[0]
    state.lights = _build_lights(scene, stage, stage_path.parent)
    if state.cache.cache_events:
        state.diagnostics.append({"kind": "mesh_cache", "mode": req.mesh_cache, "assets": state.cache.cache_report()})
    return state


def _split_scale(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A 4x4 pose (column vectors, no shear) -> its per-axis scale and the pose without it."""
    scale = np.linalg.norm(m[:3, :3], axis=0)
    unscaled = np.array(m, dtype=np.float64)
    unscaled[:3, :3] = m[:3, :3] / np.where(scale == 0, 1.0, scale)
    return scale, unscaled


def scaled_proxy_collider(scene: Any, name: str, proxy: Any, matrix: np.ndarray) -> tuple[Any, np.ndarray]:
    """A hidden collider of the proxy mesh at ``matrix`` with the scale baked into its own copy of the mesh
    (the object itself unscaled); returns it and the scale, which the render object's pose gets back
    (``pose_with_scale``). Bullet's convex hulls misbehave under a large object scale: in bpy 5.0.1 a
    2.2 cm cube at x51 dropped 15 m came back up to 8 m and from 30 m went through the floor, while the
    same cube with the scale in its vertices rests at the margin (docs/blender.md)."""
    import mathutils

    scale, unscaled = _split_scale(np.asarray(matrix, dtype=np.float64))
    data = proxy.copy()
    data.transform(mathutils.Matrix.Diagonal((*scale.tolist(), 1.0)))
    return _hidden_collider(scene, name, data, unscaled), scale


def pose_with_scale(matrix: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The render object's pose from its unscaled collider's pose and the scale baked into the collider."""
    return np.asarray(matrix, dtype=np.float64) @ np.diag([*np.asarray(scale, dtype=np.float64).tolist(), 1.0])


def _add_instances(state: SceneState, stage: Any) -> None:
    """The floor and every labelled prim as Blender objects and physics bodies; an ObjectResult each for
    counted objects and distractors. With after-physics placement distractors get no body: the paper
    simulates the counted objects, the floor and the container only, and they are placed afterwards."""
    import bpy
    import mathutils
    from pxr import Usd, UsdGeom, UsdPhysics

    from mixcount.engine.physics import SHAPES, Body
    from mixcount.usd.read import labelled_prims

    scene, stage_dir = state.scene, state.stage_path.parent
    floor = _import_floor(state.stage_path)
    for ids in labelled_prims(stage):
        prim = stage.GetPrimAtPath(ids.path)
        if ids.role == "floor":
            collider = _floor_collider(scene, floor, state.spec.physics.floor_collider_depth)
            state.bodies.append(Body(collider, "passive", "CONVEX_HULL"))
            continue
        asset = _reference_path(prim, stage_dir)
        if asset is None:
            raise RuntimeError(f"prim {ids.path} references no asset")
        mesh = state.cache.mesh(asset)
        obj = bpy.data.objects.new(prim.GetName(), mesh)
        scene.collection.objects.link(obj)
        m = _np_matrix(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
        obj.matrix_world = mathutils.Matrix(m.tolist())
        obj.pass_index = int(ids.instance_id)
        state.blender_objects[ids.path] = obj
        if ids.role == "container":
            _add_container_collision(state, prim, obj, asset, m)
            continue
        kind = "active" if prim.HasAPI(UsdPhysics.RigidBodyAPI) else "passive"
        proxy_prim = stage.GetPrimAtPath(f"{ids.path}/Proxy")
        if ids.role == "distractor" and state.placed_after_physics:
            pass  # placed on free floor after physics (place_distractors_in_view), never simulated
        elif (proxy_prim and proxy_prim.HasAPI(UsdPhysics.CollisionAPI)
                and UsdPhysics.CollisionAPI(proxy_prim).GetCollisionEnabledAttr().Get() is not False):
            # collide through the convex proxy: a hidden object that the simulation moves; settle()
            # copies its pose onto the render object. The instance's scale is baked into its own copy of the
            # proxy: under a large object scale Bullet's hulls misbehave (a 2.2 cm die at x51 came back up
            # from a 15 m drop and went through the floor from 30 m; baked, it rests), docs/blender.md
            pobj, scale = scaled_proxy_collider(scene, prim.GetName() + "_proxy", state.cache.proxy(asset, proxy_prim), m)
            state.proxies[obj.name] = pobj
            state.proxy_scales[obj.name] = scale
            state.bodies.append(Body(pobj, kind, "CONVEX_HULL"))
        else:
            approx = str(prim.GetAttribute("physics:approximation").Get() or state.spec.physics.collision_shape)
            state.bodies.append(Body(obj, kind, SHAPES[approx]))
        size = prim.GetCustomDataByKey("mixcount:size_m")
        state.objects.append(ObjectResult(
            name=prim.GetName(), path=ids.path, role=ids.role, instance_id=ids.instance_id,
            object_id=ids.object_id, class_index=ids.class_index, asset=str(asset),
            size_m=float(size) if size is not None else float(max(obj.dimensions)),
            spawn_matrix=tuple(tuple(float(v) for v in row) for row in m)))


def _add_container_collision(state: SceneState, prim: Any, obj: Any, asset: Path, m: np.ndarray) -> None:
    """The container's static colliders: its convex parts, else its decimated mesh, else the render mesh."""
    import bpy

    from mixcount.engine.physics import Body
    from mixcount.usd.read import convex_parts

    coll = prim.GetCustomDataByKey("mixcount:collision_asset")
    if coll and not Path(str(coll)).is_absolute():  # stage-relative (portable datasets, docs/usd.md)
        coll = str((state.stage_path.parent / str(coll)).resolve())
    parts = convex_parts(str(coll)) if coll else []
    if parts:  # the container's convex decomposition: one static convex body per part
        for k, (pts, tris) in enumerate(parts):
            data = bpy.data.meshes.new(f"{prim.GetName()}_part{k:03d}")
            data.from_pydata(pts.tolist(), [], tris.tolist())
            state.bodies.append(Body(_hidden_collider(state.scene, data.name, data, m), "passive", "CONVEX_HULL",
                                     collision_margin=0.0))
        state.diagnostics.append({"kind": "container_collision", "source": "convex parts", "parts": len(parts)})
    elif coll:
        cobj = _hidden_collider(state.scene, prim.GetName() + "_collision", state.cache.mesh(Path(coll)), m)
        state.bodies.append(Body(cobj, "passive", "MESH"))
    else:  # no decimated collision asset: Bullet gets every render triangle (slow on a capture)
        state.bodies.append(Body(obj, "passive", "MESH"))
        state.diagnostics.append({"kind": "container_collision", "source": "render mesh",
                                  "triangles": int(state.cache.corners[str(asset)].shape[1])})
