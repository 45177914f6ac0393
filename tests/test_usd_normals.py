"""normals_against_winding: the worker's cheap check for authored normals that face against the winding."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from pxr import Sdf, Usd, UsdGeom, Vt

from mixcount.usd.read import normals_against_winding


def _write(path: Path, *, flip: bool = False, interp: str = "vertex", primvar: bool = False,
           left_handed: bool = False, normals: bool = True) -> Path:
    box = trimesh.creation.icosphere(subdivisions=2)  # outward winding, outward vertex normals
    faces = box.faces[:, ::-1] if left_handed else box.faces  # leftHanded: the other winding is outward
    vn = box.vertex_normals * (-1.0 if flip else 1.0)
    if interp == "faceVarying":
        values = vn[faces.ravel()]
    elif interp == "uniform":
        values = box.face_normals * (-1.0 if flip else 1.0)
    else:
        values = vn
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/Asset/mesh")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(box.vertices.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.astype(np.int32).ravel()))
    if left_handed:
        mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    if normals and primvar:
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray, interp)
        pv.Set(Vt.Vec3fArray.FromNumpy(values.astype(np.float32)))
        # a stale plain attribute that disagrees: the primvar must win
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy((-values).astype(np.float32)))
        mesh.SetNormalsInterpolation(interp)
    elif normals:
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(values.astype(np.float32)))
        mesh.SetNormalsInterpolation(interp)
    stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("interp", ["vertex", "faceVarying", "uniform"])
@pytest.mark.parametrize("primvar", [False, True])
def test_inverted_normals_are_found_for_every_interpolation(tmp_path: Path, interp: str, primvar: bool) -> None:
    assert normals_against_winding(str(_write(tmp_path / "ok.usda", interp=interp, primvar=primvar))) is False
    assert normals_against_winding(str(_write(tmp_path / "bad.usda", flip=True, interp=interp,
                                              primvar=primvar))) is True


def test_left_handed_winding_and_missing_normals(tmp_path: Path) -> None:
    assert normals_against_winding(str(_write(tmp_path / "lh.usda", left_handed=True))) is False
    assert normals_against_winding(str(_write(tmp_path / "lh_bad.usda", left_handed=True, flip=True))) is True
    assert normals_against_winding(str(_write(tmp_path / "none.usda", normals=False))) is False


def test_converted_demo_asset_agrees_with_its_winding(tmp_path: Path) -> None:
    """Assets from mixcount.usd.assets keep normals that agree with the winding (the worker keeps them)."""
    from mixcount.usd.assets import convert_asset

    mesh = trimesh.creation.capsule(radius=0.02, height=0.05)
    src = tmp_path / "capsule.glb"
    mesh.export(src)
    paths = convert_asset(src, tmp_path / "assets", content_hash="caps")
    stage = Usd.Stage.Open(str(paths.visual))
    authored = [UsdGeom.Mesh(p).GetNormalsAttr().Get() for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert authored and all(n is not None and len(n) for n in authored)  # the check has normals to judge
    assert normals_against_winding(str(paths.visual)) is False
