"""Visibility in the worker (bpy side): mesh triangles for the silhouette rasteriser, the exact camera
model, and the one-render-per-object reference kept as a test oracle.

The fast path never renders per object: ``unoccluded_mask`` rasterises the object's own full mesh with
:mod:`mixcount.annotate.raster` (numpy). ``oracle_masks`` is the paper's method (every other object
hidden, one id-pass render each) and only runs when a request asks for it (tests, benchmarks).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable

import numpy as np

from mixcount.annotate.raster import PinholeCamera, placed_silhouette


def mesh_arrays(mesh: Any) -> tuple[np.ndarray, np.ndarray]:
    """Local vertices (V, 3) and triangles (T, 3) of a Blender mesh datablock."""
    # attribute arrays of Blender's own element types are copied as memory (position ~0.001 s, corners
    # ~0.01 s on a 786k-face capture; loop_triangles' "vertices" took 0.17 s). A mesh whose corners are
    # three per face is all triangles, stored face after face: its corners are the triangles.
    verts = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.attributes["position"].data.foreach_get("vector", verts)
    if len(mesh.loops) == 3 * len(mesh.polygons):
        tris = np.empty(len(mesh.loops), dtype=np.int32)
        mesh.attributes[".corner_vert"].data.foreach_get("value", tris)
    else:
        mesh.calc_loop_triangles()
        tris = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int32)
        mesh.loop_triangles.foreach_get("vertices", tris)
    return verts.reshape(-1, 3).astype(np.float64), tris.reshape(-1, 3).astype(np.int64)


def camera_model(scene: Any, cam_obj: Any) -> PinholeCamera:
    """The pinhole model Blender renders with (horizontal sensor fit, square pixels, no shift)."""
    cam = cam_obj.data
    w = scene.render.resolution_x
    h = scene.render.resolution_y
    return PinholeCamera.from_physical(cam.lens, cam.sensor_width, w, h,
                                       np.array(cam_obj.matrix_world, dtype=np.float64),
                                       near=float(cam.clip_start))


def unoccluded_mask(camera: PinholeCamera, local_rows: np.ndarray, corners: np.ndarray,
                    matrix_world: np.ndarray) -> np.ndarray:
    """The object's silhouette from its mesh's local vertices (3, V) and triangle corners (3, T) as
    rows (kept per asset by the scene job's AssetCache) placed by ``matrix_world``."""
    return placed_silhouette(camera, local_rows, corners, matrix_world)


def oracle_masks(scene: Any, objects: Iterable[Any], work: Path) -> dict[int, np.ndarray]:
    """The paper's reference: for each object, hide every other renderable object, render the id pass
    and keep the pixels of that object's pass index. Slow by design (one render per object)."""
    from mixcount.engine.render_passes import remove_quiet, render_id_passes

    objects = list(objects)
    renderable = [o for o in scene.objects if o.type == "MESH" and not o.hide_render]
    saved = {o.name: o.hide_render for o in renderable}
    out: dict[int, np.ndarray] = {}
    try:
        for target in objects:
            for o in renderable:
                o.hide_render = o is not target
            path = Path(work) / f"_oracle_{target.pass_index}.exr"
            passes = render_id_passes(scene, path)
            remove_quiet(path)
            out[int(target.pass_index)] = passes["index"] == int(target.pass_index)
    finally:
        for o in renderable:
            o.hide_render = saved[o.name]
    return out
