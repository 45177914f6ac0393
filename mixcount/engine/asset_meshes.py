"""Each asset's meshes in the worker (bpy): the render mesh imported once per scene, or appended from its
.blend cache, the collision proxy, the hull and collider points kept per asset, and the worker's
``cache_meshes`` operation that writes those caches ahead of the scenes.

Split out of :mod:`mixcount.engine.scene_build` (issue 58: that file held both the per-asset meshes and the
per-scene build): :class:`AssetCache` is what a scene's build asks for an asset's datablocks,
:func:`cache_asset_meshes` serves ``cache_meshes`` (:mod:`mixcount.engine.worker_main`) with no scene at all.
Every referenced asset file is imported ONCE with ``wm.usd_import`` (UsdPreviewSurface -> Principled BSDF),
its mesh parts baked and joined into one mesh datablock - or that datablock is appended from the asset's
.blend cache (:mod:`mixcount.engine.mesh_cache`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mixcount.worker.contract import MeshCacheRequest, MeshCacheResult


class AssetCache:
    """One joined mesh datablock per asset file, imported once per scene.

    With ``mesh_cache`` "zstd" or "raw" the finished mesh also goes to a .blend beside the asset
    (:mod:`mixcount.engine.mesh_cache`), and later scenes append it from there instead of importing the
    USD file again. ``cache_events`` records, per asset, "hit", "written" or the reason it was not."""

    def __init__(self, mesh_cache: str) -> None:
        self.mesh_cache = mesh_cache
        self.meshes: dict[str, Any] = {}
        self.columns: dict[str, np.ndarray] = {}  # local vertices as (3, V): rows reduce fast
        self.corners: dict[str, np.ndarray] = {}  # triangles' vertex indices as (3, T): rows gather fast
        self.hulls: dict[str, np.ndarray] = {}
        self.hull_vertices: dict[str, np.ndarray] = {}
        self.proxies: dict[str, Any] = {}
        self.proxy_points: dict[str, np.ndarray] = {}
        self.cache_events: dict[str, str] = {}

    def proxy(self, path: Path, prim: Any) -> Any:
        """The collision proxy mesh of an asset (read from the instance's ``Proxy`` prim), one per asset."""
        import bpy
        from pxr import UsdGeom

        key = str(path)
        if key not in self.proxies:
            mesh = UsdGeom.Mesh(prim)
            pts = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
            idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int64).reshape(-1, 3)
            data = bpy.data.meshes.new(f"proxy_{Path(key).stem[:16]}")
            data.from_pydata(pts.tolist(), [], idx.tolist())
            data.use_fake_user = True
            self.proxies[key] = data
            self.proxy_points[key] = pts
        return self.proxies[key]

    def mesh(self, path: Path) -> Any:
        """The asset's render mesh: from this scene's memory, the .blend cache, or a USD import."""
        from mixcount.engine import mesh_cache
        from mixcount.engine.visibility import mesh_arrays

        key = str(path)
        if key in self.meshes:
            return self.meshes[key]
        mesh = None
        cached = mesh_cache.cache_file(path) if self.mesh_cache != "off" else None
        if cached is not None:
            mesh = mesh_cache.load(cached)
            if mesh is not None:
                self.cache_events[key] = "hit"
        if mesh is None:
            mesh = _import_asset_mesh(key)
            if cached is not None:
                self.cache_events[key] = mesh_cache.store(mesh, cached, self.mesh_cache) or "written"
        self.meshes[key] = mesh
        verts, tris = mesh_arrays(mesh)
        self.columns[key] = np.ascontiguousarray(verts.T)
        self.corners[key] = np.ascontiguousarray(tris.T)
        return mesh

    def cache_report(self) -> dict[str, str]:
        """Asset file name -> what the .blend cache did for it ("hit", "written" or why not)."""
        return {Path(k).name: v for k, v in sorted(self.cache_events.items())}

    def collider_points(self, path: Path) -> np.ndarray:
        """Local points (P, 3) of the shape that collided: the proxy's points, else the convex hull's
        vertices of the mesh (not every vertex of a capture: a rest test over 786k points per body
        cost seconds a scene). Computed once per asset."""
        key = str(path)
        if key not in self.hull_vertices:
            local = self.proxy_points.get(key)
            self.hull_vertices[key] = local if local is not None else hull_vertices(self.columns[key].T)
        return self.hull_vertices[key]

    def hull(self, path: Path) -> np.ndarray:
        from mixcount.scene_decisions import hull_equations

        key = str(path)
        if key not in self.hulls:  # the proxy is the shape that collided (and a hull of <= proxy_max_vertices points)
            self.hulls[key] = hull_equations(self.proxy_points.get(key, self.columns[key].T))
        return self.hulls[key]


def hull_vertices(points: np.ndarray) -> np.ndarray:
    """The convex hull's vertices of ``points`` (N, 3); a flat or degenerate set: its box corners."""
    from scipy.spatial import ConvexHull

    pts = np.asarray(points, dtype=np.float64)
    try:
        return np.asarray(pts[ConvexHull(pts).vertices])
    except Exception:
        lo, hi = pts.min(0), pts.max(0)
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def cache_asset_meshes(req: MeshCacheRequest) -> MeshCacheResult:
    """Make (or find) the .blend mesh cache of each asset file ahead of the scenes that use it: asset file
    name -> "hit", "written" or why it could not be written (nothing in mode "off"). In an empty file."""
    import bpy

    if req.mode == "off":
        return MeshCacheResult(assets={})
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cache = AssetCache(req.mode)
    for a in req.assets:
        cache.mesh(Path(a))
    return MeshCacheResult(assets=cache.cache_report())


def _import_asset_mesh(asset: str) -> Any:
    """``wm.usd_import`` of one asset file (UsdPreviewSurface -> Principled BSDF), its mesh parts baked
    and joined into one mesh datablock (fake user) and the import's objects removed; authored normals
    that point against the winding are replaced (:func:`drop_authored_normals`)."""
    import bpy

    from mixcount.usd.read import normals_against_winding

    before = set(bpy.data.objects)
    res = bpy.ops.wm.usd_import(filepath=asset, import_lights=False, import_cameras=False, import_guide=False,
                                import_proxy=False, create_collection=False)
    if "FINISHED" not in res:
        raise RuntimeError(f"USD import of {asset} failed")
    new = [o for o in bpy.data.objects if o not in before]
    parts = [o for o in new if o.type == "MESH"]
    if not parts:
        raise RuntimeError(f"asset {asset} holds no mesh")
    bpy.context.view_layer.update()
    for o in parts:
        if o.data.users > 1:
            o.data = o.data.copy()
        o.data.transform(o.matrix_world)
        o.matrix_world.identity()
    if len(parts) > 1:
        with bpy.context.temp_override(active_object=parts[0], object=parts[0], selected_objects=parts,
                                       selected_editable_objects=parts):
            bpy.ops.object.join()
    mesh = parts[0].data
    mesh.name = f"asset_{Path(asset).stem[:16]}"
    if normals_against_winding(asset):
        drop_authored_normals(mesh)
    mesh.use_fake_user = True
    for o in list(bpy.data.objects):
        if o in before:
            continue
        bpy.data.objects.remove(o, do_unlink=True)
    return mesh


def drop_authored_normals(mesh: Any) -> None:
    """Replace authored (custom) normals that point against the face winding by Blender's own.

    A shading normal facing away from the geometric one renders black in Cycles. Whether an asset's
    normals do is decided from its USD arrays (:func:`mixcount.usd.read.normals_against_winding`); here
    the custom normals are removed, faces shaded smooth and edges sharper than 30 degrees kept sharp.
    """
    import math

    if "custom_normal" in mesh.attributes:
        mesh.attributes.remove(mesh.attributes["custom_normal"])
    mesh.shade_smooth()
    mesh.set_sharp_from_angle(angle=math.radians(30.0))
