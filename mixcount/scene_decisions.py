"""The worker's pure decisions (numpy and scipy only, no bpy): which settled bodies are kept, which
objects are in the frame and visible enough, what a scene's status is, and how Cycles' passes become the
stored depth / normal / instance maps. :mod:`mixcount.engine.scene_job` calls these between Blender steps;
tests/test_blender_decisions.py checks them without Blender.

A room of its own (issue 58), not under ``annotate/``: these are what the worker decides about a scene,
not annotation maths. It sits above ``annotate/`` (whose camera model it uses) and below ``worker/`` (whose
contract re-exports its statuses); the count target's own worker decisions are
:mod:`mixcount.counts.worker_decisions`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, NamedTuple, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.annotate.raster import PinholeCamera

Array = NDArray[Any]

# a scene's status (the worker contract re-exports these for the SceneResult it carries)
STATUS_OK = "ok"
STATUS_EMPTY = "empty"  # no counted object survived: the caller regenerates from the next seed
STATUS_REJECTED = "rejected"  # the final visibility re-check failed

BELOW_FLOOR = "below_floor"
FLUNG_OUT = "flung_out"
UNSTABLE = "unstable"
INTERPENETRATION = "interpenetration"
OUTSIDE_FRAME = "origin_outside_frame"
OCCLUDED = "occluded"
NO_SPOT_IN_VIEW = "no_spot_in_view"  # a distractor that found no free floor in every camera's view

BACKGROUND_DEPTH = 1e9  # Cycles writes 1e10 where a pixel sees no surface
MAX_VISIBILITY_ROUNDS = 3  # re-renders of the id pass after dropping occluded objects


# ------------------------------------------------------------------------------------ settling


def settle_verdict(matrix_world: Array, min_z: float, size_m: float, *, floor_shape: str,
                   half_extent: tuple[float, float], below_floor_fraction: float) -> Optional[str]:
    """Why a settled body must be dropped, or None to keep it.

    ``unstable``: a non-finite pose; ``below_floor``: its centre under z = 0 or its lowest vertex more
    than ``below_floor_fraction`` of its size under it; ``flung_out``: its centre outside the floor's
    footprint (a disc of radius ``half_extent[0]`` for a cylinder floor, a rectangle otherwise).
    """
    m = np.asarray(matrix_world, dtype=np.float64)
    if not np.isfinite(m).all():
        return UNSTABLE
    c = m[:3, 3]
    if c[2] < 0 or not np.isfinite(min_z) or min_z < -below_floor_fraction * size_m:
        return BELOW_FLOOR
    hx, hy = float(half_extent[0]), float(half_extent[1])
    if floor_shape == "cylinder":
        outside = float(np.hypot(c[0], c[1])) > hx
    else:
        outside = abs(c[0]) > hx or abs(c[1]) > hy
    return FLUNG_OUT if outside else None


def world_bounds(local_columns: Array, matrix_world: Array) -> tuple[Array, Array]:
    """World-space AABB (lo, hi) of a mesh whose local vertices are the columns of ``local_columns``
    (3, V); NaN bounds when the matrix is not finite (a body the simulation blew up).

    Rotating the columns and reducing each row reads memory in order: on a 400k-vertex capture ~5x
    faster than reducing an (V, 3) array over its first axis, which the settle checks did per body.
    """
    m = np.asarray(matrix_world, dtype=np.float64)
    if not np.isfinite(m).all() or local_columns.shape[1] == 0:
        nan = np.full(3, np.nan)
        return nan, nan.copy()
    w = m[:3, :3] @ local_columns
    return w.min(axis=1) + m[:3, 3], w.max(axis=1) + m[:3, 3]


def deepen_below_top(local_vertices: Array, matrix_world: Array, depth: float) -> Optional[Array]:
    """World vertices of a floor slab with every vertex under its top face moved to ``depth`` metres
    under the top (the floor collider); None when the slab is already that deep (or ``depth`` <= 0).

    Vertices within 1e-6 m of the highest one form the top face and stay; the rest (the slab's bottom
    rim) go down, so outline and top are unchanged and the convex hull becomes a deep solid.
    """
    m = np.asarray(matrix_world, dtype=np.float64)
    world = np.asarray(local_vertices, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]
    if depth <= 0 or len(world) == 0:
        return None
    top = float(world[:, 2].max())
    below = world[:, 2] < top - 1e-6
    if not below.any() or float(world[below, 2].min()) <= top - depth:
        return None
    world[below, 2] = top - depth
    return np.asarray(world)


def hull_equations(local_vertices: Array) -> Array:
    """Half-space equations (n, d) of the convex hull: inside where n.x + d <= 0."""
    from scipy.spatial import ConvexHull

    pts = np.unique(np.round(np.asarray(local_vertices, dtype=np.float64), 9), axis=0)
    try:
        return np.asarray(ConvexHull(pts).equations)
    except Exception:  # degenerate (flat) meshes: an axis-aligned box instead
        lo, hi = pts.min(0), pts.max(0)
        eqs = []
        for ax in range(3):
            n = np.zeros(3)
            n[ax] = 1.0
            eqs.append(np.r_[n, -hi[ax]])
            eqs.append(np.r_[-n, lo[ax]])
        return np.array(eqs)


def penetration_depth(point_world: Array, matrix_world: Array, equations: Array) -> float:
    """How deep (world metres, > 0 inside) a point lies inside a body's hull (uniform scale assumed)."""
    inv = np.linalg.inv(matrix_world)
    p = inv[:3, :3] @ point_world + inv[:3, 3]
    scale = float(np.cbrt(abs(np.linalg.det(matrix_world[:3, :3]))))
    signed = equations[:, :3] @ p + equations[:, 3]
    return float(-signed.max() * scale)


@dataclass(frozen=True)
class SettledBody:
    """A body that passed :func:`settle_verdict`: pose, world AABB, local hull equations and size."""

    matrix_world: Array
    aabb_min: Array
    aabb_max: Array
    hull: Array
    size_m: float


def interpenetrations(bodies: Sequence[SettledBody], fraction: float) -> list[tuple[int, int, float]]:
    """Deep overlaps: (dropped index, other index, depth) for every pair whose centre lies inside the
    other's hull deeper than ``fraction`` of the smaller size. In each pair the later body (the higher
    instance id) is dropped; a dropped body is not compared again."""
    dropped: set[int] = set()
    out: list[tuple[int, int, float]] = []
    for i, a in enumerate(bodies):
        if i in dropped:
            continue
        for j in range(i + 1, len(bodies)):
            if j in dropped:
                continue
            b = bodies[j]
            if np.any(a.aabb_max < b.aabb_min) or np.any(b.aabb_max < a.aabb_min):
                continue
            ma, mb = np.asarray(a.matrix_world), np.asarray(b.matrix_world)
            depth = max(penetration_depth(ma[:3, 3], mb, b.hull), penetration_depth(mb[:3, 3], ma, a.hull))
            if depth > fraction * min(a.size_m, b.size_m):
                dropped.add(j)
                out.append((j, i, depth))
    return out


# ------------------------------------------------------------------------------------ frame and visibility


def points_in_frame(camera: PinholeCamera, points: Array) -> tuple[Array, Array]:
    """World points (N, 3) -> their pixel positions (N, 2; x = column, y = row) and whether each lies
    in the image in front of the camera (the frame check's rule, for many origins at once)."""
    px, depth = camera.project(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    inside = ((depth > camera.near) & (px[:, 0] >= 0) & (px[:, 0] < camera.width)
              & (px[:, 1] >= 0) & (px[:, 1] < camera.height))
    return px, inside


def may_still_be_kept(camera: PinholeCamera, centres: Array) -> Array:
    """Bool per body centre (N, 3), during the simulation: may the body still end kept? Not when its
    centre is under the floor's top (z = 0; dropped as below_floor) nor when neither its origin nor the
    floor point under it is in the camera frame (it lies or rolls on the floor outside the view, and
    the frame check drops it). A body in the air above the view (falling into it) may."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    below = c * np.array([1.0, 1.0, 0.0])
    in_view = points_in_frame(camera, c)[1] | points_in_frame(camera, below)[1]
    return np.asarray((c[:, 2] >= 0.0) & in_view)


def near_the_pile(centre_xy: Array, radius: float, centres: Array) -> Array:
    """Bool per body centre (N, 3), during the simulation, when the cameras are framed after it: may the
    body still end kept? Not under the floor's top (z = 0), nor farther than ``radius`` (horizontally)
    from ``centre_xy``, where no camera framed on the pile will see it."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    far = np.hypot(c[:, 0] - centre_xy[0], c[:, 1] - centre_xy[1]) > radius
    return np.asarray((c[:, 2] >= 0.0) & ~far)


def origin_in_frame(camera: PinholeCamera, matrix_world: Array) -> tuple[tuple[float, float], bool]:
    """The projected origin (x = column, y = row) and whether it lies in the image in front of the camera."""
    m = np.asarray(matrix_world, dtype=np.float64)
    px, inside = points_in_frame(camera, m[None, :3, 3])
    return (float(px[0, 0]), float(px[0, 1])), bool(inside[0])


class Visibility(NamedTuple):
    """One object's visibility in an id pass: visible pixels, amodal pixels and their ratio."""

    visible_px: int
    amodal_px: int
    visibility: float


def changed_region(index: Array, dropped_ids: Sequence[int]) -> Optional[tuple[int, int, int, int]]:
    """The pixels an id pass changes once ``dropped_ids`` leave the scene: the inclusive bounding box
    (row0, col0, row1, col1) of the pixels they were seen at, or None when none was seen (then nothing
    changes). The id pass records only the first surface along each pixel-centre ray (no bounces), so
    removing an object changes exactly the pixels where it was that first surface."""
    seen = np.isin(index, np.asarray(list(dropped_ids), dtype=index.dtype))
    if not seen.any():
        return None
    rows = np.nonzero(seen.any(axis=1))[0]
    cols = np.nonzero(seen.any(axis=0))[0]
    return int(rows[0]), int(cols[0]), int(rows[-1]), int(cols[-1])


def paste_region(before: Mapping[str, Array], region_render: Mapping[str, Array],
                 region: tuple[int, int, int, int]) -> dict[str, Array]:
    """The id passes after a border re-render: ``before`` everywhere, ``region_render`` inside ``region``."""
    row0, col0, row1, col1 = region
    out = {}
    for key, arr in before.items():
        merged = arr.copy()
        merged[row0:row1 + 1, col0:col1 + 1] = region_render[key][row0:row1 + 1, col0:col1 + 1]
        out[key] = merged
    return out


def amodal_mask(silhouette: Array, index: Array, instance_id: int) -> Array:
    """The object's amodal (unoccluded) mask inside the frame: its rasterised silhouette united with its
    visible pixels in the id pass, so the amodal mask always contains the visible one (the rasteriser and
    Cycles may disagree on a pixel at the silhouette's edge)."""
    return np.logical_or(np.asarray(silhouette, dtype=bool), np.asarray(index) == int(instance_id))


def measure_visibility(index: Array, silhouettes: Mapping[int, Array]) -> dict[int, Visibility]:
    """instance id -> :class:`Visibility` with visibility = visible / amodal pixels (BOP's visib_fract).

    Both counts are pixels of the frame: the part of an object outside the image is in neither, so
    truncation by the frame border does not lower visibility (only occlusion does)."""
    # visible pixels of every id from one bincount; amodal = silhouette + visible - both, where "both"
    # reads the id map at the silhouette's pixels only (two 1M-pixel passes per object fewer at 1024²)
    flat = np.asarray(index).ravel()
    counts = np.bincount(flat) if flat.dtype.kind in "iu" and flat.size and flat.min() >= 0 else None
    out = {}
    for inst, sil in silhouettes.items():
        inst = int(inst)
        if counts is not None:
            v = int(counts[inst]) if 0 <= inst < len(counts) else 0
        else:
            v = int(np.count_nonzero(flat == inst))
        s = np.asarray(sil, dtype=bool).ravel()
        a = int(np.count_nonzero(s)) + v - int(np.count_nonzero(flat[s] == inst))
        out[inst] = Visibility(v, a, float(v / a) if a > 0 else 0.0)
    return out


def occluded(visibility: Mapping[int, float], threshold: float) -> list[int]:
    """Instance ids to drop (counted objects and distractors alike): occlusion (1 - visibility) >= the
    visibility threshold v_t, so a kept object is more than 1 - v_t visible."""
    return [i for i, v in visibility.items() if v <= 1.0 - threshold]


def scene_status(counted_visibility: Mapping[int, float], threshold: float,
                 distractor_visibility: Optional[Mapping[int, float]] = None) -> tuple[str, list[int]]:
    """The final re-check: "empty" with no counted object left, "rejected" (and the failing ids) when a
    kept counted object or distractor is less than 1 - v_t visible, else "ok"."""
    if not counted_visibility:
        return STATUS_EMPTY, []
    every = {**counted_visibility, **(distractor_visibility or {})}
    failing = [i for i, v in every.items() if v < 1.0 - threshold]
    return (STATUS_REJECTED, failing) if failing else (STATUS_OK, [])


# ------------------------------------------------------------------------------------ passes


def background_mask(depth_pass: Array) -> Array:
    """Pixels that see no surface (Cycles' depth 1e10)."""
    return np.asarray(depth_pass) > BACKGROUND_DEPTH


def planar_depth(depth_pass: Array) -> Array:
    """Cycles' Depth pass -> float32 planar depth along the optical axis (metres), 0 where no surface.

    Blender 5.0's Cycles Depth pass is already planar (checked against ray-plane intersections with the
    floor in tests/test_blender_worker.py), so only the background changes."""
    d = np.asarray(depth_pass, dtype=np.float32).copy()
    d[background_mask(depth_pass)] = 0.0
    return d


def camera_normals(normal_world: Array, cam_to_world: Array, depth_pass: Array) -> Array:
    """World-space normals (H, W, 3) -> float32 camera space (x right, y up, z towards the camera), 0 on
    the background."""
    R = np.asarray(cam_to_world, dtype=np.float64)[:3, :3]
    n = np.asarray(normal_world, dtype=np.float64) @ R  # R^T n in row-vector form
    n[background_mask(depth_pass)] = 0.0
    return n.astype(np.float32)


def instance_map(index: Array, keep_ids: Sequence[int]) -> Array:
    """int32 id pass with only ``keep_ids`` (kept counted objects and distractors); 0 elsewhere."""
    ids = np.asarray(index).astype(np.int32)
    ids[~np.isin(ids, list(keep_ids))] = 0
    return ids
