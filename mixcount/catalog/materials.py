"""The glTF base colour of a trimesh geometry, read one way for every user.

glTF's base colour is ``baseColorFactor x texture(uv) x COLOR_0``. trimesh keeps the factor and the
texture on ``visual.material`` (``baseColorFactor`` / ``baseColorTexture`` for PBR materials,
``main_color`` / ``image`` for simple ones) and the COLOR_0 of a primitive that also has a material in
``visual.vertex_attributes["color"]``. The stub captioner's colours (:mod:`mixcount.captions.colours`),
the orientation-free appearance descriptor (:mod:`mixcount.curation.finding.appearance3d`) and the USD
converter (:mod:`mixcount.usd.assets`) all read them through these functions.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, replace
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
    """The base-colour factor as RGB in [0, 1] (linear, as glTF and Blender's importers take it); white
    when the material names none. A glTF material without ``baseColorFactor`` has glTF's default, 1 (not
    trimesh's ``main_color``, a made-up 0.4 grey); an .mtl material's is its ``Kd``."""
    from trimesh.visual.material import PBRMaterial

    material = getattr(visual, "material", None)
    factor = getattr(material, "baseColorFactor", None)
    if factor is None and isinstance(material, PBRMaterial):
        return np.ones(3)
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


# ------------------------------------------------------------------ looks for parts without a colour
#
# A model part with no texture, no vertex colours and no material (an STL, PLY or OBJ-without-.mtl CAD
# export) renders in the renderer's default near-white grey: on a light floor it washes out. Such parts
# get a look from ``[palette]`` instead (the USD asset's material, the canonical render's material, the
# caption's colour: one decision, :func:`object_look`).

LOOK_KEYS = ("material", "colour", "color")  # a metadata record's entries that name an object's look
# sRGB of the caption colour names (mixcount.captions.colours.NAMES and common names people write), for a
# metadata entry such as ``colour: red``; each one is named back as itself by the captions' rule table
NAME_RGB: dict[str, tuple[int, int, int]] = {
    "black": (25, 25, 25), "dark grey": (80, 80, 80), "grey": (128, 128, 128), "gray": (128, 128, 128),
    "light grey": (190, 190, 190), "silver": (192, 192, 196), "white": (240, 240, 240),
    "red": (200, 30, 35), "maroon": (110, 20, 25), "orange": (236, 112, 20), "brown": (120, 70, 30),
    "tan": (180, 140, 100), "beige": (225, 205, 165), "yellow": (242, 200, 20), "gold": (200, 160, 30),
    "olive": (110, 105, 30), "lime": (150, 220, 40), "green": (40, 155, 60), "dark green": (20, 85, 35),
    "teal": (15, 150, 150), "cyan": (20, 180, 200), "blue": (30, 95, 196), "navy": (20, 30, 90),
    "light blue": (140, 185, 235), "purple": (120, 60, 170), "magenta": (200, 40, 190), "pink": (235, 120, 170),
}


@dataclass(frozen=True)
class Look:
    """One palette look: sRGB base colour in [0, 1], metallic, roughness; ``source`` says why the object
    has it (``metadata`` / ``category <word>`` / ``default``)."""

    name: str
    rgb: tuple[float, float, float]
    metallic: float
    roughness: float
    source: str = "default"

    def as_tuple(self) -> tuple[float, float, float, float, float]:
        """(r, g, b, metallic, roughness): how a scene's asset reference and a render request carry it."""
        return (*self.rgb, self.metallic, self.roughness)

    def rgb8(self) -> tuple[int, int, int]:
        return tuple(int(round(c * 255)) for c in self.rgb)  # type: ignore[return-value]


def srgb_to_linear(rgb: "tuple[float, ...] | NDArray[np.float64]") -> NDArray[np.float64]:
    """sRGB-encoded [0, 1] -> linear (what UsdPreviewSurface's diffuseColor and Blender's Base Color take)."""
    c = np.asarray(rgb, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(rgb: "tuple[float, ...] | NDArray[np.float64]") -> NDArray[np.float64]:
    """Linear [0, 1] -> sRGB-encoded (how an image, and a person's colour name, sees it)."""
    c = np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)


def _hex_rgb(text: str) -> Optional[tuple[float, float, float]]:
    t = text.strip().lstrip("#")
    if len(t) != 6:
        return None
    try:
        return tuple(int(t[i:i + 2], 16) / 255.0 for i in (0, 2, 4))  # type: ignore[return-value]
    except ValueError:
        return None


def palette_looks(palette: Any) -> dict[str, Look]:
    """``[palette]`` looks by lower-case name."""
    out = {}
    for entry in palette.looks:
        rgb = _hex_rgb(str(entry["colour"]))
        assert rgb is not None  # PaletteConfig.validate checked it
        out[str(entry["name"]).lower()] = Look(str(entry["name"]), rgb, float(entry["metallic"]),
                                               float(entry["roughness"]))
    return out


def _metadata_entry(metadata_json: Optional[str]) -> Any:
    """The first look entry (:data:`LOOK_KEYS`) of a stored metadata record, top level or under
    ``metadata``; None when it names none."""
    if not metadata_json:
        return None
    try:
        meta = json.loads(metadata_json)
    except (TypeError, ValueError):
        return None
    for node in (meta, meta.get("metadata") if isinstance(meta, dict) else None):
        if isinstance(node, dict):
            for key in LOOK_KEYS:
                if node.get(key) not in (None, ""):
                    return node[key]
    return None


def look_from_entry(value: Any, looks: dict[str, Look]) -> Optional[Look]:
    """A metadata entry as a look: a palette look's name ("steel", "blue plastic"), a colour name ("red":
    the palette's plastic of that name, else a plastic of that colour), ``#rrggbb``, or [r, g, b] in 0-1
    or 0-255. None when it names none of these."""
    if isinstance(value, (list, tuple)) and len(value) in (3, 4) and all(isinstance(v, (int, float)) for v in value):
        c = np.asarray(value[:3], dtype=np.float64)
        c = c / 255.0 if c.max() > 1.0 else c
        rgb = tuple(float(v) for v in np.clip(c, 0.0, 1.0))
        return Look("#%02x%02x%02x" % tuple(int(round(v * 255)) for v in rgb), rgb, 0.0, 0.4, "metadata")  # type: ignore[arg-type]
    if not isinstance(value, str):
        return None
    text = " ".join(value.lower().replace("_", " ").replace("-", " ").split())
    for key in (text, f"{text} plastic", text.replace("aluminum", "aluminium"),
                text.replace("stainless steel", "steel").replace("metal", "steel")):
        if key in looks:
            return replace(looks[key], source="metadata")
    if text.replace("gray", "grey") in NAME_RGB:
        rgb8 = NAME_RGB[text.replace("gray", "grey")]
        return Look(text, tuple(c / 255.0 for c in rgb8), 0.0, 0.4, "metadata")  # type: ignore[arg-type]
    rgb = _hex_rgb(text) if text.startswith("#") or len(text) == 6 else None
    return Look(text if text.startswith("#") else f"#{text}", rgb, 0.0, 0.4, "metadata") if rgb else None


def object_look(palette: Any, *, name: str, category: str, metadata_json: Optional[str],
                content_hash: str) -> Optional[Look]:
    """The look of an object's parts that have no colour of their own: its metadata entry, else the first
    ``palette.categories`` word among its name's and category's words, else one of ``palette.default`` by
    its content hash (the same asset, the same look in every catalog). None when the palette names none."""
    from mixcount.scene.words import words_of

    looks = palette_looks(palette)
    entry = _metadata_entry(metadata_json)
    if entry is not None:
        found = look_from_entry(entry, looks)
        if found is not None:
            return found
    words = set(words_of(f"{name} {category}"))
    words |= {w[:-1] for w in words if w.endswith("s") and len(w) > 3}  # "nuts", "screws"
    for item in palette.categories:
        word, _, look_name = str(item).partition("=")
        if word.strip().lower() in words:
            return replace(looks[look_name.strip().lower()], source=f"category {word.strip().lower()}")
    if not palette.default:
        return None
    digest = hashlib.sha256((content_hash or name).encode()).digest()
    pick = palette.default[int.from_bytes(digest[:4], "big") % len(palette.default)]
    return replace(looks[pick.lower()], source="default")


def is_placeholder_image(image: Any) -> bool:
    """True for the image trimesh gives a model whose material is missing (an OBJ with texture coordinates
    and no ``.mtl``, or one naming a ``.mtl`` that is not there: ``trimesh.visual.material.empty_material``,
    a few pixels of one grey), not a texture anyone made."""
    import trimesh

    try:
        pixels = np.asarray(image.convert("RGBA"))
        stand_in = np.asarray(trimesh.visual.material.empty_material().image.convert("RGBA"))
    except (AttributeError, OSError, ValueError):
        return False
    return pixels.shape == stand_in.shape and bool((pixels == stand_in).all())


def is_placeholder_material(material: Any) -> bool:
    """True for trimesh's stand-in material (:func:`is_placeholder_image`): no colour of the model's own."""
    image = getattr(material, "image", None)
    return (type(material).__name__ == "SimpleMaterial" and image is not None
            and getattr(material, "baseColorTexture", None) is None and is_placeholder_image(image))


def uncoloured(visual: Any) -> bool:
    """Whether a trimesh geometry's visual carries no colour at all: no material (so no texture and no
    material colour; trimesh's stand-in for a missing one is none, :func:`is_placeholder_material`) and no
    vertex or face colours. Such a part gets the object's :class:`Look`."""
    if visual is None:
        return True
    material = getattr(visual, "material", None)
    if material is not None:
        return is_placeholder_material(material)
    return getattr(visual, "kind", None) is None
