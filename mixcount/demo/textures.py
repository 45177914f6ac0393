"""Demo-library textures and vertex colours: stripes, speckle, gradients, labels, dots, atlases of pips
and letters (PIL), drawn deterministically from the object's random stream."""

from __future__ import annotations

import colorsys
from typing import Callable

import numpy as np
from PIL import Image, ImageDraw, ImageFont


def rgb(h: float, s: float, v: float) -> tuple[int, int, int]:
    r, g, b = colorsys.hsv_to_rgb(h % 1.0, s, v)
    return int(r * 255), int(g * 255), int(b * 255)


def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # very old Pillow
        return ImageFont.load_default()


def tex_stripes(colors: list[tuple[int, int, int]], n: int, vertical: bool = True, size: int = 128) -> Image.Image:
    img = Image.new("RGB", (size, size), colors[0])
    d = ImageDraw.Draw(img)
    w = size / n
    for k in range(n):
        box_ = (k * w, 0, (k + 1) * w, size) if vertical else (0, k * w, size, (k + 1) * w)
        d.rectangle(box_, fill=colors[k % len(colors)])
    return img


def tex_speckle(base: tuple[int, int, int], rng: np.random.Generator, amount: float = 18, size: int = 128) -> Image.Image:
    noise = rng.normal(0.0, amount, (size, size, 1))
    arr = np.clip(np.asarray(base, dtype=np.float64)[None, None, :] + noise, 0, 255).astype(np.uint8)
    return Image.fromarray(arr, "RGB")


def tex_gradient(top: tuple[int, int, int], bottom: tuple[int, int, int], size: int = 128) -> Image.Image:
    t = np.linspace(0, 1, size)[:, None, None]
    arr = (np.asarray(bottom)[None, None, :] * (1 - t) + np.asarray(top)[None, None, :] * t)
    arr = np.repeat(arr, size, axis=1).astype(np.uint8)
    return Image.fromarray(arr[::-1], "RGB")  # image row 0 is v = 1 (top)


def tex_label(bg: tuple[int, int, int], band: tuple[int, int, int], text: str, size: tuple[int, int] = (256, 128)) -> Image.Image:
    img = Image.new("RGB", size, bg)
    d = ImageDraw.Draw(img)
    w, h = size
    d.rectangle((0, int(h * 0.35), w, int(h * 0.65)), fill=band)
    font = _font(max(10, h // 5))
    for x0 in (w * 0.05, w * 0.55):
        d.text((x0, h * 0.38), text, fill=bg, font=font)
    return img


def tex_dots(bg: tuple[int, int, int], dot: tuple[int, int, int], n: int, rng: np.random.Generator, size: int = 128) -> Image.Image:
    img = Image.new("RGB", (size, size), bg)
    d = ImageDraw.Draw(img)
    for x, y in rng.uniform(0, size, (n, 2)):
        r = size / 40
        d.ellipse((x - r, y - r, x + r, y + r), fill=dot)
    return img


def tex_atlas(cells: list[Callable[[ImageDraw.ImageDraw, tuple[int, int, int, int]], None]], bg: tuple[int, int, int], cell: int = 64) -> Image.Image:
    """A 3x2 atlas for :func:`box` with ``atlas=(3, 2)``; image rows run top-down, v bottom-up."""
    img = Image.new("RGB", (3 * cell, 2 * cell), bg)
    d = ImageDraw.Draw(img)
    for k, draw in enumerate(cells):
        col, row = k % 3, k // 3
        top = (1 - row) * cell
        draw(d, (col * cell, top, (col + 1) * cell, top + cell))
    return img


def pips(n: int, color: tuple[int, int, int]) -> Callable[[ImageDraw.ImageDraw, tuple[int, int, int, int]], None]:
    layout = {
        1: [(0.5, 0.5)], 2: [(0.25, 0.25), (0.75, 0.75)], 3: [(0.25, 0.25), (0.5, 0.5), (0.75, 0.75)],
        4: [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)],
        5: [(0.25, 0.25), (0.75, 0.25), (0.5, 0.5), (0.25, 0.75), (0.75, 0.75)],
        6: [(0.25, 0.22), (0.75, 0.22), (0.25, 0.5), (0.75, 0.5), (0.25, 0.78), (0.75, 0.78)],
    }[n]

    def draw(d: ImageDraw.ImageDraw, b: tuple[int, int, int, int]) -> None:
        x0, y0, x1, y1 = b
        r = (x1 - x0) * 0.09
        for fx, fy in layout:
            cx, cy = x0 + fx * (x1 - x0), y0 + fy * (y1 - y0)
            d.ellipse((cx - r, cy - r, cx + r, cy + r), fill=color)

    return draw


def letter(ch: str, color: tuple[int, int, int]) -> Callable[[ImageDraw.ImageDraw, tuple[int, int, int, int]], None]:
    def draw(d: ImageDraw.ImageDraw, b: tuple[int, int, int, int]) -> None:
        x0, y0, x1, y1 = b
        d.rectangle((x0 + 3, y0 + 3, x1 - 3, y1 - 3), outline=color, width=3)
        d.text((x0 + (x1 - x0) * 0.3, y0 + (y1 - y0) * 0.18), ch, fill=color, font=_font(int((y1 - y0) * 0.6)))

    return draw


def vertex_colors_by_height(verts: np.ndarray, bottom: tuple[int, int, int], top: tuple[int, int, int]) -> np.ndarray:
    z = verts[:, 2]
    t = ((z - z.min()) / max(np.ptp(z), 1e-9))[:, None]
    col = np.asarray(bottom) * (1 - t) + np.asarray(top) * t
    return np.c_[col, np.full(len(verts), 255)].astype(np.uint8)


def solid_colors(verts: np.ndarray, color: tuple[int, int, int], rng: np.random.Generator, jitter: float = 10) -> np.ndarray:
    col = np.clip(np.asarray(color)[None, :] + rng.normal(0, jitter, (len(verts), 1)), 0, 255)
    return np.c_[col, np.full(len(verts), 255)].astype(np.uint8)
