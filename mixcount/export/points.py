"""One point per object: where point-supervised counting models (FSC-147 dots, CountGD points) put it.

A point must lie on a *visible* pixel of its object, so that a density map or a point-in-box test agrees
with the mask. An annotation that carries ``point`` ([x, y], written by the annotator) is used as is;
otherwise the point is computed from the visible mask (COCO RLE ``segmentation``): the visible pixel
farthest from the mask's edge (largest Euclidean distance transform; ties go to the first pixel in
row-major order), so thin or occluded shapes still get an interior point, never one in a hole.

Coordinates are continuous image coordinates: pixel (col, row) covers [col, col+1) x [row, row+1), so
the computed point is the pixel centre (col + 0.5, row + 0.5) and ``floor(point)`` is the pixel.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np


def decode_mask(segmentation: Mapping[str, Any]) -> np.ndarray:
    """Boolean (H, W) mask of a COCO RLE (compressed ``counts`` string or bytes, or uncompressed list)."""
    from pycocotools import mask as mask_util

    rle = dict(segmentation)
    h, w = (int(v) for v in rle["size"])
    if isinstance(rle["counts"], list):
        rle = mask_util.frPyObjects(rle, h, w)
    elif isinstance(rle["counts"], str):
        rle["counts"] = rle["counts"].encode("ascii")
    return mask_util.decode(rle).astype(bool)


def object_point(annotation: Mapping[str, Any]) -> tuple[float, float]:
    """(x, y) of one visible pixel of the annotated object (see module docstring)."""
    given = annotation.get("point")
    if given is not None:
        return float(given[0]), float(given[1])
    from scipy.ndimage import distance_transform_edt

    mask = decode_mask(annotation["segmentation"])
    rows = np.nonzero(mask.any(axis=1))[0]
    cols = np.nonzero(mask.any(axis=0))[0]
    if len(rows) == 0:  # no visible pixel (never written by compose): the box centre is all there is
        x, y, w, h = (float(v) for v in annotation["bbox"])
        return x + w / 2, y + h / 2
    r0, c0 = int(rows[0]), int(cols[0])
    crop = mask[r0:rows[-1] + 1, c0:cols[-1] + 1]
    # pad with background so pixels on the crop border measure their distance to the object's edge
    dist = distance_transform_edt(np.pad(crop, 1))[1:-1, 1:-1]
    r, c = np.unravel_index(int(np.argmax(dist)), dist.shape)
    return float(c0 + c) + 0.5, float(r0 + r) + 0.5
