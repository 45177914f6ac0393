"""Collision proxies: one convex hull per object with a bounded number of vertices.

Counted objects and distractors collide in Bullet as convex hulls. Bullet's hull shape keeps every vertex
it is given and its support function visits all of them on every contact query, so a capture of 200k
faces as its own hull makes physics the slowest step of a scene. The proxy is the hull reduced to at most
``max_vertices`` points (config ``ingest.proxy_max_vertices``):

1. the convex hull of the input points (the object's collision mesh, or its full mesh);
2. if that hull has more vertices than allowed, a greedy "furthest point outside" selection among its
   vertices: start from the extreme points along 13 directions, then repeatedly add the hull vertex
   lying furthest outside the hull of the points chosen so far (an incremental quickhull stopped at
   ``max_vertices`` points). The result is an inner approximation whose worst gap is reported as
   ``error_m`` (the largest distance of any input point outside the proxy).

The proxy is written as a binary PLY in the catalog's collision folder, in the same frame as the collision
mesh (metres, Z-up, un-centred), named by geometry hash and budget so a rebuild with the same inputs
reuses it. Pure numpy + scipy (qhull) + trimesh for the file; no bpy.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mixcount.atomic import atomic_path
from mixcount.errors import IngestError

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

    from mixcount.catalog.models import CatalogObject

# extreme points along the 3 axes, 6 face diagonals' halves and 4 body diagonals seed the selection
_SEED_DIRECTIONS = np.array(
    [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -1, 0], [1, 0, 1], [1, 0, -1], [0, 1, 1], [0, 1, -1],
     [1, 1, 1], [1, 1, -1], [1, -1, 1], [-1, 1, 1]], dtype=np.float64)


@dataclass(frozen=True)
class Proxy:
    """A convex proxy: vertices (N, 3), outward triangles (F, 3) and the worst inner gap in metres."""

    vertices: np.ndarray
    faces: np.ndarray
    error_m: float


@dataclass(frozen=True)
class ProxyFacts:
    path: str
    vertex_count: int
    error_m: float


def proxy_name(geometry_hash: str, max_vertices: int) -> str:
    return f"{geometry_hash[:32]}_hull{int(max_vertices)}.ply"


def _hull(points: np.ndarray) -> Any:
    from scipy.spatial import ConvexHull, QhullError

    try:
        return ConvexHull(points)
    except QhullError:
        try:  # flat or nearly flat input: joggle the points so qhull builds a thin hull
            return ConvexHull(points, qhull_options="QJ")
        except QhullError as exc:
            raise IngestError(f"cannot build a convex proxy: {str(exc).strip().splitlines()[0][:160]}") from None


def _outside(points: np.ndarray, equations: np.ndarray) -> np.ndarray:
    """Signed distance of each point outside a hull given by qhull's plane equations (<= 0 inside)."""
    return (points @ equations[:, :3].T + equations[:, 3]).max(axis=1)


def convex_proxy(points: np.ndarray, max_vertices: int) -> Proxy:
    """The convex hull of ``points`` with at most ``max_vertices`` vertices (see the module docstring)."""
    pts = np.asarray(points, dtype=np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 4:
        raise IngestError(f"cannot build a convex proxy from {len(pts)} points")
    if max_vertices < 4:
        raise IngestError(f"proxy_max_vertices must be at least 4, not {max_vertices}")
    full = _hull(pts)
    candidates = pts[full.vertices]
    if len(candidates) > max_vertices:
        centred = candidates - candidates.mean(axis=0)
        seeds: list[int] = []
        for d in _SEED_DIRECTIONS:
            proj = centred @ d
            for k in (int(proj.argmax()), int(proj.argmin())):
                if k not in seeds:
                    seeds.append(k)
        chosen = seeds[: max(4, min(len(seeds), max_vertices // 2))]
        # quickhull rounds stopped at the budget: every facet of the current hull proposes the point furthest
        # outside it, and the furthest half of the proposals (at least one) join. A point inside the growing
        # hull stays inside, so only points still outside remain candidates.
        pending = np.setdiff1d(np.arange(len(candidates)), chosen)
        while len(chosen) < max_vertices and len(pending):
            eq = _hull(candidates[chosen]).equations
            signed = candidates[pending] @ eq[:, :3].T + eq[:, 3]
            facet = signed.argmax(axis=1)
            dist = signed[np.arange(len(pending)), facet]
            outside = dist > 1e-9
            if not outside.any():
                break
            pending, facet, dist = pending[outside], facet[outside], dist[outside]
            order = np.lexsort((-dist, facet))  # by facet, furthest first
            first = order[np.r_[True, facet[order][1:] != facet[order][:-1]]]
            best = first[np.argsort(-dist[first])]
            take = best[: max(1, min(len(best) // 2 or 1, max_vertices - len(chosen)))]
            chosen.extend(int(k) for k in pending[take])
            pending = np.delete(pending, take)
        candidates = candidates[chosen]
    hull = _hull(candidates)
    used = np.unique(hull.simplices)
    remap = np.full(len(candidates), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    verts = candidates[used]
    faces = remap[hull.simplices]
    # qhull's simplices are unoriented: turn each triangle so its normal agrees with the plane equation
    normals = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    flip = (normals * hull.equations[:, :3]).sum(axis=1) < 0
    faces[flip] = faces[flip][:, ::-1]
    error = float(max(0.0, _outside(pts, hull.equations).max()))
    return Proxy(verts, faces, error)


def write_proxy(proxy: Proxy, out_path: Path) -> None:
    """Binary PLY, written to a temporary name and renamed (a killed worker leaves no half file)."""
    import trimesh

    out_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out_path) as tmp:
        trimesh.Trimesh(vertices=proxy.vertices, faces=proxy.faces, process=False).export(str(tmp), file_type="ply")


def read_proxy(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a proxy PLY."""
    import trimesh

    mesh = trimesh.load(str(path), force="mesh", process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def build_proxy(points: np.ndarray, out_path: Path, max_vertices: int) -> ProxyFacts:
    """Build (or reuse, when ``out_path`` exists) the proxy of ``points`` and return its facts."""
    if out_path.is_file():
        try:
            verts, _faces = read_proxy(out_path)
            if 4 <= len(verts) <= max_vertices:
                return ProxyFacts(str(out_path.resolve()), int(len(verts)), float("nan"))
        except Exception:  # noqa: BLE001 - an unreadable leftover is rebuilt
            pass
    proxy = convex_proxy(points, max_vertices)
    write_proxy(proxy, out_path)
    return ProxyFacts(str(out_path.resolve()), int(len(proxy.vertices)), proxy.error_m)


def proxy_from_collision(collision_path: str | Path, geometry_hash: str, out_dir: Path,
                         max_vertices: int) -> ProxyFacts:
    """The proxy of an already-ingested object, from its stored collision mesh (no re-analysis)."""
    import trimesh

    path = Path(collision_path)
    if not path.is_file():
        raise IngestError(f"collision mesh {path} does not exist")
    mesh = trimesh.load(str(path), force="mesh", process=False)
    return build_proxy(np.asarray(mesh.vertices), Path(out_dir) / proxy_name(geometry_hash, max_vertices),
                       max_vertices)


def is_current(proxy_path: str | None, max_vertices: int) -> bool:
    """Whether a stored proxy path exists and was built with this vertex budget."""
    if not proxy_path:
        return False
    p = Path(proxy_path)
    return p.is_file() and p.name.endswith(f"_hull{int(max_vertices)}.ply")


def refresh_proxy(session: "Session", obj: "CatalogObject", collision_dir: Path, max_vertices: int) -> bool:
    """Build the collision proxy of an already-ingested object from its stored collision mesh when it has
    none (a catalog from before proxies) or one of another budget; updates the row in place (same id,
    no re-analysis). Returns whether it wrote. A failure leaves the row without proxy: the compositor
    then collides through the full mesh's hull, as before proxies existed."""
    if is_current(obj.proxy_path, max_vertices) or not obj.collision_path or not obj.geometry_hash:
        return False
    try:
        facts = proxy_from_collision(obj.collision_path, obj.geometry_hash, collision_dir, max_vertices)
    except IngestError:
        return False
    obj.proxy_path, obj.proxy_vertex_count = facts.path, facts.vertex_count
    session.commit()
    return True
