"""One point per object on its visible pixels (pure numpy + scipy), for counting models trained on
points (FSC-147 style) and for COCO ``keypoints``.

The point is the visible pixel farthest from the mask's edge (the maximum of the Euclidean distance
transform), so it lies well inside the visible part even for thin, concave or split masks, where a
centroid can fall on another object. The image border counts as an edge: an object cut by the frame gets
its point inside the part that is shown. Ties go to the first pixel in row-major order (deterministic).

Convention: the point is returned as integer pixel indices ``[x, y] = [column, row]`` of that pixel,
which is what COCO keypoints hold (detectron2's COCO loader adds 0.5 to reach the pixel centre in the
continuous frame of ``bbox`` and ``segmentation``, where pixel (r, c) covers [c, c + 1) x [r, r + 1)).
``ids[y, x]`` is the object's own id.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray


def interior_point(mask: NDArray[Any]) -> list[int]:
    """``[x, y]`` (column, row) of the pixel of ``mask`` farthest from its edge; ValueError when empty."""
    from scipy.ndimage import distance_transform_edt

    m = np.asarray(mask, dtype=bool)
    rows = np.nonzero(m.any(axis=1))[0]
    cols = np.nonzero(m.any(axis=0))[0]
    if len(rows) == 0:
        raise ValueError("interior_point of an empty mask")
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    crop = np.pad(m[r0:r1, c0:c1], 1)  # the padding (and so the image border) is outside the mask
    dist = distance_transform_edt(crop)[1:-1, 1:-1]
    r, c = np.unravel_index(int(np.argmax(dist)), dist.shape)
    return [c0 + int(c), r0 + int(r)]
