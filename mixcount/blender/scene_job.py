"""One scene in the worker: stage -> Blender scene -> settle -> visibility filter -> passes (bpy).

Scene building (chosen over ``wm.usd_import`` of the whole stage, see docs/blender.md): the stage is read
with pxr; every referenced asset file is imported ONCE with ``wm.usd_import`` (UsdPreviewSurface ->
Principled BSDF), its mesh parts baked and joined into one mesh datablock, and every instance prim becomes
a linked duplicate (a new object sharing that mesh) placed by the prim's world matrix. Objects keep the
prim's name, so mapping back to prims is by name; ``pass_index`` is the instance id. The floor (with its
material) is imported through ``prim_path_mask``; camera and lights are built from their prims.

Writes into ``out_dir``: ``rgb.png``, ``ids.npy`` (int32 instance ids of counted objects and distractors,
0 elsewhere), ``depth.npy`` (float32 planar depth in metres along the optical axis, 0 = no surface),
``normal.npy`` (float32 unit normals in camera space: x right, y up, z towards the viewer; 0 = none) and
``worker.json`` (per-object records, camera, timings, diagnostics). ``status`` in worker.json is
"ok", "empty" (no counted object survived: the caller regenerates from the next seed) or "rejected".
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np

from mixcount.annotate.raster import PinholeCamera

STATUS_OK = "ok"
STATUS_EMPTY = "empty"
STATUS_REJECTED = "rejected"


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


# ------------------------------------------------------------------------------------ building


class AssetCache:
    """One joined mesh datablock per asset file, imported once per scene."""

    def __init__(self) -> None:
        self.meshes: dict[str, Any] = {}
        self.arrays: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.hulls: dict[str, np.ndarray] = {}
        self.flipped_normals: dict[str, bool] = {}

    def mesh(self, path: Path) -> Any:
        import bpy

        from mixcount.blender.visibility import mesh_arrays

        key = str(path)
        if key in self.meshes:
            return self.meshes[key]
        before = set(bpy.data.objects)
        res = bpy.ops.wm.usd_import(filepath=key, import_lights=False, import_cameras=False, import_guide=False,
                                    import_proxy=False, create_collection=False)
        if "FINISHED" not in res:
            raise RuntimeError(f"USD import of {key} failed")
        new = [o for o in bpy.data.objects if o not in before]
        parts = [o for o in new if o.type == "MESH"]
        if not parts:
            raise RuntimeError(f"asset {key} holds no mesh")
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
        mesh.name = f"asset_{Path(key).stem[:16]}"
        self.flipped_normals[key] = fix_inverted_normals(mesh)
        mesh.use_fake_user = True
        for o in list(bpy.data.objects):
            if o in before:
                continue
            bpy.data.objects.remove(o, do_unlink=True)
        self.meshes[key] = mesh
        self.arrays[key] = mesh_arrays(mesh)
        return mesh

    def hull(self, path: Path) -> np.ndarray:
        from mixcount.blender.physics import hull_equations

        key = str(path)
        if key not in self.hulls:
            self.hulls[key] = hull_equations(self.arrays[key][0])
        return self.hulls[key]


def fix_inverted_normals(mesh: Any) -> bool:
    """Drop authored (custom) normals that point against the face winding on most corners.

    A shading normal facing away from the geometric one renders black in Cycles; assets converted with
    inverted normals (seen with mixcount.usd.assets v1 on glTF sources) are repaired here: the custom
    normals are removed, faces shaded smooth and edges sharper than 30 degrees kept sharp.
    """
    import math

    if "custom_normal" not in mesh.attributes or len(mesh.polygons) == 0:
        return False
    n = len(mesh.loops)
    corner = np.empty(n * 3, dtype=np.float64)
    mesh.corner_normals.foreach_get("vector", corner)
    poly = np.empty(len(mesh.polygons) * 3, dtype=np.float64)
    mesh.polygons.foreach_get("normal", poly)
    loop_poly = np.repeat(np.arange(len(mesh.polygons)),
                          [p.loop_total for p in mesh.polygons])
    dots = (corner.reshape(-1, 3) * poly.reshape(-1, 3)[loop_poly]).sum(1)
    if float(np.mean(dots < 0)) <= 0.5:
        return False
    mesh.attributes.remove(mesh.attributes["custom_normal"])
    mesh.shade_smooth()
    mesh.set_sharp_from_angle(angle=math.radians(30.0))
    return True


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


# ------------------------------------------------------------------------------------ the job


def run_scene(req: dict[str, Any]) -> dict[str, Any]:
    """Handle one ``scene`` request (see module docstring); returns the worker.json dict."""
    import bpy
    import mathutils
    from pxr import Usd, UsdGeom

    from mixcount.blender import passes as P
    from mixcount.blender.physics import SHAPES, Body, penetration_depth, simulate
    from mixcount.blender.visibility import camera_model, oracle_masks, unoccluded_mask, world_vertices
    from mixcount.usd.read import labelled_prims

    timer = Timer()
    stage_path = Path(req["stage"]).resolve()
    out_dir = Path(req["out_dir"])
    out_dir.mkdir(parents=True, exist_ok=True)
    stage_dir = stage_path.parent
    below_frac = float(req["settle"]["below_floor_fraction"])
    pen_frac = float(req["settle"]["penetration_fraction"])
    diagnostics: list[dict[str, Any]] = []

    with timer.stage("import"):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        P.configure_common(scene, threads=int(req["threads"]))
        stage = Usd.Stage.Open(str(stage_path))
        if stage is None:
            raise RuntimeError(f"cannot open stage {stage_path}")
        spec = json.loads(stage.GetRootLayer().customLayerData["mixcount"]["spec"])
        v_t = float(req["visibility_threshold"])
        phys_prim = stage.GetPrimAtPath("/World/PhysicsScene")
        frames = int(req.get("physics_frames") or phys_prim.GetCustomDataByKey("mixcount:frames") or spec["physics"]["frames"])
        substeps = max(int(phys_prim.GetCustomDataByKey("mixcount:substeps") or spec["physics"]["substeps"]),
                       int(req["min_substeps"]))  # objects dropped from 15 m tunnel at 2 substeps
        iterations = int(phys_prim.GetCustomDataByKey("mixcount:solver_iterations")
                         or spec["physics"]["solver_iterations"])
        from pxr import UsdPhysics

        gravity = float(UsdPhysics.Scene(phys_prim).GetGravityMagnitudeAttr().Get() or spec["physics"]["gravity"])

        floor = _import_floor(stage_path)
        cache = AssetCache()
        records: list[dict[str, Any]] = []
        objs: dict[str, Any] = {}
        bodies: list[Body] = []
        for ids in labelled_prims(stage):
            prim = stage.GetPrimAtPath(ids.path)
            if ids.role == "floor":
                bodies.append(Body(floor, "passive", "CONVEX_HULL"))
                continue
            asset = _reference_path(prim, stage_dir)
            if asset is None:
                raise RuntimeError(f"prim {ids.path} references no asset")
            mesh = cache.mesh(asset)
            obj = bpy.data.objects.new(prim.GetName(), mesh)
            scene.collection.objects.link(obj)
            m = _np_matrix(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
            obj.matrix_world = mathutils.Matrix(m.tolist())
            obj.pass_index = int(ids.instance_id)
            objs[ids.path] = obj
            if ids.role == "container":
                coll = prim.GetCustomDataByKey("mixcount:collision_asset")
                if coll:
                    cmesh = cache.mesh(Path(coll))
                    cobj = bpy.data.objects.new(prim.GetName() + "_collision", cmesh)
                    scene.collection.objects.link(cobj)
                    cobj.matrix_world = mathutils.Matrix(m.tolist())
                    cobj.hide_render = True
                    bodies.append(Body(cobj, "passive", "MESH"))
                else:
                    bodies.append(Body(obj, "passive", "MESH"))
                continue
            approx = str(prim.GetAttribute("physics:approximation").Get() or "convexHull")
            has_rb = prim.HasAPI(UsdPhysics.RigidBodyAPI)
            bodies.append(Body(obj, "active" if has_rb else "passive", SHAPES.get(approx, "CONVEX_HULL")))
            size = prim.GetCustomDataByKey("mixcount:size_m")
            records.append({
                "name": prim.GetName(), "path": ids.path, "role": ids.role, "instance_id": ids.instance_id,
                "object_id": ids.object_id, "class_index": ids.class_index, "asset": str(asset),
                "size_m": float(size) if size is not None else float(max(obj.dimensions)),
                "spawn_matrix": m.tolist(), "status": "kept", "reason": None,
            })
        cam_prims = [p for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]
        if not cam_prims:
            raise RuntimeError("stage has no camera")
        cam_obj = _build_camera(scene, cam_prims[0])
        if len(cam_prims) > 1:
            diagnostics.append({"kind": "cameras", "message": f"{len(cam_prims)} cameras: rendering {cam_prims[0].GetName()} only"})
        light_info = _build_lights(scene, stage, stage_dir)

    by_name = {r["name"]: r for r in records}

    def drop(rec: dict[str, Any], reason: str, stage_name: str, **extra: Any) -> None:
        rec["status"], rec["reason"] = "dropped", reason
        diagnostics.append({"kind": "dropped", "object": rec["name"], "instance_id": rec["instance_id"],
                            "role": rec["role"], "reason": reason, "stage": stage_name, **extra})
        obj = objs.pop(rec["path"], None)
        if obj is not None:
            bpy.data.objects.remove(obj, do_unlink=True)

    with timer.stage("physics"):
        settled = simulate(scene, bodies, frames=frames, substeps=substeps, iterations=iterations, gravity=gravity)

    with timer.stage("settle_checks"):
        fl = spec["floor"]
        hx, hy = float(fl["half_extent"][0]), float(fl["half_extent"][1])
        live = []
        for rec in records:
            obj = objs[rec["path"]]
            mat = settled.get(obj.name, np.array(obj.matrix_world))
            rec["matrix_world"] = mat.tolist()
            local, _ = cache.arrays[rec["asset"]]
            wv = world_vertices(local, mat)
            rec["min_z"] = float(wv[:, 2].min()) if np.isfinite(wv).all() else float("nan")
            c = mat[:3, 3]
            if not np.isfinite(mat).all():
                drop(rec, "unstable", "settle")
            elif c[2] < 0 or rec["min_z"] < -below_frac * rec["size_m"]:
                drop(rec, "below_floor", "settle", min_z=rec["min_z"])
            elif (fl["shape"] == "cylinder" and float(np.hypot(c[0], c[1])) > hx) or \
                    (fl["shape"] != "cylinder" and (abs(c[0]) > hx or abs(c[1]) > hy)):
                drop(rec, "flung_out", "settle", position=c.tolist())
            else:
                rec["_aabb"] = (wv.min(0), wv.max(0))
                live.append(rec)
        # deep interpenetration: one body's centre inside another's hull, deeper than a fraction of its size
        for i, a in enumerate(live):
            if a["status"] != "kept":
                continue
            for b in live[i + 1:]:
                if b["status"] != "kept":
                    continue
                (alo, ahi), (blo, bhi) = a["_aabb"], b["_aabb"]
                if np.any(ahi < blo) or np.any(bhi < alo):
                    continue
                ma, mb = np.array(a["matrix_world"]), np.array(b["matrix_world"])
                d1 = penetration_depth(ma[:3, 3], mb, cache.hull(b["asset"]))
                d2 = penetration_depth(mb[:3, 3], ma, cache.hull(a["asset"]))
                depth = max(d1, d2)
                if depth > pen_frac * min(a["size_m"], b["size_m"]):
                    drop(b, "interpenetration", "settle", other=a["name"], depth=round(depth, 4))
        for rec in records:
            rec.pop("_aabb", None)

    camera: PinholeCamera = camera_model(scene, cam_obj)
    H, W = camera.height, camera.width
    with timer.stage("frame_check"):
        for rec in records:
            if rec["status"] != "kept":
                continue
            mat = np.array(rec["matrix_world"])
            px, depth = camera.project(mat[None, :3, 3])
            rec["origin_px"] = [float(px[0, 0]), float(px[0, 1])]
            if depth[0] <= camera.near or not (0 <= px[0, 0] < W and 0 <= px[0, 1] < H):
                drop(rec, "origin_outside_frame", "frame")

    with timer.stage("silhouettes"):
        sil: dict[int, np.ndarray] = {}
        for rec in records:
            if rec["status"] != "kept":
                continue
            local, tris = cache.arrays[rec["asset"]]
            mask = unoccluded_mask(camera, local, tris, np.array(rec["matrix_world"]))
            sil[rec["instance_id"]] = mask
            rec["unoccluded_px"] = int(mask.sum())

    def measure(index: np.ndarray) -> None:
        ids, counts = np.unique(index, return_counts=True)
        vis = dict(zip(ids.tolist(), counts.tolist()))
        for rec in records:
            if rec["status"] != "kept":
                continue
            v = int(vis.get(rec["instance_id"], 0))
            u = rec["unoccluded_px"]
            rec["visible_px"] = v
            rec["visibility"] = float(min(1.0, v / u)) if u > 0 else 0.0

    exr = out_dir / "_ids.exr"
    rounds = 0
    while True:
        with timer.stage("id_pass"):
            id_passes = P.render_id_passes(scene, exr)
        with timer.stage("visibility"):
            measure(id_passes["index"])
            low = [r for r in records if r["status"] == "kept" and r["role"] == "counted"
                   and r["visibility"] <= 1.0 - v_t]
            if not low or rounds >= 3:
                break
            for rec in low:
                drop(rec, "occluded", "visibility", visibility=round(rec["visibility"], 4))
            rounds += 1
    P.remove_quiet(exr)

    counted = [r for r in records if r["status"] == "kept" and r["role"] == "counted"]
    status = STATUS_OK
    if not counted:
        status = STATUS_EMPTY
    elif any(r["visibility"] < 1.0 - v_t for r in counted):
        status = STATUS_REJECTED
        diagnostics.append({"kind": "recheck_failed",
                            "objects": [r["name"] for r in counted if r["visibility"] < 1.0 - v_t]})

    result: dict[str, Any] = {
        "status": status, "stage": str(stage_path), "scene_id": spec["scene_id"], "seed": spec["seed"],
        "visibility_threshold": v_t, "id_pass_rounds": rounds + 1,
        "physics": {"frames": frames, "substeps": substeps, "solver_iterations": iterations, "gravity": gravity},
        "camera": {
            "name": cam_obj.name, "width": W, "height": H, "K": camera.K.tolist(),
            "cam_to_world": camera.cam_to_world.tolist(), "focal_length_mm": float(cam_obj.data.lens),
            "sensor_width_mm": float(cam_obj.data.sensor_width),
            "clip_range": [float(cam_obj.data.clip_start), float(cam_obj.data.clip_end)],
            "convention": "camera looks down -Z, +Y up (Blender/USD); K maps to pixel x right, y down",
        },
        "lights": light_info, "objects": records, "diagnostics": diagnostics,
    }
    if status == STATUS_OK:
        with timer.stage("write_passes"):
            ids = id_passes["index"].copy()
            keep_ids = {r["instance_id"] for r in records if r["status"] == "kept"}
            ids[~np.isin(ids, list(keep_ids))] = 0
            np.save(out_dir / "ids.npy", ids.astype(np.int32))
            R = camera.cam_to_world[:3, :3]
            normal = id_passes["normal"] @ R  # world -> camera: R^T n, row-vector form
            bg = id_passes["depth"] > 1e9
            normal[bg] = 0.0
            np.save(out_dir / "normal.npy", normal.astype(np.float32))
            depth = planar_depth(id_passes["depth"], camera, req.get("depth_is_ray_length", False))
            depth[bg] = 0.0
            np.save(out_dir / "depth.npy", depth.astype(np.float32))
        with timer.stage("rgb"):
            P.configure_rgb(scene, samples=int(req["samples"]), denoise=bool(req["denoise"]))
            P.render_to(scene, out_dir / "rgb.png")
        if req.get("oracle"):
            with timer.stage("oracle"):
                kept = [objs[r["path"]] for r in records if r["status"] == "kept"]
                masks = oracle_masks(scene, kept, out_dir)
                save = {}
                for rec in records:
                    if rec["status"] != "kept":
                        continue
                    om = masks[rec["instance_id"]]
                    rm = sil[rec["instance_id"]]
                    rec["oracle_unoccluded_px"] = int(om.sum())
                    inter = int((om & rm).sum())
                    union = int((om | rm).sum())
                    rec["oracle_iou"] = inter / union if union else 1.0
                    rec["oracle_visibility"] = (rec["visible_px"] / int(om.sum())) if om.any() else 0.0
                    save[f"oracle_{rec['instance_id']}"] = np.packbits(om)
                    save[f"raster_{rec['instance_id']}"] = np.packbits(rm)
                np.savez_compressed(out_dir / "oracle_masks.npz", shape=np.array([H, W]), **save)
    result["timings"] = timer.times
    (out_dir / "worker.json").write_text(json.dumps(result, indent=1))
    return result


def planar_depth(depth: np.ndarray, camera: PinholeCamera, is_ray_length: bool) -> np.ndarray:
    """Cycles' depth pass -> planar depth along the optical axis (metres). Blender 5.0's Cycles Depth pass
    is already planar (checked against ray-plane intersections with the floor), so this is the identity
    unless ``is_ray_length``."""
    d = depth.astype(np.float64)
    if not is_ray_length:
        return d
    h, w = d.shape
    xs = (np.arange(w) + 0.5 - camera.cx) / camera.fx
    ys = (np.arange(h) + 0.5 - camera.cy) / camera.fy
    norm = np.sqrt(1.0 + xs[None, :] ** 2 + ys[:, None] ** 2)
    return d / norm
