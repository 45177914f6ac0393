"""The whole curation on the generated demo library, through the CLI, with real bpy renders (64 px):
every planted recolour is reported as a colour variant pair (both active), every exact copy, rescale, turned-and-rescaled copy, re-tessellated copy, copy under
another name and source, and copy rebuilt from the surface (remeshed, other units, re-baked, split) is
flagged with the right pair (recall and precision per trap kind), one object of each planted group is
kept, the broken files are flagged, at most 4 % of the clean objects carry a duplicate flag, precision
is at least 0.95, the non-manifold tote stays
active with a mesh_quality warning, and `filter` prints the figures against the generator's
ground_truth.json. Also writes the contact sheet `make demo` writes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import RENDERED_DEMO
from PIL import Image
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.grouping import connected_groups
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.cli import main
from mixcount.curation.finding.ground_truth import TRAP_KINDS, VARIANT_TRAPS, evaluate_against_ground_truth
from mixcount.curation.flag_kinds import DUPLICATE_KINDS

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def test_demo_library_precision_recall(tmp_path, capsys, rendered_demo_catalog):
    rendered, truth = rendered_demo_catalog  # generated, ingested and rendered at 64 px (tests/conftest.py)
    assert all(truth[key] for key, _ in TRAP_KINDS) and truth["broken"] and truth["mesh_quality"]
    shutil.copytree(rendered, tmp_path / "db")  # this test filters its own copy
    db = str(tmp_path / "db" / "catalog.db")
    base = ["--db", db, *RENDERED_DEMO]
    capsys.readouterr()
    assert main(base + ["catalog", "filter", "--json"]) == 0
    captured = capsys.readouterr()
    assert "precision" in captured.err and "recall" in captured.err
    summary = json.loads(captured.out)
    gt = summary["ground_truth"]

    assert gt["recall"] == 1.0 and not gt["missed_pairs"]
    for kind, row in gt["by_trap"].items():
        assert row["planted"] >= 1 and row["recall"] == 1.0, (kind, row)
    # issue 49: copies found by their shape (another source, other resolution, pose, a squash) also raise, for
    # a person, products of one demo mould in near colours (the espresso and the paper cups: one cup
    # geometry, colours 0.075 apart; the blue and the white plate). Never a duplicate (nothing excluded for
    # it), always two objects of one category: possible copies / variants to confirm.
    assert gt["duplicate_precision"] == 1.0, gt["false_pair_kinds"]
    for pair, kinds in gt["false_pair_kinds"].items():
        a, b = pair.split(" | ")
        assert set(kinds) <= {"possible_copy", "colour_variant"}, (pair, kinds)
        assert a.split("_")[0].split("-")[0].lower() == b.split("_")[0].split("-")[0].lower(), pair  # one mould
    assert gt["broken_flagged"] == gt["broken_planted"] == len(truth["broken"])
    assert gt["clean_flag_rate"] <= 0.04, gt["clean_flagged"]
    assert len(gt["clean_paired"]) <= 6, gt["clean_paired"]  # any pairing: before issue 34, the two dice
    assert gt["by_trap"]["recolour"]["flags"] == ["colour_variant"] and gt["variant_pairs"] >= 2
    assert gt["precision"] >= 0.8, gt["false_pairs"]
    with capsys.disabled():
        print(f"\ndemo library: pair precision {gt['precision']} ({gt['pairs_correct']}/{gt['pairs_predicted']}), "
              f"duplicate precision {gt['duplicate_precision']}, recall {gt['recall']} ({gt['pairs_found']}/"
              f"{gt['pairs_planted']}), to decide {summary['to_decide_objects']} of {summary['objects']} objects, "
              f"{summary['to_decide_pairs']} pairs; false {gt['false_pair_kinds']}")
    (tote,) = gt["mesh_quality_planted"]
    assert tote["status"] == "active" and tote["mesh_quality"] > 0.3 and not tote["degenerate"]

    # the right pair, by folder name, for every trap; and one member of each pair is excluded
    catalog = open_catalog(db, data_dir="")
    try:
        with catalog.session() as s:
            by_folder = {Path(o.model_path).parent.name: o for o in s.scalars(select(CatalogObject))}
            planted = []
            for key, kind in TRAP_KINDS:
                for original, twin, *_ in truth[key]:
                    a, b = by_folder[original], by_folder[twin]
                    kinds = set(s.scalars(select(Flag.kind).where(Flag.object_id == b.id, Flag.pair_object_id == a.id)))
                    if kind in VARIANT_TRAPS:  # one geometry in other colours: a class pair, both kept
                        assert kinds == {"colour_variant"}, (key, original, twin, kinds)
                        assert b.status == "active", (original, twin)  # never excluded as a copy
                        continue
                    assert kinds & set(DUPLICATE_KINDS), (key, original, twin)
                    planted.append((original, twin))
            for group in connected_groups(planted):  # an original and all its copies: one kept
                assert sorted(by_folder[g].status for g in group).count("active") == 1, group
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
