"""A USD / USDZ source model as the converter wraps it (:mod:`mixcount.usd.assets`): its box in metres,
Z-up, and overrides that take invalid faces out of its meshes without touching the source file.

A USD source is referenced as it is (``/Asset/Source``), so a face that names a vertex twice would reach
Blender's importer untouched (issue 60: it warns "Invalid face data" and may crash on a whole stage).
:func:`override_invalid_faces` authors, in the wrapping layer, an ``over`` of each such mesh with the
faces kept (``faceVertexCounts`` / ``faceVertexIndices``), every face-varying or uniform primvar and
normal filtered alike (an indexed primvar gets filtered indices, its values stay), and each GeomSubset's
face indices renumbered. Meshes whose topology is animated (time samples) are left alone and counted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mixcount.errors import CompositionError
from mixcount.frame import up_axis_rotation
from mixcount.usd.mesh_clean import polygon_problems


def usd_bounds(model: Path) -> tuple[np.ndarray, np.ndarray]:
    """The USD model's box in metres, Z-up (its own metersPerUnit and up axis applied)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(model))
    if stage is None:
        raise CompositionError(f"cannot open USD model {model}")
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    rot = up_axis_rotation(str(UsdGeom.GetStageUpAxis(stage)))
    cache = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_, UsdGeom.Tokens.render])
    box = cache.ComputeWorldBound(stage.GetPseudoRoot()).ComputeAlignedRange()
    lo, hi = np.asarray(box.GetMin()) * mpu, np.asarray(box.GetMax()) * mpu
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) @ rot.T
    return corners.min(0), corners.max(0)


def _filtered(values: Any, keep: np.ndarray) -> Any:
    """A Vt array with the rows of ``keep`` (same type), or None when its length does not match."""
    if values is None or len(values) != len(keep):
        return None
    rows = [values[int(i)] for i in np.flatnonzero(keep)]
    return type(values)(rows)


def _override_mesh(stage: Any, target: str, prim: Any, counts: np.ndarray, idx: np.ndarray, bad: np.ndarray) -> None:
    from pxr import Sdf, UsdGeom, Vt

    keep_face = ~bad
    keep_corner = np.repeat(keep_face, counts)
    over = stage.OverridePrim(target)
    mesh = UsdGeom.Mesh(over)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([int(c) for c in counts[keep_face]]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in idx[keep_corner]]))
    per = {UsdGeom.Tokens.faceVarying: keep_corner, UsdGeom.Tokens.uniform: keep_face}
    for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars():
        keep = per.get(pv.GetInterpolation())
        if keep is None:
            continue
        out = UsdGeom.PrimvarsAPI(over).CreatePrimvar(pv.GetPrimvarName(), pv.GetTypeName(), pv.GetInterpolation())
        if pv.IsIndexed():
            new = _filtered(pv.GetIndices(), keep)
            if new is not None:
                out.SetIndices(new)
        else:
            new = _filtered(pv.Get(), keep)
            if new is not None:
                out.Set(new)
    src_mesh = UsdGeom.Mesh(prim)
    keep = per.get(src_mesh.GetNormalsInterpolation())
    if keep is not None and src_mesh.GetNormalsAttr().HasAuthoredValue():
        new = _filtered(src_mesh.GetNormalsAttr().Get(), keep)
        if new is not None:
            mesh.CreateNormalsAttr(new)
    renumber = np.cumsum(keep_face) - 1
    for subset in UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(prim)):
        faces = np.asarray(subset.GetIndicesAttr().Get() or [], dtype=np.int64)
        faces = faces[(faces >= 0) & (faces < len(keep_face))]
        kept = [int(renumber[f]) for f in faces if keep_face[f]]
        path = Sdf.Path(target).AppendChild(subset.GetPrim().GetName())
        UsdGeom.Subset(stage.OverridePrim(path)).CreateIndicesAttr(Vt.IntArray(kept))


def override_invalid_faces(stage: Any, model: Path, under: str) -> dict[str, int]:
    """Overrides in ``stage`` (the wrapping layer) of every mesh of ``model`` below its default prim,
    referenced at ``under``, that has invalid faces (module docstring); returns the counts dropped
    (``invalid_polygon``) and left (``animated_kept``)."""
    from pxr import Sdf, Usd, UsdGeom

    src = Usd.Stage.Open(str(model))
    root = src.GetDefaultPrim() if src is not None else None
    removed: dict[str, int] = {}
    if not root:
        return removed
    for prim in Usd.PrimRange(root):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        c_attr, i_attr = mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr()
        counts = np.asarray(c_attr.Get() or [], dtype=np.int64)
        idx = np.asarray(i_attr.Get() or [], dtype=np.int64)
        points = mesh.GetPointsAttr().Get()
        bad = polygon_problems(counts, idx, len(points) if points is not None else 0)
        if not bad.any():
            continue
        if c_attr.GetNumTimeSamples() or i_attr.GetNumTimeSamples() or counts.sum() != len(idx):
            removed["animated_kept"] = removed.get("animated_kept", 0) + int(bad.sum())
            continue
        target = Sdf.Path(under).AppendPath(prim.GetPath().MakeRelativePath(root.GetPath()))
        _override_mesh(stage, str(target), prim, counts, idx, bad)
        removed["invalid_polygon"] = removed.get("invalid_polygon", 0) + int(bad.sum())
    return removed
