"""Faces a converted asset must not carry: degenerate or invalid triangles, found and dropped at conversion.

Blender 5.0's USD importer checks every face for a repeated vertex index; one such face and it warns
"Invalid face data detected for mesh ..." and runs a destructive ``BKE_mesh_validate`` over the mesh,
after which the import of a whole composed stage could segfault (issue 60: 2 of 6 ``settled.usda`` of a
115-capture library; exactly the stages holding assets with such triangles). Captures carry them (a
scanner's mesh welds two corners of a sliver), and trimesh loads with ``process=False`` keep them.

A triangle is dropped when it

* ``out_of_range``: names a vertex index below 0 or past the last point,
* ``non_finite``: touches a point with a NaN or infinite coordinate,
* ``repeated_vertex``: names the same vertex twice (Blender's "invalid face data"),
* ``zero_area``: has three distinct corners but no area at the precision written (float32 points):
  collinear or coincident corners, invisible and a source of NaN normals downstream.

Nothing else changes: points, normals, UVs and vertex colours stay indexed as they were (a point no
face uses any more is harmless); per-face colours are filtered with their faces. The counts go into
the asset layer's record (``customLayerData["mixcount"]["faces_removed"]``), so a user can see what
the converter took out.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

PROBLEMS = ("out_of_range", "non_finite", "repeated_vertex", "zero_area")


def bad_triangles(points: np.ndarray, faces: np.ndarray) -> dict[str, np.ndarray]:
    """One boolean mask per problem (PROBLEMS; the first that applies wins) over ``faces`` (T, 3)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    out_of_range = ((f < 0) | (f >= len(pts))).any(axis=1)
    safe = np.where(out_of_range[:, None], 0, f)
    if len(pts) == 0:
        safe = np.zeros_like(f)
        pts = np.zeros((1, 3))
    finite = np.isfinite(pts).all(axis=1)
    non_finite = ~out_of_range & ~finite[safe].all(axis=1)
    repeated = ~out_of_range & ~non_finite & ((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2]))
    written = np.where(finite[:, None], pts, 0.0).astype(np.float32).astype(np.float64)
    a, b, c = written[safe[:, 0]], written[safe[:, 1]], written[safe[:, 2]]
    zero = ~out_of_range & ~non_finite & ~repeated & (np.linalg.norm(np.cross(b - a, c - a), axis=1) == 0.0)
    return {"out_of_range": out_of_range, "non_finite": non_finite, "repeated_vertex": repeated, "zero_area": zero}


def clean_triangles(points: np.ndarray, faces: np.ndarray,
                    per_face: Optional[np.ndarray] = None) -> tuple[np.ndarray, Optional[np.ndarray], dict[str, int]]:
    """``faces`` without the bad ones, ``per_face`` values (one row per face, or None) filtered alike,
    and how many of each problem were dropped (only problems that occurred)."""
    masks = bad_triangles(points, faces)
    bad = np.zeros(len(np.asarray(faces).reshape(-1, 3)), dtype=bool)
    for m in masks.values():
        bad |= m
    counts = {k: int(m.sum()) for k, m in masks.items() if m.any()}
    keep = ~bad
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)[keep]
    if per_face is not None and len(per_face) == len(keep):
        per_face = np.asarray(per_face)[keep]
    return f, per_face, counts


def add_counts(total: dict[str, int], more: dict[str, int]) -> dict[str, int]:
    """``total`` plus ``more``, key by key (both maps of problem -> faces)."""
    for k, v in more.items():
        total[k] = total.get(k, 0) + int(v)
    return total


def polygon_problems(counts: np.ndarray, indices: np.ndarray, n_points: int) -> np.ndarray:
    """Per polygon of a USD mesh (faceVertexCounts / faceVertexIndices): True when it has fewer than 3
    corners, an index out of range or a repeated index (what Blender's importer calls invalid)."""
    counts = np.asarray(counts, dtype=np.int64)
    idx = np.asarray(indices, dtype=np.int64)
    bad = counts < 3
    if counts.sum() != len(idx):
        return np.ones(len(counts), dtype=bool)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]) if len(counts) else np.zeros(0, dtype=np.int64)
    out = (idx < 0) | (idx >= n_points)
    face_of = np.repeat(np.arange(len(counts)), counts)
    bad |= np.bincount(face_of, weights=out, minlength=len(counts)) > 0
    for k in np.flatnonzero(~bad & (counts > 3)):  # polygons: a set per face (rare in converted assets)
        ring = idx[starts[k]:starts[k] + counts[k]]
        bad[k] = len(np.unique(ring)) != len(ring)
    tri = ~bad & (counts == 3)
    if tri.any():
        s = starts[tri]
        a, b, c = idx[s], idx[s + 1], idx[s + 2]
        bad[np.flatnonzero(tri)] = (a == b) | (b == c) | (a == c)
    return bad
