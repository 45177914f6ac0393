"""Vertex colours in canonical renders (issue 35, item 3): a green OBJ can and a pink PLY donut, coloured
only by their vertex colours (no material), keep their colour on the canonical render - the picture the
contact sheet and the external exemplars show - as they do in the scene render.

User's side: ``catalog ingest`` then ``catalog render`` through the CLI, a real bpy render (32 px,
2 samples); the mean colour of the object's pixels (the render's coverage mask) has the vertex colour's
hue and is clearly coloured (white would have no saturation)."""

from __future__ import annotations

import colorsys

import numpy as np
import pytest
import trimesh
from PIL import Image
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CatalogObject
from mixcount.cli import main
from mixcount.curation.renders import canonical_render_path, mask_path_for

pytestmark = [pytest.mark.blender, pytest.mark.slow]

GREEN = (40, 190, 70)
PINK = (240, 110, 180)


def painted(mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1)))
    return mesh


def hue_sat(rgb) -> tuple[float, float]:
    h, _l, s = colorsys.rgb_to_hls(*(np.asarray(rgb, dtype=float) / 255.0))
    return h * 360.0, s


def test_obj_and_ply_vertex_colours_survive_the_canonical_render(tmp_path, capsys):
    lib = tmp_path / "lib"
    lib.mkdir()
    painted(trimesh.creation.cylinder(radius=0.033, height=0.115, sections=32), GREEN).export(lib / "green_can.obj")
    painted(trimesh.creation.torus(major_radius=0.045, minor_radius=0.02), PINK).export(lib / "pink_donut.ply")
    db = str(tmp_path / "catalog.db")
    small = ["--db", db, "--config", "quick", "--set", "canonical_render.resolution=32", "--set", "canonical_render.samples=2"]
    assert main([*small, "catalog", "ingest", str(lib), "--workers", "1"]) == 0
    assert main([*small, "catalog", "render"]) == 0
    cap = capsys.readouterr()
    assert "2 rendered" in cap.out + cap.err

    cat = open_catalog(db, data_dir="")
    try:
        with cat.session() as s:
            objs = {o.model_path.rsplit("/", 1)[-1]: o.id for o in s.scalars(select(CatalogObject))}
            paths = {name: canonical_render_path(s, oid) for name, oid in objs.items()}
    finally:
        cat.close()
    for name, colour in (("green_can.obj", GREEN), ("pink_donut.ply", PINK)):
        path = paths[name]
        assert path is not None
        rgb = np.asarray(Image.open(path).convert("RGB"), dtype=float)
        mask = np.asarray(Image.open(mask_path_for(path)))
        assert (mask > 200).sum() > 50
        mean = rgb[mask > 200].mean(axis=0)
        hue, sat = hue_sat(mean)
        want_hue, _ = hue_sat(colour)
        assert sat > 0.25, f"{name} renders without colour: mean {mean.round(1)}"
        assert min(abs(hue - want_hue), 360 - abs(hue - want_hue)) < 20, f"{name}: hue {hue:.0f}, want {want_hue:.0f}"
