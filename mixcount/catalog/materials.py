"""The glTF base colour of a trimesh geometry, read one way for every user.

glTF's base colour is ``baseColorFactor x texture(uv) x COLOR_0``. trimesh keeps the factor and the
texture on ``visual.material`` (``baseColorFactor`` / ``baseColorTexture`` for PBR materials,
``main_color`` / ``image`` for simple ones) and the COLOR_0 of a primitive that also has a material in
``visual.vertex_attributes["color"]``. The stub captioner's colours (:mod:`mixcount.captions.colours`),
the orientation-free appearance descriptor (:mod:`mixcount.curation.appearance3d`) and the USD
converter (:mod:`mixcount.usd.assets`) all read them through these functions.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray


def base_colour_texture(visual: Any) -> Optional[NDArray[np.uint8]]:
    """The base-colour texture as an (H, W, 3) uint8 RGB array, or None."""
    material = getattr(visual, "material", None)
    image = getattr(material, "baseColorTexture", None)
    if image is None:
        image = getattr(material, "image", None)
    if image is None:
        return None
    return np.asarray(image.convert("RGB"))


def base_colour_factor(visual: Any) -> NDArray[np.float64]:
    """The base-colour factor as RGB in [0, 1]; white when the material names none."""
    material = getattr(visual, "material", None)
    factor = getattr(material, "baseColorFactor", None)
    if factor is None:
        factor = getattr(material, "main_color", None)
    if factor is None:
        return np.ones(3)
    f = np.asarray(factor, dtype=np.float64)[:3]
    return f / 255.0 if f.max() > 1.0 else f


def material_vertex_colours(visual: Any, n_vertices: int) -> Optional[NDArray[np.float64]]:
    """COLOR_0 kept beside a material, as (n_vertices, 3) RGB in [0, 1], or None."""
    attrs = getattr(visual, "vertex_attributes", None)
    if attrs is None or "color" not in attrs:
        return None
    col = np.asarray(attrs["color"], dtype=np.float64)
    if col.ndim != 2 or len(col) != n_vertices or col.shape[1] < 3:
        return None
    scale = 255.0 if col.max() > 1.0 else 1.0  # uint8 colours: judged on every channel, alpha included
    return col[:, :3] / scale
