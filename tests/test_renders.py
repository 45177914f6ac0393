"""Canonical renders with real bpy (64 px, 2 samples): pure-white background, centred object, scale-free
framing, failures recorded while the batch goes on, resumable by model hash and settings hash, and the
worker runner killing a hung render and restarting after a crashed one."""

from __future__ import annotations

import dataclasses
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh
from PIL import Image
from sqlalchemy import select

from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CatalogObject, Render
from mixcount.config import load_config
from mixcount.curation.renders import canonical_render_path, mask_path_for, render_catalog

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def small_config(**render):
    values = {"canonical_render.resolution": 64, "canonical_render.samples": 2, **{f"canonical_render.{k}": v for k, v in render.items()}}
    return load_config(["configs/quick.toml"], values=values)


def coloured(mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1)))
    return mesh


def write_library(root: Path) -> Path:
    root.mkdir(parents=True)
    coloured(trimesh.creation.box(extents=(0.05, 0.03, 0.02)), (220, 30, 30)).export(root / "redbox.glb")
    coloured(trimesh.creation.box(extents=(0.15, 0.09, 0.06)), (220, 30, 30)).export(root / "bigredbox.glb")
    coloured(trimesh.creation.icosphere(subdivisions=2, radius=0.03), (30, 60, 220)).export(root / "blueball.glb")
    coloured(trimesh.creation.cylinder(radius=0.02, height=0.08), (30, 200, 60)).export(root / "vanishing.glb")
    return root


def by_name(catalog) -> dict[str, CatalogObject]:
    with catalog.session() as s:
        return {o.name: o for o in s.scalars(select(CatalogObject))}


def test_render_catalog_white_centred_resumable(tmp_path, catalog):
    lib = write_library(tmp_path / "lib")
    cfg = small_config()
    ingest_paths(catalog, [lib], config=cfg)
    objs = by_name(catalog)
    assert len(objs) == 4
    vanishing = next(o for n, o in objs.items() if "vanishing" in n)
    Path(vanishing.model_path).unlink()  # ingested fine, gone by render time: that object fails, batch goes on

    summary = render_catalog(catalog, cfg.canonical_render)
    assert (summary.objects, summary.rendered, summary.failed) == (4, 3, 1)
    assert summary.failures[0]["id"] == vanishing.id and summary.failures[0]["error"]

    with catalog.session() as s:
        failed = s.scalar(select(Render).where(Render.object_id == vanishing.id))
        assert failed.error and failed.path is None
        assert canonical_render_path(s, vanishing.id) is None
        paths = {n: canonical_render_path(s, o.id) for n, o in objs.items() if o.id != vanishing.id}
    for name, path in paths.items():
        assert path is not None and path.is_absolute() and path.parent == catalog.renders_dir
        rgb = np.asarray(Image.open(path))
        mask = np.asarray(Image.open(mask_path_for(path)))
        assert rgb.shape == (64, 64, 3)
        for corner in (rgb[0, 0], rgb[0, -1], rgb[-1, 0], rgb[-1, -1]):
            assert tuple(corner) == (255, 255, 255)
        assert (rgb[mask == 0] == 255).all(), "background must be pure white"
        ys, xs = np.nonzero(mask > 127)
        assert 0.1 < (mask > 127).mean() < 0.9
        assert abs((ys.min() + ys.max()) / 2 - 31.5) <= 2 and abs((xs.min() + xs.max()) / 2 - 31.5) <= 2
        assert ys.min() >= 1 and xs.min() >= 1 and ys.max() <= 62 and xs.max() <= 62  # framed with a margin
        obj_px = rgb[mask > 200].astype(float).mean(axis=0)
        if "red" in name:
            assert obj_px[0] > obj_px[1] + 40 and obj_px[0] > obj_px[2] + 40
        else:
            assert obj_px[2] > obj_px[0] + 40

    # scale-free framing: a box three times larger renders (nearly) the same picture
    small = np.asarray(Image.open(paths[next(n for n in paths if n.startswith("redbox"))]), dtype=float)
    big = np.asarray(Image.open(paths[next(n for n in paths if n.startswith("bigredbox"))]), dtype=float)
    assert np.abs(small - big).mean() < 4.0

    again = render_catalog(catalog, cfg.canonical_render)
    assert (again.rendered, again.skipped, again.failed) == (0, 3, 1)  # failures are retried, the rest skipped

    bigger = render_catalog(catalog, small_config(resolution=48).canonical_render)  # settings changed: render again
    assert bigger.rendered == 3
    assert np.asarray(Image.open(paths[next(iter(paths))])).shape == (48, 48, 3)


def test_runner_kills_hung_render_and_survives_crash(tmp_path, monkeypatch):
    from mixcount.curation.renders import canonical_request
    from mixcount.worker.canonical_contract import CanonicalRequest
    from mixcount.worker.canonical_runner import run_jobs

    monkeypatch.setattr("mixcount.worker.client.WORKER_MODULE", "tests.fault_worker")  # hang / crash hooks
    glb = tmp_path / "box.glb"
    coloured(trimesh.creation.box(extents=(0.04, 0.04, 0.04)), (200, 200, 30)).export(glb)
    obj = types.SimpleNamespace(model_path=str(glb), id=1, source_up_axis="Y", face_count=12)
    base = canonical_request(small_config(resolution=32, samples=1, denoise=False).canonical_render, obj, tmp_path / "out")
    assert isinstance(base, CanonicalRequest) and base.stem == "obj_000001"
    jobs = [(key, dataclasses.replace(base, stem=stem))
            for key, stem in (("first", "first"), ("hang", "hang_300"), ("crash", "crash_3"), ("last", "last"))]
    seen: dict[str, Any] = {}
    run_jobs(jobs, on_result=lambda o: seen.__setitem__(o.key, o), workers=1, timeout_s=8.0,
             threads_per_worker=0)
    assert set(seen) == {"first", "hang", "crash", "last"}
    assert seen["first"].result is not None and seen["last"].result is not None
    assert [v.view for v in seen["last"].result.views] == ["canonical"]
    assert seen["last"].result.views[0].path == str(tmp_path / "out" / "last.png")
    assert seen["hang"].result is None and "timed out" in seen["hang"].error
    assert seen["crash"].result is None and "worker died (exit code 3)" in seen["crash"].error
    assert (tmp_path / "out" / "last.png").is_file() and not (tmp_path / "out" / "hang.png").exists()
