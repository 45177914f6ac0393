"""Dominant colours of an object, named from real pixels.

Two sources, both deterministic:

* the canonical render (PNG on pure white, RGB or RGBA): object pixels are the opaque ones (RGBA) or the
  ones that are not near-pure white (RGB);
* the model itself (trimesh): colours sampled on the surface, area-weighted, from the base-colour texture
  through the UVs, from vertex/face colours, or from the material's base colour factor.

Each pixel gets a name from a small HSV rule table (``name_rgb``); the names whose share of the object's
pixels passes a threshold are the dominant colours. Naming each pixel and counting the names (instead of
naming a k-means centre) keeps e.g. a red-and-white ball "red and white" rather than a pink average.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable

import numpy as np

from mixcount.catalog.materials import (
    base_colour_factor,
    base_colour_texture,
    linear_to_srgb,
    material_vertex_colours,
    srgb_to_linear,
)
from mixcount.frame import load_model

# Hue bins (degrees, lower bound inclusive) for saturated colours; brightness variants are in _refine.
_HUES: tuple[tuple[float, str], ...] = (
    (0.0, "red"),
    (15.0, "orange"),
    (42.0, "yellow"),
    (70.0, "lime"),
    (90.0, "green"),
    (160.0, "teal"),
    (190.0, "blue"),
    (255.0, "purple"),
    (290.0, "magenta"),
    (330.0, "pink"),
    (348.0, "red"),
)

NAMES: tuple[str, ...] = (
    "black", "dark grey", "grey", "light grey", "white", "red", "maroon", "orange", "brown", "tan",
    "beige", "yellow", "gold", "olive", "lime", "green", "dark green", "teal", "blue", "navy",
    "light blue", "purple", "magenta", "pink",
)


def name_hsv(h: float, s: float, v: float) -> str:
    """Name one colour given HSV in [0, 1] (h in turns). Rules, not nearest-neighbour: easy to read."""
    if v < 0.16:
        return "black"
    if s < 0.16 or (v < 0.3 and s < 0.3):
        if v > 0.88:
            return "white"
        if v > 0.66:
            return "light grey"
        if v > 0.38:
            return "grey"
        return "dark grey"
    deg = h * 360.0
    base = "red"
    for lower, name in _HUES:
        if deg >= lower:
            base = name
    return _refine(base, s, v)


def _refine(base: str, s: float, v: float) -> str:
    if base in ("red", "pink"):
        if v < 0.45:
            return "maroon"
        if base == "red" and s < 0.45 and v > 0.7:
            return "pink"
        return base
    if base == "orange":
        if v < 0.62:
            return "brown"
        if s < 0.45:
            return "beige" if v > 0.8 else "tan"
        return "orange"
    if base == "yellow":
        if v < 0.5:
            return "olive"
        if s < 0.4:
            return "beige"
        if v < 0.8:
            return "gold"
        return "yellow"
    if base == "green":
        return "dark green" if v < 0.4 else "green"
    if base == "blue":
        if v < 0.42:
            return "navy"
        if s < 0.45 and v > 0.7:
            return "light blue"
        return "blue"
    return base


def name_rgb(rgb: tuple[int, int, int] | np.ndarray) -> str:
    """Name one 8-bit RGB colour."""
    r, g, b = (float(c) / 255.0 for c in rgb[:3])
    return name_hsv(*colorsys.rgb_to_hsv(r, g, b))


@dataclass(frozen=True)
class ColourSummary:
    """Dominant colour names (most common first), their shares, and how varied the surface is."""

    names: tuple[str, ...]
    shares: tuple[float, ...]
    variation: float  # std of luminance over object pixels, 0..1: high = patterned/textured
    source: str  # "albedo" (a render's albedo pass) | "render" (its shaded pixels) | "model" | "none"
    luminance: float = 0.0  # mean luminance over the object's pixels, 0..1 (tells two shades of one name apart)
    # whether the colours come from an image texture (a print or pattern) rather than flat or vertex colours;
    # None when not known (a render's pixels)
    textured: bool | None = None

    def as_dict(self) -> dict[str, object]:
        return {
            "names": list(self.names),
            "shares": [round(s, 3) for s in self.shares],
            "variation": round(self.variation, 3),
            "source": self.source,
            "luminance": round(self.luminance, 3),
            "textured": self.textured,
        }


EMPTY = ColourSummary((), (), 0.0, "none")


def summarise(pixels: np.ndarray, *, source: str, min_share: float = 0.12, max_names: int = 3) -> ColourSummary:
    """Name every pixel (N x 3 uint8), count names, keep those above ``min_share`` (at least one)."""
    if pixels.size == 0:
        return EMPTY
    px = np.asarray(pixels, dtype=np.uint8).reshape(-1, 3)
    # Quantise to 5 bits per channel: naming ~32k distinct colours instead of every pixel.
    q = (px >> 3).astype(np.int32)
    keys = (q[:, 0] << 10) | (q[:, 1] << 5) | q[:, 2]
    uniq, counts = np.unique(keys, return_counts=True)
    tally: dict[str, int] = {}
    for key, count in zip(uniq.tolist(), counts.tolist()):
        rgb = (((key >> 10) & 31) * 8 + 4, ((key >> 5) & 31) * 8 + 4, (key & 31) * 8 + 4)
        name = name_rgb(rgb)
        tally[name] = tally.get(name, 0) + count
    total = float(len(px))
    ranked = sorted(tally.items(), key=lambda kv: (-kv[1], NAMES.index(kv[0])))
    kept = [(n, c / total) for n, c in ranked if c / total >= min_share][:max_names] or [
        (ranked[0][0], ranked[0][1] / total)
    ]
    lum = (0.2126 * px[:, 0] + 0.7152 * px[:, 1] + 0.0722 * px[:, 2]) / 255.0
    return ColourSummary(tuple(n for n, _ in kept), tuple(s for _, s in kept), float(lum.std()), source,
                         float(lum.mean()))


def render_pixels(path: Path, *, max_side: int = 256) -> np.ndarray:
    """Object pixels of a canonical render (N x 3 uint8): opaque ones, or the not-near-white ones."""
    from PIL import Image

    with Image.open(path) as im:
        im.load()
        if max(im.size) > max_side:
            im = im.resize(
                (max(1, im.width * max_side // max(im.size)), max(1, im.height * max_side // max(im.size))),
                Image.Resampling.NEAREST,
            )
        if im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info:
            arr = np.asarray(im.convert("RGBA"))
            alpha = arr[..., 3]
            if not (alpha == 255).all():  # a real alpha channel: the object is what is (mostly) opaque
                mask = alpha > 200
                if not mask.any():
                    mask = alpha > 0
                return arr[..., :3][mask]
            arr = arr[..., :3]  # fully opaque RGBA: a render on white, like RGB
        else:
            arr = np.asarray(im.convert("RGB"))
    # RGB on white: drop the background (near-pure white, nearly grey).
    spread = arr.max(axis=-1).astype(int) - arr.min(axis=-1).astype(int)
    background = (arr.min(axis=-1) >= 247) & (spread <= 6)
    return arr[~background]


def colours_from_render(path: Path) -> ColourSummary:
    """Dominant colours of a canonical render's object: from its albedo (the surface colour the renderer
    shaded, shading and highlights left out: a yellow duck is yellow whichever way it is lit) when the
    render has one beside it, else from the shaded pixels."""
    from mixcount.curation.renders import albedo_path_for

    albedo = albedo_path_for(path)
    if albedo.is_file():
        return summarise(render_pixels(albedo), source="albedo")
    return summarise(render_pixels(path), source="render")


def lit_colours_from_render(path: Path) -> ColourSummary:
    """Dominant colours of a render's lit side: the object's pixels at or above its median brightness (max
    channel). The shaded side is named by its shadow (a gold ball's reads "brown", a white one's "grey");
    the lit side is where a reader takes the object's colour from."""
    px = render_pixels(path)
    if px.size == 0:
        return EMPTY
    value = px.max(axis=1)
    return summarise(px[value >= np.median(value)], source="render")


def rendered_factor(visual) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The base-colour factor the renderer applies (RGB in [0, 1]).

    A glTF ``baseColorFactor`` (trimesh's ``PBRMaterial``) multiplies the texture in Blender's glTF importer
    and in the USD asset. An .mtl material (trimesh's ``SimpleMaterial``) with a ``map_Kd`` texture is
    rendered with the texture alone: Blender's OBJ importer links the image to the base colour and leaves
    ``Kd`` out, so the canonical render of pybullet's duck (texture (255, 216, 0), ``Kd`` 0.64) shows a
    yellow, not a gold, duck; ``Kd`` counts only for an .mtl material without a texture.
    """
    from trimesh.visual.material import PBRMaterial

    material = getattr(visual, "material", None)
    if not isinstance(material, PBRMaterial) and base_colour_texture(visual) is not None:
        return np.ones(3)
    return base_colour_factor(visual)


def mesh_colour_samples(mesh, rng: np.random.Generator, count: int,  # type: ignore[no-untyped-def]
                        look: np.ndarray | None = None) -> np.ndarray:
    """``count`` surface colours of one trimesh.Trimesh, area-weighted (N x 3 uint8); a part with no colour
    of its own (:func:`mixcount.catalog.materials.uncoloured`) has ``look`` (8-bit sRGB) when one is given,
    as it renders."""
    import trimesh

    from mixcount.catalog.materials import uncoloured

    if len(mesh.faces) == 0 or count <= 0:
        return np.zeros((0, 3), dtype=np.uint8)
    area = np.asarray(mesh.area_faces, dtype=float)
    weights = area / area.sum() if area.sum() > 0 else None
    faces = rng.choice(len(mesh.faces), size=count, p=weights)
    visual = mesh.visual
    if look is not None and uncoloured(visual):
        return np.tile(np.asarray(look, dtype=np.uint8)[:3], (count, 1))
    if isinstance(visual, trimesh.visual.TextureVisuals):
        # glTF base colour = baseColorFactor x texture(uv) x COLOR_0; trimesh keeps COLOR_0 of a
        # primitive that also has a material in visual.vertex_attributes["color"]. The factor (glTF's, an
        # .mtl's Kd) and COLOR_0 are linear, the texture sRGB: multiplied in linear, named in sRGB as the
        # renderer shows it (a glTF factor of 0.85 is a white surface, not a light grey one)
        colour = np.tile(rendered_factor(visual), (count, 1))
        vcol = material_vertex_colours(visual, len(mesh.vertices))
        if vcol is not None:
            colour *= vcol[mesh.faces[faces]].mean(axis=1)
        image = base_colour_texture(visual)
        uv = getattr(visual, "uv", None)
        if image is not None and uv is not None and len(uv) == len(mesh.vertices):
            bary = rng.dirichlet((1.0, 1.0, 1.0), size=count)
            tri_uv = np.asarray(uv, dtype=float)[mesh.faces[faces]]  # count x 3 x 2
            pts = np.einsum("nk,nkd->nd", bary, tri_uv)
            h, w = image.shape[:2]
            x = np.mod(pts[:, 0], 1.0) * (w - 1)
            y = (1.0 - np.mod(pts[:, 1], 1.0)) * (h - 1)  # trimesh flips glTF's V on load
            colour *= srgb_to_linear(image[y.round().astype(int), x.round().astype(int)].astype(float) / 255.0)
        return np.round(linear_to_srgb(colour) * 255.0).astype(np.uint8)
    if isinstance(visual, trimesh.visual.ColorVisuals) and visual.defined:
        if visual.kind == "face":
            cols = np.asarray(visual.face_colors)[faces, :3]
        else:
            vc = np.asarray(visual.vertex_colors)[:, :3].astype(float)
            cols = vc[mesh.faces[faces]].mean(axis=1)
        return np.asarray(cols).astype(np.uint8)
    return np.zeros((0, 3), dtype=np.uint8)


def colours_from_model(path: Path, *, samples: int = 4000, seed: int = 0,
                       look: tuple[float, ...] | None = None) -> ColourSummary:
    """Dominant colours sampled from a model file's surface (texture, vertex colours or material; ``look``,
    sRGB in [0, 1] first, for its parts with none of these, as the renders give them)."""
    import trimesh

    try:
        loaded = load_model(path)
    except Exception:  # noqa: BLE001 - unreadable model: no colours, caption from the other facts
        return EMPTY
    meshes = list(loaded.geometry.values()) if isinstance(loaded, trimesh.Scene) else [loaded]
    meshes = [m for m in meshes if isinstance(m, trimesh.Trimesh) and len(m.faces)]
    if not meshes:
        return EMPTY
    rng = np.random.default_rng(seed)
    areas = np.array([max(m.area, 0.0) for m in meshes])
    shares = areas / areas.sum() if areas.sum() > 0 else np.full(len(meshes), 1.0 / len(meshes))
    look8 = None if look is None else np.clip(np.round(np.asarray(look[:3], dtype=float) * 255), 0, 255)
    parts = [mesh_colour_samples(m, rng, int(round(samples * s)), look8) for m, s in zip(meshes, shares)]
    pixels = np.concatenate([p for p in parts if len(p)] or [np.zeros((0, 3), dtype=np.uint8)])
    textured = any(base_colour_texture(m.visual) is not None and getattr(m.visual, "uv", None) is not None
                   for m in meshes)
    return replace(summarise(pixels, source="model"), textured=textured)


def count_parts(path: Path) -> int | None:
    """Separate parts of a model: connected components of its surface once vertices at the same position
    are merged (texture seams and normals do not split a part). None when the file cannot be read."""
    import trimesh

    try:
        loaded = load_model(path)
    except Exception:  # noqa: BLE001 - unreadable model: the caption goes without the fact
        return None
    meshes = list(loaded.geometry.values()) if isinstance(loaded, trimesh.Scene) else [loaded]
    total = 0
    for m in meshes:
        if not isinstance(m, trimesh.Trimesh) or not len(m.faces):
            continue
        plain = trimesh.Trimesh(m.vertices, m.faces, process=False)
        plain.merge_vertices(merge_tex=True, merge_norm=True)
        total += int(plain.body_count)
    return total or None


# Colour families: names a reader takes for one colour ("light grey" beside "grey", "maroon" beside "red").
# A caption's colour agrees with a render's dominant colour when their families meet.
FAMILIES: dict[str, str] = {
    "black": "black", "dark grey": "grey", "grey": "grey", "light grey": "grey", "white": "white",
    "red": "red", "maroon": "red", "orange": "orange", "brown": "brown", "tan": "brown", "beige": "beige",
    "yellow": "yellow", "gold": "yellow", "olive": "green", "lime": "green", "green": "green",
    "dark green": "green", "teal": "teal", "blue": "blue", "navy": "blue", "light blue": "blue",
    "purple": "purple", "magenta": "pink", "pink": "pink",
    # colour words of names (shops, DTC variants)
    "gray": "grey", "golden": "yellow", "silver": "grey", "cyan": "teal", "violet": "purple", "cream": "beige",
    "ivory": "white", "peach": "orange", "coral": "orange", "crimson": "red", "scarlet": "red",
    "turquoise": "teal", "lavender": "purple", "mint": "green", "charcoal": "grey", "khaki": "beige",
    "burgundy": "red", "aqua": "teal", "indigo": "blue", "rose": "pink", "salmon": "pink", "amber": "orange",
    "bronze": "brown", "copper": "brown",
}
# Caption colour families that agree with a render's dominant family besides its own. Shading only darkens:
# a render's "brown" may be a shaded orange or gold, its "grey" a shaded white; a caption darker than the
# render is not excused (an orange cone captioned "brown", a white one "grey": the .mtl Kd bug). Neighbours
# on the hue wheel agree both ways (the bins' borders, e.g. orange / yellow at 42 degrees, are arbitrary).
NEAR: dict[str, frozenset[str]] = {
    "white": frozenset({"beige"}), "grey": frozenset({"white", "black"}), "black": frozenset({"grey"}),
    "beige": frozenset({"white", "yellow", "brown"}), "brown": frozenset({"beige", "orange", "yellow", "red"}),
    "orange": frozenset({"yellow", "red"}), "yellow": frozenset({"orange", "beige"}),
    "teal": frozenset({"green", "blue"}), "pink": frozenset({"red", "purple"}), "purple": frozenset({"pink", "blue"}),
    "red": frozenset({"pink", "orange"}), "green": frozenset({"teal"}), "blue": frozenset({"teal", "purple"}),
}


def family(name: str) -> str | None:
    """The family of a colour name or a name's colour word (None for a word that is no colour)."""
    return FAMILIES.get(name.lower())


def colours_agree(caption_colours: "Iterable[str]", dominant: str) -> bool:
    """Whether a caption's colour words agree with a render's dominant colour name (its family, or one
    :data:`NEAR` lists for it)."""
    want = family(dominant)
    if want is None:
        return False
    got = {family(c) for c in caption_colours} - {None}
    return want in got or bool(got & NEAR.get(want, frozenset()))


def colour_words_in(text: str) -> list[str]:
    """The colour names and name colour words of a caption, longest first ("light grey" before "grey")."""
    low = " " + " ".join(text.lower().replace(",", " ").split()) + " "
    found = []
    for name in sorted(FAMILIES, key=len, reverse=True):
        if f" {name} " in low:
            found.append(name)
            low = low.replace(f" {name} ", " ")
    return found
