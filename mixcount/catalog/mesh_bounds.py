"""Mesh facts of any capture within bounds: absurd coordinates refused with the reason, big meshes
measured exactly where it is cheap and analysed on a reduced copy where it is not (issue 60).

A 10 M-face PLY took 216 s and 7.2 GB with one worker: trimesh's processing (vertex merge, edge
grouping, cached triangles) and pymeshlab's decimation of the full mesh each hold several copies of it.
Above ``ingest.facts_face_budget`` faces, :func:`full_facts` measures on the model's own arrays, a
chunk at a time, what is exact and cheap: the box, the surface area, the signed volume, the counts and
whether every edge is shared by exactly two faces (watertight, after merging vertices at the same
position as trimesh does); :func:`cluster_copy` then reduces the mesh by vertex clustering (a grid of
cells sized so that about the budget of faces remain) for what needs a mesh object: the geometry hash,
the collision mesh and its convex proxy. The object records that its hash and collision mesh come from
a copy (``facts_note``) and ingest says so.

Coordinates: a vertex beyond :data:`ABSURD_M` metres from the origin (1e9 m: farther than anything on or
around the Earth, so no georeferenced capture either) is a unit or export error; so is inf / nan. Both
make the model broken with the reason, before any library computes with them (trimesh's vertex merge
casts coordinates x 1e8 to int64 and warned "invalid value encountered in cast" on stderr).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mixcount.errors import IngestError

ABSURD_M = 1e9  # no vertex of a real object lies farther from the origin (metres)
CHUNK = 1_000_000  # faces per chunk of the exact measures (a few tens of MB each)


def check_coordinates(vertices: np.ndarray) -> None:
    """IngestError when any vertex is inf / nan or farther than :data:`ABSURD_M` (the count and the worst)."""
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        bad = int(len(finite) - np.count_nonzero(finite))
        raise IngestError(f"mesh has non-finite vertex coordinates ({bad} of {len(vertices)} vertices hold inf or "
                          "nan): a broken export")
    if len(vertices) == 0:
        return
    peak = float(np.abs(vertices).max())
    if peak > ABSURD_M:
        far = int(np.count_nonzero(np.abs(vertices).max(axis=1) > ABSURD_M))
        raise IngestError(f"mesh is degenerate: absurd coordinates ({far} of {len(vertices)} vertices up to "
                          f"{peak:.3g} m from the origin, beyond {ABSURD_M:.0e} m): a unit or export error")


@dataclass(frozen=True)
class FullFacts:
    """What was measured on the whole mesh when the analysis used a reduced copy."""

    vertex_count: int  # after merging vertices at the same position (as trimesh's processing does)
    face_count: int
    extents: tuple[float, float, float]
    area: float
    watertight: bool
    volume: float | None
    copy_faces: int  # faces of the reduced copy the hash and collision mesh come from

    def note(self) -> str:
        return (f"big mesh: {self.face_count:,} faces; box, area, volume and watertightness measured on the whole "
                f"mesh, geometry hash and collision mesh from a {self.copy_faces:,}-face copy "
                "(ingest.facts_face_budget)")


def _merged_index(vertices: np.ndarray) -> tuple[np.ndarray, int]:
    """(inverse: vertex -> merged vertex, merged count): vertices equal to 1e-8 m are one (trimesh's rule)."""
    from trimesh.grouping import unique_rows

    unique, inverse = unique_rows(vertices, digits=8)
    return np.asarray(inverse, dtype=np.int64), int(len(unique))


def _watertight(faces: np.ndarray, inverse: np.ndarray, n_vertices: int) -> bool:
    """Every edge (of merged vertices) used by exactly two faces."""
    f = inverse[faces]
    keys = np.empty(3 * len(f), dtype=np.int64)
    for k, (a, b) in enumerate(((0, 1), (1, 2), (2, 0))):
        lo, hi = np.minimum(f[:, a], f[:, b]), np.maximum(f[:, a], f[:, b])
        keys[k * len(f):(k + 1) * len(f)] = lo * n_vertices + hi
    del f
    keys.sort()
    starts = np.flatnonzero(np.concatenate(([True], keys[1:] != keys[:-1])))
    counts = np.diff(np.concatenate((starts, [len(keys)])))
    return bool(len(counts) and np.all(counts == 2))


def full_facts(vertices: np.ndarray, faces: np.ndarray, copy_faces: int = 0) -> FullFacts:
    """Counts, box, area, watertightness and (closed meshes) volume of the whole mesh, in chunks."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    pts = vertices[used]
    extents = tuple(float(x) for x in (pts.max(axis=0) - pts.min(axis=0)))
    del pts
    area, volume = 0.0, 0.0
    for start in range(0, len(faces), CHUNK):
        tri = vertices[faces[start:start + CHUNK]]  # (n, 3, 3)
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area += float(np.sqrt((cross ** 2).sum(axis=1)).sum()) / 2.0
        volume += float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0
    inverse, merged = _merged_index(vertices)
    watertight = _watertight(faces, inverse, len(vertices))
    referenced = np.zeros(merged, dtype=bool)
    referenced[inverse[used]] = True
    return FullFacts(int(np.count_nonzero(referenced)), int(len(faces)), extents, area, watertight,  # type: ignore[arg-type]
                     abs(volume) if watertight else None, copy_faces)


def cluster_copy(vertices: np.ndarray, faces: np.ndarray, budget: int, area: float) -> tuple[np.ndarray, np.ndarray]:
    """A copy of about ``budget`` faces by vertex clustering: vertices in one grid cell become their mean,
    faces that collapse or repeat are dropped. The cell starts at sqrt(2 area / budget) (a surface of
    that area meshed at that spacing has about ``budget`` faces) and grows until the copy fits."""
    lo = vertices.min(axis=0)
    span = float(max((vertices.max(axis=0) - lo).max(), 1e-12))
    cell = max(float(np.sqrt(2.0 * max(area, 1e-24) / max(budget, 1))), span / 2_000_000.0)
    for _ in range(12):
        grid = np.floor((vertices - lo) / cell).astype(np.int64)
        n = int(grid.max()) + 1
        keys = (grid[:, 0] * n + grid[:, 1]) * n + grid[:, 2]
        del grid
        uniq, inverse = np.unique(keys, return_inverse=True)
        del keys
        f = inverse[faces]
        keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
        f = f[keep]
        f = np.unique(f, axis=0) if len(f) else f
        if len(f) <= 1.25 * budget or len(f) < 4:
            break
        cell *= float(np.sqrt(len(f) / budget))
    counts = np.bincount(inverse, minlength=len(uniq)).astype(np.float64)
    verts = np.stack([np.bincount(inverse, weights=vertices[:, k], minlength=len(uniq)) for k in range(3)], axis=1)
    verts /= np.maximum(counts, 1.0)[:, None]
    if len(f) == 0:
        raise IngestError("mesh is degenerate: nothing is left of it at its own scale")
    return verts, f.astype(np.int64)
