"""A container's collision asset holds its convex decomposition (V-HACD), which keeps the hollow."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh


def _tray(path: Path) -> trimesh.Trimesh:
    """An open box 0.30 x 0.20 x 0.08 m with 1 cm walls and bottom (a container's shape)."""
    slabs = [trimesh.creation.box((0.30, 0.20, 0.01), trimesh.transformations.translation_matrix((0, 0, 0.005)))]
    for sx, sy, x, y in ((0.01, 0.20, -0.145, 0), (0.01, 0.20, 0.145, 0), (0.30, 0.01, 0, -0.095), (0.30, 0.01, 0, 0.095)):
        slabs.append(trimesh.creation.box((sx, sy, 0.08), trimesh.transformations.translation_matrix((x, y, 0.04))))
    tray = trimesh.util.concatenate(slabs)
    tray.export(str(path))
    return tray


def test_collision_asset_holds_convex_parts_that_keep_the_hollow(tmp_path: Path) -> None:
    from pxr import Usd, UsdGeom, UsdPhysics
    from scipy.spatial import Delaunay

    from mixcount.catalog.mesh import build_collision_mesh, load_normalised
    from mixcount.usd.assets import CONVEX_PARTS_MAX, CONVEX_PARTS_PRIM, convert_asset
    from mixcount.usd.read import convex_parts

    model = tmp_path / "tray.glb"
    _tray(model)
    ply = tmp_path / "tray_collision.ply"
    build_collision_mesh(load_normalised(model).mesh, ply, 2000)
    paths = convert_asset(model, tmp_path / "assets", content_hash="tray", collision_path=str(ply))
    assert paths.collision is not None
    stage = Usd.Stage.Open(str(paths.collision))
    prims = [p for p in Usd.PrimRange(stage.GetPrimAtPath(CONVEX_PARTS_PRIM)) if p.IsA(UsdGeom.Mesh)]
    assert prims and all(UsdPhysics.MeshCollisionAPI(p).GetApproximationAttr().Get() == "convexHull" for p in prims)
    assert all(UsdGeom.Imageable(p).ComputePurpose() == UsdGeom.Tokens.guide for p in prims)
    parts = convex_parts(str(paths.collision))
    assert 2 <= len(parts) <= CONVEX_PARTS_MAX
    everything = np.vstack([pts for pts, _ in parts])
    # the parts span the tray (the asset is centred on its bbox: 0.30 x 0.20 x 0.08 after Y-up -> Z-up)
    span = everything.max(0) - everything.min(0)
    assert np.allclose(sorted(span), sorted([0.30, 0.20, 0.08]), atol=0.02), span
    # ... and leave its hollow empty: the middle of the cavity lies in no part (one hull would fill it)
    cavity = (everything.min(0) + everything.max(0)) / 2  # mid-height, mid-tray: inside the walls, above the bottom
    inside = [Delaunay(pts).find_simplex(cavity[None, :])[0] >= 0 for pts, _ in parts]
    assert not any(inside), "a convex part fills the container's hollow"
    single_hull = Delaunay(everything)
    assert single_hull.find_simplex(cavity[None, :])[0] >= 0  # the point is inside the tray's overall hull
