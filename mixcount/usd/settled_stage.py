"""settled.usda: a scene's stage as the worker left it (dropped prims removed, kept bodies at their settled
pose, every camera where it rendered from), and :func:`decompose` (a 4x4 matrix -> translate / orient /
scale, the pose metadata.json records).

The worker's results are read through two small protocols (:class:`SettledBody`, :class:`RenderedCamera`:
:class:`~mixcount.worker.contract.ObjectResult` and :class:`~mixcount.worker.contract.CameraView` fit
them), so this room needs nothing from the worker room above it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Optional, Protocol, Sequence

import numpy as np

from mixcount.atomic import atomic_path
from mixcount.scene.rotation import quat_from_matrix
from mixcount.usd.stage import USD_WRITING


class SettledBody(Protocol):
    """One body of the worker's result (ObjectResult): its prim, whether it stayed, its pose."""

    @property
    def path(self) -> str: ...

    @property
    def kept(self) -> bool: ...

    @property
    def matrix_world(self) -> Any: ...

    @property
    def visibility(self) -> Optional[float]: ...


class RenderedCamera(Protocol):
    """One camera the worker rendered from (CameraView): its name, record (``cam_to_world``) and framing."""

    @property
    def name(self) -> str: ...

    @property
    def camera(self) -> Mapping[str, Any]: ...

    @property
    def framing(self) -> Mapping[str, Any]: ...


def decompose(matrix: Any) -> dict[str, list[float]]:
    """translate / orient (w, x, y, z) / scale of a 4x4 column-vector matrix (no shear)."""
    m = np.asarray(matrix, dtype=np.float64)
    scale = np.linalg.norm(m[:3, :3], axis=0)
    rot = m[:3, :3] / np.where(scale == 0, 1.0, scale)
    return {"translate": m[:3, 3].tolist(), "orient": list(quat_from_matrix(rot)), "scale": scale.tolist()}


def _set_camera_pose(stage: Any, view: RenderedCamera) -> None:
    """A camera prim moved to the pose the worker framed (``view``: one of SceneResult.views), with the
    framing's derivation in its customData (``mixcount:framing``, JSON)."""
    from pxr import Gf, UsdGeom

    prim = stage.GetPrimAtPath(f"/World/Cameras/{view.name}")
    if not prim or not prim.IsValid() or "cam_to_world" not in view.camera:
        return
    pose = decompose(view.camera["cam_to_world"])
    for op in UsdGeom.Xformable(prim).GetOrderedXformOps():
        if op.GetOpType() == UsdGeom.XformOp.TypeTranslate:
            op.Set(Gf.Vec3d(*pose["translate"]))
        elif op.GetOpType() == UsdGeom.XformOp.TypeOrient:
            w, x, y, z = pose["orient"]
            op.Set(Gf.Quatf(w, Gf.Vec3f(x, y, z)))
    framing = dict(view.framing)
    cam = framing.pop("camera", None)
    if cam is not None:
        prim.SetCustomDataByKey("mixcount:look_at", Gf.Vec3d(*cam["look_at"]))
        prim.SetCustomDataByKey("mixcount:distance", float(cam["distance"]))
    prim.SetCustomDataByKey("mixcount:framing", json.dumps(framing, sort_keys=True))


def write_settled_stage(scene_usda: Path, out: Path, objects: Sequence[SettledBody],
                        views: Sequence[RenderedCamera]) -> None:
    """scene.usda -> settled.usda: dropped prims removed, kept ones at their settled pose (same names and
    customData, plus mixcount:visibility and mixcount:status on each kept instance), every camera at the
    pose it was rendered from (``views``: SceneResult.views)."""
    with USD_WRITING:
        _write_settled(scene_usda, out, objects, views)


def _write_settled(scene_usda: Path, out: Path, objects: Sequence[SettledBody], views: Sequence[RenderedCamera]) -> None:
    from pxr import Gf, Sdf, Usd, UsdGeom

    src = Sdf.Layer.FindOrOpen(str(scene_usda))
    # named by a temporary file beside ``out`` (anonymous, its relative asset paths would not resolve)
    with atomic_path(out) as tmp:
        layer = Sdf.Layer.New(Sdf.FileFormat.FindByExtension("usda"), str(tmp))
        layer.TransferContent(src)
        stage = Usd.Stage.Open(layer)
        for rec in objects:
            if not rec.kept:
                stage.RemovePrim(rec.path)
                continue
            prim = stage.GetPrimAtPath(rec.path)
            pose = decompose(rec.matrix_world)
            xf = UsdGeom.Xformable(prim)
            for op in xf.GetOrderedXformOps():
                kind = op.GetOpType()
                if kind == UsdGeom.XformOp.TypeTranslate:
                    op.Set(Gf.Vec3d(*pose["translate"]))
                elif kind == UsdGeom.XformOp.TypeOrient:
                    w, x, y, z = pose["orient"]
                    op.Set(Gf.Quatf(w, Gf.Vec3f(x, y, z)) if op.GetPrecision() == UsdGeom.XformOp.PrecisionFloat
                           else Gf.Quatd(w, Gf.Vec3d(x, y, z)))
                elif kind == UsdGeom.XformOp.TypeScale:
                    op.Set(Gf.Vec3f(*pose["scale"]))
            if rec.visibility is not None:
                prim.SetCustomDataByKey("mixcount:visibility", float(rec.visibility))
        for view in views:
            _set_camera_pose(stage, view)
        data = dict(layer.customLayerData)
        mc = dict(data.get("mixcount", {}))
        mc["settled"] = True
        data["mixcount"] = mc
        layer.customLayerData = data
        if not layer.Save():
            raise OSError(f"could not write {out}")
