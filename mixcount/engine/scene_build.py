"""Building one scene in Blender from its USD stage (bpy; runs only inside the worker process).

Chosen over ``wm.usd_import`` of the whole stage (see docs/blender.md): the stage is read with pxr; every
referenced asset file is imported ONCE with ``wm.usd_import`` (UsdPreviewSurface -> Principled BSDF), its
mesh parts baked and joined into one mesh datablock - or that datablock is appended from the asset's
.blend cache (:mod:`mixcount.engine.mesh_cache`, :class:`AssetCache`) -, and every instance prim becomes
a linked duplicate (a new object sharing that mesh) placed by the prim's world matrix. Objects keep the
prim's name, so mapping back to prims is by name; ``pass_index`` is the instance id. The floor (with its
material) is imported through ``prim_path_mask``; camera and lights are built from their prims; physics
bodies (collision proxies, the container's convex parts, the floor's deep collider) are set up for
:func:`mixcount.engine.scene_job.settle`.

:func:`load_scene` returns the :class:`SceneState` the steps of :mod:`mixcount.engine.scene_job` refine.
:func:`cache_asset_meshes` serves the worker's ``cache_meshes`` operation.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

import mixcount.scene_decisions as D
from mixcount.scene.spec import SceneSpec
from mixcount.worker.contract import DROPPED, MeshCacheRequest, MeshCacheResult, ObjectResult, SceneRequest


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


class AssetCache:
    """One joined mesh datablock per asset file, imported once per scene.

    With ``mesh_cache`` "zstd" or "raw" the finished mesh also goes to a .blend beside the asset
    (:mod:`mixcount.engine.mesh_cache`), and later scenes append it from there instead of importing the
    USD file again. ``cache_events`` records, per asset, "hit", "written" or the reason it was not."""

    def __init__(self, mesh_cache: str) -> None:
        self.mesh_cache = mesh_cache
        self.meshes: dict[str, Any] = {}
        self.columns: dict[str, np.ndarray] = {}  # local vertices as (3, V): rows reduce fast
        self.corners: dict[str, np.ndarray] = {}  # triangles' vertex indices as (3, T): rows gather fast
        self.hulls: dict[str, np.ndarray] = {}
        self.hull_vertices: dict[str, np.ndarray] = {}
        self.proxies: dict[str, Any] = {}
        self.proxy_points: dict[str, np.ndarray] = {}
        self.cache_events: dict[str, str] = {}

    def proxy(self, path: Path, prim: Any) -> Any:
        """The collision proxy mesh of an asset (read from the instance's ``Proxy`` prim), one per asset."""
        import bpy
        from pxr import UsdGeom

        key = str(path)
        if key not in self.proxies:
            mesh = UsdGeom.Mesh(prim)
            pts = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
            idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int64).reshape(-1, 3)
            data = bpy.data.meshes.new(f"proxy_{Path(key).stem[:16]}")
            data.from_pydata(pts.tolist(), [], idx.tolist())
            data.use_fake_user = True
            self.proxies[key] = data
            self.proxy_points[key] = pts
        return self.proxies[key]

    def mesh(self, path: Path) -> Any:
        """The asset's render mesh: from this scene's memory, the .blend cache, or a USD import."""
        from mixcount.engine import mesh_cache
        from mixcount.engine.visibility import mesh_arrays

        key = str(path)
        if key in self.meshes:
            return self.meshes[key]
        mesh = None
        cached = mesh_cache.cache_file(path) if self.mesh_cache != "off" else None
        if cached is not None:
            mesh = mesh_cache.load(cached)
            if mesh is not None:
                self.cache_events[key] = "hit"
        if mesh is None:
            mesh = _import_asset_mesh(key)
            if cached is not None:
                self.cache_events[key] = mesh_cache.store(mesh, cached, self.mesh_cache) or "written"
        self.meshes[key] = mesh
        verts, tris = mesh_arrays(mesh)
        self.columns[key] = np.ascontiguousarray(verts.T)
        self.corners[key] = np.ascontiguousarray(tris.T)
        return mesh

    def cache_report(self) -> dict[str, str]:
        """Asset file name -> what the .blend cache did for it ("hit", "written" or why not)."""
        return {Path(k).name: v for k, v in sorted(self.cache_events.items())}

    def collider_points(self, path: Path) -> np.ndarray:
        """Local points (P, 3) of the shape that collided: the proxy's points, else the convex hull's
        vertices of the mesh (not every vertex of a capture: a rest test over 786k points per body
        cost seconds a scene). Computed once per asset."""
        key = str(path)
        if key not in self.hull_vertices:
            local = self.proxy_points.get(key)
            self.hull_vertices[key] = local if local is not None else hull_vertices(self.columns[key].T)
        return self.hull_vertices[key]

    def hull(self, path: Path) -> np.ndarray:
        from mixcount.scene_decisions import hull_equations

        key = str(path)
        if key not in self.hulls:  # the proxy is the shape that collided (and a hull of <= proxy_max_vertices points)
            self.hulls[key] = hull_equations(self.proxy_points.get(key, self.columns[key].T))
        return self.hulls[key]


def hull_vertices(points: np.ndarray) -> np.ndarray:
    """The convex hull's vertices of ``points`` (N, 3); a flat or degenerate set: its box corners."""
    from scipy.spatial import ConvexHull

    pts = np.asarray(points, dtype=np.float64)
    try:
        return np.asarray(pts[ConvexHull(pts).vertices])
    except Exception:
        lo, hi = pts.min(0), pts.max(0)
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def cache_asset_meshes(req: MeshCacheRequest) -> MeshCacheResult:
    """Make (or find) the .blend mesh cache of each asset file ahead of the scenes that use it: asset file
    name -> "hit", "written" or why it could not be written (nothing in mode "off"). In an empty file."""
    import bpy

    if req.mode == "off":
        return MeshCacheResult(assets={})
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cache = AssetCache(req.mode)
    for a in req.assets:
        cache.mesh(Path(a))
    return MeshCacheResult(assets=cache.cache_report())


def _import_asset_mesh(asset: str) -> Any:
    """``wm.usd_import`` of one asset file (UsdPreviewSurface -> Principled BSDF), its mesh parts baked
    and joined into one mesh datablock (fake user) and the import's objects removed; authored normals
    that point against the winding are replaced (:func:`drop_authored_normals`)."""
    import bpy

    from mixcount.usd.read import normals_against_winding

    before = set(bpy.data.objects)
    res = bpy.ops.wm.usd_import(filepath=asset, import_lights=False, import_cameras=False, import_guide=False,
                                import_proxy=False, create_collection=False)
    if "FINISHED" not in res:
        raise RuntimeError(f"USD import of {asset} failed")
    new = [o for o in bpy.data.objects if o not in before]
    parts = [o for o in new if o.type == "MESH"]
    if not parts:
        raise RuntimeError(f"asset {asset} holds no mesh")
    bpy.context.view_layer.update()
    for o in parts:
        if o.data.users > 1:
            o.data = o.data.copy()
        o.data.transform(o.matrix_world)
        o.matrix_world.identity()
    if len(parts) > 1:
        with bpy.context.temp_override(active_object=parts[0], object=parts[0], selected_objects=parts,
                                       selected_editable_objects=parts):
            bpy.ops.object.join()
    mesh = parts[0].data
    mesh.name = f"asset_{Path(asset).stem[:16]}"
    if normals_against_winding(asset):
        drop_authored_normals(mesh)
    mesh.use_fake_user = True
    for o in list(bpy.data.objects):
        if o in before:
            continue
        bpy.data.objects.remove(o, do_unlink=True)
    return mesh


def drop_authored_normals(mesh: Any) -> None:
    """Replace authored (custom) normals that point against the face winding by Blender's own.

    A shading normal facing away from the geometric one renders black in Cycles. Whether an asset's
    normals do is decided from its USD arrays (:func:`mixcount.usd.read.normals_against_winding`); here
    the custom normals are removed, faces shaded smooth and edges sharper than 30 degrees kept sharp.
    """
    import math

    if "custom_normal" in mesh.attributes:
        mesh.attributes.remove(mesh.attributes["custom_normal"])
    mesh.shade_smooth()
    mesh.set_sharp_from_angle(angle=math.radians(30.0))


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
