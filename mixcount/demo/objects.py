"""The demo library's object builders: one ``build_<kind>(k, rng)`` per everyday category (the k-th
variant, drawn from ``rng``), the containers, and the non-manifold tote; each returns a :class:`Spec`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from PIL import Image, ImageDraw

from mixcount.demo.geometry import Part, box, extrude, polygon, revolve, star, torus
from mixcount.demo.textures import (
    letter,
    pips,
    rgb,
    solid_colors,
    tex_atlas,
    tex_dots,
    tex_gradient,
    tex_label,
    tex_speckle,
    tex_stripes,
    vertex_colors_by_height,
)


@dataclass
class Spec:
    """A built object: parts plus catalog-facing names."""

    category: str
    variant: str
    parts: list[Part]
    description: str
    container: bool = False
    extra: dict[str, Any] = field(default_factory=dict)


def _img_part(geom: tuple[np.ndarray, np.ndarray, np.ndarray], image: Image.Image, rough: float = 0.5,
              metal: float = 0.0, offset: tuple[float, float, float] = (0, 0, 0)) -> Part:
    v, f, uv = geom
    return Part(v, f, uv, image=image, roughness=rough, metallic=metal, offset=offset)


def _col_part(geom: tuple[np.ndarray, np.ndarray, np.ndarray], colors: np.ndarray, rough: float = 0.5,
              metal: float = 0.0, offset: tuple[float, float, float] = (0, 0, 0)) -> Part:
    v, f, uv = geom
    return Part(v, f, uv, colors=colors, roughness=rough, metallic=metal, offset=offset)


def sphere_profile(r: float, n: int = 16, squash: float = 1.0) -> list[tuple[float, float]]:
    phi = np.linspace(0, np.pi, n + 1)
    pts = []
    for p in phi:
        rr = r * np.sin(p)
        z = -r * np.cos(p) * squash
        pts.append((rr, z + r * squash))
    pts[0] = (0.0, pts[0][1])
    pts[-1] = (0.0, pts[-1][1])
    return pts


BALLS = [  # variant, radius m, texture kind, colours
    ("Tennis", 0.0335, "seam", [(204, 230, 60), (250, 250, 245)]),
    ("Golf", 0.0214, "dots", [(245, 245, 240), (200, 200, 195)]),
    ("Beach", 0.11, "segments", [(230, 40, 40), (250, 250, 250), (40, 90, 220), (250, 210, 30)]),
    ("Bouncy", 0.016, "vertex", [(160, 40, 200)]),
    ("Soccer", 0.055, "dots", [(250, 250, 250), (20, 20, 20)]),
    ("Rubber", 0.03, "vertex", [(40, 170, 90)]),
]


def build_ball(k: int, rng: np.random.Generator) -> Spec:
    variant, r, kind, cols = BALLS[k % len(BALLS)]
    r *= float(rng.uniform(0.97, 1.03))
    geom = revolve(sphere_profile(r, 18), 36)
    if kind == "vertex":
        part = _col_part(geom, solid_colors(geom[0], cols[0], rng, 6), rough=0.35)
    else:
        if kind == "seam":
            img = tex_speckle(cols[0], rng, 12)
            d = ImageDraw.Draw(img)
            xs = np.linspace(0, 128, 65)
            d.line([(x, 64 + 30 * np.sin(x / 128 * 4 * np.pi)) for x in xs], fill=cols[1], width=4)
        elif kind == "dots":
            img = tex_dots(cols[0], cols[1], 90 if variant == "Golf" else 14, rng)
        else:
            img = tex_stripes(cols, 8)
        part = _img_part(geom, img, rough=0.6 if variant != "Beach" else 0.3)
    return Spec("ball", variant, [part], f"a {variant.lower()} ball")


MARKER_COLOURS = [("Peach", (250, 170, 130)), ("Blue", (40, 80, 210)), ("Red", (210, 30, 40)),
                  ("Green", (30, 160, 70)), ("Black", (25, 25, 25)), ("Yellow", (245, 215, 40))]


def build_marker(k: int, rng: np.random.Generator) -> Spec:
    variant, col = MARKER_COLOURS[k % len(MARKER_COLOURS)]
    r = float(rng.uniform(0.0075, 0.0095))
    length = float(rng.uniform(0.11, 0.135))
    body = revolve([(0, 0), (r, 0), (r, length), (0, length)], 24)
    label = tex_label((245, 245, 245), col, "MARK", (256, 64))
    cap_len = length * 0.3
    cap = revolve([(0, 0), (r * 1.12, 0), (r * 1.12, cap_len), (r * 0.6, cap_len * 1.08), (0, cap_len * 1.08)], 24)
    return Spec("marker", variant, [
        _img_part(body, label, rough=0.45),
        _col_part(cap, solid_colors(cap[0], col, rng, 4), rough=0.4, offset=(0, 0, length * 0.93)),
    ], f"a {variant.lower()} marker with a white barrel")


FRUIT = [("Apple", (200, 30, 35), (120, 170, 40)), ("Orange", (245, 140, 20), None),
         ("Lemon", (250, 225, 50), None), ("Plum", (90, 30, 100), None),
         ("Pear", (170, 200, 60), (200, 170, 60)), ("Lime", (90, 180, 40), None), ("GreenApple", (120, 200, 60), (200, 220, 80))]


def build_fruit(k: int, rng: np.random.Generator) -> Spec:
    variant, col, col2 = FRUIT[k % len(FRUIT)]
    if variant in ("Apple", "GreenApple"):  # dimpled at both poles, widest above the middle
        sc = float(rng.uniform(0.9, 1.1))
        prof = [(0, 0.005), (0.01, 0.002), (0.024, 0.005), (0.035, 0.016), (0.04, 0.03), (0.039, 0.042),
                (0.032, 0.053), (0.02, 0.058), (0.009, 0.055), (0, 0.05)]
        prof = [(x * sc, z * sc) for x, z in prof]
    elif variant == "Pear":  # wide bottom, narrow neck
        sc = float(rng.uniform(0.9, 1.1))
        prof = [(0, 0), (0.018, 0.002), (0.029, 0.014), (0.031, 0.029), (0.025, 0.044), (0.017, 0.056),
                (0.014, 0.068), (0.01, 0.078), (0, 0.082)]
        prof = [(x * sc, z * sc) for x, z in prof]
    elif variant in ("Lemon", "Lime"):
        r = float(rng.uniform(0.027, 0.032))
        prof = [(x * 0.75, z * 1.3) for x, z in sphere_profile(r, 18)]
    else:
        r = float(rng.uniform(0.025, 0.04))
        prof = sphere_profile(r, 18, squash=0.95)
    geom = revolve(prof, 32)
    if col2 is not None:
        part = _img_part(geom, tex_gradient(col2, col), rough=0.4)
    elif variant in ("Orange", "Lemon"):
        part = _img_part(geom, tex_speckle(col, rng, 16), rough=0.7)
    else:
        part = _col_part(geom, vertex_colors_by_height(geom[0], col, tuple(min(255, c + 40) for c in col)), rough=0.5)
    return Spec("fruit", variant, [part], f"a {variant.lower()}")


def build_block(k: int, rng: np.random.Generator) -> Spec:
    hue = (0.13 * k + 0.05) % 1.0
    col = rgb(hue, 0.75, 0.9)
    edge = float(rng.choice([0.03, 0.035, 0.04, 0.05]))
    letters = "ABCDEFGHJKLMNPRSTUVWXYZ"
    cells = [letter(letters[(k * 6 + i) % len(letters)], rgb(hue + 0.5, 0.8, 0.5)) for i in range(6)]
    img = tex_atlas(cells, col)
    names = ["Red", "Orange", "Yellow", "Green", "Teal", "Blue", "Purple", "Pink"]
    return Spec("block", f"{names[int(hue * 8) % 8]}{letters[k * 6 % len(letters)]}",
                [_img_part(box((edge, edge, edge), atlas=(3, 2)), img, rough=0.7)], "a wooden letter block")


def build_mug(k: int, rng: np.random.Generator) -> Spec:
    variants = [("White", (240, 240, 235)), ("Navy", (30, 40, 90)), ("Terracotta", (190, 90, 60)), ("Mint", (150, 220, 190))]
    variant, col = variants[k % len(variants)]
    r = float(rng.uniform(0.038, 0.045))
    h = float(rng.uniform(0.085, 0.1))
    t = 0.004
    body = revolve([(0, 0), (r, 0), (r, h), (r - t, h), (r - t, t), (0, t)], 40)
    handle = torus(h * 0.28, 0.006, 20, 10)
    # stand the handle ring up (ring in the XZ plane) beside the body
    hv = handle[0][:, [0, 2, 1]] * np.array([1, -1, 1])
    handle = (hv, handle[1], handle[2])
    if k % 2 == 0:
        img = tex_stripes([col, rgb(0.6 + k * 0.1, 0.6, 0.8)], 2, vertical=False)
        parts = [_img_part(body, img, rough=0.25)]
    else:
        parts = [_col_part(body, solid_colors(body[0], col, rng, 3), rough=0.25)]
    parts.append(_col_part(handle, solid_colors(handle[0], col, rng, 3), rough=0.25, offset=(r + h * 0.2, 0, h * 0.5)))
    return Spec("mug", variant, parts, f"a {variant.lower()} ceramic mug")


def build_bottle(k: int, rng: np.random.Generator) -> Spec:
    variants = [("Water", (170, 210, 240), "AQUA"), ("Juice", (250, 160, 40), "JUICE"), ("Soda", (40, 160, 60), "FIZZ"),
                ("Milk", (250, 250, 250), "MILK"), ("Oil", (200, 180, 60), "OLIO")]
    variant, col, text = variants[k % len(variants)]
    r = float(rng.uniform(0.028, 0.036))
    h = float(rng.uniform(0.18, 0.24))
    nr = r * 0.35
    prof = [(0, 0), (r, 0), (r, h * 0.62), (r * 0.75, h * 0.75), (nr, h * 0.86), (nr, h), (0, h)]
    body = revolve(prof, 32)
    cap = revolve([(0, 0), (nr * 1.15, 0), (nr * 1.15, 0.018), (0, 0.018)], 20)
    return Spec("bottle", variant, [
        _img_part(body, tex_label(col, rgb(0.1 * k, 0.7, 0.6), text), rough=0.15),
        _col_part(cap, solid_colors(cap[0], rgb(0.17 * k + 0.3, 0.8, 0.8), rng, 3), rough=0.4, offset=(0, 0, h - 0.004)),
    ], f"a plastic {variant.lower()} bottle with a label")


def build_die(k: int, rng: np.random.Generator) -> Spec:
    variants = [("White", (245, 245, 240), (20, 20, 20)), ("Red", (200, 20, 30), (250, 250, 250)),
                ("Black", (25, 25, 25), (250, 250, 250)), ("Green", (30, 140, 70), (250, 250, 250))]
    variant, bg, fg = variants[k % len(variants)]
    edge = float(rng.choice([0.02, 0.022, 0.025, 0.03]))
    img = tex_atlas([pips(n, fg) for n in (1, 6, 2, 5, 3, 4)], bg)
    return Spec("die", variant, [_img_part(box((edge, edge, edge), atlas=(3, 2)), img, rough=0.3)], f"a {variant.lower()} die")


def build_figurine(k: int, rng: np.random.Generator) -> Spec:
    variants = [("Knight", (150, 150, 160)), ("Queen", (200, 170, 60)), ("Pawn", (60, 40, 30)), ("Robot", (80, 120, 200))]
    variant, col = variants[k % len(variants)]
    h = float(rng.uniform(0.06, 0.1))
    base = revolve([(0, 0), (h * 0.28, 0), (h * 0.28, h * 0.08), (h * 0.16, h * 0.12), (h * 0.1, h * 0.6), (0, h * 0.6)], 28)
    head = revolve(sphere_profile(h * 0.16, 14), 24)
    parts = [
        _col_part(base, vertex_colors_by_height(base[0], tuple(int(c * 0.6) for c in col), col), rough=0.5, metal=0.3 if variant == "Queen" else 0.0),
        _col_part(head, solid_colors(head[0], col, rng, 5), rough=0.5, offset=(0, 0, h * 0.56)),
    ]
    if variant == "Robot":
        cube = box((h * 0.3, h * 0.2, h * 0.2))
        parts.append(_col_part(cube, solid_colors(cube[0], (200, 200, 210), rng, 2), rough=0.3, metal=0.8, offset=(0, 0, h * 0.95)))
    return Spec("figurine", variant, parts, f"a small {variant.lower()} figurine")


def build_can(k: int, rng: np.random.Generator) -> Spec:
    variants = [("Cola", (200, 20, 30), "COLA"), ("Lemonade", (250, 220, 60), "LEMON"), ("Tonic", (60, 140, 220), "TONIC"),
                ("Beans", (120, 60, 30), "BEANS"), ("Tomato", (220, 60, 40), "SOUP"), ("Energy", (30, 30, 30), "VOLT")]
    variant, col, text = variants[k % len(variants)]
    r = float(rng.uniform(0.032, 0.038))
    h = float(rng.uniform(0.1, 0.125))
    body = revolve([(0, 0), (r * 0.9, 0), (r, 0.006), (r, h - 0.008), (r * 0.9, h), (r * 0.8, h - 0.002), (0, h - 0.002)], 36)
    return Spec("can", variant, [_img_part(body, tex_label(col, (230, 230, 235), text), rough=0.3, metal=0.6)],
                f"a {variant.lower()} can")


def build_cup(k: int, rng: np.random.Generator) -> Spec:
    variants = [("Paper", (245, 240, 230)), ("Espresso", (250, 250, 250)), ("Party", (220, 40, 60))]
    variant, col = variants[k % len(variants)]
    h = float(rng.uniform(0.06, 0.11))
    rb, rt, t = h * 0.3, h * 0.45, 0.0015
    body = revolve([(0, 0), (rb, 0), (rt, h), (rt - t, h), (rb - t, t), (0, t)], 36)
    return Spec("cup", variant, [_col_part(body, vertex_colors_by_height(body[0], col, rgb(0.1 * k, 0.5, 0.9)), rough=0.6)],
                f"a {variant.lower()} cup")


def build_pencil(k: int, rng: np.random.Generator) -> Spec:
    variants = [("Yellow", (245, 200, 30)), ("Red", (200, 40, 40)), ("Blue", (40, 90, 200))]
    variant, col = variants[k % len(variants)]
    length = float(rng.uniform(0.14, 0.18))
    r = 0.0037
    shaft = extrude(polygon(6, r), length)
    tip = revolve([(0, 0), (r * 0.95, 0.018), (0, 0.018)], 12)  # cone, point at z = 0
    img = tex_stripes([col, tuple(int(c * 0.85) for c in col)], 6)
    return Spec("pencil", variant, [
        _img_part(shaft, img, rough=0.5),
        _col_part(tip, solid_colors(tip[0], (225, 190, 140), rng, 4), rough=0.8, offset=(0, 0, -0.018)),
    ], f"a {variant.lower()} pencil")


def build_eraser(k: int, rng: np.random.Generator) -> Spec:
    variants = [("Pink", (240, 150, 170)), ("White", (245, 245, 245))]
    variant, col = variants[k % len(variants)]
    ext = (float(rng.uniform(0.04, 0.06)), float(rng.uniform(0.018, 0.024)), 0.011)
    geom = box(ext)
    return Spec("eraser", variant, [_col_part(geom, solid_colors(geom[0], col, rng, 4), rough=0.9)], f"a {variant.lower()} eraser")


def build_coin(k: int, rng: np.random.Generator) -> Spec:
    variants = [("Gold", (220, 180, 60)), ("Silver", (200, 200, 205)), ("Copper", (190, 110, 60))]
    variant, col = variants[k % len(variants)]
    r = float(rng.uniform(0.01, 0.015))
    geom = revolve([(0, 0), (r, 0), (r, 0.002), (0, 0.002)], 32)
    img = Image.new("RGB", (128, 128), col)
    d = ImageDraw.Draw(img)
    for i in range(0, 128, 8):
        d.line((0, i, 128, i), fill=tuple(int(c * 0.8) for c in col), width=2)
    return Spec("coin", variant, [_img_part(geom, img, rough=0.25, metal=1.0)], f"a {variant.lower()} coin")


def build_cookie(k: int, rng: np.random.Generator) -> Spec:
    variants = [("Star", 5), ("Flower", 8)]
    variant, n = variants[k % len(variants)]
    r = float(rng.uniform(0.03, 0.04))
    geom = extrude(star(n, r, r * (0.55 if n == 5 else 0.8)), 0.008)
    return Spec("cookie", variant, [_img_part(geom, tex_speckle((200, 150, 90), rng, 20), rough=0.9)], f"a {variant.lower()}-shaped cookie")


def build_donut(k: int, rng: np.random.Generator) -> Spec:
    variants = [("Pink", (240, 130, 170)), ("Chocolate", (90, 50, 30))]
    variant, col = variants[k % len(variants)]
    R = float(rng.uniform(0.03, 0.036))
    geom = torus(R, R * 0.45, 36, 16)
    colors = np.where((geom[0][:, 2] > 0)[:, None], np.r_[col, 255], np.r_[(215, 165, 100), 255]).astype(np.uint8)
    return Spec("donut", variant, [_col_part(geom, colors, rough=0.6)], f"a donut with {variant.lower()} icing")


BUILDERS: list[tuple[str, Callable[[int, np.random.Generator], Spec], int]] = [
    ("ball", build_ball, 6), ("marker", build_marker, 5), ("fruit", build_fruit, 6), ("block", build_block, 5),
    ("mug", build_mug, 4), ("bottle", build_bottle, 4), ("die", build_die, 4), ("figurine", build_figurine, 4),
    ("can", build_can, 5), ("cup", build_cup, 3), ("pencil", build_pencil, 3), ("eraser", build_eraser, 2),
    ("coin", build_coin, 3), ("cookie", build_cookie, 2), ("donut", build_donut, 2),
]


def build_plate(k: int, rng: np.random.Generator) -> Spec:
    r = float(rng.uniform(0.11, 0.14))
    prof = [(0, 0), (r * 0.7, 0), (r, 0.022), (r - 0.004, 0.024), (r * 0.68, 0.005), (0, 0.005)]
    geom = revolve(prof, 48)
    col = [(245, 245, 240), (200, 225, 240)][k % 2]
    return Spec("plate", ["White", "Blue"][k % 2], [_img_part(geom, tex_stripes([col, rgb(0.55, 0.5, 0.7)], 16, vertical=False), rough=0.2)],
                "a round ceramic plate", container=True)


def build_bowl(k: int, rng: np.random.Generator) -> Spec:
    r = float(rng.uniform(0.1, 0.15))
    depth = float(rng.uniform(0.05, 0.07))
    t = 0.004
    phi = np.linspace(0, np.pi / 2, 12)
    outer = [(r * np.sin(p), depth * (1 - np.cos(p))) for p in phi]
    inner = [((r - t) * np.sin(p), t + (depth - t) * (1 - np.cos(p))) for p in phi[::-1]]
    prof = [(0.0, 0.0)] + outer[1:] + inner[:-1] + [(0.0, t)]
    geom = revolve(prof, 48)
    col = [(230, 200, 150), (120, 160, 120)][k % 2]
    return Spec("bowl", ["Wooden", "Sage"][k % 2], [_col_part(geom, vertex_colors_by_height(geom[0], col, tuple(min(255, c + 25) for c in col)), rough=0.6)],
                "a shallow bowl", container=True)


def build_tray(k: int, rng: np.random.Generator) -> Spec:
    w, d = float(rng.uniform(0.28, 0.35)), float(rng.uniform(0.2, 0.25))
    h, t = 0.03, 0.006
    # one closed thin-walled shell swept around a rounded rectangle (walls about t thick)
    prof = [(0, 0), (1.0, 0), (1.0, h), (1.0 - 2 * t / d, h), (1.0 - 2 * t / d, t), (0, t)]
    geom = revolve(prof, 96, squircle=(w / 2, d / 2, 10.0))
    col = [(160, 110, 60), (60, 60, 65)][k % 2]
    img = tex_stripes([col, tuple(int(c * 0.9) for c in col)], 24, vertical=True)
    return Spec("tray", ["Wooden", "Slate"][k % 2], [_img_part(geom, img, rough=0.6)],
                "a rectangular tray with a low rim", container=True)


CONTAINER_BUILDERS = [build_plate, build_tray, build_bowl]


def build_tote(rng: np.random.Generator) -> Spec:
    """A canvas tote: an open box (no top face: a hole) with a flat seam flap along two vertical corners,
    whose edges the walls already share, so those edges have three faces. Non-manifold and open, and
    perfectly usable: it renders, and physics uses its convex hull."""
    w, d, h = float(rng.uniform(0.17, 0.2)), 0.07, float(rng.uniform(0.2, 0.23))
    v, f, uv = box((w, d, h))
    top = [k for k in range(len(f)) if np.allclose(v[f[k], 2], h / 2)]
    f = np.delete(f, top, axis=0)
    for sx in (1, -1):
        corner = [(sx * w / 2, -d / 2, -h / 2), (sx * w / 2, -d / 2, h / 2)]
        flap = corner + [(sx * (w / 2 + 0.02), -d / 2 - 0.02, h / 2), (sx * (w / 2 + 0.02), -d / 2 - 0.02, -h / 2)]
        base = len(v)
        v = np.vstack([v, flap])
        uv = np.vstack([uv, [[0.0, 0.0], [0.0, 1.0], [0.1, 1.0], [0.1, 0.0]]])
        quad = [[base, base + 3, base + 2], [base, base + 2, base + 1]]
        f = np.vstack([f, quad if sx > 0 else [q[::-1] for q in quad]])
    img = tex_stripes([(60, 110, 70), (225, 215, 180)], 6, vertical=True)
    return Spec("bag", "Tote", [Part(v, f, uv, image=img, roughness=0.9)], "a canvas tote bag with a seam flap")
