"""Nothing renders magenta (issue 60): every file a stage needs is checked before a render, a converted
asset missing a texture is converted again, and converted assets carry no degenerate or invalid faces.

Real usd-core and trimesh, no bpy: the stage walk on a stage naming a missing reference, a missing
texture and an empty PNG; the triangle rule on every problem kind (and on nothing else); a real asset
conversion of a mesh with welded and zero-area triangles, its record, and its texture deleted."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from mixcount.errors import AssetError
from mixcount.usd.dependencies import missing_files, problem_line, require_files
from mixcount.usd.mesh_clean import bad_triangles, clean_triangles, polygon_problems


def _stage(tmp: Path) -> Path:
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    (tmp / "textures").mkdir()
    Image.new("RGB", (4, 4), (200, 10, 10)).save(tmp / "textures" / "ok.png")
    (tmp / "textures" / "empty.png").write_bytes(b"")
    asset = Usd.Stage.CreateNew(str(tmp / "asset.usda"))
    UsdGeom.Xform.Define(asset, "/Asset")
    tex = UsdShade.Shader.Define(asset, "/Asset/Tex")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./asset_tex/gone.png"))
    asset.GetRootLayer().Save()
    stage = Usd.Stage.CreateNew(str(tmp / "scene.usda"))
    ref = UsdGeom.Xform.Define(stage, "/World/A")
    ref.GetPrim().GetReferences().AddReference("./asset.usda")
    for k, name in enumerate(("ok.png", "empty.png")):
        sh = UsdShade.Shader.Define(stage, f"/World/T{k}")
        sh.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(f"./textures/{name}"))
    UsdGeom.Xform.Define(stage, "/World/B").GetPrim().GetReferences().AddReference("./missing.usdc")
    stage.GetRootLayer().Save()
    return tmp / "scene.usda"


def test_stage_walk_names_each_unusable_file(tmp_path: Path) -> None:
    path = _stage(tmp_path)
    found = {(d.path.name, why, d.layer.name) for d, why in missing_files(path)}
    assert found == {("missing.usdc", "missing", "scene.usda"), ("empty.png", "empty", "scene.usda"),
                     ("gone.png", "missing", "asset.usda")}  # followed into the referenced layer
    line = problem_line(path)
    assert line is not None and "\n" not in line and "(and 2 more)" in line
    with pytest.raises(AssetError, match=r"^scene x: .* is (missing|empty): "):
        require_files(path, "scene x")
    (tmp_path / "missing.usdc").unlink(missing_ok=True)
    for p in (tmp_path / "textures" / "empty.png", tmp_path / "asset.usda"):
        p.unlink()
    assert sorted(d.path.name for d, _ in missing_files(path)) == ["asset.usda", "empty.png", "missing.usdc"]


def test_triangle_rule_flags_each_problem_once_and_nothing_else() -> None:
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [np.nan, 0, 0], [0, 0, 0]], dtype=np.float64)
    faces = np.array([[0, 1, 2],   # fine
                      [0, 1, 9],   # out of range
                      [0, 1, 4],   # a NaN corner
                      [0, 0, 2],   # repeated vertex
                      [0, 1, 3],   # collinear: zero area
                      [5, 1, 2],   # vertex 5 sits on vertex 0 but the triangle has area: fine
                      [0, 5, 1]])  # coincident corners: zero area
    masks = bad_triangles(pts, faces)
    assert {k: np.flatnonzero(m).tolist() for k, m in masks.items()} == {
        "out_of_range": [1], "non_finite": [2], "repeated_vertex": [3], "zero_area": [4, 6]}
    colours = np.arange(len(faces))
    kept, per_face, counts = clean_triangles(pts, faces, colours)
    assert kept.tolist() == [[0, 1, 2], [5, 1, 2]] and per_face.tolist() == [0, 5]
    assert counts == {"out_of_range": 1, "non_finite": 1, "repeated_vertex": 1, "zero_area": 2}
    # polygons as USD stores them: a quad with a repeated index, a 2-gon, a clean quad and triangle
    assert polygon_problems([4, 2, 4, 3], [0, 1, 1, 2, 0, 1, 0, 1, 2, 3, 0, 1, 2], 4).tolist() == [True, True, False, False]


def test_conversion_drops_bad_faces_records_them_and_refills_a_lost_texture(tmp_path: Path) -> None:
    from pxr import Sdf, Usd, UsdGeom

    from mixcount.usd.assets import convert_asset

    mesh = trimesh.creation.icosphere(2)
    faces = np.array(mesh.faces)
    faces[:7, 2] = faces[:7, 0]  # welded corners, as a capture's export has them
    verts = np.vstack([mesh.vertices, mesh.vertices[faces[10, 0]]])
    faces[10, 2] = len(verts) - 1  # a corner moved onto another: zero area, distinct indices
    uv = np.vstack([mesh.vertices[:, :2] * 0.5 + 0.5, [[0.5, 0.5]]])
    img = Image.new("RGB", (8, 8), (30, 160, 40))
    textured = trimesh.Trimesh(verts, faces, process=False,
                               visual=trimesh.visual.TextureVisuals(uv=uv, image=img))
    textured.export(tmp_path / "scan.glb")
    out = tmp_path / "assets"
    asset = convert_asset(tmp_path / "scan.glb", out, content_hash="scan", units="m", up_axis="Z")
    record = dict(Sdf.Layer.FindOrOpen(str(asset.visual)).customLayerData["mixcount"])
    assert dict(record["faces_removed"]) == {"repeated_vertex": 7, "zero_area": 1}
    assert record["faces_kept"] == len(faces) - 8
    stage = Usd.Stage.Open(str(asset.visual))
    meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert sum(len(m.GetFaceVertexCountsAttr().Get()) for m in meshes) == len(faces) - 8
    for m in meshes:
        bad = polygon_problems(m.GetFaceVertexCountsAttr().Get(), m.GetFaceVertexIndicesAttr().Get(),
                               len(m.GetPointsAttr().Get()))
        assert not bad.any()
    # a texture of the cached asset deleted: the next conversion (compose's) puts it back
    tex = sorted((out / "scan_tex").glob("*.png"))
    assert tex and problem_line(asset.visual) is None
    tex[0].unlink()
    assert problem_line(asset.visual) is not None
    convert_asset(tmp_path / "scan.glb", out, content_hash="scan", units="m", up_axis="Z")
    assert tex[0].is_file() and problem_line(asset.visual) is None
    # and with the source gone too: one line naming the model
    tex[0].unlink()
    (tmp_path / "scan.glb").unlink()
    with pytest.raises(AssetError, match="scan.glb"):
        convert_asset(tmp_path / "scan.glb", out, content_hash="scan", units="m", up_axis="Z")


def test_usd_source_keeps_its_file_and_loses_its_invalid_faces(tmp_path: Path) -> None:
    """A USD source is referenced as it is; the wrapping layer overrides its meshes' invalid faces, with
    face-varying UVs, per-face colours and a GeomSubset filtered alike."""
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt

    from mixcount.usd.assets import convert_asset

    src = Usd.Stage.CreateNew(str(tmp_path / "scan.usda"))
    UsdGeom.SetStageUpAxis(src, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(src, 0.01)
    root = UsdGeom.Xform.Define(src, "/Scan")
    src.SetDefaultPrim(root.GetPrim())
    mesh = UsdGeom.Mesh.Define(src, "/Scan/Geom/body")
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(x, y, z) for x, y, z in
                                         [(0, 0, 0), (10, 0, 0), (10, 10, 0), (0, 10, 0), (5, 5, 8)]]))
    counts = [4, 3, 3, 3, 3, 3]  # the quad, then a welded triangle, then four good ones (one repeated)
    idx = [0, 1, 2, 3, 0, 0, 4, 0, 1, 4, 1, 2, 4, 2, 3, 4, 3, 0, 4]
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(idx)
    pv = UsdGeom.PrimvarsAPI(mesh)
    pv.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying).Set(
        Vt.Vec2fArray([Gf.Vec2f(k / 19.0, 0.5) for k in range(len(idx))]))
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(Vt.Vec3fArray([Gf.Vec3f(k / 6.0, 0, 0) for k in range(6)]))
    UsdGeom.Subset.CreateGeomSubset(mesh, "top", UsdGeom.Tokens.face, Vt.IntArray([1, 2, 5]))
    src.GetRootLayer().Save()
    before = (tmp_path / "scan.usda").read_bytes()
    asset = convert_asset(tmp_path / "scan.usda", tmp_path / "assets", content_hash="usdscan")
    assert (tmp_path / "scan.usda").read_bytes() == before  # the source is never written
    record = dict(Sdf.Layer.FindOrOpen(str(asset.visual)).customLayerData["mixcount"])
    assert dict(record["faces_removed"]) == {"invalid_polygon": 1}
    stage = Usd.Stage.Open(str(asset.visual))
    body = UsdGeom.Mesh(stage.GetPrimAtPath("/Asset/Source/Geom/body"))
    assert list(body.GetFaceVertexCountsAttr().Get()) == [4, 3, 3, 3, 3]
    got_idx = list(body.GetFaceVertexIndicesAttr().Get())
    assert got_idx == idx[:4] + idx[7:]
    assert not polygon_problems(body.GetFaceVertexCountsAttr().Get(), got_idx, 5).any()
    st = UsdGeom.PrimvarsAPI(body).GetPrimvar("st").Get()
    assert [round(v[0] * 19) for v in st] == list(range(4)) + list(range(7, 19))
    assert [round(c[0] * 6) for c in body.GetDisplayColorPrimvar().Get()] == [0, 2, 3, 4, 5]
    top = UsdGeom.Subset(stage.GetPrimAtPath("/Asset/Source/Geom/body/top"))
    assert list(top.GetIndicesAttr().Get()) == [1, 4]  # faces 2 and 5 renumbered, the dropped face 1 gone


def test_a_dataset_moved_without_its_assets_names_the_broken_link(tmp_path: Path) -> None:
    path = _stage(tmp_path)
    (tmp_path / "textures" / "empty.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    (tmp_path / "missing.usdc").symlink_to("../elsewhere/missing.usdc")  # a relative link, as OUT/assets holds
    (tmp_path / "asset_tex").mkdir()
    Image.new("RGB", (2, 2)).save(tmp_path / "asset_tex" / "gone.png")
    line = problem_line(path)
    assert line is not None and line.startswith(f"layer {tmp_path / 'missing.usdc'} is a broken link to "
                                                "../elsewhere/missing.usdc"), line
    assert "(and" not in line  # the only problem left
