"""Different objects whose colours share one name ("red" and a darker red) still get captions that differ at
every tier, colour variants or not: the stub says "darker"/"lighter" from the measured mean luminance of the
pair before any collision is flagged; only objects nothing seen tells apart (one file twice) collide."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from sqlalchemy import select

from mixcount.captions.captioning import caption_catalog
from mixcount.captions.stub import StubCaptioner
from mixcount.catalog.models import CaptionSet, CatalogObject, Flag


def _glb(path: Path, rgb: tuple[int, int, int]) -> Path:
    mesh = trimesh.creation.cylinder(0.03, 0.15, sections=32)
    mesh.visual.vertex_colors = np.tile([*rgb, 255], (len(mesh.vertices), 1))
    mesh.export(path)
    return path


def _add(s, tmp_path: Path, key: str, name: str, rgb: tuple[int, int, int]) -> int:
    glb = _glb(tmp_path / f"{key}.glb", rgb)
    obj = CatalogObject(source="folder", source_id=key, name=name, category="food", model_path=str(glb),
                        dim_x=0.06, dim_y=0.06, dim_z=0.15, watertight=True, volume=4e-4, face_count=128,
                        metadata_json=f'{{"metadata": {{"name": "{name}"}}}}')
    s.add(obj)
    s.flush()
    return int(obj.id)


def test_variants_with_one_colour_name_are_told_apart_by_measured_shade(catalog, tmp_path):
    with catalog.session() as s:
        light = _add(s, tmp_path, "a", "Ketchup bottle", (235, 40, 45))
        dark = _add(s, tmp_path, "b", "Ketchup bottle (dark recolour)", (185, 25, 30))
        twin_a = _add(s, tmp_path, "c", "Hot sauce bottle", (235, 40, 45))  # same look, not variants
        twin_b = _add(s, tmp_path, "d", "Hot sauce bottle", (185, 25, 30))
        s.add_all([Flag(object_id=light, kind="colour_variant", score=0.9, reason="test", pair_object_id=dark),
                   Flag(object_id=dark, kind="colour_variant", score=0.9, reason="test", pair_object_id=light)])
        s.commit()
    summary = caption_catalog(catalog, StubCaptioner("stub-test"), concurrency=1, colour_source="model",
                              dedupe=False)
    assert summary.variants_toned == 4
    with catalog.session() as s:
        sets = {cs.object_id: cs for cs in s.scalars(select(CaptionSet).where(CaptionSet.active.is_(True)))}
    for x, y in ((light, dark), (twin_a, twin_b)):
        for tier in ("short", "concise", "detailed"):
            a, b = getattr(sets[x], tier), getattr(sets[y], tier)
            assert a.lower() != b.lower(), (tier, a, b)
    assert sets[dark].short == "darker red ketchup bottle" and sets[light].short == "lighter red ketchup bottle"
    assert sets[dark].concise.startswith("Darker slender red ketchup bottle")
    # not variants, but two different objects: told apart the same way, no collision left to flag
    assert {sets[twin_a].short, sets[twin_b].short} == {"lighter red hot sauce bottle", "darker red hot sauce bottle"}
    assert summary.collision_pairs == 0
    assert summary.caption_check["by_kind"]["same_as_variant"] == 0

    # a rerun (resumed: nothing captioned again) keeps the variants apart
    again = caption_catalog(catalog, StubCaptioner("stub-test"), concurrency=1, colour_source="model",
                            dedupe=False)
    assert (again.captioned, again.variants_toned) == (0, 0)
    with catalog.session() as s:
        short = {cs.object_id: cs.short for cs in s.scalars(select(CaptionSet).where(CaptionSet.active.is_(True)))}
    assert short[dark] == "darker red ketchup bottle"
