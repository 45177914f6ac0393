"""SceneSpec -> ``scene.usda``: the scene as a USD stage any USD tool opens (contract in docs/usd.md).

The stage starts from the layers in ``usd_templates/`` (scene root with stage metadata and the
hierarchy, floor with its material network, camera rig, lights), copied into one layer, then filled
from the spec: every instance is an Xform with translate / orient / scale ops that references the
cached asset (``mixcount.usd.assets``), UsdPhysics rigid bodies and colliders, the dome light and sun,
the cameras, and customData on every prim that matters. ``customLayerData`` records the scene id,
seed, config hash, split and the whole spec as JSON.

Deterministic bytes: prims and properties are authored in a fixed order, dictionaries are sorted by
USD itself, and nothing time-dependent is written.

Portable (docs/usd.md, "Portable datasets"): no path in the stage is absolute. Catalog assets, environment
maps and floor textures are entries of the dataset's ``OUT/assets/`` (relative links to the catalog's files
until ``mixcount package`` copies them, :mod:`mixcount.dataset.package`), referenced relative to the stage
(``@../../assets/<hash>.usdc@``); scene-local files are relative too; the spec in ``customLayerData``
records paths by :func:`mixcount.dataset.package.portable_paths`.
"""

from __future__ import annotations

import json
import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Protocol

import numpy as np

from mixcount.atomic import atomic_path
from mixcount.errors import CompositionError
from mixcount.resources import data_dir
from mixcount.scene.environment_sampling import write_pattern_png
from mixcount.scene.framing import look_at_rotation
from mixcount.scene.spec import ROLE_CONTAINER, PlacedObject, SceneSpec
from mixcount.usd.assets import AssetPaths, convert_asset
from mixcount.usd.portable import (
    PathRoots,
    environment_entry,
    link_into_dataset,
    material_entry,
    portable_paths,
    stage_reference,
)

TEMPLATES_DIR = data_dir("usd_templates")
TEMPLATE_LAYERS = ("scene_root.usda", "floor.usda", "camera_rig.usda", "lights.usda")
STAGE_NAME = "scene.usda"
CYLINDER_SEGMENTS = 64
MM_TO_LENS_UNITS = 1.0  # written in mm; strict USD units would be 0.01 (tenths of a metre)


def scene_dir_for(out_dir: Path, scene_id: str) -> Path:
    return Path(out_dir) / "scenes" / scene_id


# ------------------------------------------------------------------------------------ templates


def _merge_spec(src_layer: Any, dst_layer: Any, path: Any) -> None:
    """Copy prim spec ``path`` from src to dst; where dst already has it (an ``over`` in src), recurse."""
    from pxr import Sdf

    src = src_layer.GetPrimAtPath(path)
    if dst_layer.GetPrimAtPath(path) is None or src.specifier == Sdf.SpecifierDef:
        Sdf.CopySpec(src_layer, path, dst_layer, path)
        return
    for child in src.nameChildren:
        _merge_spec(src_layer, dst_layer, child.path)


def _template_layer(skip: tuple[str, ...] = ()) -> Any:
    """One anonymous layer holding all templates (root first, then the others merged into /World)."""
    from pxr import Sdf

    layers = [Sdf.Layer.OpenAsAnonymous(str(TEMPLATES_DIR / name)) for name in TEMPLATE_LAYERS]
    if any(layer is None for layer in layers):
        raise CompositionError(f"USD templates missing in {TEMPLATES_DIR}")
    dst = Sdf.Layer.CreateAnonymous(".usda")
    dst.TransferContent(layers[0])
    dst.documentation = ""
    for layer in layers[1:]:
        for prim in layer.rootPrims:
            _merge_spec(layer, dst, prim.path)
    for path in skip:
        spec = dst.GetPrimAtPath(path)
        if spec is not None:
            parent = dst.GetPrimAtPath(str(Sdf.Path(path).GetParentPath()))
            del parent.nameChildren[spec.name]
    return dst


# ------------------------------------------------------------------------------------ geometry


def floor_mesh(shape: str, hx: float, hy: float, t: float, uv_m: float, segments: int = CYLINDER_SEGMENTS
               ) -> tuple[np.ndarray, list[int], list[int], np.ndarray]:
    """Points, face counts, face indices and faceVarying st of the floor (top face at z = 0)."""
    if shape == "cube":
        pts = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0],
                        [-hx, -hy, -t], [hx, -hy, -t], [hx, hy, -t], [-hx, hy, -t]], dtype=float)
        faces = [[0, 1, 2, 3], [7, 6, 5, 4], [4, 5, 1, 0], [5, 6, 2, 1], [6, 7, 3, 2], [7, 4, 0, 3]]
    elif shape == "cylinder":
        ang = np.arange(segments) * 2 * math.pi / segments
        ring = np.stack([hx * np.cos(ang), hy * np.sin(ang)], axis=1)
        pts = np.vstack([np.hstack([ring, np.zeros((segments, 1))]), np.hstack([ring, np.full((segments, 1), -t)])])
        faces = [list(range(segments)), list(range(2 * segments - 1, segments - 1, -1))]
        for i in range(segments):
            j = (i + 1) % segments
            faces.append([segments + i, segments + j, j, i])
    else:
        raise CompositionError(f"unknown floor shape {shape!r}")
    counts = [len(f) for f in faces]
    indices = [i for f in faces for i in f]
    st = []
    for f in faces:
        p = pts[f]
        normal = np.cross(p[1] - p[0], p[2] - p[0])
        axis = int(np.argmax(np.abs(normal)))
        if axis == 2:
            uv = p[:, :2]
        elif axis == 0:
            uv = p[:, [1, 2]]
        else:
            uv = p[:, [0, 2]]
        st.append(uv / uv_m)
    return pts, counts, indices, np.vstack(st)


# ------------------------------------------------------------------------------------ authoring


def _set_ids(prim: Any, role: str, object_id: int, class_index: int, instance_id: int) -> None:
    """customData (the contract; USD tools) and the same values as ``userProperties:mixcount:*``
    attributes, which Blender's USD importer turns into custom properties (it drops customData)."""
    from pxr import Sdf

    values = (("role", role, Sdf.ValueTypeNames.String), ("object_id", int(object_id), Sdf.ValueTypeNames.Int),
              ("class_index", int(class_index), Sdf.ValueTypeNames.Int),
              ("instance_id", int(instance_id), Sdf.ValueTypeNames.Int))
    for key, value, _vtype in values:
        prim.SetCustomDataByKey(f"mixcount:{key}", value)
    for key, value, vtype in values:
        prim.CreateAttribute(f"userProperties:mixcount:{key}", vtype, custom=True).Set(value)


def _set_pose(xf: Any, position: Any, orientation: Any, scale: Any) -> None:
    from pxr import Gf, UsdGeom

    xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*[float(v) for v in position]))
    w, x, y, z = (float(v) for v in orientation)
    xf.AddOrientOp(UsdGeom.XformOp.PrecisionFloat).Set(Gf.Quatf(w, Gf.Vec3f(x, y, z)))
    xf.AddScaleOp(UsdGeom.XformOp.PrecisionFloat).Set(Gf.Vec3f(*[float(v) for v in scale]))


@dataclass(frozen=True)
class _Links:
    """Where the stage is written and the dataset root whose ``assets/`` its references point into."""

    out_dir: Path
    stage_dir: Path

    def ref(self, src: Path, rel: str) -> str:
        """Link ``src`` in as ``assets/<rel>``; the stage's relative path to it."""
        link_into_dataset(self.out_dir, src, rel)
        return stage_reference(self.out_dir, self.stage_dir, rel)

    def asset(self, paths: AssetPaths) -> str:
        """The visual asset (and its texture folder) linked in; its reference."""
        tex = paths.visual.with_name(f"{paths.visual.stem}_tex")
        if tex.is_dir():
            link_into_dataset(self.out_dir, tex, tex.name)
        return self.ref(paths.visual, paths.visual.name)


def _add_instance(stage: Any, path: str, obj: PlacedObject, asset: AssetPaths, approximation: str,
                  links: _Links, proxies: bool = True) -> Any:
    """An instance prim: a rigid body referencing its asset. When the asset holds a collision proxy, the
    proxy child (``<path>/Proxy``, purpose guide) is the collider; with ``proxies`` off its collision is
    disabled and the instance collides by ``approximation`` of its render mesh (the hull of every vertex)."""
    from pxr import UsdGeom, UsdPhysics

    xf = UsdGeom.Xform.Define(stage, path)
    prim = xf.GetPrim()
    prim.GetReferences().AddReference(links.asset(asset))
    _set_ids(prim, obj.role, obj.object_id, obj.class_index, obj.instance_id)
    prim.SetCustomDataByKey("mixcount:size_m", float(obj.size_m))
    _set_pose(xf, obj.position, obj.orientation, obj.scale)
    UsdPhysics.RigidBodyAPI.Apply(prim)
    if asset.has_proxy:
        proxy = UsdPhysics.CollisionAPI(stage.OverridePrim(f"{path}/Proxy"))
        proxy.CreateCollisionEnabledAttr(bool(proxies))
        if proxies:
            return prim
    UsdPhysics.CollisionAPI.Apply(prim)
    UsdPhysics.MeshCollisionAPI.Apply(prim).CreateApproximationAttr(approximation)
    return prim


def _bind_floor_material(stage: Any, spec: SceneSpec, scene_dir: Path, links: _Links) -> None:
    from pxr import Gf, Sdf, UsdShade

    mat = spec.floor.material
    shader_root = "/World/Looks/FloorMaterial"
    surf = UsdShade.Shader(stage.GetPrimAtPath(f"{shader_root}/PreviewSurface"))
    tex = UsdShade.Shader(stage.GetPrimAtPath(f"{shader_root}/BaseColorTex"))
    mprim = stage.GetPrimAtPath(shader_root)
    mprim.SetCustomDataByKey("mixcount:kind", mat.kind)
    mprim.SetCustomDataByKey("mixcount:name", mat.name)
    if mat.kind == "procedural":
        params = dict(mat.params)
        rel = f"textures/floor_{params['pattern']}.png"
        px = int(params.get("px", 0)) or 256
        write_pattern_png(params, px, scene_dir / rel)
        tex.GetInput("file").Set(Sdf.AssetPath(f"./{rel}"))
        surf.GetInput("roughness").Set(float(params.get("roughness", 0.6)))
        mprim.SetCustomDataByKey("mixcount:params", json.dumps(params, sort_keys=True))
    else:
        maps = dict(mat.maps)
        base = maps.get("base_color") or maps.get("albedo") or maps.get("diffuse")
        if base:
            tex.GetInput("file").Set(Sdf.AssetPath(links.ref(Path(base), material_entry(base))))
        else:
            surf.GetInput("diffuseColor").GetAttr().GetConnections()
            surf.GetInput("diffuseColor").DisconnectSource()
            surf.GetInput("diffuseColor").Set(Gf.Vec3f(0.5, 0.5, 0.5))
        st_out = UsdShade.Shader(stage.GetPrimAtPath(f"{shader_root}/StReader")).GetOutput("result")
        for key, _inp, space, out, typ in (("roughness", "roughness", "raw", "r", Sdf.ValueTypeNames.Float),
                                          ("normal", "normal", "raw", "rgb", Sdf.ValueTypeNames.Float3)):
            if not maps.get(key):
                continue
            sh = UsdShade.Shader.Define(stage, f"{shader_root}/{key.capitalize()}Tex")
            sh.CreateIdAttr("UsdUVTexture")
            sh.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(
                links.ref(Path(maps[key]), material_entry(maps[key]))))
            sh.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(space)
            sh.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(st_out)
            sh.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
            sh.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
            if key == "normal":
                sh.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
                sh.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
                surf.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(
                    sh.CreateOutput(out, typ))
            else:
                surf.GetInput("roughness").ConnectToSource(sh.CreateOutput(out, typ))


def _write_floor(stage: Any, spec: SceneSpec, scene_dir: Path, links: _Links) -> None:
    from pxr import Sdf, UsdGeom, Vt

    f = spec.floor
    pts, counts, indices, st = floor_mesh(f.shape, f.half_extent[0], f.half_extent[1], f.thickness, f.uv_scale_m)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Floor"))
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray(counts))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(indices))
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([pts.min(0), pts.max(0)]).astype(np.float32)))
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                 UsdGeom.Tokens.faceVarying)
    pv.Set(Vt.Vec2fArray.FromNumpy(st.astype(np.float32)))
    prim = mesh.GetPrim()
    prim.SetCustomDataByKey("mixcount:shape", f.shape)
    prim.SetCustomDataByKey("mixcount:uv_scale_m", float(f.uv_scale_m))
    _bind_floor_material(stage, spec, scene_dir, links)


def _write_lights(stage: Any, spec: SceneSpec, links: _Links) -> None:
    from pxr import Gf, Sdf, UsdGeom, UsdLux

    env = spec.environment
    dome = UsdLux.DomeLight(stage.GetPrimAtPath("/World/Lights/Dome"))
    dome.GetIntensityAttr().Set(float(env.strength))
    UsdGeom.Xformable(dome).GetOrderedXformOps()[0].Set(Gf.Vec3f(90.0, 0.0, float(env.rotation_deg)))
    prim = dome.GetPrim()
    prim.SetCustomDataByKey("mixcount:kind", env.kind)
    prim.SetCustomDataByKey("mixcount:strength", float(env.strength))
    prim.SetCustomDataByKey("mixcount:rotation_deg", float(env.rotation_deg))
    if env.kind == "hdri":
        src = Path(env.path or "")
        if not src.is_file():
            raise CompositionError(f"environment map {env.path} of scene {spec.scene_id} does not exist")
        dome.CreateTextureFileAttr(Sdf.AssetPath(links.ref(src, environment_entry(src))))
        prim.SetCustomDataByKey("mixcount:environment_id", int(env.environment_id or 0))
        return
    # procedural sky: the dome is a uniform sky tint, the sun a distant light; the exact sky model
    # parameters travel in customData for renderers that have one (Blender's sky texture)
    turb = float(env.turbidity or 3.0)
    tint = Gf.Vec3f(0.55 + 0.05 * turb, 0.7 + 0.03 * turb, 1.0)
    dome.CreateColorAttr(Gf.Vec3f(*[min(1.0, c) for c in tint]))
    for key in ("sun_elevation_deg", "sun_azimuth_deg", "sun_strength", "turbidity"):
        prim.SetCustomDataByKey(f"mixcount:{key}", float(getattr(env, key)))
    sun = UsdLux.DistantLight(stage.GetPrimAtPath("/World/Lights/Sun"))
    sun.GetIntensityAttr().Set(float(env.sun_strength))
    e, a = math.radians(float(env.sun_elevation_deg)), math.radians(float(env.sun_azimuth_deg))
    towards_sun = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    from mixcount.scene.rotation import quat_from_matrix

    q = quat_from_matrix(look_at_rotation(towards_sun, np.zeros(3), 0.0))  # light shines down its -Z
    xf = UsdGeom.Xformable(sun)
    xf.AddOrientOp(UsdGeom.XformOp.PrecisionFloat).Set(Gf.Quatf(q[0], Gf.Vec3f(q[1], q[2], q[3])))


def _write_cameras(stage: Any, spec: SceneSpec) -> None:
    from pxr import Gf, Sdf, UsdGeom

    layer = stage.GetRootLayer()
    template = Sdf.Path("/World/Cameras/cam_template")
    for cam in spec.cameras:
        path = Sdf.Path(f"/World/Cameras/{cam.name}")
        Sdf.CopySpec(layer, template, layer, path)
        ucam = UsdGeom.Camera(stage.GetPrimAtPath(path))
        # Values in millimetres (what the Blender worker reads). Strict USD says "tenths of a scene
        # unit" (0.5 for 50 mm at metersPerUnit 1); the field of view depends only on the ratio, which
        # is the same either way. MM_TO_LENS_UNITS = 0.01 would give the strict values.
        ucam.GetFocalLengthAttr().Set(float(cam.focal_length_mm) * MM_TO_LENS_UNITS)
        ucam.GetHorizontalApertureAttr().Set(float(cam.sensor_width_mm) * MM_TO_LENS_UNITS)
        ucam.GetVerticalApertureAttr().Set(float(cam.sensor_height_mm) * MM_TO_LENS_UNITS)
        ucam.GetClippingRangeAttr().Set(Gf.Vec2f(*[float(v) for v in cam.clip_range]))
        xf = UsdGeom.Xformable(ucam)
        xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*cam.position))
        w, x, y, z = cam.orientation
        xf.AddOrientOp(UsdGeom.XformOp.PrecisionFloat).Set(Gf.Quatf(w, Gf.Vec3f(x, y, z)))
        prim = ucam.GetPrim()
        prim.SetCustomDataByKey("mixcount:focal_length_mm", float(cam.focal_length_mm))
        prim.SetCustomDataByKey("mixcount:sensor_width_mm", float(cam.sensor_width_mm))
        prim.SetCustomDataByKey("mixcount:sensor_height_mm", float(cam.sensor_height_mm))
        prim.SetCustomDataByKey("mixcount:resolution", Gf.Vec2i(*cam.resolution))
        prim.SetCustomDataByKey("mixcount:look_at", Gf.Vec3d(*cam.look_at))
        for key in ("elevation_deg", "azimuth_deg", "roll_deg", "distance"):
            prim.SetCustomDataByKey(f"mixcount:{key}", float(getattr(cam, key)))
    parent = layer.GetPrimAtPath("/World/Cameras")
    del parent.nameChildren["cam_template"]


class ConvertibleAsset(Protocol):
    """What a conversion reads of an object: a scene's :class:`~mixcount.scene.spec.AssetRef` or a pool's
    :class:`~mixcount.scene.object_records.ObjectRecord` (the same fields)."""

    @property
    def model_path(self) -> str: ...
    @property
    def content_hash(self) -> str: ...
    @property
    def source_units(self) -> Optional[str]: ...
    @property
    def source_up_axis(self) -> Optional[str]: ...
    @property
    def collision_path(self) -> Optional[str]: ...
    @property
    def proxy_path(self) -> Optional[str]: ...
    @property
    def look(self) -> Optional[tuple[float, ...]]: ...


def convert_object_asset(obj: ConvertibleAsset, assets_dir: Path, *, container: bool) -> AssetPaths:
    """Convert (or find cached) one object's asset as a scene uses it: with its collision proxy when the
    catalog has one; as the scene's ``container`` also with its decimated collision mesh."""
    return convert_asset(
        obj.model_path, assets_dir, content_hash=obj.content_hash, units=obj.source_units,
        up_axis=obj.source_up_axis, collision_path=obj.collision_path if container else None,
        proxy_path=obj.proxy_path, look=obj.look,
    )


def convert_scene_assets(spec: SceneSpec, assets_dir: Path) -> dict[int, AssetPaths]:
    """Convert (or find cached) every asset the scene uses (:func:`convert_object_asset`)."""
    container_id = spec.container.object_id if spec.container else None
    return {a.object_id: convert_object_asset(a, assets_dir, container=a.object_id == container_id)
            for a in spec.assets}


# usd-core used by one thread at a time in this process: asset conversion, stage and settled-stage writing
# take it (an executor's worker threads write stages while another scene is finalised, and two threads
# converting the same asset - Usd.Stage.CreateNew of one path - deadlock)
USD_WRITING = threading.RLock()


def write_stage(spec: SceneSpec, out_dir: Path, catalog: Any = None, *, assets_dir: Optional[Path] = None,
                scene_dir: Optional[Path] = None) -> Path:
    """Write ``out_dir/scenes/<scene_id>/scene.usda`` (or ``scene_dir/scene.usda``) and return its path.

    ``catalog`` supplies ``usd_assets_dir`` for the converted assets (``assets_dir`` overrides it). Holds
    :data:`USD_WRITING` while it converts and writes.
    """
    with USD_WRITING:
        return _write_stage(spec, out_dir, catalog, assets_dir=assets_dir, scene_dir=scene_dir)


def _write_stage(spec: SceneSpec, out_dir: Path, catalog: Any, *, assets_dir: Optional[Path],
                 scene_dir: Optional[Path]) -> Path:
    from pxr import Sdf

    if assets_dir is None:
        if catalog is None:
            raise CompositionError("write_stage needs a catalog or an assets_dir for the converted USD assets")
        assets_dir = Path(catalog.usd_assets_dir)
    scene_dir = Path(scene_dir) if scene_dir is not None else scene_dir_for(Path(out_dir), spec.scene_id)
    scene_dir.mkdir(parents=True, exist_ok=True)
    assets = convert_scene_assets(spec, Path(assets_dir))
    links = _Links(Path(out_dir), scene_dir)
    roots = PathRoots(Path(out_dir), (Path(assets_dir),))

    skip = () if spec.environment.kind == "sky" else ("/World/Lights/Sun",)
    path = scene_dir / STAGE_NAME
    # authored in a layer named by the temporary file beside the stage (an anonymous layer would anchor the
    # relative asset paths at the working directory: every reference unresolved while authoring)
    with atomic_path(path) as tmp:
        layer = Sdf.Layer.New(Sdf.FileFormat.FindByExtension("usda"), str(tmp))
        layer.TransferContent(_template_layer(skip))
        _author_stage(layer, spec, scene_dir, assets, links, roots)
        if not layer.Save():
            raise CompositionError(f"could not write {path}")
    return path


def _author_stage(layer: Any, spec: SceneSpec, scene_dir: Path, assets: dict[int, AssetPaths], links: "_Links",
                  roots: PathRoots) -> None:
    """The scene's prims into ``layer``: layer metadata, physics scene, floor, container, instances,
    cameras and lights."""
    from pxr import Usd, UsdGeom, UsdPhysics

    stage = Usd.Stage.Open(layer)
    # nested like every mixcount customData: read with stage.GetMetadataByDictKey("customLayerData",
    # "mixcount:seed") or layer.customLayerData["mixcount"]["seed"] (see mixcount.usd.read)
    layer.customLayerData = {"mixcount": {
        "config_hash": spec.config_hash,
        "scene_id": spec.scene_id,
        "seed": int(spec.seed),
        "spec": json.dumps(portable_paths(spec.to_dict(), roots), sort_keys=True, separators=(",", ":")),
        "split": spec.split,
    }}
    # the physics run as the stage's time range (Blender's importer sets its frame range from it)
    layer.endTimeCode = float(spec.physics.frames)
    phys = UsdPhysics.Scene(stage.GetPrimAtPath("/World/PhysicsScene"))
    phys.GetGravityMagnitudeAttr().Set(float(spec.physics.gravity))
    pprim = phys.GetPrim()
    pprim.SetCustomDataByKey("mixcount:frames", int(spec.physics.frames))
    pprim.SetCustomDataByKey("mixcount:substeps", int(spec.physics.substeps))
    pprim.SetCustomDataByKey("mixcount:solver_iterations", int(spec.physics.solver_iterations))

    _write_floor(stage, spec, scene_dir, links)
    _set_ids(stage.GetPrimAtPath("/World/Floor"), "floor", -1, -1, 0)

    if spec.container is not None:
        c = spec.container
        xf = UsdGeom.Xform.Define(stage, "/World/Container")
        prim = xf.GetPrim()
        prim.GetReferences().AddReference(links.asset(assets[c.object_id]))
        _set_ids(prim, ROLE_CONTAINER, c.object_id, -1, c.instance_id)
        _set_pose(xf, c.position, c.orientation, c.scale)
        coll_paths = assets[c.object_id].collision
        if coll_paths is not None:
            coll_ref = links.ref(coll_paths, coll_paths.name)
            # relative to the stage like every asset path (the worker resolves it against the stage's folder)
            prim.SetCustomDataByKey("mixcount:collision_asset", coll_ref)
            cxf = UsdGeom.Xform.Define(stage, "/World/Container/Collision")
            cxf.CreatePurposeAttr(UsdGeom.Tokens.guide)  # collides, never rendered
            cprim = cxf.GetPrim()
            cprim.GetReferences().AddReference(coll_ref)
            UsdPhysics.CollisionAPI.Apply(cprim)
            UsdPhysics.MeshCollisionAPI.Apply(cprim).CreateApproximationAttr(UsdPhysics.Tokens.none)
        else:  # no decimated mesh recorded: the visual mesh itself is the static collider
            UsdPhysics.CollisionAPI.Apply(prim)
            UsdPhysics.MeshCollisionAPI.Apply(prim).CreateApproximationAttr(UsdPhysics.Tokens.none)

    approx, proxies = spec.physics.collision_shape, spec.physics.collision_proxies
    for obj in spec.objects:
        _add_instance(stage, f"/World/Objects/obj_{obj.instance_id:04d}", obj, assets[obj.object_id], approx,
                      links, proxies)
    for k, obj in enumerate(spec.distractors, start=1):
        _add_instance(stage, f"/World/Distractors/dist_{k:02d}", obj, assets[obj.object_id], approx, links, proxies)

    _write_cameras(stage, spec)
    _write_lights(stage, spec, links)

