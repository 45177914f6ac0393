"""Catalog asset -> USD asset: geometry in metres/Z-up/centred, textures survive and are bound, cache."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from mixcount.usd.assets import convert_asset


def textured_box(path: Path, extents=(0.06, 0.05, 0.04), seed: int = 0) -> tuple[Path, dict[str, np.ndarray]]:
    """A GLB box (glTF is Y-up) with base-colour, metallic-roughness and normal textures."""
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.box(extents=extents)
    mesh.unmerge_vertices()
    images = {
        "base": (rng.random((16, 16, 3)) * 255).astype(np.uint8),
        "mr": (rng.random((8, 8, 3)) * 255).astype(np.uint8),
        "normal": np.tile(np.array([128, 128, 255], dtype=np.uint8), (8, 8, 1)),
    }
    material = trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.fromarray(images["base"]), metallicRoughnessTexture=Image.fromarray(images["mr"]),
        normalTexture=Image.fromarray(images["normal"]), roughnessFactor=0.7, metallicFactor=0.1,
    )
    mesh.visual = trimesh.visual.TextureVisuals(uv=rng.random((len(mesh.vertices), 2)), material=material)
    mesh.apply_translation([0.3, 0.1, -0.2])  # off-centre on purpose: the asset must be re-centred
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(str(path))
    return path, images


def _bbox(stage, prim_path="/Asset"):
    from pxr import Usd, UsdGeom

    cache = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_, UsdGeom.Tokens.render])
    r = cache.ComputeWorldBound(stage.GetPrimAtPath(prim_path)).ComputeAlignedRange()
    return np.asarray(r.GetMin()), np.asarray(r.GetMax())


def test_textures_survive_conversion_and_are_bound(tmp_path):
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    glb, images = textured_box(tmp_path / "lib" / "box.glb")
    paths = convert_asset(glb, tmp_path / "usd_assets", content_hash="abc123")
    assert paths.visual == tmp_path / "usd_assets" / "abc123.usdc"
    stage = Usd.Stage.Open(str(paths.visual))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == "Z"
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/Asset")
    lo, hi = _bbox(stage)
    # glTF Y-up -> Z-up: extents (x, y, z) = (0.06, 0.04, 0.05); origin at the bbox centre
    np.testing.assert_allclose(hi - lo, [0.06, 0.04, 0.05], atol=1e-6)
    np.testing.assert_allclose((hi + lo) / 2, [0, 0, 0], atol=1e-6)

    meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert meshes
    found = {}
    for prim in meshes:
        assert UsdGeom.PrimvarsAPI(prim).GetPrimvar("st").HasValue()
        material, _rel = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        assert material, "mesh has no bound material"
        surface = material.ComputeSurfaceSource()[0]
        assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
        for name in ("diffuseColor", "roughness", "normal"):
            src = surface.GetInput(name).GetConnectedSources()[0]
            assert src, f"{name} is not connected to a texture"
            tex = UsdShade.Shader(src[0].source.GetPrim())
            assert tex.GetIdAttr().Get() == "UsdUVTexture"
            asset = tex.GetInput("file").Get()
            resolved = Path(asset.resolvedPath)
            assert resolved.is_file() and resolved.parent.name == "abc123_tex"
            found[name] = np.asarray(Image.open(resolved).convert("RGB"))
    np.testing.assert_array_equal(found["diffuseColor"], images["base"])  # PNG is lossless: same pixels
    np.testing.assert_array_equal(found["roughness"], images["mr"])
    np.testing.assert_array_equal(found["normal"], images["normal"])


def test_conversion_is_cached_by_content_hash(tmp_path):
    glb, _ = textured_box(tmp_path / "box.glb")
    first = convert_asset(glb, tmp_path / "assets", content_hash="k1")
    mtime = first.visual.stat().st_mtime_ns
    again = convert_asset(glb, tmp_path / "assets", content_hash="k1")
    assert again.visual == first.visual and again.visual.stat().st_mtime_ns == mtime
    assert again.center == pytest.approx(first.center)
    forced = convert_asset(glb, tmp_path / "assets", content_hash="k1", force=True)
    assert forced.visual.stat().st_mtime_ns >= mtime
    assert sorted(p.name for p in (tmp_path / "assets").iterdir()) == ["k1.usdc", "k1_tex"]  # no temp leftovers


def test_vertex_colours_units_and_collision(tmp_path):
    from pxr import Usd, UsdGeom

    mesh = trimesh.creation.icosphere(subdivisions=1, radius=2.0)  # 4 cm across, given in centimetres
    mesh.visual.vertex_colors = np.tile([200, 30, 30, 255], (len(mesh.vertices), 1))
    mesh.visual.vertex_colors[:5] = [10, 10, 200, 255]
    obj = tmp_path / "ball.ply"
    mesh.export(str(obj))
    coll = tmp_path / "ball_collision.ply"
    (mesh.copy().apply_scale(0.01)).apply_transform(  # collision meshes are metres, Z-up already
        trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])).export(str(coll))
    paths = convert_asset(obj, tmp_path / "assets", content_hash="ball", units="cm", up_axis="Y",
                          collision_path=str(coll))
    stage = Usd.Stage.Open(str(paths.visual))
    lo, hi = _bbox(stage)
    np.testing.assert_allclose(hi - lo, np.ptp(mesh.vertices, axis=0)[[0, 2, 1]] * 0.01, rtol=1e-5)
    mesh_prim = next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    colours = np.asarray(UsdGeom.Mesh(mesh_prim).GetDisplayColorPrimvar().Get())
    assert colours.shape[1] == 3 and np.ptp(colours, axis=0).max() > 0.5
    # the bound material reads the colours (renderers ignore displayColor under a material otherwise)
    from pxr import UsdShade

    material = UsdShade.MaterialBindingAPI(mesh_prim).ComputeBoundMaterial()[0]
    surface = material.ComputeSurfaceSource()[0]
    reader = UsdShade.Shader(surface.GetInput("diffuseColor").GetConnectedSources()[0][0].source.GetPrim())
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float3"
    assert reader.GetInput("varname").Get() == "displayColor"
    cstage = Usd.Stage.Open(str(paths.collision))
    clo, chi = _bbox(cstage)
    np.testing.assert_allclose(chi - clo, hi - lo, rtol=1e-4)
    np.testing.assert_allclose((chi + clo) / 2, (hi + lo) / 2, atol=1e-6)  # same frame as the visual


def test_node_transforms_move_normals_with_the_geometry(tmp_path):
    """A GLB whose node is rotated (how Z-up content is stored in Y-up glTF): normals must still
    point out of a convex shape after conversion, or renderers shade it black."""
    from pxr import Usd, UsdGeom

    sphere = trimesh.creation.uv_sphere(radius=0.03)
    sphere.apply_scale([1.0, 1.5, 0.8])  # anisotropic, so only the right inverse-transpose passes
    scene = trimesh.Scene()
    rot = trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])
    rot[:3, 3] = [0.1, 0.2, 0.3]
    scene.add_geometry(sphere, transform=rot)
    glb = tmp_path / "rotated.glb"
    scene.export(str(glb))
    paths = convert_asset(glb, tmp_path / "assets", content_hash="rot")
    stage = Usd.Stage.Open(str(paths.visual))
    mesh = UsdGeom.Mesh(next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)))
    pts = np.asarray(mesh.GetPointsAttr().Get())
    normals = np.asarray(mesh.GetNormalsAttr().Get())
    outward = np.einsum("ij,ij->i", normals, pts - pts.mean(axis=0)) > 0
    assert outward.mean() > 0.99
    # the analytic ellipsoid normal at each point: gradient of (x/a)^2 + (y/b)^2 + (z/c)^2
    ext = np.ptp(pts, axis=0) / 2
    analytic = pts / ext**2
    analytic /= np.linalg.norm(analytic, axis=1, keepdims=True)
    assert np.median(np.einsum("ij,ij->i", normals, analytic)) > 0.99
