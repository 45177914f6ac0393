"""Untextured parts through the user's commands (issue 56 item 5): folders copied as a user would from
Debian's ``prusa-slicer`` and PyPI's ``metaworld`` plus one whose ``metadata.json`` says ``colour:
"#d020c0"``, ingested, rendered (real bpy, 32 px) and captioned. Each canonical render shows its part in
its palette look (the object's pixels have the look's hue and are clearly coloured, not the default
near-white), its caption names that colour, and compose's pool hands the same look to the scene's
USD asset."""

from __future__ import annotations

import colorsys
import json
import shutil

import numpy as np
import pytest
from PIL import Image
from public_packages import cad_part_folders
from sqlalchemy import select

from mixcount.captions.colours import name_rgb
from mixcount.catalog.db import open_catalog
from mixcount.catalog.materials import object_look
from mixcount.catalog.models import CaptionSet, CatalogObject
from mixcount.catalog.pool_loader import load_pool
from mixcount.cli import main
from mixcount.config import load_config
from mixcount.curation.renders import canonical_render_path, mask_path_for

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def _hue_sat(rgb) -> tuple[float, float]:
    h, _l, s = colorsys.rgb_to_hls(*(np.asarray(rgb, dtype=float) / 255.0))
    return h * 360.0, s


def test_untextured_parts_render_and_are_captioned_in_their_look(tmp_path, capsys):
    shapes, meshes = cad_part_folders()
    lib = tmp_path / "lib"
    for folder, src in (("Hex nut", shapes / "M3_hex_nut.stl"), ("Puck", meshes / "puck" / "puck.stl"),
                        ("Magenta box", shapes / "box.stl")):
        (lib / folder).mkdir(parents=True)
        shutil.copy(src, lib / folder / src.name)
    (lib / "Magenta box" / "metadata.json").write_text(json.dumps({"name": "Box", "colour": "#d020c0"}))
    db = str(tmp_path / "catalog.db")
    small = ["--db", db, "--config", "quick", "--set", "canonical_render.resolution=32",
             "--set", "canonical_render.samples=2"]
    assert main([*small, "catalog", "ingest", str(lib), "--workers", "1"]) == 0
    assert main([*small, "catalog", "render"]) == 0
    assert main([*small, "catalog", "caption"]) == 0
    capsys.readouterr()

    palette = load_config(["quick"]).palette
    cat = open_catalog(db, data_dir="")
    try:
        with cat.session() as s:
            objs = list(s.scalars(select(CatalogObject)))
            assert len(objs) == 3 and not any(o.textured for o in objs)
            looks = {o.id: object_look(palette, name=o.name, category=o.category or "", metadata_json=o.metadata_json,
                                       content_hash=o.content_hash or "") for o in objs}
            renders = {o.id: canonical_render_path(s, o.id) for o in objs}
            short = {cs.object_id: cs.short for cs in s.scalars(select(CaptionSet).where(CaptionSet.active.is_(True)))}
            names = {o.id: o.name for o in objs}
        assert main([*small, "catalog", "split"]) == 0  # compose's pool holds objects with a split
        with cat.session() as s:
            pool = {r.object_id: r.look for r in load_pool(s, palette=palette)}
    finally:
        cat.close()
    by_name = {names[i]: looks[i] for i in looks}
    assert by_name["Hex nut"].name == "brass" and by_name["Box"].source == "metadata", by_name
    for oid, look in looks.items():
        path = renders[oid]
        assert path is not None
        rgb = np.asarray(Image.open(path).convert("RGB"), dtype=float)
        mask = np.asarray(Image.open(mask_path_for(path)))
        assert (mask > 200).sum() > 30
        hue, sat = _hue_sat(np.median(rgb[mask > 200], axis=0))
        want, _ = _hue_sat(look.rgb8())
        assert sat > 0.2, f"{names[oid]} renders without colour (look {look.name})"
        assert min(abs(hue - want), 360 - abs(hue - want)) < 25, f"{names[oid]}: hue {hue:.0f}, look {look.name} {want:.0f}"
        assert name_rgb(look.rgb8()) in short[oid].split(), (names[oid], short[oid], look)
        assert oid not in pool or pool[oid] == pytest.approx(look.as_tuple())
    assert any(v is not None for v in pool.values()), pool
