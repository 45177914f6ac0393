"""The canonical render's heavy path (issue 69, item 1): a model of more triangles than
``canonical_render.heavy_faces`` gets its albedo from the colour passes of the RGB render itself (no second
render) and OIDN's ``heavy_denoise_prefilter``; a model at or under it renders byte for byte as before, and its
render rows keep their settings hash.

Real bpy in one worker process (48 px, 4 samples): a vertex-coloured icosphere (1280 triangles) rendered with
the default threshold (light), with ``heavy_faces = 0`` (heavy), with other heavy settings that must not
touch a light object, and heavy with the light path's prefilter (ACCURATE: the same bytes as light)."""

from __future__ import annotations

import dataclasses
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh
from PIL import Image

from mixcount.config import ConfigError, load_config
from mixcount.curation.renders import (
    albedo_path_for,
    canonical_request,
    mask_path_for,
    object_settings_hash,
    render_settings,
    settings_hash,
)


def small_config(*overrides: str):
    return load_config(["configs/quick.toml"], overrides=["canonical_render.resolution=48",
                                                           "canonical_render.samples=4", *overrides])


def painted_ball(path: Path) -> Path:
    """An icosphere (1280 triangles) whose vertex colours change over the surface: the albedo has structure."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    v = mesh.vertices / 0.04
    rgb = np.stack([0.55 + 0.4 * v[:, 0], 0.5 + 0.3 * v[:, 1], 0.45 - 0.35 * v[:, 2]], axis=1)
    colours = np.clip(np.rint(rgb * 255), 0, 255).astype(np.uint8)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.column_stack([colours, np.full(len(v), 255)]))
    mesh.export(path)
    return path


def image(path: Path | str) -> np.ndarray:
    return np.asarray(Image.open(path), dtype=np.float64)


def test_heavy_settings_validate():
    cfg = load_config()
    assert (cfg.canonical_render.heavy_faces, cfg.canonical_render.heavy_denoise_prefilter) == (300000, "FAST")
    with pytest.raises(ConfigError, match="heavy_faces must be an integer >= 0"):
        load_config(overrides=["canonical_render.heavy_faces=-1"])
    with pytest.raises(ConfigError, match="heavy_denoise_prefilter must be one of ACCURATE, FAST, NONE"):
        load_config(overrides=["canonical_render.heavy_denoise_prefilter=BEST"])


def test_settings_hash_changes_only_for_heavy_objects():
    base = load_config().canonical_render
    light = types.SimpleNamespace(face_count=1280)
    unknown = types.SimpleNamespace(face_count=None)
    heavy = types.SimpleNamespace(face_count=1_200_000)
    # a light object's hash is the one every render had before the heavy path existed
    assert object_settings_hash(base, light) == settings_hash(render_settings(base))  # type: ignore[arg-type]
    assert object_settings_hash(base, unknown) == settings_hash(render_settings(base))  # type: ignore[arg-type]
    others = [dataclasses.replace(base, heavy_denoise_prefilter="NONE"), dataclasses.replace(base, heavy_faces=5000)]
    for cfg in others:
        assert object_settings_hash(cfg, light) == object_settings_hash(base, light)  # type: ignore[arg-type]
    assert object_settings_hash(base, heavy) != object_settings_hash(base, light)  # type: ignore[arg-type]
    assert object_settings_hash(others[0], heavy) != object_settings_hash(base, heavy)  # type: ignore[arg-type]
    assert object_settings_hash(others[1], heavy) == object_settings_hash(base, heavy)  # type: ignore[arg-type]
    # a threshold under the object's count moves it to the heavy path: its hash changes
    assert (object_settings_hash(dataclasses.replace(base, heavy_faces=1000), light)  # type: ignore[arg-type]
            == object_settings_hash(base, heavy))  # type: ignore[arg-type]


@pytest.mark.blender
@pytest.mark.slow
def test_heavy_path_matches_the_light_path_and_light_stays_byte_identical(tmp_path):
    from mixcount.worker.canonical_runner import run_jobs

    model = painted_ball(tmp_path / "ball.ply")
    obj = types.SimpleNamespace(model_path=str(model), id=1, source_up_axis="", face_count=1280)
    runs = {"light": (), "heavy": ("canonical_render.heavy_faces=0",),
            "light_other": ("canonical_render.heavy_faces=5000", "canonical_render.heavy_denoise_prefilter=NONE"),
            "heavy_accurate": ("canonical_render.heavy_faces=0", "canonical_render.heavy_denoise_prefilter=ACCURATE")}
    jobs = [(name, canonical_request(small_config(*over).canonical_render, obj, tmp_path / name))
            for name, over in runs.items()]
    # one decider: the catalog's face count picks the path and the request carries it; the worker counts
    # Blender's triangles itself only for a request that does not say (None)
    zero = small_config("canonical_render.heavy_faces=0").canonical_render
    uncounted = canonical_request(zero, types.SimpleNamespace(**{**vars(obj), "face_count": None}), tmp_path / "said")
    assert [req.heavy for _, req in jobs] == [False, True, False, True] and uncounted.heavy is False
    jobs += [("said_light", uncounted),
             ("worker_counts", dataclasses.replace(uncounted, heavy=None, out_dir=str(tmp_path / "counted")))]
    seen: dict[str, Any] = {}
    run_jobs(jobs, on_result=lambda o: seen.__setitem__(o.key, o), workers=1, timeout_s=120.0, threads_per_worker=0)
    for name, _ in jobs:
        assert seen[name].result is not None, seen[name].error
    res = {name: seen[name].result for name, _ in jobs}
    assert [(r.faces, r.heavy) for r in res.values()] == [(1280, False), (1280, True), (1280, False), (1280, True),
                                                          (1280, False), (1280, True)]

    view = {name: r.views[0] for name, r in res.items()}
    # light: the same bytes whatever the heavy settings (RGB, mask, albedo)
    for pick in (lambda v: v.path, lambda v: v.mask_path, lambda v: albedo_path_for(v.path)):
        assert Path(pick(view["light"])).read_bytes() == Path(pick(view["light_other"])).read_bytes()
    assert not [p.name for p in (tmp_path / "heavy").iterdir() if p.name.startswith(".")]  # no EXR left behind
    # the colour passes do not change the combined image, and at the light path's albedo samples (4 here, as
    # ALBEDO_SAMPLES) and its prefilter the heavy path writes the same files: one render does the work of two
    for pick in (lambda v: v.path, lambda v: v.mask_path, lambda v: albedo_path_for(v.path)):
        assert Path(pick(view["light"])).read_bytes() == Path(pick(view["heavy_accurate"])).read_bytes()

    mask = image(view["light"].mask_path)
    assert np.array_equal(image(view["heavy"].mask_path), mask)
    albedo_path = albedo_path_for(view["heavy"].path)
    assert albedo_path.is_file() and albedo_path == Path(view["heavy"].path).with_name("obj_000001_albedo.png")
    heavy_albedo, light_albedo = image(albedo_path), image(albedo_path_for(view["light"].path))
    assert heavy_albedo.shape == light_albedo.shape == (48, 48, 4)
    assert np.array_equal(heavy_albedo[..., 3], mask)  # the render's coverage as alpha
    inside = mask > 200
    assert inside.sum() > 200
    albedo_diff = np.abs(heavy_albedo[..., :3] - light_albedo[..., :3])[inside].mean(axis=0)
    assert (albedo_diff < 3.0).all(), albedo_diff
    assert np.ptp(light_albedo[..., :3][inside], axis=0).max() > 40  # the colours vary: a real comparison
    # the RGB render differs by the prefilter only
    rgb_diff = np.abs(image(view["heavy"].path) - image(view["light"].path)).mean(axis=(0, 1))
    assert (rgb_diff < 4.0).all(), rgb_diff
    assert mask_path_for(view["heavy"].path).is_file()
