"""Catalog asset -> cached USD asset (pure pxr), converted once per content hash.

Layout in ``catalog.usd_assets_dir`` (``usd_assets/<catalog>/``: one folder per catalog, since the same file
may be read in another frame by another catalog): ``<content_hash>.usdc`` (default prim ``/Asset``, kind
component, metres, Z-up, origin at the bounding-box centre) and its textures in
``<content_hash>_tex/`` referenced by relative paths, so the pair can be moved together.
``<content_hash>_collision.usdc`` holds the decimated collision mesh in the same frame. A cached asset is
reused only when it was converted by this converter version in the same frame (units and up axis: an
object whose up axis was corrected at ingest gets a new asset) and, for the collision layer, from the
same collision mesh file.

When the object has a convex collision proxy (:mod:`mixcount.catalog.proxies`), the asset also holds it as
``/Asset/Proxy``: a Mesh with ``purpose = guide`` (never rendered; Blender's USD importer skips guide
prims unless asked) and ``UsdPhysics.CollisionAPI`` + ``MeshCollisionAPI`` (approximation
``convexHull``), the collider of every instance of the asset.

Geometry comes from trimesh (GLB/GLTF/OBJ/PLY/STL; read into parts by :mod:`mixcount.usd.model_parts`):
every node of the scene graph is placed by its world transform, scaled to metres and turned Z-up exactly
as ingest does (glTF Y-up: (x, y, z) -> (x, -z, y)), so the asset's size equals the catalog's dims.
Materials become UsdPreviewSurface with UsdUVTexture readers for base colour, metallic-roughness (glTF
packing: G = roughness, B = metallic) and normal maps; vertex or face colours become ``displayColor``.
A part with none of these (an STL or PLY CAD export) gets the object's palette look (``look``:
:func:`mixcount.catalog.materials.object_look`) as a plain UsdPreviewSurface instead of the renderer's
default near-white; the look is recorded in the layer, so a changed look converts the asset again.
USD/USDZ sources are wrapped: the asset references the source file under a transform to metres, Z-up
and centred.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from mixcount.errors import AssetError, CompositionError
from mixcount.frame import source_frame, up_axis_rotation
from mixcount.usd.mesh_clean import add_counts, clean_triangles
from mixcount.usd.model_parts import Part, load_parts, look_tag
from mixcount.usd.read import CONVEX_PARTS_PRIM
from mixcount.usd.usd_source import override_invalid_faces, usd_bounds

CONVERTER_VERSION = 8  # 5: palette looks / 6: degenerate, invalid triangles dropped (usd/mesh_clean.py) / 7: textures outside the model's folder read (frame.load_model) / 8: every colour of a STEP kept (catalog/derived.py); bump when the converter output changes: cached assets are rebuilt
# V-HACD (vhacdx through trimesh) settings of that decomposition: part of the converter's output, so
# fixed here with the version rather than configured (a changed value must rebuild every cached asset)
CONVEX_PARTS_MAX = 16
CONVEX_PARTS_MAX_VERTICES = 64
USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")
PROXY_PRIM = "/Asset/Proxy"  # the collision proxy inside an asset (prim name "Proxy" under each instance)


@dataclass(frozen=True)
class AssetPaths:
    visual: Path
    collision: Optional[Path]
    center: tuple[float, float, float]  # bbox centre of the normalised model, subtracted in the asset
    has_proxy: bool = False  # the asset holds a collision proxy at PROXY_PRIM


def asset_key(content_hash: str, model_path: str, units: Optional[str] = None) -> str:
    """The converted asset's file stem: the model's content hash, plus its unit when that is not metres. One
    file read in two units (two objects of one unit-cube model given other sizes, issue 70) is two assets;
    keyed by the hash alone, both classes of a scene drew the one converted last (a 20 mm part at 2 mm)."""
    key = content_hash or hashlib.sha256(str(model_path).encode()).hexdigest()
    return key if units in (None, "", "m") else f"{key}_u{units}"


# ------------------------------------------------------------------------------------ pxr side


def _texture_shader(stage: Any, mat_path: str, name: str, rel: str, st_out: Any, color_space: str) -> Any:
    from pxr import Sdf, UsdShade

    tex = UsdShade.Shader.Define(stage, f"{mat_path}/{name}")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(rel))
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(st_out)
    return tex


def _define_material(stage: Any, mat_path: str, info: dict[str, Any], tex_dir: Path, rel_dir: str,
                     index: int, textured: bool) -> Any:
    from pxr import Gf, Sdf, UsdShade

    material = UsdShade.Material.Define(stage, mat_path)
    surf = UsdShade.Shader.Define(stage, f"{mat_path}/PreviewSurface")
    surf.CreateIdAttr("UsdPreviewSurface")
    surf.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(0)
    factor = info["base_color_factor"]
    has_base = textured and info.get("base_color_tex") is not None
    has_mr = textured and info.get("mr_tex") is not None
    has_normal = textured and info.get("normal_tex") is not None
    st_out = None
    if has_base or has_mr or has_normal:
        reader = UsdShade.Shader.Define(stage, f"{mat_path}/StReader")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        st_out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    if has_base:
        name = f"basecolor_{index}.png"
        info["base_color_tex"].convert("RGBA" if info["base_color_tex"].mode in ("RGBA", "LA", "P") else "RGB").save(
            tex_dir / name, format="PNG")
        tex = _texture_shader(stage, mat_path, "BaseColorTex", f"./{rel_dir}/{name}", st_out, "sRGB")
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*[float(v) for v in factor[:4]]))
        rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    elif info.get("vertex_color"):
        # diffuse = displayColor primvar (the mesh's vertex colours); glTF's factor multiplies it, so
        # the converter bakes the factor into the primvar values (see _define_mesh)
        reader = UsdShade.Shader.Define(stage, f"{mat_path}/ColorReader")
        reader.CreateIdAttr("UsdPrimvarReader_float3")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("displayColor")
        out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float3)
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(out)
    else:
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*[float(v) for v in factor[:3]]))
    if has_mr:
        name = f"metallic_roughness_{index}.png"
        info["mr_tex"].convert("RGB").save(tex_dir / name, format="PNG")
        tex = _texture_shader(stage, mat_path, "MetallicRoughnessTex", f"./{rel_dir}/{name}", st_out, "raw")
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(
            Gf.Vec4f(1.0, float(info["roughness"]), float(info["metallic"]), 1.0))
        g = tex.CreateOutput("g", Sdf.ValueTypeNames.Float)
        b = tex.CreateOutput("b", Sdf.ValueTypeNames.Float)
        surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).ConnectToSource(g)
        surf.CreateInput("metallic", Sdf.ValueTypeNames.Float).ConnectToSource(b)
    else:
        surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(info["roughness"]))
        surf.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(float(info["metallic"]))
    if has_normal:
        name = f"normal_{index}.png"
        info["normal_tex"].convert("RGB").save(tex_dir / name, format="PNG")
        tex = _texture_shader(stage, mat_path, "NormalTex", f"./{rel_dir}/{name}", st_out, "raw")
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2.0, 2.0, 2.0, 1.0))
        tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1.0, -1.0, -1.0, 0.0))
        n = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        surf.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(n)
    material.CreateSurfaceOutput().ConnectToSource(surf.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    return material


def _define_mesh(stage: Any, path: str, part: Part, center: np.ndarray,
                 removed: Optional[dict[str, int]] = None) -> Any:
    """One Mesh prim of ``part`` without degenerate or invalid triangles (their counts added to ``removed``)."""
    from pxr import UsdGeom, Vt

    per_face = part.display_color if part.color_interp != "vertex" else None
    faces, per_face, counts = clean_triangles(part.points, part.faces, per_face)
    if counts:
        part = Part(part.points, faces, part.normals, part.uv, part.material,
                     per_face if part.color_interp != "vertex" else part.display_color, part.color_interp)
        add_counts(removed if removed is not None else {}, counts)
    mesh = UsdGeom.Mesh.Define(stage, path)
    pts = part.points - center
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(part.faces), 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(part.faces.astype(np.int32).ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([pts.min(0), pts.max(0)]).astype(np.float32)))
    if part.normals is not None:
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(part.normals.astype(np.float32)))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    pv = UsdGeom.PrimvarsAPI(mesh)
    if part.uv is not None:
        from pxr import Sdf

        st = pv.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
        st.Set(Vt.Vec2fArray.FromNumpy(part.uv[:, :2].astype(np.float32)))
    if part.display_color is not None:
        interp = UsdGeom.Tokens.vertex if part.color_interp == "vertex" else UsdGeom.Tokens.uniform
        dc = mesh.CreateDisplayColorPrimvar(interp)
        dc.Set(Vt.Vec3fArray.FromNumpy(part.display_color.astype(np.float32)))
    return mesh


def _write_layer_atomically(build: Any, final: Path, tex_dir: Optional[Path], replace_textures: bool = False) -> None:
    """Build into a temporary directory beside ``final`` and move into place (concurrent workers are
    safe: the last rename wins and both results are identical)."""
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.stem}.", dir=final.parent))
    try:
        tmp_tex = tmp / tex_dir.name if tex_dir is not None else None
        if tmp_tex is not None:
            tmp_tex.mkdir()
        tmp_layer = tmp / final.name
        build(tmp_layer, tmp_tex)
        if tmp_tex is not None and tex_dir is not None:
            if tex_dir.exists() and replace_textures:
                shutil.rmtree(tex_dir, ignore_errors=True)
            if not tex_dir.exists():  # same content hash -> same textures: keep what a reader may be using
                try:
                    os.replace(tmp_tex, tex_dir)
                except OSError:
                    pass  # a concurrent writer put identical textures there first
            for f in tmp_tex.iterdir() if tmp_tex.is_dir() and tex_dir.is_dir() else ():  # a texture lost from a kept folder
                if not (tex_dir / f.name).exists():
                    os.replace(f, tex_dir / f.name)
        os.replace(tmp_layer, final)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _is_current(path: Path, proxy: Optional[str] = None, *, frame: Optional[str] = None,
                source: Optional[str] = None, look: Optional[str] = None) -> bool:
    """Converted by this converter version (and, for a visual asset, with the proxy asked for and in the
    ``frame`` asked for; for a collision layer, from the ``source`` mesh file asked for)."""
    if not path.exists():
        return False
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(path))
    if layer is not None:
        layer.Reload()  # another process may have rewritten it since this one last opened it
    data = layer.customLayerData.get("mixcount", {}) if layer else {}
    if data.get("converter_version") != CONVERTER_VERSION:
        return False
    if frame is not None and data.get("frame", "") != frame:
        return False
    if source is not None and data.get("source", "") != source:
        return False
    if look is not None and data.get("look", "") != look:
        return False
    from mixcount.usd.dependencies import problem_line

    if problem_line(path) is not None:  # a texture of its _tex/ gone: converted again, never rendered magenta
        return False
    return proxy is None or data.get("proxy", "") == proxy


def _start_stage(path: Path, key: str, source: str, center: np.ndarray, frame: str, look: str = "") -> tuple[Any, Any]:
    from pxr import Gf, Kind, Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    root = UsdGeom.Xform.Define(stage, "/Asset")
    stage.SetDefaultPrim(root.GetPrim())
    Usd.ModelAPI(root.GetPrim()).SetKind(Kind.Tokens.component)
    stage.GetRootLayer().customLayerData = {"mixcount": {
        "converter_version": CONVERTER_VERSION, "content_hash": key,
        "source": source, "center_m": Gf.Vec3d(*[float(c) for c in center]), "frame": frame, "look": look,
    }}
    return stage, root


def convert_asset(model_path: str | Path, out_dir: Path, *, content_hash: str = "", units: Optional[str] = None,
                  up_axis: Optional[str] = None, collision_path: Optional[str] = None,
                  proxy_path: Optional[str] = None, textured: bool = True, force: bool = False,
                  look: Optional[tuple[float, ...]] = None) -> AssetPaths:
    """Convert one model to ``out_dir/<hash>.usdc`` (+ textures, + collision, + proxy prim) unless cached.
    ``look``: (sRGB r, g, b, metallic, roughness) for parts without a colour of their own."""
    model = Path(model_path)
    key = asset_key(content_hash, str(model), units)
    visual = out_dir / f"{key}.usdc"
    tex_dir = out_dir / f"{key}_tex"
    coll = out_dir / f"{key}_collision.usdc" if collision_path else None
    proxy = Path(proxy_path) if proxy_path and Path(proxy_path).is_file() else None
    proxy_tag = str(proxy.resolve()) if proxy is not None else ""
    frame = "/".join(source_frame(model, units, up_axis)[1:]) if model.suffix.lower() not in USD_EXTENSIONS else "usd"
    look = None if model.suffix.lower() in USD_EXTENSIONS else look  # a USD source keeps its own materials
    coll_source = str(Path(collision_path)) if collision_path else None
    if not force and _is_current(visual, proxy_tag, frame=frame, look=look_tag(look)) and (
            coll is None or _is_current(coll, source=coll_source)):
        from pxr import Sdf

        c = Sdf.Layer.FindOrOpen(str(visual)).customLayerData.get("mixcount", {}).get("center_m", (0.0, 0.0, 0.0))
        return AssetPaths(visual, coll, tuple(float(v) for v in c), proxy is not None)  # type: ignore[arg-type]
    if not model.is_file():
        raise AssetError(f"model file {model} of asset {key[:12]} does not exist")
    scale, _units, up = source_frame(model, units, up_axis)
    if model.suffix.lower() in USD_EXTENSIONS:
        lo, hi = usd_bounds(model)
        center = (lo + hi) / 2
        if proxy is not None:
            check_proxy_fits(proxy, lo, hi, model)
        _write_layer_atomically(lambda p, _t: _wrap_usd(p, key, model, center, proxy), visual, None)
    else:
        parts = load_parts(model, scale, up, look)
        allpts = np.vstack([p.points for p in parts])
        center = (allpts.min(0) + allpts.max(0)) / 2
        if proxy is not None:
            check_proxy_fits(proxy, allpts.min(0), allpts.max(0), model)

        def build(path: Path, tdir: Optional[Path]) -> None:
            from pxr import UsdGeom, UsdShade

            stage, _root = _start_stage(path, key, str(model), center, frame, look_tag(look))
            UsdGeom.Scope.Define(stage, "/Asset/Looks")
            UsdGeom.Scope.Define(stage, "/Asset/Geom")
            removed: dict[str, int] = {}
            for i, part in enumerate(parts):
                mesh = _define_mesh(stage, f"/Asset/Geom/mesh_{i:03d}", part, center, removed)
                if part.material is not None:
                    mat = _define_material(stage, f"/Asset/Looks/mat_{i:03d}", part.material, tdir,  # type: ignore[arg-type]
                                           tex_dir.name, i, textured and part.uv is not None)
                    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
            if proxy is not None:
                _define_proxy(stage, proxy, center)
            _record(stage, faces_removed=dict(sorted(removed.items())),
                    faces_kept=sum(len(p.faces) for p in parts) - sum(removed.values()))
            stage.GetRootLayer().Save()

        _write_layer_atomically(build, visual, tex_dir, replace_textures=force)
    if coll is not None and collision_path:
        _write_layer_atomically(lambda p, _t: _write_collision(p, key, Path(collision_path), center), coll, None)
    return AssetPaths(visual, coll, (float(center[0]), float(center[1]), float(center[2])), proxy is not None)


PROXY_FIT_TOLERANCE = 0.05  # of the model's box diagonal: how far a proxy may reach past the model's box


def check_proxy_fits(proxy: Path, lo: np.ndarray, hi: np.ndarray, model: Path) -> None:
    """Refuse a collision proxy that does not fit its model (``lo``/``hi``: the model's box in metres, Z-up).

    A proxy is an inner hull of the model's collision mesh in the same frame, so its box lies within the
    model's. One built in another frame - an OBJ in centimetres read as metres - is a body 100x the object
    that flings a whole scene apart (bodies ended hundreds of km away); that must fail here, by name,
    not as a scene of explosions."""
    from mixcount.catalog.proxies import read_proxy

    verts, _faces = read_proxy(proxy)
    plo, phi = verts.min(axis=0), verts.max(axis=0)
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    tol = PROXY_FIT_TOLERANCE * float(np.linalg.norm(hi - lo))
    if (plo < lo - tol).any() or (phi > hi + tol).any():
        raise CompositionError(
            f"collision proxy {proxy.name} does not fit model {model}: proxy box {np.round(plo, 4).tolist()} .. "
            f"{np.round(phi, 4).tolist()} m, model box {np.round(lo, 4).tolist()} .. {np.round(hi, 4).tolist()} m "
            "(built in other units or another up axis? rebuild it from the model in metres, Z-up)")


def _define_proxy(stage: Any, ply: Path, center: np.ndarray) -> None:
    """The convex collision proxy (metres, Z-up, same frame as the model) as a guide Mesh with UsdPhysics
    collision (approximation convexHull); the layer records its source so a changed proxy reconverts."""
    from pxr import UsdGeom, UsdPhysics

    from mixcount.catalog.proxies import read_proxy

    verts, faces = read_proxy(ply)
    mesh = _define_mesh(stage, PROXY_PRIM, Part(verts, faces, None, None, None, None), center)
    mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)
    UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
    UsdPhysics.MeshCollisionAPI.Apply(mesh.GetPrim()).CreateApproximationAttr(UsdPhysics.Tokens.convexHull)
    _record(stage, proxy=str(ply.resolve()))


def _record(stage: Any, **values: Any) -> None:
    """``values`` added to the asset layer's record (``customLayerData["mixcount"]``)."""
    layer = stage.GetRootLayer()
    data = dict(layer.customLayerData)
    data["mixcount"] = {**dict(data.get("mixcount", {})), **values}
    layer.customLayerData = data


def _write_collision(path: Path, key: str, ply: Path, center: np.ndarray) -> None:
    """The decimated collision mesh (already metres, Z-up, same frame as the model) -> Mesh prim."""
    import trimesh

    if not ply.is_file():
        raise CompositionError(f"collision mesh {ply} does not exist")
    mesh = trimesh.load(str(ply), force="mesh", process=False)
    stage, _root = _start_stage(path, key, str(ply), center, "")
    part = Part(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64),
                 None, None, None, None)
    _define_mesh(stage, "/Asset/collision", part, center)
    _define_convex_parts(stage, mesh, center)
    stage.GetRootLayer().Save()


def _define_convex_parts(stage: Any, mesh: Any, center: np.ndarray) -> None:
    """The collision mesh's convex decomposition as guide Meshes with UsdPhysics collision (approximation
    convexHull) under CONVEX_PARTS_PRIM; nothing when V-HACD yields no part.

    Only containers get a collision asset. As a triangle mesh in Bullet a 2000-face tray made a
    160-object scene's physics 19.7 s; as one convex hull 3.5 s, but a hull fills a bowl. A handful of
    convex parts keeps the hollow and most of the speed (docs/performance.md).
    """
    import trimesh
    from pxr import UsdGeom, UsdPhysics

    try:
        parts = trimesh.decomposition.convex_decomposition(
            mesh, maxConvexHulls=CONVEX_PARTS_MAX, maxNumVerticesPerCH=CONVEX_PARTS_MAX_VERTICES)
    except Exception:  # a degenerate mesh: the worker keeps the triangle mesh
        return
    if isinstance(parts, dict):
        parts = [parts]
    UsdGeom.Scope.Define(stage, CONVEX_PARTS_PRIM)
    for k, p in enumerate(parts):
        verts = np.asarray(p["vertices"], dtype=np.float64)
        faces = np.asarray(p["faces"], dtype=np.int64).reshape(-1, 3)
        if len(verts) < 4 or len(faces) < 4:
            continue
        usd_mesh = _define_mesh(stage, f"{CONVEX_PARTS_PRIM}/part_{k:03d}",
                                Part(verts, faces, None, None, None, None), center)
        usd_mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)
        UsdPhysics.CollisionAPI.Apply(usd_mesh.GetPrim())
        UsdPhysics.MeshCollisionAPI.Apply(usd_mesh.GetPrim()).CreateApproximationAttr(UsdPhysics.Tokens.convexHull)


def _wrap_usd(path: Path, key: str, model: Path, center: np.ndarray, proxy: Optional[Path] = None) -> None:
    """A USD source stays as it is: reference it under a transform to metres, Z-up and centred (its invalid
    faces taken out by overrides in this layer: :func:`mixcount.usd.usd_source.override_invalid_faces`)."""
    from pxr import Gf, Usd, UsdGeom

    src = Usd.Stage.Open(str(model))
    mpu = float(UsdGeom.GetStageMetersPerUnit(src))
    rot = up_axis_rotation(str(UsdGeom.GetStageUpAxis(src)))
    stage, root = _start_stage(path, key, str(model), center, "usd")
    src_xf = UsdGeom.Xform.Define(stage, "/Asset/Source")
    m = np.eye(4)
    m[:3, :3] = rot * mpu
    m[:3, 3] = -center
    src_xf.AddTransformOp().Set(Gf.Matrix4d(m.T.tolist()))  # USD matrices are row-vector (transposed)
    src_xf.GetPrim().GetReferences().AddReference(str(model.resolve()))
    _record(stage, faces_removed=override_invalid_faces(stage, model, "/Asset/Source"))
    if proxy is not None:
        _define_proxy(stage, proxy, center)
    stage.GetRootLayer().Save()
