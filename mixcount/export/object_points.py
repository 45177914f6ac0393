"""One point per object: where point-supervised counting models (FSC-147 dots, CountGD points) put it.

A point must lie on a *visible* pixel of its object, so that a density map or a point-in-box test agrees
with the mask. The pixel is the annotation's ``point`` (written by compose) or, for datasets without one,
the same rule applied to the visible mask (COCO RLE ``segmentation``): the visible pixel farthest from
the mask's edge, so thin or occluded shapes still get an interior point, never one in a hole.

Coordinates are continuous image coordinates: pixel (col, row) covers [col, col+1) x [row, row+1), so
the computed point is the pixel centre (col + 0.5, row + 0.5) and ``floor(point)`` is the pixel.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from mixcount.annotate.interior_points import interior_point


def decode_mask(segmentation: Mapping[str, Any]) -> "np.ndarray[Any, Any]":
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
    """(x, y) pixel centre of one visible pixel of the annotated object (see module docstring).

    The annotation's ``point`` (integer pixel indices [column, row], docs/annotations.md) is used when
    present; otherwise the same pixel is computed from the visible mask with
    :func:`mixcount.annotate.interior_points.interior_point`. Either way the result is that pixel's centre."""
    given = annotation.get("point")
    if given is not None:
        col, row = int(given[0]), int(given[1])
    else:
        mask = decode_mask(annotation["segmentation"])
        if not mask.any():  # no visible pixel (never written by compose): the box centre is all there is
            x, y, w, h = (float(v) for v in annotation["bbox"])
            return x + w / 2, y + h / 2
        col, row = interior_point(mask)
    return float(col) + 0.5, float(row) + 0.5
