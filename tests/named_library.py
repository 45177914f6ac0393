"""A generated library shaped like real ones: person-written names, broad categories, bookkeeping in names.

Real libraries (Objaverse, GSO, OmniObject3D, plain folders, shops' catalogues) carry a ``metadata.json``
whose ``name`` was written by a person ("Red coffee mug", "Bottle (PartNet-Mobility 3763)", "Teddy bear
convex-hull approximation") and whose ``category`` is broad ("kitchenware", "sports", "toy"). This module
writes such a library from meshes it generates (trimesh primitives and combinations, some textured, one with
more than 100k faces), either as plain folders (``<slug>/model.glb`` + ``metadata.json``) or as Digital Twin
Catalog folders (``<Category>_<ID>_<Variant>/3d-asset.glb`` + ``metadata.json``). Both trees also hold DTC
folders with no person-written name (``Markers_B07Z5P84J2_Peach``): there the category is the noun.

Each entry says which word of its name is the head noun (``noun``), written here by hand: the tests check the
captioner against it, not against the captioner's own parsing. Recolour pairs share one mesh.

:func:`caption_figures` turns captioned rows into the issue's figures (noun kept, category tacked on,
bookkeeping fragments, uncaptioned objects, shared captions) so tests and reports measure the same way.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import trimesh
from PIL import Image, ImageDraw

RGB = tuple[int, int, int]

# Words of source tags and bookkeeping that must never reach a caption (from the names below).
BOOKKEEPING = {"partnet", "mobility", "high", "low", "res", "convex", "hull", "approximation", "recolour",
               "recolor", "copy", "procedural", "primitive", "random"}
BROAD_CATEGORIES = {"kitchenware", "sports", "sport", "food", "toy", "animal", "furniture", "lighting", "clothing",
                    "tool", "electronics", "garden", "outdoor", "decor", "accessory", "misc", "stationery"}


@dataclass
class Entry:
    """One object of the library: its person-written name (None: a DTC folder name only), category, the
    head noun a reader expects (None when the name has none), and how to build its mesh."""

    slug: str
    name: str | None
    category: str
    noun: str | None
    build: Callable[[], trimesh.Trimesh]
    dtc_folder: str | None = None  # for unnamed DTC entries: the folder name
    recolour_of: str | None = None
    tags: dict[str, str] = field(default_factory=dict)
    fmt: str = "glb"  # "obj": model.obj + model.mtl (+ texture.png) whatever the layout, as scans ship


# --- mesh helpers -----------------------------------------------------------------------------------------
def _coloured(mesh: trimesh.Trimesh, rgb: RGB) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1)))
    return mesh


def _at(mesh: trimesh.Trimesh, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.apply_translation((x, y, z))
    return mesh


def _ellipsoid(a: float, b: float, c: float, subdiv: int = 3) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdiv, 1.0)
    m.apply_scale((a, b, c))
    return m


def _frustum(r_bottom: float, r_top: float, h: float, sections: int = 48) -> trimesh.Trimesh:
    m = trimesh.creation.cylinder(1.0, h, sections=sections)
    v = m.vertices.copy()
    top = v[:, 2] > 0
    v[top, :2] *= r_top
    v[~top, :2] *= r_bottom
    return trimesh.Trimesh(v, m.faces, process=True)


def _rot(mesh: trimesh.Trimesh, axis: tuple[float, float, float], deg: float) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.radians(deg), axis))
    return mesh


def _join(*parts: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.util.concatenate(list(parts))


def _texture(kind: str, colours: list[RGB], size: int = 128) -> Image.Image:
    """A texture image: "stripes", "dots", "checker" or "patches" in the given colours (first = ground)."""
    img = Image.new("RGB", (size, size), colours[0])
    draw = ImageDraw.Draw(img)
    if kind == "stripes":
        step = size // 8
        for i in range(0, size, step * 2):
            draw.rectangle((0, i, size, i + step - 1), fill=colours[1])
    elif kind == "dots":
        for i in range(4):
            for j in range(4):
                cx, cy = 16 + 32 * i, 16 + 32 * j
                draw.ellipse((cx - 6, cy - 6, cx + 6, cy + 6), fill=colours[1])
    elif kind == "checker":
        step = size // 8
        for i in range(8):
            for j in range(8):
                if (i + j) % 2:
                    draw.rectangle((i * step, j * step, (i + 1) * step - 1, (j + 1) * step - 1),
                                   fill=colours[(i // 2 + j) % (len(colours) - 1) + 1])
    elif kind == "patches":
        for i in range(3):
            for j in range(3):
                cx, cy = 20 + 44 * i, 20 + 44 * j
                draw.regular_polygon((cx, cy, 14), 5, fill=colours[1])
    return img


def _textured(mesh: trimesh.Trimesh, image: Image.Image) -> trimesh.Trimesh:
    """Spherical UVs around the bbox centre and a PBR base-colour texture."""
    mesh = mesh.copy()
    p = mesh.vertices - mesh.bounds.mean(axis=0)
    u = np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi) + 0.5
    span = np.ptp(p[:, 2]) or 1.0
    v = 0.02 + 0.96 * (p[:, 2] - p[:, 2].min()) / span  # off the texture's edge rows (no wrap blend at a pole)
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=image, baseColorFactor=[255, 255, 255, 255])
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.column_stack([u, v]), material=material)
    return mesh


# --- the objects -------------------------------------------------------------------------------------------
RED, WHITE, BLACK, BLUE, GREEN = (200, 25, 30), (240, 240, 240), (20, 20, 22), (30, 80, 210), (40, 150, 60)
YELLOW, ORANGE, BROWN, GREY, TAN = (240, 205, 30), (240, 130, 20), (115, 70, 35), (128, 128, 130), (205, 170, 120)
NAVY, PINK, PURPLE, GOLD, LIGHTBLUE = (25, 35, 95), (235, 120, 170), (120, 50, 160), (200, 160, 40), (140, 190, 235)
MAROON, LIME, TEAL, BEIGE = (110, 20, 30), (160, 220, 40), (20, 130, 130), (225, 210, 175)


def _mug() -> trimesh.Trimesh:
    handle = _rot(trimesh.creation.torus(0.028, 0.007), (1, 0, 0), 90)
    return _coloured(_join(trimesh.creation.cylinder(0.04, 0.095, sections=48), _at(handle, x=0.045)), RED)


def _ketchup() -> trimesh.Trimesh:
    body = trimesh.creation.cylinder(0.03, 0.15, sections=40)
    cap = _at(trimesh.creation.cone(0.022, 0.04, sections=40), z=0.075)
    return _join(body, cap)


def _soup_can() -> trimesh.Trimesh:
    return trimesh.creation.cylinder(0.033, 0.1, sections=56)


def _bunny() -> trimesh.Trimesh:
    body = trimesh.creation.uv_sphere(1.0, count=[262, 262])  # > 100k faces, as a scan would have
    v = body.vertices * (0.09, 0.065, 0.075)
    v[:, 2] += 0.02 * np.sin(3 * v[:, 0] / 0.09) * (v[:, 2] > 0)
    body = trimesh.Trimesh(v, body.faces, process=False)
    ears = [_at(_ellipsoid(0.012, 0.008, 0.04, 2), x=0.05, y=s * 0.02, z=0.09) for s in (-1, 1)]
    return _coloured(_join(body, *ears), WHITE)


def _teddy() -> trimesh.Trimesh:
    rng = np.random.default_rng(7)
    pts = np.vstack([rng.normal(c, s, (60, 3)) for c, s in (((0, 0, 0), 0.04), ((0, 0, 0.07), 0.03),
                                                            ((0.03, 0, 0.1), 0.01), ((-0.03, 0, 0.1), 0.01))])
    return _coloured(trimesh.convex.convex_hull(pts), BROWN)


def _lamp() -> trimesh.Trimesh:
    base = _coloured(trimesh.creation.cylinder(0.07, 0.02), WHITE)
    arm = _coloured(_at(_rot(trimesh.creation.cylinder(0.006, 0.3), (0, 1, 0), 20), x=0.05, z=0.15), GOLD)
    shade = _coloured(_at(_rot(trimesh.creation.cone(0.08, 0.1), (0, 1, 0), 160), x=0.11, z=0.33), WHITE)
    return _join(base, arm, shade)


def _sneakers() -> trimesh.Trimesh:
    shoe = trimesh.creation.capsule(0.2, 0.045)
    shoe = _rot(shoe, (0, 1, 0), 90)
    shoe.apply_scale((1.0, 0.8, 0.55))
    pair = _join(_at(shoe, y=-0.05), _at(shoe, y=0.05))
    return _textured(pair, _texture("checker", [WHITE, RED, GOLD]))


def _hydrant() -> trimesh.Trimesh:
    body = trimesh.creation.cylinder(0.1, 0.5, sections=40)
    top = _at(trimesh.creation.icosphere(2, 0.1), z=0.25)
    nozzles = [_at(_rot(trimesh.creation.cylinder(0.035, 0.1), (0, 1, 0), 90), x=s * 0.12, z=0.1) for s in (-1, 1)]
    return _coloured(_join(body, top, *nozzles), RED)


def _hammer() -> trimesh.Trimesh:
    handle = _coloured(trimesh.creation.cylinder(0.014, 0.3), BROWN)
    head = _coloured(_at(trimesh.creation.box((0.12, 0.03, 0.035)), z=0.16), BLACK)
    return _join(handle, head)


def _domino() -> trimesh.Trimesh:
    return _textured(trimesh.creation.box((0.048, 0.024, 0.008)), _texture("dots", [BLACK, WHITE]))


def _cat() -> trimesh.Trimesh:
    body = _coloured(_ellipsoid(0.16, 0.07, 0.08), BEIGE)
    head = _coloured(_at(_ellipsoid(0.055, 0.05, 0.05), x=0.17, z=0.08), BROWN)
    tail = _coloured(_at(_rot(trimesh.creation.cylinder(0.012, 0.2), (0, 1, 0), 60), x=-0.22, z=0.06), BROWN)
    return _join(body, head, tail)


def _cheese_box() -> trimesh.Trimesh:
    return _textured(trimesh.creation.box((0.12, 0.12, 0.045)), _texture("stripes", [YELLOW, BLUE]))


def _duck() -> trimesh.Trimesh:
    body = _coloured(_ellipsoid(0.05, 0.04, 0.035), YELLOW)
    head = _coloured(_at(_ellipsoid(0.025, 0.025, 0.025), x=0.035, z=0.045), YELLOW)
    beak = _coloured(_at(_rot(trimesh.creation.cone(0.01, 0.025), (0, 1, 0), 90), x=0.058, z=0.045), ORANGE)
    return _join(body, head, beak)


def _racket() -> trimesh.Trimesh:
    frame = trimesh.creation.torus(0.11, 0.01)
    frame.apply_scale((1.0, 0.8, 1.0))
    handle = _at(_rot(trimesh.creation.cylinder(0.014, 0.3), (0, 1, 0), 90), x=-0.25)
    return _join(_coloured(frame, BLACK), _coloured(handle, LIME))


def _ball(scale_z: float, subdiv: int, pattern: str, colours: list[RGB]) -> Callable[[], trimesh.Trimesh]:
    def build() -> trimesh.Trimesh:
        return _textured(_ellipsoid(0.11, 0.11, 0.11 * scale_z, subdiv), _texture(pattern, colours))
    return build


def _spoon() -> trimesh.Trimesh:
    bowl = _ellipsoid(0.035, 0.022, 0.008)
    handle = _at(trimesh.creation.box((0.2, 0.012, 0.006)), x=-0.13)
    return _coloured(_join(bowl, handle), TAN)


def _cereal() -> trimesh.Trimesh:
    return _textured(trimesh.creation.box((0.19, 0.07, 0.28)), _texture("checker", [RED, YELLOW, WHITE]))


def _car() -> trimesh.Trimesh:
    body = _coloured(trimesh.creation.box((0.16, 0.07, 0.04)), BLUE)
    cabin = _coloured(_at(trimesh.creation.box((0.08, 0.06, 0.035)), x=-0.01, z=0.037), BLUE)
    wheels = [_coloured(_at(_rot(trimesh.creation.cylinder(0.018, 0.012), (1, 0, 0), 90), x=sx * 0.055,
                            y=sy * 0.04, z=-0.02), BLACK) for sx in (-1, 1) for sy in (-1, 1)]
    return _join(body, cabin, *wheels)


def _clock() -> trimesh.Trimesh:
    face = _rot(trimesh.creation.cylinder(0.06, 0.04, sections=48), (1, 0, 0), 90)
    bells = [_at(_ellipsoid(0.025, 0.025, 0.02, 2), x=s * 0.04, z=0.065) for s in (-1, 1)]
    return _coloured(_join(face, *bells), PINK)


def _mouse() -> trimesh.Trimesh:
    return _coloured(_ellipsoid(0.055, 0.032, 0.018), GREY)


def _water_bottle() -> trimesh.Trimesh:
    return _coloured(trimesh.creation.capsule(0.2, 0.035), LIGHTBLUE)


def _partnet_bottle() -> trimesh.Trimesh:
    body = trimesh.creation.cylinder(0.045, 0.16, sections=40)
    neck = _at(_frustum(0.045, 0.015, 0.07), z=0.115)
    return _coloured(_join(body, neck), GREEN)


def _teapot() -> trimesh.Trimesh:
    body = _ellipsoid(0.08, 0.08, 0.06)
    spout = _at(_rot(trimesh.creation.cone(0.018, 0.08), (0, 1, 0), 60), x=0.08, z=0.02)
    handle = _at(_rot(trimesh.creation.torus(0.04, 0.008), (1, 0, 0), 90), x=-0.085)
    return _coloured(_join(body, spout, handle), WHITE)


def _flower_pot() -> trimesh.Trimesh:
    return _coloured(_frustum(0.055, 0.08, 0.12), (170, 85, 45))


def _traffic_cone() -> trimesh.Trimesh:
    cone = _textured(trimesh.creation.cone(0.14, 0.7, sections=40), _texture("stripes", [ORANGE, WHITE]))
    return cone


def _cap() -> trimesh.Trimesh:
    dome = _ellipsoid(0.09, 0.09, 0.06)
    brim = _at(trimesh.creation.box((0.09, 0.12, 0.006)), x=0.09, z=-0.01)
    return _coloured(_join(dome, brim), NAVY)


def _paddle() -> trimesh.Trimesh:
    blade = _coloured(_ellipsoid(0.075, 0.07, 0.006), RED)
    handle = _coloured(_at(trimesh.creation.box((0.1, 0.028, 0.022)), x=-0.11), BLACK)
    return _join(blade, handle)


def _pawn() -> trimesh.Trimesh:
    foot = trimesh.creation.cylinder(0.016, 0.008, sections=32)
    stem = _at(_frustum(0.011, 0.006, 0.03, 32), z=0.018)
    head = _at(trimesh.creation.icosphere(2, 0.009), z=0.04)
    return _coloured(_join(foot, stem, head), BLACK)


def _dice() -> trimesh.Trimesh:
    return _textured(trimesh.creation.box((0.016, 0.016, 0.016)), _texture("dots", [WHITE, BLACK]))


def _banana() -> trimesh.Trimesh:
    m = _rot(trimesh.creation.capsule(0.16, 0.018, count=[24, 24]), (0, 1, 0), 90)
    v = m.vertices.copy()
    v[:, 2] += 4.0 * v[:, 0] ** 2
    return _coloured(trimesh.Trimesh(v, m.faces), YELLOW)


def _apple() -> trimesh.Trimesh:
    body = _coloured(_ellipsoid(0.04, 0.04, 0.036), RED)
    stem = _coloured(_at(trimesh.creation.cylinder(0.003, 0.02), z=0.042), BROWN)
    leaf = _coloured(_at(_ellipsoid(0.012, 0.005, 0.002, 2), x=0.01, z=0.048), GREEN)
    return _join(body, stem, leaf)


def _candle() -> trimesh.Trimesh:
    wax = _coloured(trimesh.creation.cylinder(0.025, 0.15, sections=40), BEIGE)
    wick = _coloured(_at(trimesh.creation.cylinder(0.002, 0.015), z=0.082), BLACK)
    return _join(wax, wick)


def _remote() -> trimesh.Trimesh:
    return _textured(trimesh.creation.box((0.19, 0.05, 0.022)), _texture("dots", [BLACK, GREY]))


def _screwdriver() -> trimesh.Trimesh:
    handle = _coloured(trimesh.creation.cylinder(0.016, 0.1, sections=6), YELLOW)
    shaft = _coloured(_at(trimesh.creation.cylinder(0.003, 0.12), z=0.11), GREY)
    return _join(handle, shaft)


def _brush() -> trimesh.Trimesh:
    handle = _coloured(trimesh.creation.cylinder(0.006, 0.16), RED)
    ferrule = _coloured(_at(trimesh.creation.cylinder(0.008, 0.03), z=0.095), GREY)
    bristles = _coloured(_at(_frustum(0.008, 0.004, 0.03), z=0.125), BLACK)
    return _join(handle, ferrule, bristles)


def _wine_glass() -> trimesh.Trimesh:
    foot = trimesh.creation.cylinder(0.035, 0.004)
    stem = _at(trimesh.creation.cylinder(0.004, 0.09), z=0.047)
    bowl = _at(_frustum(0.02, 0.04, 0.08), z=0.13)
    return _coloured(_join(foot, stem, bowl), LIGHTBLUE)


def _bowl() -> trimesh.Trimesh:
    return _coloured(_frustum(0.045, 0.08, 0.06, 64), TEAL)


def _sofa() -> trimesh.Trimesh:
    seat = trimesh.creation.box((1.8, 0.8, 0.4))
    back = _at(trimesh.creation.box((1.8, 0.2, 0.5)), y=0.3, z=0.45)
    arms = [_at(trimesh.creation.box((0.2, 0.8, 0.3)), x=s * 0.9, z=0.35) for s in (-1, 1)]
    return _coloured(_join(seat, back, *arms), GREEN)


def _chair() -> trimesh.Trimesh:
    seat = trimesh.creation.box((0.45, 0.45, 0.04))
    legs = [_at(trimesh.creation.box((0.04, 0.04, 0.45)), x=sx * 0.2, y=sy * 0.2, z=-0.24)
            for sx in (-1, 1) for sy in (-1, 1)]
    back = _at(trimesh.creation.box((0.45, 0.04, 0.5)), y=0.2, z=0.27)
    return _coloured(_join(seat, back, *legs), BROWN)


def _procedural() -> trimesh.Trimesh:
    pts = np.random.default_rng(17).normal(0, (0.06, 0.03, 0.045), (40, 3))
    return _coloured(trimesh.convex.convex_hull(pts), MAROON)


def _headphones() -> trimesh.Trimesh:
    band = _rot(trimesh.creation.torus(0.085, 0.008), (1, 0, 0), 90)
    cups = [_at(_rot(trimesh.creation.cylinder(0.035, 0.03), (0, 1, 0), 90), x=s * 0.085, z=-0.03) for s in (-1, 1)]
    return _coloured(_join(band, *cups), BLACK)


def _umbrella() -> trimesh.Trimesh:
    canopy = _coloured(_at(trimesh.creation.cone(0.45, 0.2, sections=8), z=0.8), PURPLE)
    stick = _coloured(_at(trimesh.creation.cylinder(0.01, 0.85), z=0.42), BLACK)
    return _join(canopy, stick)


def _guitar() -> trimesh.Trimesh:
    lower = _ellipsoid(0.09, 0.07, 0.03)
    upper = _at(_ellipsoid(0.065, 0.055, 0.03), x=0.12)
    neck = _at(trimesh.creation.box((0.2, 0.025, 0.015)), x=0.27)
    return _coloured(_join(lower, upper, neck), TAN)


def _marker(colour: RGB, length: float) -> Callable[[], trimesh.Trimesh]:
    def build() -> trimesh.Trimesh:
        body = trimesh.creation.cylinder(0.008, length, sections=24)
        tip = _at(trimesh.creation.cone(0.008, 0.015, sections=24), z=length / 2)
        return _coloured(_join(body, tip), colour)
    return build


def _dtc_mug() -> trimesh.Trimesh:
    body = trimesh.creation.cylinder(0.045, 0.08, sections=48)
    handle = _at(_rot(trimesh.creation.torus(0.025, 0.008), (1, 0, 0), 90), x=0.05)
    return _coloured(_join(body, handle), NAVY)


def _dtc_bowl() -> trimesh.Trimesh:
    return _coloured(_frustum(0.05, 0.09, 0.05, 64), GREEN)


def _dtc_toy_truck() -> trimesh.Trimesh:
    body = _coloured(trimesh.creation.box((0.2, 0.08, 0.06)), RED)
    cab = _coloured(_at(trimesh.creation.box((0.06, 0.08, 0.05)), x=0.07, z=0.055), RED)
    wheels = [_coloured(_at(_rot(trimesh.creation.cylinder(0.02, 0.015), (1, 0, 0), 90), x=sx * 0.07,
                            y=sy * 0.045, z=-0.03), BLACK) for sx in (-1, 1) for sy in (-1, 1)]
    return _join(body, cab, *wheels)


def _recoloured(builder: Callable[[], trimesh.Trimesh], colour: RGB | None = None,
                texture: Image.Image | None = None) -> Callable[[], trimesh.Trimesh]:
    """The same mesh with another flat colour or texture (a recolour: same geometry, other look)."""
    def build() -> trimesh.Trimesh:
        mesh = builder()
        plain = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        return _textured(plain, texture) if texture is not None else _coloured(plain, colour or WHITE)
    return build


def _juice_carton() -> trimesh.Trimesh:
    """An orange juice carton whose print is mostly brown and gold: its texture's mean is not orange."""
    return _textured(trimesh.creation.box((0.07, 0.07, 0.2)), _texture("checker", [(150, 90, 40), (205, 160, 45),
                                                                                    ORANGE]))


def _patterned_bowl(colours: list[RGB]) -> Callable[[], trimesh.Trimesh]:
    def build() -> trimesh.Trimesh:
        return _textured(_frustum(0.045, 0.075, 0.055, 64), _texture("dots", colours))
    return build


def _dispenser() -> trimesh.Trimesh:
    body = _coloured(trimesh.creation.box((0.12, 0.1, 0.2)), WHITE)
    nozzle = _coloured(_at(trimesh.creation.cylinder(0.012, 0.05), x=0.07, z=0.02), PINK)
    return _join(body, nozzle)


def _worm() -> trimesh.Trimesh:
    return _coloured(_rot(trimesh.creation.capsule(0.4, 0.01, count=[16, 16]), (0, 1, 0), 90), PINK)


def _sauce() -> trimesh.Trimesh:
    body = trimesh.creation.cylinder(0.022, 0.11, sections=6)
    neck = _at(_frustum(0.022, 0.008, 0.04, 6), z=0.075)
    return _join(body, neck)


def _obj_duck() -> trimesh.Trimesh:
    """pybullet's duck, in short: an OBJ whose .mtl says Kd 0.64 beside a texture of (255, 216, 0)."""
    body = _join(_ellipsoid(0.05, 0.04, 0.035), _at(_ellipsoid(0.025, 0.025, 0.025), x=0.035, z=0.045))
    return _textured(body, Image.new("RGB", (64, 64), (255, 216, 0)))


ENTRIES: list[Entry] = [
    Entry("red_coffee_mug", "Red coffee mug", "kitchenware", "mug", _mug),
    Entry("soccer_ball", "Soccer ball", "sports", "ball", _ball(1.0, 3, "patches", [WHITE, BLACK])),
    Entry("ketchup_bottle", "Ketchup bottle", "food", "bottle", _recoloured(_ketchup, RED)),
    Entry("ketchup_bottle_blue", "Ketchup bottle (blue recolour)", "food", "bottle", _recoloured(_ketchup, BLUE),
          recolour_of="ketchup_bottle"),
    Entry("partnet_bottle_3763", "Bottle (PartNet-Mobility 3763)", "kitchenware", "bottle", _partnet_bottle),
    Entry("stanford_bunny_hr", "Stanford bunny (high-res)", "animal", "bunny", _bunny),
    Entry("teddy_hull", "Teddy bear convex-hull approximation", "toy", "bear", _teddy),
    Entry("desk_lamp", "Desk lamp", "lighting", "lamp", _lamp),
    Entry("sneakers", "Sneakers", "clothing", "sneakers", _sneakers),
    Entry("fire_hydrant", "Fire hydrant", "furniture", "hydrant", _hydrant),
    Entry("hammer", "Hammer", "tool", "hammer", _hammer),
    Entry("domino_0042", "Domino 0042", "toy", "domino", _domino),
    Entry("siamese_cat", "Siamese cat", "animal", "cat", _cat),
    Entry("cheese_box", "Cheese box", "food", "box", _cheese_box),
    Entry("alphabet_soup", "Alphabet soup can", "food", "can",
          _recoloured(_soup_can, texture=_texture("stripes", [ORANGE, WHITE]))),
    Entry("alphabet_soup_red", "Alphabet soup can (red recolour)", "food", "can",
          _recoloured(_soup_can, texture=_texture("stripes", [RED, WHITE])), recolour_of="alphabet_soup"),
    Entry("rubber_duck", "Rubber duck", "toy", "duck", _duck),
    Entry("tennis_racket", "Tennis racket", "sports", "racket", _racket),
    Entry("basketball", "Basketball", "sports", "basketball", _ball(0.93, 4, "stripes", [ORANGE, BLACK])),
    Entry("volleyball_lr", "Volleyball (low-res)", "sports", "volleyball", _ball(0.8, 1, "stripes", [YELLOW, BLUE])),
    Entry("wooden_spoon", "Wooden spoon", "kitchenware", "spoon", _spoon),
    Entry("cereal_box", "Cereal box", "food", "box", _cereal),
    Entry("toy_car", "Toy car", "toy", "car", _car),
    Entry("alarm_clock", "Alarm clock", "electronics", "clock", _clock),
    Entry("computer_mouse", "Computer mouse", "electronics", "mouse", _mouse),
    Entry("water_bottle_copy", "Water bottle (copy)", "kitchenware", "bottle", _water_bottle),
    Entry("teapot", "Teapot", "kitchenware", "teapot", _teapot),
    Entry("flower_pot", "Flower pot", "garden", "pot", _flower_pot),
    Entry("traffic_cone", "Traffic cone", "outdoor", "cone", _traffic_cone),
    Entry("baseball_cap", "Baseball cap", "clothing", "cap", _cap),
    Entry("tt_paddle", "Table tennis paddle", "sports", "paddle", _paddle),
    Entry("chess_pawn", "Chess pawn (primitive)", "toy", "pawn", _pawn),
    Entry("dice_copy", "Dice 6 (copy)", "toy", "dice", _dice),
    Entry("banana", "Banana", "food", "banana", _banana),
    Entry("apple", "Apple", "food", "apple", _apple),
    Entry("candle", "Candle", "decor", "candle", _candle),
    Entry("remote_control", "Remote control", "electronics", "control", _remote),
    Entry("screwdriver", "Screwdriver", "tool", "screwdriver", _screwdriver),
    Entry("paint_brush", "Paint brush", "tool", "brush", _brush),
    Entry("wine_glass", "Wine glass", "kitchenware", "glass", _wine_glass),
    Entry("bowl_2", "Bowl 2", "kitchenware", "bowl", _bowl),
    Entry("sofa", "Sofa", "furniture", "sofa", _sofa),
    Entry("wooden_chair", "Wooden chair", "furniture", "chair", _chair),
    Entry("random_17", "Random object 17 (procedural)", "misc", None, _procedural),
    Entry("headphones", "Headphones", "electronics", "headphones", _headphones),
    Entry("umbrella", "Umbrella", "accessory", "umbrella", _umbrella),
    Entry("toy_guitar", "Toy guitar", "toy", "guitar", _guitar),
    # the cases: the name's colour beats a texture's mean, compounds and proper nouns, an OBJ + .mtl
    Entry("juice_carton", "Orange juice carton", "food", "carton", _juice_carton),
    Entry("black_bowl", "Black bowl", "kitchenware", "bowl", _patterned_bowl([WHITE, BLACK])),
    Entry("white_bowl", "White bowl", "kitchenware", "bowl", lambda: _coloured(_frustum(0.04, 0.085, 0.045, 64), WHITE)),
    Entry("ice_cream_dispenser", "Ice-cream dispenser", "kitchenware", "dispenser", _dispenser),
    Entry("earthworm", "Earthworm (scan, 5 m export)", "animal", "earthworm", _worm),
    Entry("duck_obj", "Duck", "toy", "duck", _obj_duck, fmt="obj"),
    # different objects whose plain captions would be equal: told apart by what is seen (proportions, shade)
    Entry("block_cube", "Wooden block", "toy", "block", lambda: _coloured(trimesh.creation.box((0.05,) * 3), TAN)),
    Entry("block_plank", "Wooden block", "toy", "block",
          lambda: _coloured(trimesh.creation.box((0.2, 0.05, 0.05)), TAN)),
    Entry("hot_sauce", "Hot sauce bottle", "food", "bottle", _recoloured(_sauce, (235, 40, 45))),
    Entry("hot_sauce_dark", "Hot sauce bottle", "food", "bottle", _recoloured(_sauce, (150, 20, 25)),
          recolour_of="hot_sauce"),
    # DTC folders without a person-written name: the category (from the folder name) is the noun
    Entry("dtc_marker_peach", None, "marker", "marker", _marker((250, 180, 140), 0.13), dtc_folder="Markers_B07Z5P84J2_Peach"),
    Entry("dtc_marker_teal", None, "marker", "marker", _marker(TEAL, 0.1), dtc_folder="Markers_B07Z5Q11K8_Teal"),
    Entry("dtc_mug_navy", None, "mug", "mug", _dtc_mug, dtc_folder="Mugs_B09ABCDE12_Navy"),
    Entry("dtc_bowl_green", None, "bowl", "bowl", _dtc_bowl, dtc_folder="Bowls_B0C7Q8R9S1_Green"),
    Entry("dtc_volleyball", None, "ball", "volleyball", _ball(0.88, 3, "stripes", [WHITE, GOLD]),
          dtc_folder="Ball_B07XK2LMN3_Volleyball"),
    Entry("dtc_truck", None, "toy", "toy", _dtc_toy_truck, dtc_folder="Toy_B0D4E5F6G7_TruckRed"),
]


LAYOUTS = ("folder", "dtc", "obj")
# Written by hand per named entry: the compound noun a caption must keep as the name says it (the case of
# a proper noun included) and the colour words of the name (they win over a texture's mean).
COMPOUNDS = {
    "red_coffee_mug": "coffee mug", "soccer_ball": "soccer ball", "ketchup_bottle": "ketchup bottle",
    "ketchup_bottle_blue": "ketchup bottle", "stanford_bunny_hr": "Stanford bunny", "teddy_hull": "teddy bear",
    "desk_lamp": "desk lamp", "fire_hydrant": "fire hydrant", "siamese_cat": "Siamese cat",
    "cheese_box": "cheese box", "alphabet_soup": "alphabet soup can", "alphabet_soup_red": "alphabet soup can",
    "rubber_duck": "rubber duck", "tennis_racket": "tennis racket", "wooden_spoon": "wooden spoon",
    "cereal_box": "cereal box", "toy_car": "toy car", "alarm_clock": "alarm clock",
    "computer_mouse": "computer mouse", "water_bottle_copy": "water bottle", "flower_pot": "flower pot",
    "traffic_cone": "traffic cone", "baseball_cap": "baseball cap", "tt_paddle": "table tennis paddle",
    "chess_pawn": "chess pawn", "remote_control": "remote control", "paint_brush": "paint brush",
    "wine_glass": "wine glass", "wooden_chair": "wooden chair", "toy_guitar": "toy guitar",
    "juice_carton": "orange juice carton", "ice_cream_dispenser": "ice-cream dispenser",
    "block_cube": "wooden block", "block_plank": "wooden block", "hot_sauce": "hot sauce bottle",
    "hot_sauce_dark": "hot sauce bottle",
}
NAME_COLOURS = {"red_coffee_mug": ["red"], "ketchup_bottle_blue": ["blue"], "alphabet_soup_red": ["red"],
                "juice_carton": ["orange"], "black_bowl": ["black"], "white_bowl": ["white"]}


def _dtc_id(slug: str) -> str:
    return "B0" + hashlib.sha256(slug.encode()).hexdigest()[:8].upper().replace("A", "K")


def _camel(slug: str) -> str:
    return "".join(w.capitalize() for w in re.split(r"[_\W]+", slug) if w and not w.isdigit())


def _write_obj(mesh: trimesh.Trimesh, path: Path) -> None:
    """``mesh`` as a scan ships it: ``model.obj`` + ``model.mtl`` (``Kd 0.64``, as pybullet's and many
    exporters' .mtl files say) + ``texture.png`` for a textured mesh; vertex colours on the ``v`` lines (no
    .mtl) for the others."""
    visual = mesh.visual
    image = getattr(getattr(visual, "material", None), "baseColorTexture", None)
    lines = ["mtllib model.mtl", "usemtl material0"]
    if image is not None:
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in visual.uv]
        lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in mesh.faces]
        image.save(path.parent / "texture.png")
        mtl = "newmtl material0\nKa 0 0 0\nKd 0.64 0.64 0.64\nKs 0.5 0.5 0.5\nmap_Kd texture.png\n"
    else:  # vertex colours on the v lines and no material (a material's Kd would be rendered instead)
        cols = np.asarray(visual.vertex_colors)[:, :3] / 255.0
        lines = [f"v {x:.6f} {y:.6f} {z:.6f} {r:.4f} {g:.4f} {b:.4f}" for (x, y, z), (r, g, b) in zip(mesh.vertices, cols)]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
        mtl = ""
    path.write_text("\n".join(lines) + "\n")
    if mtl:
        (path.parent / "model.mtl").write_text(mtl)


def build_named_library(root: Path, layout: str = "folder", only: set[str] | None = None) -> dict[str, dict]:
    """Write the library under ``root`` in ``layout`` ("folder": ``<slug>/model.glb``; "dtc":
    ``<Category>_<ID>_<Variant>/3d-asset.glb``; "obj": ``<slug>/model.obj`` + ``model.mtl``, textures and
    vertex colours as scans ship them), each named entry with ``metadata.json`` {name, category}.
    Unnamed entries are DTC folders in both trees. Returns slug -> truth (folder, name, category, noun,
    recolour_of, textured, compound, colours); also written to ``root/truth.json``. ``only``: these slugs
    alone (a bench's smoke run)."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    root.mkdir(parents=True, exist_ok=True)
    y_up = trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0))  # our Z-up -> glTF's Y-up
    truth: dict[str, dict] = {}
    for e in ENTRIES:
        if only is not None and e.slug not in only:
            continue
        if e.dtc_folder is not None:
            folder, model = e.dtc_folder, "3d-asset.glb"
        elif layout == "dtc":
            folder, model = f"{e.category.capitalize()}_{_dtc_id(e.slug)}_{_camel(e.slug)}", "3d-asset.glb"
        else:
            folder, model = e.slug, "model.glb"
        target = root / folder
        target.mkdir(parents=True, exist_ok=True)
        mesh = e.build()
        mesh.apply_transform(y_up)
        if e.fmt == "obj" or (layout == "obj" and e.dtc_folder is None):
            model = "model.obj"
            _write_obj(mesh, target / model)
        else:
            mesh.export(target / model)
        if e.name is not None:
            (target / "metadata.json").write_text(json.dumps({"name": e.name, "category": e.category}))
        truth[e.slug] = {"folder": folder, "name": e.name, "category": e.category, "noun": e.noun,
                         "recolour_of": e.recolour_of, "faces": int(len(mesh.faces)),
                         "textured": getattr(getattr(mesh.visual, "material", None), "baseColorTexture", None)
                         is not None, "compound": COMPOUNDS.get(e.slug), "colours": NAME_COLOURS.get(e.slug, [])}
    (root / "truth.json").write_text(json.dumps(truth, indent=1, sort_keys=True))
    return truth


# --- figures ----------------------------------------------------------------------------------------------
def _words(text: str) -> list[str]:
    return re.findall(r"[a-z]+(?:-[a-z]+)*|\d+", text.lower())


def _singular(word: str) -> str:
    from mixcount.catalog.naming import singular

    return singular(word)


def has_noun(text: str, noun: str) -> bool:
    """The noun (or its singular/plural) is a word of ``text``."""
    target = _singular(noun)
    return any(_singular(w) == target for w in _words(text))


def caption_figures(rows: list[dict], truth: dict[str, dict]) -> dict:
    """Figures of the issue over captioned rows of ACTIVE objects.

    ``rows``: dicts with ``folder`` (the object's library folder), ``status`` and ``captions`` ({short,
    concise, detailed} or None), as ``catalog list --json`` gives them (folder = model_path's parent name).
    """
    by_folder = {t["folder"]: (slug, t) for slug, t in truth.items()}
    active = [r for r in rows if r["status"] == "active"]
    with_noun = noun_kept = tacked = fragments = uncaptioned = 0
    details: dict[str, list[str]] = {"noun_missing": [], "tacked": [], "fragments": []}
    texts: dict[str, dict[str, list[str]]] = {"short": {}, "concise": {}, "detailed": {}}
    for r in active:
        slug, t = by_folder[r["folder"]]
        caps = r.get("captions")
        if not caps:
            uncaptioned += 1
            continue
        for tier in texts:
            texts[tier].setdefault(" ".join(caps[tier].lower().rstrip(".").split()), []).append(slug)
        if t["noun"]:
            with_noun += 1
            if has_noun(caps["short"], t["noun"]) and has_noun(caps["concise"], t["noun"]):
                noun_kept += 1
            else:
                details["noun_missing"].append(f"{slug}: {caps['short']!r} / {caps['concise']!r}")
        name_words = set(_words(t["name"] or t["folder"]))
        cat_words = set(_words(t["category"]))
        broad = (cat_words | BROAD_CATEGORIES) - name_words - ({_singular(t["noun"])} if t["noun"] else set())
        if any(w in broad or _singular(w) in broad for tier in ("short", "concise") for w in _words(caps[tier])):
            tacked += 1
            details["tacked"].append(f"{slug}: {caps['short']!r} / {caps['concise']!r}")
        bad = [w for tier in ("short", "concise", "detailed") for w in _words(caps[tier])
               if w in BOOKKEEPING or (tier != "detailed" and any(c.isdigit() for c in w))]
        bad += [w for w in re.findall(r"\b[A-Z0-9]*\d[A-Z0-9]{4,}\b", " ".join(caps.values()))]
        if bad:
            fragments += 1
            details["fragments"].append(f"{slug}: {sorted(set(bad))}")
    shared = {tier: sorted(ss for ss in groups.values() if len(ss) > 1) for tier, groups in texts.items()}
    person = person_figures(active, by_folder)
    return {
        "active": len(active),
        "with_noun": with_noun,
        "noun_in_short_and_concise": noun_kept,
        "noun_share": round(noun_kept / with_noun, 3) if with_noun else None,
        "category_tacked_on": tacked,
        "bookkeeping_fragments": fragments,
        "uncaptioned": uncaptioned,
        "shared_captions": {tier: len(v) for tier, v in shared.items()},
        "shared_detail": shared,
        "details": details,
        **person,
    }


# what no tier may say (independent of the caption check's own patterns): numbers (sizes, shares, counts)
# and words about the mesh or its size
MESH_WORDS = {"surface", "watertight", "non-watertight", "parts", "part", "percent", "vertices", "faces",
              "triangles", "mesh", "irregular", "compact"}
SIZE_UNITS = {"cm", "mm", "m", "measures", "measuring", "inches", "inch", "metres", "meters"}


def person_figures(active: list[dict], by_folder: dict[str, tuple[str, dict]]) -> dict:
    """Figures of issue 50 over captioned active rows: mesh facts and absolute sizes in any tier, the name's
    colour words, compound nouns (proper nouns case-sensitive) and head nouns kept in short and concise."""
    mesh = sizes = colour_total = colour_kept = compound_total = compound_kept = 0
    misses: dict[str, list[str]] = {"mesh_facts": [], "sizes": [], "colour_lost": [], "compound_lost": []}
    for r in active:
        slug, t = by_folder[r["folder"]]
        caps = r.get("captions")
        if not caps:
            continue
        words = [w for tier in ("short", "concise", "detailed") for w in _words(caps[tier])]
        if set(words) & MESH_WORDS or "%" in " ".join(caps.values()):
            mesh += 1
            misses["mesh_facts"].append(f"{slug}: {caps['detailed']!r}")
        if set(words) & SIZE_UNITS or any(w.isdigit() for w in words):
            sizes += 1
            misses["sizes"].append(f"{slug}: {caps['detailed']!r}")
        pair = caps["short"] + " | " + caps["concise"]
        for colour in t.get("colours") or []:
            colour_total += 1
            if all(colour in _words(caps[tier]) for tier in ("short", "concise")):
                colour_kept += 1
            else:
                misses["colour_lost"].append(f"{slug}: {pair!r}")
        compound = t.get("compound")
        if compound:
            compound_total += 1
            proper = compound != compound.lower()
            if all((compound in caps[tier]) if proper else (compound in caps[tier].lower())
                   for tier in ("short", "concise")):
                compound_kept += 1
            else:
                misses["compound_lost"].append(f"{slug}: {pair!r}")
    return {
        "mesh_facts": mesh, "absolute_sizes": sizes,
        "name_colours": colour_total, "name_colours_kept": colour_kept,
        "name_colour_share": round(colour_kept / colour_total, 3) if colour_total else None,
        "compounds": compound_total, "compounds_kept": compound_kept,
        "compound_share": round(compound_kept / compound_total, 3) if compound_total else None,
        "person_misses": misses,
    }


def rows_from_list_json(records: list[dict]) -> list[dict]:
    """``catalog list --json`` records -> rows for :func:`caption_figures`."""
    return [{"folder": Path(r["model_path"]).parent.name, "status": r["status"], "captions": r.get("captions"),
             "id": r["id"]} for r in records if r.get("model_path")]
