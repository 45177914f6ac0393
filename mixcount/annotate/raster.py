"""Silhouette rasterisation in numpy: the unoccluded mask of an object without a render per object.

The paper renders every object alone to learn how many pixels it would cover unoccluded; that is ~80 %
of a scene's time. An object's unoccluded silhouette is just the union of its projected triangles, so it
needs no depth test: project the full mesh with the exact pinhole camera and mark every pixel whose
centre lies inside any triangle. Cycles with one sample and a tiny pixel filter samples exactly the pixel
centres, so the two agree to a fraction of a percent IoU (checked against the one-render-per-object
oracle in tests/test_blender_worker.py).

Conventions: image rows go down, columns right; pixel (r, c) has its centre at (c + 0.5, r + 0.5).
Camera space is Blender's / USD's: x right, y up, the camera looks down -z.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

# triangle bounding boxes up to this many pixels a side are filled in one vectorised batch per size
_BUCKETS = (1, 2, 4, 8, 16, 32, 64)
_BATCH_PIXELS = 4_000_000  # cap on T * B * B per numpy batch (memory)


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics in pixels plus the camera-to-world matrix (4x4, Blender/USD camera convention)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    cam_to_world: NDArray[Any]
    near: float = 1e-4

    @classmethod
    def from_physical(cls, focal_mm: float, sensor_width_mm: float, width: int, height: int,
                      cam_to_world: NDArray[Any], near: float = 1e-4) -> "PinholeCamera":
        """Horizontal sensor fit with square pixels (what the worker sets in Blender)."""
        fx = focal_mm / sensor_width_mm * width
        return cls(fx, fx, width / 2.0, height / 2.0, int(width), int(height),
                   np.asarray(cam_to_world, dtype=np.float64), near)

    @property
    def K(self) -> NDArray[Any]:
        """The OpenCV-style intrinsic matrix (x right, y down, z forward)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def world_to_cam(self, points: NDArray[Any]) -> NDArray[Any]:
        inv = np.linalg.inv(self.cam_to_world)
        pts = np.asarray(points, dtype=np.float64)
        return np.asarray(pts @ inv[:3, :3].T + inv[:3, 3])

    def project(self, points: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any]]:
        """World points (N, 3) -> pixel coordinates (N, 2) (x = column, y = row) and depth (N,) along
        the viewing axis (positive in front of the camera)."""
        pc = self.world_to_cam(points)
        depth = -pc[:, 2]
        safe = np.where(np.abs(depth) < 1e-12, 1e-12, depth)
        x = self.cx + self.fx * pc[:, 0] / safe
        y = self.cy - self.fy * pc[:, 1] / safe
        return np.stack([x, y], axis=1), depth


def _fill_batch(mask: NDArray[Any], xs: list[NDArray[Any]], ys: list[NDArray[Any]], x0: NDArray[Any],
                y0: NDArray[Any], b: int) -> None:
    """Mark pixels of a b x b window at (x0, y0) whose centres lie inside each triangle (corner
    coordinates ``xs``, ``ys``: three (T,) rows each). With ``b = 1`` (a box holding one centre, nearly
    all of a dense capture's triangles) the same arithmetic runs on the 1-D rows, without windows."""
    h, w = mask.shape
    if b == 1:
        def at(a: NDArray[Any]) -> NDArray[Any]:
            return a
        px, py = x0 + 0.5, y0 + 0.5
    else:
        def at(a: NDArray[Any]) -> NDArray[Any]:
            return a[:, None, None]
        d = np.arange(b)
        px = x0[:, None, None] + d[None, None, :] + 0.5  # (T, 1, b)
        py = y0[:, None, None] + d[None, :, None] + 0.5  # (T, b, 1)

    def edge(p: int, q: int) -> NDArray[Any]:
        return np.asarray(at(xs[q] - xs[p]) * (py - at(ys[p])) - at(ys[q] - ys[p]) * (px - at(xs[p])))

    e0, e1, e2 = edge(0, 1), edge(1, 2), edge(2, 0)
    inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
    if b == 1:
        t = np.nonzero(inside)[0]
        cols, rows = x0[t], y0[t]
    else:
        t, ry, rx = np.nonzero(inside)
        cols, rows = x0[t] + rx, y0[t] + ry
    ok = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
    mask[rows[ok], cols[ok]] = True


def _between_centre_lines(coord: NDArray[Any], size: int, corners: NDArray[Any]) -> NDArray[Any]:
    """Bool (T,): True for triangles whose three corners lie strictly between the same two pixel-centre
    lines along one axis (``coord`` per vertex, ``size`` pixels on that axis): their box holds no centre.

    One int32 cell per vertex, three gathers a triangle: cheaper than the box arithmetic of
    :func:`_rasterize`, which needs six float gathers. A corner exactly on a centre line gets a cell of its
    own, so its triangles are never culled here; cells beyond the frame collapse to -1 / ``size`` (a
    triangle wholly outside the frame is culled, as the box test would cull it)."""
    g = coord - 0.5
    f = np.floor(g)
    cell = np.clip(f, -1, size).astype(np.int32)
    on = np.nonzero(g == f)[0]
    if len(on):
        cell[on] = -2 - np.arange(len(on), dtype=np.int32)
    a, b, c = cell[corners[0]], cell[corners[1]], cell[corners[2]]
    return np.asarray((a == b) & (b == c))


def _cull_between_centres(x: NDArray[Any], y: NDArray[Any], corners: NDArray[Any],
                          shape: tuple[int, int]) -> NDArray[Any]:
    """``corners`` without the triangles :func:`_between_centre_lines` finds on either axis.

    A dense capture seen small has most triangles between pixel centres (a 313k-face asset 60 px across:
    13 % survive), and the cull halves its silhouette's time. A large one has few such triangles and the
    cull would only add passes, so an axis that culls less than a third is not applied."""
    for coord, size in ((x, shape[1]), (y, shape[0])):
        if corners.shape[1] == 0:
            break
        kept = ~_between_centre_lines(coord, size, corners)
        if 3 * int(np.count_nonzero(kept)) <= 2 * corners.shape[1]:
            corners = np.compress(kept, corners, axis=1)
    return corners


def rasterize_triangles(points2d: NDArray[Any], triangles: NDArray[Any], shape: tuple[int, int],
                        valid: NDArray[Any] | None = None) -> NDArray[Any]:
    """Boolean (H, W) mask of the union of 2-D triangles (pixel centres inside any triangle).

    ``points2d`` (V, 2) in pixels (x = column, y = row), ``triangles`` (T, 3) vertex indices,
    ``valid`` an optional (V,) bool: triangles touching an invalid vertex (behind the camera) are skipped.
    """
    pts = np.asarray(points2d, dtype=np.float64)
    corners = np.ascontiguousarray(np.asarray(triangles, dtype=np.int64).reshape(-1, 3).T)
    return _rasterize(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]), corners, shape, valid)


def _rasterize(x: NDArray[Any], y: NDArray[Any], corners: NDArray[Any], shape: tuple[int, int],
               valid: NDArray[Any] | None = None) -> NDArray[Any]:
    """:func:`rasterize_triangles` on vertex coordinate rows ``x``, ``y`` (V,) and ``corners`` (3, T),
    the triangles' vertex indices as three contiguous rows (gathers from them are ~2x faster than from
    the columns of a (T, 3) array, and a caller can keep them per mesh)."""
    h, w = int(shape[0]), int(shape[1])
    mask = np.zeros((h, w), dtype=bool)
    if corners.shape[1] == 0:
        return mask
    if valid is not None and not np.all(valid):
        v = np.asarray(valid)
        corners = corners[:, v[corners[0]] & v[corners[1]] & v[corners[2]]]
    corners = _cull_between_centres(x, y, corners, (h, w))
    # per-corner coordinate rows: element-wise min/max over three arrays is ~10x faster than a
    # reduction over a length-3 axis, and the windows are filled from the same rows (no (T, 3, 2) array)
    xs = [x[corners[k]] for k in range(3)]
    ys = [y[corners[k]] for k in range(3)]
    x0 = np.ceil(np.minimum(np.minimum(xs[0], xs[1]), xs[2]) - 0.5).astype(np.int64)
    x1 = np.floor(np.maximum(np.maximum(xs[0], xs[1]), xs[2]) - 0.5).astype(np.int64)
    y0 = np.ceil(np.minimum(np.minimum(ys[0], ys[1]), ys[2]) - 0.5).astype(np.int64)
    y1 = np.floor(np.maximum(np.maximum(ys[0], ys[1]), ys[2]) - 0.5).astype(np.int64)
    np.maximum(x0, 0, out=x0)
    np.maximum(y0, 0, out=y0)
    np.minimum(x1, w - 1, out=x1)
    np.minimum(y1, h - 1, out=y1)
    keep = np.nonzero((x1 >= x0) & (y1 >= y0))[0]
    xs, ys = [a[keep] for a in xs], [a[keep] for a in ys]
    x0c, y0c, x1c, y1c = x0[keep], y0[keep], x1[keep], y1[keep]
    size = np.maximum(x1c - x0c, y1c - y0c) + 1
    done = np.zeros(len(keep), dtype=bool)
    for b in _BUCKETS:
        sel = np.nonzero(~done & (size <= b))[0]
        done[sel] = True
        step = max(1, _BATCH_PIXELS // (b * b))
        for k in range(0, len(sel), step):
            s = sel[k:k + step]
            _fill_batch(mask, [a[s] for a in xs], [a[s] for a in ys], x0c[s], y0c[s], b)
    for i in np.nonzero(~done)[0]:  # large triangles: one window each
        bw = int(x1c[i] - x0c[i] + 1)
        bh = int(y1c[i] - y0c[i] + 1)
        b = max(bw, bh)
        one_x, one_y = [a[i:i + 1] for a in xs], [a[i:i + 1] for a in ys]
        # split big windows into 64-pixel tiles to bound memory
        for ty in range(0, bh, 64):
            for tx in range(0, bw, 64):
                _fill_batch(mask, one_x, one_y, x0c[i:i + 1] + tx, y0c[i:i + 1] + ty, min(64, b))
    return mask


def silhouette(camera: PinholeCamera, vertices_world: NDArray[Any], triangles: NDArray[Any]) -> NDArray[Any]:
    """The unoccluded mask of one mesh (world-space vertices) seen by ``camera``."""
    pts, depth = camera.project(vertices_world)
    return rasterize_triangles(pts, triangles, (camera.height, camera.width), valid=depth > camera.near)


def placed_silhouette(camera: PinholeCamera, local_rows: NDArray[Any], corners: NDArray[Any],
                      matrix_world: NDArray[Any]) -> NDArray[Any]:
    """:func:`silhouette` of a mesh placed by ``matrix_world`` (4x4), from its local vertices as rows
    (3, V) and its triangles' corners as rows (3, T), both kept per mesh by the caller.

    One 3x3 product maps the local vertices straight into camera space (rows in, rows out): a world
    copy of the vertices and a (V, 2) pixel array are never made. Up to rounding in the last bits of
    the camera-space coordinates, the mask is :func:`silhouette`'s."""
    to_cam = np.linalg.inv(camera.cam_to_world) @ np.asarray(matrix_world, dtype=np.float64)
    pc = to_cam[:3, :3] @ local_rows + to_cam[:3, 3:4]
    depth = -pc[2]
    safe = np.where(np.abs(depth) < 1e-12, 1e-12, depth)
    x = camera.cx + camera.fx * pc[0] / safe
    y = camera.cy - camera.fy * pc[1] / safe
    return _rasterize(x, y, corners, (camera.height, camera.width), valid=depth > camera.near)
