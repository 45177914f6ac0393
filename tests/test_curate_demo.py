"""The whole curation on the generated demo library, through the CLI, with real bpy renders (64 px):
every planted exact copy, recolour and rescale is flagged with the right pair, the broken files are
flagged, at most 10 % of the clean objects carry a duplicate flag, and `filter` prints precision and
recall against the generator's ground_truth.json. Also writes the contact sheet `make demo` writes."""

from __future__ import annotations

import json

import pytest
from PIL import Image
from sqlalchemy import select

from mixcount.curation.flags import DUPLICATE_KINDS, evaluate_against_ground_truth
from mixcount.catalog.db import open_catalog
from mixcount.demo.library import generate_demo_library
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.cli import main

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def test_demo_library_precision_recall(tmp_path, capsys):
    truth = generate_demo_library(tmp_path / "demo", seed=0)
    assert truth["exact_copies"] and truth["recolours"] and truth["rescales"] and truth["broken"]
    db = str(tmp_path / "catalog.db")
    base = ["--db", db, "--config", "configs/quick.toml", "--set", "render.resolution=64", "--set", "render.samples=2"]
    assert main(base + ["catalog", "ingest", str(tmp_path / "demo")]) == 0
    assert main(base + ["catalog", "render"]) == 0
    capsys.readouterr()
    assert main(base + ["catalog", "filter", "--json"]) == 0
    captured = capsys.readouterr()
    assert "precision" in captured.err and "recall" in captured.err
    summary = json.loads(captured.out)
    gt = summary["ground_truth"]

    assert gt["recall"] == 1.0 and not gt["missed_pairs"]
    assert gt["broken_flagged"] == gt["broken_planted"] == len(truth["broken"])
    assert gt["clean_flag_rate"] <= 0.10
    assert gt["precision"] >= 0.7

    # the right pair, by folder name, for every trap; and one member of each pair is excluded
    catalog = open_catalog(db, data_dir="")
    try:
        with catalog.session() as s:
            by_folder = {o.name: o for o in s.scalars(select(CatalogObject))}
            for key in ("exact_copies", "recolours", "rescales"):
                for original, twin, *_ in truth[key]:
                    a, b = by_folder[original], by_folder[twin]
                    kinds = set(s.scalars(select(Flag.kind).where(Flag.object_id == b.id, Flag.pair_object_id == a.id)))
                    assert kinds & set(DUPLICATE_KINDS), (key, original, twin)
                    assert sorted([a.status, b.status]) == ["active", "excluded"], (key, original, twin)
            for broken in truth["broken"]:
                obj = by_folder[broken["folder"]]
                assert obj.status == "broken"
                assert s.scalar(select(Flag.kind).where(Flag.object_id == obj.id)) == "degenerate"
        assert evaluate_against_ground_truth(catalog) == gt  # stable across calls
    finally:
        catalog.close()

    # rerun is idempotent; the contact sheet of the demo library is written
    assert main(base + ["catalog", "filter", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["ground_truth"] == gt
    assert main(base + ["catalog", "sheet", "--out", str(tmp_path / "sheet"), "--json"]) == 0
    written = json.loads(capsys.readouterr().out)
    assert written["objects"] == truth["expected"]["total"]
    with Image.open(written["pngs"][0]) as im:
        assert im.width >= 600 and im.height >= 300
    print(json.dumps(gt, indent=1))  # the figures, for the record (pytest -s)
