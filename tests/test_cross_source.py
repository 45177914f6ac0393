"""Copies another source published (issue 34), through the CLI on a real catalog with real bpy renders
(64 px): the textured bunny scan and three copies decimated to 3-4 % of the faces, flattened 15-20 %
along one axis, stored in mm / cm / m, turned, re-baked (one 10 % darker, one recoloured); a plain
yellow cow, its decimated, flattened copy in cm, an olive copy decimated and flattened and a red copy
turned and stored in mm; and 35 clean objects: 11 shape families (balls, bottles, mugs, cans, cups, blocks,
dice, figurines, cookies, donuts, fruit) and two real scans in plain colours (airplane, bone).

* same-look copies on a patterned surface are duplicates (one kept);
* the same plain colour on a loosely agreeing shape is a ``possible_copy``: both active, shown by
  ``catalog sheet --only flagged`` with both thumbnails side by side and the figures;
* the recoloured bunny copy (another source, other colours) is a ``possible_copy`` of each bunny: its
  colour pattern repeats in other colours;
* no pair at all between two different objects (before issue 34: none either, and none of the copies);
* the olive cow (another source, another plain colour, decimated and flattened) is a ``possible_copy`` of
  the cow: the same shape with each principal axis scaled to its extent (a squash scales one axis);
* the red cow (another plain colour, turned, in mm, the shape untouched) is a ``colour_variant`` of the
  cow: both active."""

from __future__ import annotations

import json
from itertools import combinations
from pathlib import Path

import pytest
from cross_source_library import COPIES, same_object, write_library
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.cli import main
from mixcount.curation.flag_kinds import DUPLICATE_KINDS, severity

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def test_copies_from_another_source(tmp_path, capsys):
    lib = write_library(tmp_path / "lib")
    db = str(tmp_path / "catalog.db")
    base = ["--db", db, "--config", "configs/quick.toml", "--set", "canonical_render.resolution=64", "--set", "canonical_render.samples=2"]
    assert main(base + ["catalog", "ingest", str(lib)]) == 0
    assert main(base + ["catalog", "render"]) == 0
    capsys.readouterr()
    assert main(base + ["catalog", "filter", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["missing_renders"] == 0 and not summary["descriptor_failures"]

    catalog = open_catalog(db, data_dir="")
    try:
        with catalog.session() as s:
            objs = {o.id: o for o in s.scalars(select(CatalogObject))}
            folder = {i: Path(o.model_path).parent.name for i, o in objs.items()}
            status = {folder[i]: o.status for i, o in objs.items()}
            flags = s.scalars(select(Flag).where(Flag.pair_object_id.is_not(None))).all()
            singles = {(folder[f.object_id], f.kind) for f in s.scalars(select(Flag).where(Flag.pair_object_id.is_(None)))
                       if severity(f.kind, f.reason) == "decide"}
            ids = {name: i for i, name in folder.items()}
    finally:
        catalog.close()
    pairs: dict[frozenset[str], dict[str, str]] = {}
    alike: set[frozenset[str]] = set()
    for f in flags:
        key = frozenset((folder[f.object_id], folder[f.pair_object_id]))
        if severity(f.kind, f.reason) == "info":  # a look-alike: ranked for a person, decides nothing
            alike.add(key)
            continue
        pairs.setdefault(key, {})[f.kind] = f.reason
    assert len(status) == 43 and all(n in status for group in COPIES for n in group)

    # no pairing to decide between two different objects, except objects built from one demo mould (the
    # same builder: identical or near-identical geometry, other colours): variants for a person to confirm,
    # never duplicates; the queue is a short one
    false = sorted(sorted(p) for p in pairs if not same_object(*p))
    mould = [p for p in false if len({n.rstrip("0123456789") for n in p}) == 1 and set(pairs[frozenset(p)]) == {"possible_copy"}]
    assert false == mould, [(p, sorted(pairs[frozenset(p)])) for p in false if p not in mould]
    assert all("the shape carries evidence" in pairs[frozenset(p)]["possible_copy"] for p in mould)
    assert not any(status[n] != "active" for p in mould for n in p)
    # the queue is the objects of those pairs: no usable mesh warning, no look-alike in it
    in_queue = {n for p in pairs for n in p} | {n for n, _ in singles}
    assert summary["to_decide_pairs"] == len(pairs) and summary["to_decide_objects"] == len(in_queue)
    assert {k for _, k in singles} <= {"degenerate", "size_outlier"}, singles
    assert not any(same_object(*p) for p in alike)  # a copy is never only a look-alike
    with capsys.disabled():
        print(f"\ncross-source library: {len(status)} objects, to decide {summary['to_decide_objects']} objects and "
              f"{len(pairs)} pairs (between different objects {len(false)}, all of one mould: {mould}), "
              f"look-alikes {len(alike)}, single-object flags to decide {sorted(singles)}")

    # the same bunny from three sources, patterned surface: duplicates, one kept
    same_look = ("bunny", "bunny_dec_flat_mm", "bunny_dec_flat_cm_dark")
    for a, b in combinations(same_look, 2):
        kinds = pairs.get(frozenset((a, b)), {})
        assert set(kinds) & set(DUPLICATE_KINDS), (a, b, kinds)
    assert sorted(status[n] for n in same_look).count("active") == 1
    reason = pairs[frozenset(("bunny", "bunny_dec_flat_mm"))]["near_duplicate_appearance"]
    assert reason.startswith("copy from another source") and "proportions" in reason and "refined" in reason

    # the plain cow and its flattened copy: for a person, both active
    cow = pairs.get(frozenset(("cow_yellow", "cow_yellow_dec_flat_cm")), {})
    assert set(cow) == {"possible_copy"}, cow
    assert "same plain colour" in cow["possible_copy"] and "D2" in cow["possible_copy"]
    assert status["cow_yellow"] == status["cow_yellow_dec_flat_cm"] == "active"

    # another source AND other colours: the print's pattern repeats -> for a person; a plain colour -> nothing
    for other in same_look:
        kinds = pairs.get(frozenset((other, "bunny_dec_flat_recoloured")), {})
        assert set(kinds) == {"possible_copy"}, (other, kinds)
        assert "maybe a colour variant from another source" in kinds["possible_copy"]
    assert status["bunny_dec_flat_recoloured"] == "active"

    # another source in another plain colour: the axis-normalised shape pairs it, for a person
    olive = pairs.get(frozenset(("cow_yellow", "cow_olive_dec_flat")), {})
    assert set(olive) == {"possible_copy"}, olive
    assert "maybe a colour variant from another source" in olive["possible_copy"]
    assert "each principal axis scaled to its extent" in olive["possible_copy"]
    # the same shape at any scale in another plain colour: one geometry in two colours, both active
    red = pairs.get(frozenset(("cow_yellow", "cow_red_turned_mm")), {})
    assert set(red) == {"colour_variant"}, red
    assert all(status[n] == "active" for n in ("cow_yellow", "cow_olive_dec_flat", "cow_red_turned_mm"))
    # the airplane (mirror-asymmetric along two axes like the cow) and the bone (symmetric) pair with nothing
    assert not any(n in p for p in pairs for n in ("airplane_grey", "bone_ivory"))

    # the review page shows the possible copy with both thumbnails and the figures
    assert main(base + ["catalog", "sheet", "--out", str(tmp_path / "sheet"), "--only", "flagged", "--json"]) == 0
    written = json.loads(capsys.readouterr().out)
    page = (tmp_path / "sheet" / "review.html").read_text()
    shown = [name for name, i in ids.items() if f'id="obj-{i}"' in page]
    assert written["objects"] == len(shown)
    assert {*same_look, "bunny_dec_flat_recoloured", "cow_yellow", "cow_yellow_dec_flat_cm",
            "cow_olive_dec_flat", "cow_red_turned_mm"} <= set(shown)
    a, b = ids["cow_yellow"], ids["cow_yellow_dec_flat_cm"]
    card = page[page.index(f'id="obj-{a}"'):]
    card = card[:card.index("</article>")] if "</article>" in card else card[:20000]
    assert 'data-kind="possible_copy"' in card and f'data-pair="{b}"' in card
    assert f'alt="#{b}"' in card and "data:image/jpeg;base64," in card and "surface colours 0.0" in card
    # ... and, pair-centred, one card per pair to decide, with both renders and the evidence
    assert written["pairs_to_decide"] == written["pairs"] == len(pairs)
    decide = page[page.index('id="pairs-decide"'):page.index('id="pairs-info"')]
    pair_card = decide[decide.index(f'id="pair-{min(a, b)}-{max(a, b)}"'):]
    pair_card = pair_card[:pair_card.index("</article>")]
    assert pair_card.count('class="pthumb"') == 2 and "same plain colour" in pair_card
