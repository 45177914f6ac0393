"""The surface-colour sampling behind the offline captions is seeded by the model's content hash, not the
row id an ingest gave the object: two catalogs of one library (their ingests numbered the rows in another
order) caption the same asset with the same colour shares. Found reading 53 captions of two catalogs of a
named library: 3 differed by one percent of a colour share (a 50/50 volleyball swapped its colour order)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from mixcount.captions.base import CaptionInput


def _speckled_box(path: Path) -> None:
    """A box subdivided into many faces with per-vertex colours drawn at random from three colours, so the
    measured shares depend on which surface points are sampled."""
    mesh = trimesh.creation.box(extents=(0.1, 0.1, 0.1)).subdivide().subdivide().subdivide()
    palette = np.array([[200, 30, 30, 255], [30, 30, 200, 255], [230, 230, 230, 255]], dtype=np.uint8)
    mesh.visual.vertex_colors = palette[np.random.default_rng(7).integers(0, 3, len(mesh.vertices))]
    mesh.export(path)


def _item(model: Path, object_id: int, content_hash: str) -> CaptionInput:
    return CaptionInput(object_id=object_id, name="Box", category="box", dims=(0.1, 0.1, 0.1),
                        model_path=str(model), content_hash=content_hash)


def test_same_asset_same_colours_whatever_its_row_id(tmp_path: Path) -> None:
    model = tmp_path / "box.ply"
    _speckled_box(model)
    a = _item(model, 2, "42d2acbfa9b5bd5c764b").with_measured_colours("model")
    b = _item(model, 12, "42d2acbfa9b5bd5c764b").with_measured_colours("model")
    assert a.colours.names and a.colours == b.colours
    # the row id was the seed before: other ids sample other points, so the shares move
    by_id = [_item(model, k, "").with_measured_colours("model").colours for k in (2, 12, 30)]
    assert len({repr(c) for c in by_id}) > 1


def test_colour_seed_from_hash_else_id() -> None:
    assert _item(Path("x"), 5, "").colour_seed() == 5
    assert _item(Path("x"), 5, "ff").colour_seed() == 255
    assert _item(Path("x"), 5, "not-hex").colour_seed() == _item(Path("x"), 9, "not-hex").colour_seed()
