"""Density maps for density-regression counters (FamNet/CounTR style and LOCA/DAVE/GeCo style).

Both maps are float32 (H, W) arrays saved with ``np.save`` and sum to the object count.

``adaptive_density_map`` (``gt_density_map_adaptive_384_VarV2``): FSC-147's geometry-adaptive rule as its
authors describe it (Ranjan et al., "Learning To Count Everything", 2021): each dot is a Gaussian whose
window is the mean distance to its ``k = 3`` nearest neighbouring dots, with ``sigma = window / 4``. A
dot without neighbours (a class of one) uses the mean exemplar box side as its window; sigma is at least
1 px. Each Gaussian is cut at 3 sigma and renormalised over the pixels that fall inside the image, so a
dot near the border still adds exactly 1 and the map sums to the count.

``loca_object_density_map`` (``gt_density_map_adaptive_512_512_object_VarV2``): what LOCA's
``utils/data.py::generate_density_maps`` computes, step for step: dots scaled to 512 x 512 and truncated
to integer pixels (clipped inside), one unit per dot, then ``scipy.ndimage.gaussian_filter`` with
``sigma = (mean exemplar height, mean exemplar width) / 8`` measured in the 512 x 512 frame (default
``mode="reflect"``, which keeps the total mass, so the map sums to the count).
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

NEIGHBOURS = 3
SIGMA_PER_WINDOW = 0.25
MIN_SIGMA = 1.0
TRUNCATE = 3.0


def _gaussian_1d(centre: float, sigma: float, size: int) -> tuple[int, np.ndarray]:
    """Offset and weights of a 1-D Gaussian over the pixel centres of [0, size) within TRUNCATE sigma."""
    lo = max(0, int(np.floor(centre - TRUNCATE * sigma)))
    hi = min(size, int(np.ceil(centre + TRUNCATE * sigma)) + 1)
    x = np.arange(lo, hi, dtype=np.float64) + 0.5
    return lo, np.exp(-0.5 * ((x - centre) / sigma) ** 2)


def adaptive_sigmas(points: np.ndarray, fallback_window: float) -> np.ndarray:
    """Per-dot sigma: mean distance to the k nearest other dots / 4 (fallback window alone)."""
    n = len(points)
    if n == 0:
        return np.zeros(0)
    if n == 1:
        windows = np.array([fallback_window], dtype=np.float64)
    else:
        from scipy.spatial import cKDTree

        k = min(NEIGHBOURS, n - 1)
        dist, _ = cKDTree(points).query(points, k=k + 1)  # the first neighbour is the dot itself
        windows = np.asarray(dist, dtype=np.float64).reshape(n, k + 1)[:, 1:].mean(axis=1)
    return np.maximum(windows * SIGMA_PER_WINDOW, MIN_SIGMA)


def adaptive_density_map(points: Sequence[Sequence[float]], height: int, width: int, *,
                         fallback_window: float) -> np.ndarray:
    """(height, width) float32 map of geometry-adaptive Gaussians at ``points`` ([x, y]); sums to len(points)."""
    dmap = np.zeros((height, width), dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    for (x, y), sigma in zip(pts, adaptive_sigmas(pts, float(fallback_window))):
        cx = min(max(x, 0.0), width - 1e-6)  # a dot on the far edge still lands inside
        cy = min(max(y, 0.0), height - 1e-6)
        x0, gx = _gaussian_1d(cx, sigma, width)
        y0, gy = _gaussian_1d(cy, sigma, height)
        patch = np.outer(gy, gx)
        dmap[y0:y0 + len(gy), x0:x0 + len(gx)] += patch / patch.sum()
    return dmap.astype(np.float32)


def loca_object_density_map(points: Sequence[Sequence[float]], exemplar_boxes: Sequence[Sequence[float]],
                            height: int, width: int, target: tuple[int, int] = (512, 512)) -> np.ndarray:
    """LOCA's object density map (see module docstring). ``points`` [x, y] and ``exemplar_boxes``
    [x1, y1, x2, y2] are in the (height, width) image; the map is ``target`` (rows, cols)."""
    from scipy.ndimage import gaussian_filter

    th, tw = target
    h_ratio, w_ratio = th / height, tw / width
    dmap = np.zeros((th, tw), dtype=np.float32)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2) * np.array([w_ratio, h_ratio])
    pts = pts.astype(np.int64)  # torch .long(): truncation (coordinates are >= 0)
    pts[:, 0] = pts[:, 0].clip(0, tw - 1)
    pts[:, 1] = pts[:, 1].clip(0, th - 1)
    np.add.at(dmap, (pts[:, 1], pts[:, 0]), 1.0)
    boxes = np.asarray(exemplar_boxes, dtype=np.float64).reshape(-1, 4)[:3]
    window = np.array([((boxes[:, 3] - boxes[:, 1]) * h_ratio).mean(), ((boxes[:, 2] - boxes[:, 0]) * w_ratio).mean()])
    return gaussian_filter(dmap, window / 8).astype(np.float32)


def density_sum_error(dmap: np.ndarray, count: int) -> Optional[float]:
    """Relative difference between the map's sum and the count (None for a count of 0)."""
    if count == 0:
        return None
    return abs(float(dmap.sum()) - count) / count
