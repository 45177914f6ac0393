"""The trimesh side of the USD asset converter (:mod:`mixcount.usd.assets`): a model file read into
:class:`Part` s (points, faces, normals, UVs in metres, Z-up, as ingest places them) with their materials
(glTF PBR factors and textures, an ``.mtl``'s colour, vertex or face colours, or the object's palette look).

Apart from the pxr side because it is what decides how an asset looks: :mod:`mixcount.usd.assets` writes
these parts into USD prims and knows nothing of trimesh's scene graph."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from mixcount.catalog.materials import is_placeholder_material, material_vertex_colours, srgb_to_linear
from mixcount.errors import CompositionError
from mixcount.frame import load_model, to_metres_z_up, up_axis_rotation, walk_geometry


@dataclass
class Part:
    """One geometry of a model in metres, Z-up: its triangles, normals, UVs and colour."""

    points: np.ndarray
    faces: np.ndarray
    normals: Optional[np.ndarray]
    uv: Optional[np.ndarray]
    material: Optional[dict[str, Any]]  # base_color_factor, images, metallic, roughness
    display_color: Optional[np.ndarray]
    color_interp: str = "vertex"


def _image(obj: Any) -> Any:
    try:
        from PIL import Image

        return obj if isinstance(obj, Image.Image) else None
    except Exception:  # pragma: no cover
        return None


def _material_of(geom: Any) -> tuple[Optional[dict[str, Any]], Optional[np.ndarray], str]:
    visual = getattr(geom, "visual", None)
    kind = getattr(visual, "kind", None)
    if kind == "texture" or (visual is not None and hasattr(visual, "material") and kind is None):
        mat = visual.material
        if is_placeholder_material(mat):
            return None, None, "vertex"  # trimesh's stand-in for a missing material: no colour of its own (the look)
        info: dict[str, Any] = {"base_color_factor": [0.8, 0.8, 0.8, 1.0], "metallic": 0.0, "roughness": 0.5}
        factor = getattr(mat, "baseColorFactor", None)
        if factor is not None or type(mat).__name__ == "PBRMaterial":  # unset: glTF's default, 1
            factor = [1.0, 1.0, 1.0, 1.0] if factor is None else factor
            f = np.asarray(factor, dtype=float).ravel()
            info["base_color_factor"] = list((f / 255.0 if f.max() > 1.0 else f).tolist()) + [1.0] * (4 - len(f))
        elif getattr(mat, "diffuse", None) is not None:  # an .mtl's Kd; with a map_Kd the map alone, as Blender
            d = np.asarray(mat.diffuse, dtype=float).ravel() if _image(getattr(mat, "image", None)) is None else 255.0
            info["base_color_factor"] = list((np.broadcast_to(d / 255.0, (4,))).tolist())
        if getattr(mat, "metallicFactor", None) is not None:
            info["metallic"] = float(mat.metallicFactor)
        if getattr(mat, "roughnessFactor", None) is not None:
            info["roughness"] = float(mat.roughnessFactor)
        info["base_color_tex"] = _image(getattr(mat, "baseColorTexture", None)) or _image(getattr(mat, "image", None))
        info["mr_tex"] = _image(getattr(mat, "metallicRoughnessTexture", None))
        info["normal_tex"] = _image(getattr(mat, "normalTexture", None))
        return info, None, "vertex"
    if kind == "vertex":
        return None, np.asarray(visual.vertex_colors, dtype=float)[:, :3] / 255.0, "vertex"
    if kind == "face":
        return None, np.asarray(visual.face_colors, dtype=float)[:, :3] / 255.0, "uniform"
    return None, None, "vertex"


def load_parts(model_path: Path, scale: float, up: str, look: Optional[tuple[float, ...]] = None) -> list[Part]:
    """Every geometry of ``model_path`` placed by its node's world transform, scaled by ``scale`` and turned
    Z-up from ``up`` as ingest does, with its material (a part with no colour of its own gets ``look``)."""
    import trimesh

    try:
        scene = load_model(model_path, force="scene")
    except Exception as exc:
        raise CompositionError(f"cannot load model {model_path} for USD conversion: {exc}") from None
    rot = up_axis_rotation(up)
    parts: list[Part] = []
    for _node, transform, geom in walk_geometry(scene):
        pts = to_metres_z_up(trimesh.transform_points(np.asarray(geom.vertices, dtype=np.float64), transform),
                             scale, up)
        lin = np.asarray(transform)[:3, :3]
        normals = None
        try:
            vn = np.asarray(geom.vertex_normals, dtype=np.float64)
            if len(vn) == len(pts):
                normals = vn @ np.linalg.inv(lin) @ rot.T  # row vectors: n (inverse-transpose of L)
                normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        except Exception:
            normals = None
        mat, colors, interp = _material_of(geom)
        if mat is not None and colors is None:
            colors = material_vertex_colours(geom.visual, len(pts))
            if colors is not None:
                mat["vertex_color"] = True  # glTF COLOR_0 under a material: base = factor x colour
        if mat is None and colors is not None:  # plain vertex/face colours: a material that reads them
            mat = {"base_color_factor": [1.0, 1.0, 1.0, 1.0], "metallic": 0.0, "roughness": 0.5,
                   "vertex_color": True}
        if mat is None and colors is None and look is not None:  # no colour of its own: the palette look
            mat = look_material(look)
        uv = getattr(geom.visual, "uv", None) if mat is not None else None
        if uv is not None and len(uv) != len(pts):
            uv = None
        if mat is not None and mat.get("vertex_color") and colors is not None:
            colors = colors * np.asarray(mat["base_color_factor"][:3], dtype=np.float64)
        parts.append(Part(pts, np.asarray(geom.faces, dtype=np.int64), normals,
                           None if uv is None else np.asarray(uv, dtype=np.float64), mat, colors, interp))
    if not parts:
        raise CompositionError(f"model {model_path} has no triangle geometry to convert")
    return parts


def look_material(look: tuple[float, ...]) -> dict[str, Any]:
    """The material of a part without a colour: ``look`` = (sRGB r, g, b, metallic, roughness)."""
    linear = srgb_to_linear(look[:3])
    return {"base_color_factor": [float(c) for c in linear] + [1.0], "metallic": float(look[3]),
            "roughness": float(look[4]), "base_color_tex": None, "mr_tex": None, "normal_tex": None}


def look_tag(look: Optional[tuple[float, ...]]) -> str:
    """How a layer records the look it was converted with ("" = none)."""
    return "" if look is None else ",".join(f"{float(v):.4f}" for v in look)
