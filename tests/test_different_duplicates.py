"""A person's "different" decision on an exact-duplicate pair keeps both objects as classes of their own
(issue 70 item 6): two crystals of one KiCad package (Debian ``kicad-demos``' STEP), filed as "Crystal 16MHz"
and "Crystal 8MHz", are one file twice; the filter excludes one as an exact duplicate and the caption step
another time for equal captions. After the person's "different", both are active through filter and
captions again, their captions differ by the words of their names, and both reach the pool."""

from __future__ import annotations

import json
import shutil

import pytest
from public_packages import deb_tree
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CaptionSet, CatalogObject
from mixcount.cli import main


def test_different_keeps_both_of_an_exact_duplicate_pair(tmp_path, capsys):
    root, why = deb_tree("kicad-demos")
    if root is None:
        pytest.skip(why)
    step = root / "usr/share/kicad/demos/stickhub/3dmodels/Crystal_SMD_4P_2520.step"
    lib = tmp_path / "lib"
    for folder in ("Crystal 16MHz", "Crystal 8MHz"):
        (lib / folder).mkdir(parents=True)
        shutil.copy(step, lib / folder / step.name)
    db = str(tmp_path / "catalog.db")
    args = ["--db", db, "--config", "quick"]
    assert main([*args, "catalog", "ingest", str(lib), "--workers", "1"]) == 0
    assert main([*args, "catalog", "filter"]) == 0
    assert main([*args, "catalog", "caption"]) == 0
    cat = open_catalog(db, data_dir="")
    try:
        with cat.session() as s:
            objs = {o.name: o for o in s.scalars(select(CatalogObject))}
            assert sorted(o.status for o in objs.values()) == ["active", "excluded"]  # before: one is kept
            ids = {name: o.id for name, o in objs.items()}
    finally:
        cat.close()
    a, b = sorted(ids.values())
    names = {v: k for k, v in ids.items()}
    decisions = tmp_path / "decisions.json"
    decisions.write_text(json.dumps({
        "format": "mixcount-review-v1", "reviewer": "ana", "exported_at": "2026-12-07T03:00:00.000Z", "decisions": [],
        "pairs": [{"a": a, "b": b, "a_name": names[a], "b_name": names[b], "decision": "different",
                   "note": "16 and 8 MHz", "decided_at": "2026-12-07T03:00:00.000Z"}]}))
    assert main([*args, "catalog", "review", "import", str(decisions)]) == 0
    assert main([*args, "catalog", "filter"]) == 0
    assert main([*args, "catalog", "caption"]) == 0
    assert main([*args, "catalog", "split"]) == 0
    capsys.readouterr()
    cat = open_catalog(db, data_dir="")
    try:
        with cat.session() as s:
            objs = list(s.scalars(select(CatalogObject)))
            assert [o.status for o in objs] == ["active", "active"], [(o.name, o.status) for o in objs]
            assert objs[0].content_hash == objs[1].content_hash  # one file twice
            short = {o.name: cs.short for o in objs for cs in s.scalars(
                select(CaptionSet).where(CaptionSet.object_id == o.id, CaptionSet.active.is_(True)))}
        from mixcount.catalog.pool_loader import load_pool

        with cat.session() as s:
            pool = load_pool(s)
    finally:
        cat.close()
    assert short["Crystal 16MHz"] != short["Crystal 8MHz"], short
    assert short["Crystal 16MHz"].endswith("16mhz") and short["Crystal 8MHz"].endswith("8mhz"), short
    assert len(pool) == 2  # two classes for compose
