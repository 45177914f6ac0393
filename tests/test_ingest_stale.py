"""Nothing stale after a fix (issue 52): a changed asset's renders, descriptors, flags and captions go
at re-ingest, and the next step redoes them without ``--force``; an unchanged one keeps them all."""

from __future__ import annotations

import json

from sqlalchemy import select

from mixcount.captions.captioning import caption_catalog
from mixcount.captions.stub import StubCaptioner
from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CaptionSet, CatalogObject, Flag, Render
from mixcount.config import load_config
from tests.package_folders import build_package_folders


def _derive(catalog, oid: int, geometry_hash: str, content_hash: str):
    """What render / filter would have left for the object: a render row + files, a flag, descriptors."""
    catalog.renders_dir.mkdir(parents=True, exist_ok=True)
    render = catalog.renders_dir / f"obj_{oid:06d}.png"
    render.write_bytes(b"png")
    render.with_name(f"obj_{oid:06d}_mask.png").write_bytes(b"png")
    descriptors = catalog.data_dir / "descriptors"
    descriptors.mkdir(parents=True, exist_ok=True)
    shape = descriptors / f"{geometry_hash[:32]}_3.json"
    samples = descriptors / f"{content_hash[:32]}_2.npz"
    shape.write_text("{}")
    samples.write_bytes(b"npz")
    with catalog.session() as s:
        s.add(Render(object_id=oid, view="canonical", path=str(render), model_hash="x", settings_hash="y"))
        s.add(Flag(object_id=oid, kind="size_outlier", score=0.7, reason="old size"))
        s.commit()
    return render, shape, samples


def _state(catalog, oid: int):
    with catalog.session() as s:
        return (len(s.scalars(select(Render).where(Render.object_id == oid)).all()),
                sorted(f.kind for f in s.scalars(select(Flag).where(Flag.object_id == oid))),
                len(s.scalars(select(CaptionSet).where(CaptionSet.object_id == oid)).all()))


def _caption(catalog):
    return caption_catalog(catalog, StubCaptioner("stub-v1"), concurrency=1, colour_source="model", dedupe=False)


def test_changed_units_name_and_texture_invalidate_derived_data(tmp_path, catalog):
    lib = build_package_folders(tmp_path / "lib")
    duck = lib / "Rubber duck"
    config = load_config([], ["ingest.workers=1"])
    assert ingest_paths(catalog, [duck], config=config).new == 1
    with catalog.session() as s:
        obj = s.scalars(select(CatalogObject)).one()
        oid, ghash, chash = obj.id, obj.geometry_hash, obj.content_hash
    assert _caption(catalog).captioned == 1
    files = _derive(catalog, oid, ghash, chash)
    assert _state(catalog, oid) == (1, ["size_outlier"], 1)

    # unchanged: everything stays, captioning skips
    assert ingest_paths(catalog, [duck], config=config).unchanged == 1
    assert _state(catalog, oid) == (1, ["size_outlier"], 1) and all(f.exists() for f in files)
    assert _caption(catalog).skipped == 1

    # another object carries a pair flag about it (a near duplicate of its old shape)
    ingest_paths(catalog, [lib / "Dice"], config=config)
    with catalog.session() as s:
        dice = s.scalars(select(CatalogObject).where(CatalogObject.name == "Dice")).one()
        s.add(Flag(object_id=dice.id, kind="near_duplicate_geometry", score=0.9, reason="old", pair_object_id=oid))
        s.commit()
        dice_id = dice.id

    # the units are corrected (a metadata.json beside the model): the old size's products go
    (duck / "metadata.json").write_text(json.dumps({"units": "cm"}))
    summary = ingest_paths(catalog, [duck], config=config)
    assert summary.updated == 1
    assert summary.invalidated and "source_units" in summary.invalidated[0][1]
    assert _state(catalog, oid) == (0, [], 0)
    assert not any(f.exists() for f in files)
    assert _state(catalog, dice_id)[1] == ["ingest_note"]  # the pair flag about the old duck is gone
    again = _caption(catalog)
    assert (again.captioned, again.skipped) == (2, 0)  # the duck again, and the dice for the first time

    # the name changes: the captions (which use it) go again
    (duck / "metadata.json").write_text(json.dumps({"units": "cm", "name": "Yellow rubber duck"}))
    summary = ingest_paths(catalog, [duck], config=config)
    assert summary.updated == 1 and "name" in summary.invalidated[0][1]
    assert _state(catalog, oid)[2] == 0
    assert _caption(catalog).captioned == 1

    # the texture is replaced: content changes, renders go
    with catalog.session() as s:
        obj = s.get(CatalogObject, oid)
        ghash, chash = obj.geometry_hash, obj.content_hash
    files = _derive(catalog, oid, ghash, chash)
    from PIL import Image

    Image.new("RGB", (8, 8), (10, 200, 10)).save(duck / "duckCM.png")
    summary = ingest_paths(catalog, [duck], config=config)
    assert summary.updated == 1 and "content_hash" in summary.invalidated[0][1]
    assert _state(catalog, oid) == (0, [], 0) and not any(f.exists() for f in files)


def test_a_now_broken_object_takes_its_new_name(tmp_path, catalog):
    lib = build_package_folders(tmp_path / "lib")
    cube = lib / "Sugar cube"
    config = load_config([], ["ingest.workers=1"])
    ingest_paths(catalog, [cube], config=config)
    (cube / "cube.obj").write_text("not an obj at all\n")
    (cube / "metadata.json").write_text(json.dumps({"name": "Sugar cube (old)"}))
    first = ingest_paths(catalog, [cube], config=config)
    assert first.broken == 1
    (cube / "metadata.json").write_text(json.dumps({"name": "Sugar cube, broken"}))
    second = ingest_paths(catalog, [cube], config=config)
    assert second.broken == 1
    with catalog.session() as s:
        obj = s.scalars(select(CatalogObject)).one()
    assert obj.status == "broken" and obj.name == "Sugar cube, broken"
