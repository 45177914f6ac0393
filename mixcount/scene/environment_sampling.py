"""Environments and floor materials: sampling them, and the embedded procedural defaults.

Without ingested HDRIs the scene is lit by one of bpy's bundled HDRIs (real captured light, CC0 Poly
Haven maps; :mod:`mixcount.scene.bundled_environments`) or, with ``scene.default_environment = "sky"``,
by a procedural sky (sun elevation/azimuth/strength, turbidity), described in
:class:`~mixcount.scene.spec.EnvironmentSpec`. Without ingested PBR sets (or by chance,
``scene.procedural_floor_probability``) the floor gets a procedural material that favours repetitive
patterns, as the paper does: tiles, bricks, planks, checker, dots, noise. A procedural material is a
parameter dict (pattern, colours, cell counts, seed, ...) that :func:`render_pattern` turns into a
seamless RGB image; the stage writer saves it as PNG and binds it as the UsdPreviewSurface diffuse
texture, so USD viewers and Blender see the same floor without any shader-node translation.
"""

from __future__ import annotations

import colorsys
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.scene.spec import EnvironmentSpec, MaterialSpec
from mixcount.scene_config import BUNDLED_HDRI as BUNDLED_HDRI  # the names [scene] validates against
from mixcount.scene_config import DEFAULT_ENVIRONMENTS as DEFAULT_ENVIRONMENTS
from mixcount.scene_config import PATTERNS as PATTERNS
from mixcount.scene_config import SKY as SKY


def _u(rng: np.random.Generator, r: Sequence[float]) -> float:
    return float(rng.uniform(r[0], r[1]))


def _colour(rng: np.random.Generator, *, sat: tuple[float, float], val: tuple[float, float]) -> list[float]:
    h = float(rng.uniform(0.0, 1.0))
    rgb = colorsys.hsv_to_rgb(h, _u(rng, sat), _u(rng, val))
    return [round(c, 4) for c in rgb]


def sample_pattern_params(rng: np.random.Generator, pattern: str) -> dict[str, Any]:
    """Parameters of one procedural floor: everything :func:`render_pattern` needs, JSON-able."""
    a = _colour(rng, sat=(0.05, 0.6), val=(0.35, 0.9))
    # second colour: same family, clearly darker or lighter, so the repetition reads in the image
    hsv = colorsys.rgb_to_hsv(*a)
    shift = float(rng.uniform(0.25, 0.5)) * (1 if hsv[2] < 0.6 else -1)
    b = [round(c, 4) for c in colorsys.hsv_to_rgb((hsv[0] + float(rng.uniform(-0.08, 0.08))) % 1.0,
                                                  min(1.0, hsv[1] * float(rng.uniform(0.5, 1.3))),
                                                  min(1.0, max(0.0, hsv[2] + shift)))]
    params: dict[str, Any] = {
        "pattern": pattern, "color_a": a, "color_b": b, "seed": int(rng.integers(0, 2**31 - 1)),
        "roughness": round(float(rng.uniform(0.3, 0.9)), 4),
    }
    if pattern == "checker":
        params["cells"] = int(rng.choice([2, 4]))
    elif pattern == "tiles":
        params.update(cells=int(rng.choice([2, 4])), gap=round(float(rng.uniform(0.02, 0.08)), 4),
                      variation=round(float(rng.uniform(0.0, 0.15)), 4))
    elif pattern == "bricks":
        params.update(rows=int(rng.choice([4, 6, 8])), per_row=int(rng.choice([2, 3, 4])),
                      gap=round(float(rng.uniform(0.02, 0.06)), 4), variation=round(float(rng.uniform(0.05, 0.2)), 4))
    elif pattern == "planks":
        params.update(rows=int(rng.choice([4, 6, 8])), gap=round(float(rng.uniform(0.005, 0.02)), 4),
                      variation=round(float(rng.uniform(0.05, 0.25)), 4), grain=round(float(rng.uniform(0.05, 0.2)), 4))
    elif pattern == "dots":
        params.update(cells=int(rng.choice([2, 4, 8])), radius=round(float(rng.uniform(0.15, 0.4)), 4))
    elif pattern == "noise":
        params.update(cells=int(rng.choice([4, 8, 16])), octaves=int(rng.integers(2, 5)))
    else:
        raise ValueError(f"unknown floor pattern {pattern!r}")
    return params


def _mix(a: Sequence[float], b: Sequence[float], t: NDArray[Any]) -> NDArray[Any]:
    a_ = np.asarray(a, dtype=np.float64)
    b_ = np.asarray(b, dtype=np.float64)
    return np.asarray(a_ * (1.0 - t[..., None]) + b_ * t[..., None])


def _tileable_noise(rng: np.random.Generator, px: int, cells: int) -> NDArray[Any]:
    """Value noise on a periodic lattice (wraps at the image border): seamless by construction."""
    lattice = rng.random((cells, cells))
    coords = np.arange(px) * cells / px
    i0 = np.floor(coords).astype(int)
    f = coords - i0
    f = f * f * (3 - 2 * f)
    i1 = (i0 + 1) % cells
    y0, x0 = np.meshgrid(i0, i0, indexing="ij")
    y1, x1 = np.meshgrid(i1, i1, indexing="ij")
    fy, fx = np.meshgrid(f, f, indexing="ij")
    top = lattice[y0, x0] * (1 - fx) + lattice[y0, x1] * fx
    bot = lattice[y1, x0] * (1 - fx) + lattice[y1, x1] * fx
    return np.asarray(top * (1 - fy) + bot * fy)


def render_pattern(params: Mapping[str, Any], px: int) -> NDArray[Any]:
    """(px, px, 3) uint8 image of a procedural pattern; deterministic and seamless (periodic)."""
    rng = np.random.default_rng(int(params["seed"]))
    pattern = params["pattern"]
    a, b = params["color_a"], params["color_b"]
    v, u = np.meshgrid((np.arange(px) + 0.5) / px, (np.arange(px) + 0.5) / px, indexing="ij")
    if pattern == "checker":
        n = int(params["cells"])
        t = ((np.floor(u * n) + np.floor(v * n)) % 2).astype(float)
        img = _mix(a, b, t)
    elif pattern == "tiles":
        n = int(params["cells"])
        gap = float(params["gap"])
        fu, fv = (u * n) % 1.0, (v * n) % 1.0
        grout = (fu < gap) | (fv < gap)
        shade = 1.0 + float(params["variation"]) * (rng.random((n, n)) * 2 - 1)
        tile = _mix(a, a, np.zeros_like(u)) * shade[np.floor(v * n).astype(int), np.floor(u * n).astype(int)][..., None]
        img = np.where(grout[..., None], np.asarray(b, float), tile)
    elif pattern == "bricks":
        rows, per = int(params["rows"]), int(params["per_row"])
        gap = float(params["gap"])
        row = np.floor(v * rows).astype(int)
        uu = (u * per + 0.5 * (row % 2)) % per
        col = np.floor(uu).astype(int) % per
        mortar = ((v * rows) % 1.0 < gap * rows / per * 2) | (uu % 1.0 < gap)
        shade = 1.0 + float(params["variation"]) * (rng.random((rows, per)) * 2 - 1)
        brick = np.asarray(a, float) * shade[row, col][..., None]
        img = np.where(mortar[..., None], np.asarray(b, float), brick)
    elif pattern == "planks":
        rows = int(params["rows"])
        row = np.floor(v * rows).astype(int)
        offsets = rng.random(rows)
        uu = (u + offsets[row]) % 1.0  # one plank end per row, staggered
        seam = ((v * rows) % 1.0 < params["gap"] * rows) | (uu < params["gap"])
        shade = 1.0 + float(params["variation"]) * (rng.random(rows) * 2 - 1)
        grain = _tileable_noise(rng, px, 16)
        streak = 0.5 + 0.5 * np.sin(2 * np.pi * (v * rows * 3 + 2 * grain))
        wood = _mix(a, b, float(params["grain"]) * streak) * shade[row][..., None]
        img = np.where(seam[..., None], np.asarray(b, float) * 0.6, wood)
    elif pattern == "dots":
        n = int(params["cells"])
        du, dv = (u * n) % 1.0 - 0.5, (v * n) % 1.0 - 0.5
        t = (np.hypot(du, dv) < float(params["radius"])).astype(float)
        img = _mix(a, b, t)
    elif pattern == "noise":
        total = np.zeros((px, px))
        amp, norm = 1.0, 0.0
        cells = int(params["cells"])
        for _ in range(int(params["octaves"])):
            total += amp * _tileable_noise(rng, px, cells)
            norm += amp
            amp *= 0.5
            cells = min(cells * 2, px)
        img = _mix(a, b, total / norm)
    else:
        raise ValueError(f"unknown floor pattern {pattern!r}")
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_pattern_png(params: Mapping[str, Any], px: int, path: Path) -> Path:
    """Write :func:`render_pattern` as PNG (no metadata: identical params give identical bytes)."""
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(render_pattern(params, px), "RGB").save(path, format="PNG", optimize=False)
    return path


def sample_floor_material(rng: np.random.Generator, patterns: Sequence[str], materials: Sequence[Any],
                          procedural_probability: float, texture_px: int = 256) -> MaterialSpec:
    """An ingested PBR set (uniform) or, without any or by chance, a procedural pattern."""
    use_pbr = bool(materials) and float(rng.random()) >= procedural_probability
    if use_pbr:
        m = materials[int(rng.integers(len(materials)))]
        return MaterialSpec(kind="pbr", name=m.name, maps=dict(sorted(m.maps.items())), material_id=m.material_id,
                            params={"roughness": 0.6})
    pattern = str(patterns[int(rng.integers(len(patterns)))])
    params = sample_pattern_params(rng, pattern)
    params["px"] = int(texture_px)
    return MaterialSpec(kind="procedural", name=f"procedural_{pattern}", params=params)


def environments_to_draw(config: Any, environments: Sequence[Any]) -> Sequence[Any]:
    """The HDRIs a scene draws from: the ingested ``environments``, else (``config.default_environment``
    = bundled_hdri) bpy's bundled ones, else none (the procedural sky). Raises ConfigError when the
    bundled HDRIs are asked for and bpy's install has none; compose calls it once up front for that."""
    if environments or config.default_environment != BUNDLED_HDRI:
        return environments
    from mixcount.scene.bundled_environments import bundled_environments

    return bundled_environments()


def sample_environment(rng: np.random.Generator, config: Any, environments: Sequence[Any]) -> EnvironmentSpec:
    """An HDRI (uniform over ``environments``, random Z rotation) or the procedural sky.

    Without ingested ``environments``, ``config.default_environment`` decides: ``bundled_hdri`` draws
    one of the CC0 Poly Haven HDRIs that ship with bpy (found in its install without importing it,
    :func:`~mixcount.scene.bundled_environments.bundled_environments`), ``sky`` gives the procedural sky.
    The strength is drawn first either way."""
    strength = round(_u(rng, config.environment_strength), 6)
    environments = environments_to_draw(config, environments)
    if environments:
        env = environments[int(rng.integers(len(environments)))]
        return EnvironmentSpec(kind="hdri", strength=strength, rotation_deg=round(_u(rng, (0.0, 360.0)), 6),
                               environment_id=env.environment_id, path=env.path)
    if config.default_environment != SKY:
        raise ValueError(f"unknown scene.default_environment {config.default_environment!r}")
    return EnvironmentSpec(
        kind="sky", strength=strength, rotation_deg=0.0,
        sun_elevation_deg=round(_u(rng, config.sky_sun_elevation_deg), 6),
        sun_azimuth_deg=round(_u(rng, (0.0, 360.0)), 6),
        sun_strength=round(_u(rng, config.sky_sun_strength), 6),
        turbidity=round(_u(rng, config.sky_turbidity), 6),
    )
