"""Environments and floor materials: procedural defaults, `catalog ingest-env` / `ingest-materials`,
and their use in sampled scenes and written stages."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_scene_distributions import rich_pool

from mixcount.catalog.environments import classify_maps, is_environment_map
from mixcount.catalog.pool_loader import load_environments, load_materials
from mixcount.config import load_config
from mixcount.scene.environment_sampling import PATTERNS, render_pattern, sample_pattern_params
from mixcount.scene.sampler import sample_scene


def write_hdr(path: Path, w: int = 8, h: int = 4) -> Path:
    """A tiny flat (non-RLE) Radiance RGBE file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n".encode()
    pixels = np.tile(np.array([128, 128, 200, 129], dtype=np.uint8), (w * h, 1))
    path.write_bytes(header + pixels.tobytes())
    return path


def write_exr(path: Path) -> Path:
    import OpenEXR

    path.parent.mkdir(parents=True, exist_ok=True)
    rgb = np.full((4, 8, 3), 0.5, dtype="float32")
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {"RGB": rgb}).write(str(path))
    return path


@pytest.mark.parametrize("pattern", PATTERNS)
def test_patterns_are_deterministic_repetitive_and_seamless(pattern):
    rng = np.random.default_rng(3)
    params = sample_pattern_params(rng, pattern)
    json.dumps(params)  # plain JSON for the spec
    a = render_pattern(params, 64)
    b = render_pattern(params, 64)
    assert a.shape == (64, 64, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert len(np.unique(a.reshape(-1, 3), axis=0)) >= 2  # a visible pattern, not a flat colour
    # seamless: the step across the wrap-around edge is no bigger than the biggest step inside the
    # image (a checker's cell border is a legitimate hard step; a phase jump at the edge is not)
    for img in (a.astype(int), a.transpose(1, 0, 2).astype(int)):
        wrap = np.abs(img[:, 0] - img[:, -1]).max(axis=1)
        inner = np.abs(np.diff(img, axis=1)).max(axis=2)
        assert wrap.max() <= inner.max() + 2, pattern
        assert wrap.mean() <= inner.mean(axis=0).max() + 2, pattern
    other = dict(params, seed=params["seed"] + 1, color_a=[0.1, 0.9, 0.2])
    assert not np.array_equal(render_pattern(other, 64), a)


def test_default_scenes_are_lit_by_a_bundled_hdri_that_exists():
    from mixcount.scene.bundled_environments import bundled_environments, bundled_hdri_dir

    conf = load_config()
    assert conf.scene.default_environment == "bundled_hdri"
    bundled = {e.path for e in bundled_environments()}
    assert len(bundled) == 8  # bpy 5.0's studio-light worlds
    seen, rotations = set(), set()
    for seed in range(40):
        env = sample_scene(seed, "train", conf, rich_pool()).environment
        assert env.kind == "hdri" and env.environment_id is None
        assert env.path in bundled and Path(env.path).is_file() and Path(env.path).parent == bundled_hdri_dir()
        lo, hi = conf.scene.environment_strength
        assert lo <= env.strength <= hi and 0.0 <= env.rotation_deg < 360.0
        seen.add(env.path)
        rotations.add(round(env.rotation_deg))
    assert len(seen) >= 6 and len(rotations) >= 30  # uniform over the eight, randomly turned about Z
    again = sample_scene(7, "train", conf, rich_pool()).environment
    assert again == sample_scene(7, "train", conf, rich_pool()).environment  # seeded


def test_ingested_hdris_take_precedence_over_the_bundled_ones(tmp_path):
    from mixcount.scene.object_records import EnvironmentRecord

    hdr = write_hdr(tmp_path / "mine.hdr")
    env = sample_scene(3, "train", load_config(), rich_pool(),
                       environments=[EnvironmentRecord(5, "mine", str(hdr), "h")]).environment
    assert env.kind == "hdri" and env.path == str(hdr) and env.environment_id == 5


def test_bad_default_environment_is_a_config_error():
    from mixcount.errors import ConfigError

    with pytest.raises(ConfigError, match="default_environment must be one of"):
        load_config([], ["scene.default_environment=studio"])


def test_sky_config_scenes_use_sky_and_procedural_floors():
    conf = load_config([], ["scene.default_environment=sky"])
    patterns = set()
    for seed in range(60):
        s = sample_scene(seed, "train", conf, rich_pool())
        assert s.environment.kind == "sky" and s.environment.path is None
        lo, hi = conf.scene.sky_sun_elevation_deg
        assert lo <= s.environment.sun_elevation_deg <= hi
        assert s.floor.material.kind == "procedural"
        patterns.add(s.floor.material.params["pattern"])
        assert s.floor.shape in conf.scene.floor_shapes
    assert patterns == set(PATTERNS)


def test_ingest_env_and_materials_cli_then_sampled(tmp_path, db_url):
    from mixcount.catalog.db import open_catalog
    from mixcount.cli import main

    envs = tmp_path / "hdri"
    write_hdr(envs / "studio.hdr")
    write_exr(envs / "sunset.exr")
    (envs / "fake.hdr").write_text("not an hdr")
    assert is_environment_map(envs / "studio.hdr") and is_environment_map(envs / "sunset.exr")
    assert not is_environment_map(envs / "fake.hdr")
    mats = tmp_path / "materials" / "Bricks_01"
    mats.mkdir(parents=True)
    for name, colour in (("Bricks_01_Color.png", (150, 60, 40)), ("Bricks_01_Roughness.png", (200, 200, 200)),
                         ("Bricks_01_NormalGL.png", (128, 128, 255))):
        Image.new("RGB", (8, 8), colour).save(mats / name)
    (tmp_path / "materials" / "OnlyRough").mkdir()
    Image.new("RGB", (8, 8), (1, 1, 1)).save(tmp_path / "materials" / "OnlyRough" / "x_rough.png")
    assert set(classify_maps(mats)) == {"base_color", "roughness", "normal"}

    assert main(["--db", db_url, "catalog", "ingest-env", str(envs)]) == 0
    assert main(["--db", db_url, "catalog", "ingest-env", str(envs)]) == 0  # idempotent
    assert main(["--db", db_url, "catalog", "ingest-materials", str(tmp_path / "materials")]) == 0
    cat = open_catalog(db_url, data_dir="")
    with cat.session() as session:
        environments = load_environments(session)
        materials = load_materials(session)
    cat.close()
    assert sorted(e.name for e in environments) == ["studio", "sunset"]
    assert [m.name for m in materials] == ["Bricks_01"]
    assert Path(materials[0].maps["base_color"]).name == "Bricks_01_Color.png"

    conf = load_config([], ["scene.procedural_floor_probability=0.0"])
    seen = set()
    for seed in range(20):
        s = sample_scene(seed, "train", conf, rich_pool(), environments=environments, materials=materials)
        assert s.environment.kind == "hdri" and Path(s.environment.path).exists()
        assert s.floor.material.kind == "pbr" and s.floor.material.maps["base_color"].endswith("_Color.png")
        seen.add(s.environment.environment_id)
    assert len(seen) == 2  # sampled uniformly from the group
