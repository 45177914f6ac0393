"""Reading mixcount facts back from a scene stage (for the Blender worker, tests and tools).

All mixcount customData is nested under one ``mixcount`` dictionary, so USD's key-path API reads it:
``prim.GetCustomDataByKey("mixcount:role")`` and
``stage.GetMetadataByDictKey("customLayerData", "mixcount:seed")``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional


@dataclass(frozen=True)
class PrimIds:
    path: str
    role: str
    object_id: int
    class_index: int
    instance_id: int


def prim_ids(prim: Any) -> Optional[PrimIds]:
    """The mixcount ids of ``prim`` or None when it carries none."""
    role = prim.GetCustomDataByKey("mixcount:role")
    if role is None:
        return None
    return PrimIds(str(prim.GetPath()), str(role), int(prim.GetCustomDataByKey("mixcount:object_id")),
                   int(prim.GetCustomDataByKey("mixcount:class_index")),
                   int(prim.GetCustomDataByKey("mixcount:instance_id")))


def labelled_prims(stage: Any) -> list[PrimIds]:
    """Every prim with mixcount ids, in stage order (floor, container, counted, distractors)."""
    out = []
    for prim in stage.Traverse():
        ids = prim_ids(prim)
        if ids is not None:
            out.append(ids)
    return out


def normals_against_winding(asset_path: str) -> bool:
    """True when most authored corner normals of the asset's meshes point against their face winding.

    A shading normal facing away from the geometric one renders black in Cycles; some sources (and
    assets converted by mixcount.usd.assets v1 from glTF) carry such normals, so the worker drops them.
    This decides it from the USD arrays with numpy, in the prim's own space (a transform moves both
    alike), instead of asking Blender for its corner normals: on a 786k-face capture that took ~1 s
    per asset in the worker, this ~0.1 s. Normals come from ``primvars:normals`` when authored (it wins
    over ``normals`` in USD), with every interpolation USD allows; a ``leftHanded`` mesh winds the other
    way. Each face is judged by its first three corners. Meshes without normals count for nothing.
    """
    import numpy as np
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(asset_path))
    if stage is None:
        raise RuntimeError(f"cannot open asset {asset_path}")
    against = total = 0
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        corner = _corner_normals(mesh)
        if corner is None:
            continue
        pts = np.asarray(mesh.GetPointsAttr().Get() or [], dtype=np.float32)
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64)
        idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int64)
        if (len(pts) == 0 or len(counts) == 0 or int(counts.sum()) != len(idx) or len(corner) != len(idx)
                or int(idx.max()) >= len(pts) or int(idx.min()) < 0):
            continue
        flip = -1.0 if mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded else 1.0
        if (counts == 3).all():  # triangles (what the converter writes): no per-face bookkeeping
            tri = pts[idx.reshape(-1, 3)]
            face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) * flip
            dots = np.einsum("fij,fj->fi", corner.reshape(-1, 3, 3), face_n).ravel()
        else:
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
            ok = counts >= 3
            s = starts[ok]
            face_n = np.cross(pts[idx[s + 1]] - pts[idx[s]], pts[idx[s + 2]] - pts[idx[s]]) * flip
            dots = np.einsum("ij,ij->i", np.repeat(face_n, counts[ok], axis=0), corner[np.repeat(ok, counts)])
        against += int((dots < 0).sum())
        total += len(dots)
    return total > 0 and against / total > 0.5


def _corner_normals(mesh: Any) -> Any:
    """(corners, 3) normals of a UsdGeom.Mesh expanded to face-vertex corners, or None."""
    import numpy as np
    from pxr import UsdGeom

    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("normals")
    if primvar and primvar.HasAuthoredValue():
        values = primvar.ComputeFlattened()
        interp = primvar.GetInterpolation()
    else:
        values = mesh.GetNormalsAttr().Get()
        interp = mesh.GetNormalsInterpolation()
    if values is None or len(values) == 0:
        return None
    n = np.asarray(values, dtype=np.float32).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64)
    idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int64)
    if interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        return n[idx] if len(idx) and idx.max() < len(n) else None
    if interp == UsdGeom.Tokens.faceVarying:
        return n if len(n) == len(idx) else None
    if interp == UsdGeom.Tokens.uniform:
        return np.repeat(n, counts, axis=0) if len(n) == len(counts) else None
    if interp == UsdGeom.Tokens.constant:
        return np.repeat(n[:1], len(idx), axis=0)
    return None


CONVEX_PARTS_PRIM = "/Asset/ConvexParts"  # a container's convex decomposition inside its collision asset


def convex_parts(asset_path: str) -> list[tuple[Any, Any]]:
    """The convex collision parts of an asset (``/Asset/ConvexParts/*`` meshes with approximation
    convexHull): (points (V, 3) in the asset's frame, triangles (T, 3)) each; empty when it has none."""
    import numpy as np
    from pxr import Usd, UsdGeom, UsdPhysics

    stage = Usd.Stage.Open(str(asset_path))
    if stage is None:
        raise RuntimeError(f"cannot open asset {asset_path}")
    root = stage.GetPrimAtPath(CONVEX_PARTS_PRIM)
    out = []
    if not root:
        return out
    for prim in Usd.PrimRange(root):
        if not prim.IsA(UsdGeom.Mesh) or not prim.HasAPI(UsdPhysics.MeshCollisionAPI):
            continue
        if UsdPhysics.MeshCollisionAPI(prim).GetApproximationAttr().Get() != UsdPhysics.Tokens.convexHull:
            continue
        mesh = UsdGeom.Mesh(prim)
        pts = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
        m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=np.float64).T
        pts = pts @ m[:3, :3].T + m[:3, 3]
        tris = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int64).reshape(-1, 3)
        out.append((pts, tris))
    return out
