"""Captions on a library shaped like real ones (tests/named_library.py: person-written names with source
tags and ids, broad categories, recolour pairs, DTC folder names without a name), in a plain-folder and a
DTC layout: real ingest -> real filter -> real stub caption -> `catalog list --json`, all through the CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from named_library import build_named_library, caption_figures, has_noun, rows_from_list_json
from sqlalchemy import select

from mixcount.captions.check import check_catalog, check_tiers_text
from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CaptionSet, CatalogObject, Flag

pytestmark = pytest.mark.slow  # each layout's library is built, ingested, filtered and captioned: ~20 s

COLOUR_WORDS = {"black", "grey", "white", "red", "maroon", "orange", "brown", "tan", "beige", "yellow", "gold",
                "olive", "lime", "green", "teal", "blue", "navy", "purple", "magenta", "pink", "light", "dark"}


def _cli(db: Path, *args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "mixcount", "--db", str(db), *args], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


@pytest.fixture(scope="session", params=["folder", "dtc"])
def named(request, tmp_path_factory) -> dict:
    """The library in one layout, ingested, filtered and captioned with the stub (collisions only flagged)."""
    root = tmp_path_factory.mktemp(f"named_{request.param}")
    truth = build_named_library(root / "lib", request.param)
    db = root / "catalog.db"
    _cli(db, "catalog", "ingest", str(root / "lib"), "--json")
    _cli(db, "catalog", "filter")
    done = subprocess.run([sys.executable, "-m", "mixcount", "--db", str(db), "catalog", "caption",
                           "--keep-collisions", "--json"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    records = json.loads(_cli(db, "catalog", "list", "--json"))
    return {"layout": request.param, "truth": truth, "db": db, "summary": summary, "records": records,
            "stderr": done.stderr}


def test_library_is_shaped_like_a_real_one(named):
    truth, records = named["truth"], named["records"]
    assert len(records) == len(truth) >= 40
    assert max(t["faces"] for t in truth.values()) > 100_000
    layouts = {r["layout"] for r in records}
    assert layouts == ({"folder", "dtc"} if named["layout"] == "folder" else {"dtc"})
    named_objects = [r for r in records if (r["metadata"] or {}).get("name")]
    assert len(named_objects) >= 40 and all(r["status"] != "broken" for r in records)


def test_captions_name_the_object_without_category_or_bookkeeping(named):
    figures = caption_figures(rows_from_list_json(named["records"]), named["truth"])
    assert figures["active"] >= 45
    assert figures["noun_share"] >= 0.95, figures["details"]["noun_missing"]
    assert figures["category_tacked_on"] == 0, figures["details"]["tacked"]
    assert figures["bookkeeping_fragments"] == 0, figures["details"]["fragments"]
    assert figures["uncaptioned"] == 0
    assert figures["shared_captions"] == {"short": 0, "concise": 0, "detailed": 0}, figures["shared_detail"]
    # the caption check the user sees agrees: no warnings in the summary nor in `catalog list --json`
    assert named["summary"]["caption_check"]["objects_warned"] == 0, named["summary"]["warnings"]
    active = [r for r in named["records"] if r["status"] == "active"]
    assert all(r["caption_warnings"] == [] for r in active)
    assert "caption check: object" not in named["stderr"]  # no per-object warning line either


def test_no_absolute_size_in_short_and_concise_and_measured_size_in_detailed(named):
    for r in named["records"]:
        if r["status"] != "active":
            continue
        caps = r["captions"]
        words = set((caps["short"] + " " + caps["concise"]).lower().replace(",", "").split())
        assert not words & {"large", "small", "tiny", "hand-sized", "very"}, caps
        assert " cm " in caps["detailed"] or " mm " in caps["detailed"], caps["detailed"]


def test_detailed_tier_says_measured_parts(named):
    """Separate parts are counted on the model (the hammer's handle and head, the toy car's body, cabin and
    four wheels); a one-piece object says nothing about parts."""
    by_folder = {Path(r["model_path"]).parent.name: r for r in named["records"]}
    truth = named["truth"]
    detailed = {slug: by_folder[truth[slug]["folder"]]["captions"]["detailed"]
                for slug in ("hammer", "toy_car", "banana")}
    assert "in 2 separate parts" in detailed["hammer"]
    assert "in 6 separate parts" in detailed["toy_car"]
    assert "part" not in detailed["banana"]


def test_dtc_folder_names_take_the_category_as_noun_and_measured_colours(named):
    by_folder = {Path(r["model_path"]).parent.name: r for r in named["records"]}
    expected = {"Markers_B07Z5P84J2_Peach": ("marker", None), "Markers_B07Z5Q11K8_Teal": ("marker", "teal"),
                "Mugs_B09ABCDE12_Navy": ("mug", "navy"), "Bowls_B0C7Q8R9S1_Green": ("bowl", "green"),
                "Ball_B07XK2LMN3_Volleyball": ("volleyball", None), "Toy_B0D4E5F6G7_TruckRed": ("toy", "red")}
    for folder, (noun, colour) in expected.items():
        caps = by_folder[folder]["captions"]
        assert caps is not None and by_folder[folder]["status"] == "active"
        short = caps["short"].split()
        assert short[-1] == noun, caps  # the noun last; no id, no plural folder word ("markers")
        assert set(short[:-1]) & COLOUR_WORDS, caps  # a measured colour in front
        if colour:
            assert colour in short, caps
    # "Peach" is a variant word of the folder name, not measured: the colour comes from the albedo
    assert "peach" not in by_folder["Markers_B07Z5P84J2_Peach"]["captions"]["short"]


def test_recolours_are_named_by_measured_albedo(named):
    by_folder = {Path(r["model_path"]).parent.name: r for r in named["records"]}
    truth = named["truth"]
    blue = by_folder[truth["ketchup_bottle_blue"]["folder"]]
    red = by_folder[truth["ketchup_bottle"]["folder"]]
    assert blue["captions"]["short"] == "blue ketchup bottle"
    assert red["captions"]["short"] == "red ketchup bottle"
    soup_red = by_folder[truth["alphabet_soup_red"]["folder"]]["captions"]["short"]
    assert soup_red.startswith("red") and has_noun(soup_red, "can") and "recolour" not in soup_red


def test_real_filter_keeps_colour_variants_active_with_captions_differing_at_every_tier(named):
    """The curation's `catalog filter` records recolours as colour_variant pairs (both active); their
    captions must differ at every tier and the caption check has nothing to say about them."""
    by_folder = {Path(r["model_path"]).parent.name: r for r in named["records"]}
    truth = named["truth"]
    for slug in ("ketchup_bottle_blue", "alphabet_soup_red"):
        a = by_folder[truth[slug]["folder"]]
        b = by_folder[truth[truth[slug]["recolour_of"]]["folder"]]
        assert a["status"] == b["status"] == "active"
        assert any(f["kind"] == "colour_variant" and f["pair"] == b["id"] for f in a["flags"]), a["flags"]
        for tier in ("short", "concise", "detailed"):
            assert a["captions"][tier].lower() != b["captions"][tier].lower(), (tier, a["captions"], b["captions"])
        assert not any(w["kind"] == "same_as_variant" for w in a["caption_warnings"])


def test_caption_check_reports_a_caption_equal_to_its_variants(named, tmp_path):
    """Two variant members given the same short caption (as an LLM might): the check names the tier."""
    db = tmp_path / "copy.db"
    db.write_bytes(named["db"].read_bytes())
    catalog = open_catalog(f"sqlite:///{db}", data_dir=str(tmp_path / "data"))
    try:
        with catalog.session() as s:
            objs = s.scalars(select(CatalogObject).where(CatalogObject.status == "active")
                             .order_by(CatalogObject.id)).all()
            a, b = objs[0], objs[1]
            s.add_all([Flag(object_id=a.id, kind="colour_variant", score=1.0, reason="test", pair_object_id=b.id),
                       Flag(object_id=b.id, kind="colour_variant", score=1.0, reason="test", pair_object_id=a.id)])
            cs_b = s.scalars(select(CaptionSet).where(CaptionSet.object_id == b.id,
                                                      CaptionSet.active.is_(True))).one()
            cs_a = s.scalars(select(CaptionSet).where(CaptionSet.object_id == a.id,
                                                      CaptionSet.active.is_(True))).one()
            cs_b.short = cs_a.short
            s.commit()
            found = check_catalog(s)
        assert {"kind": "same_as_variant", "tier": "short", "detail": f"same as colour variant {b.id}"} in found[a.id]
        assert not any(w["tier"] != "short" for w in found[a.id] if w["kind"] == "same_as_variant")
    finally:
        catalog.close()


@pytest.mark.parametrize("tiers,kinds", [
    ({"short": "red fire hydrant sport", "concise": "Red fire hydrant with two side nozzles",
      "detailed": "A red fire hydrant with nozzles. It measures 30 cm across."}, {"category_appended"}),
    ({"short": "large red red hydrant", "concise": "Red fire hydrant with two side nozzles",
      "detailed": "A red fire hydrant. It measures 30 cm by 12.5 cm, 70 % red."}, {"size_word", "repeated_word"}),
    ({"short": "red sport", "concise": "Red hydrant B07Z5P84J2 with high-res nozzles",
      "detailed": "A red hydrant."}, {"missing_noun", "category_appended", "id_fragment", "word_bounds"}),
    ({"short": "red fire hydrant", "concise": "Red fire hydrant with two side nozzles",
      "detailed": "A red fire hydrant with two nozzles. It measures about 30 cm by 12.5 cm across, 64 % red."},
     set()),
])
def test_caption_check_kinds(tiers, kinds):
    found = {w["kind"] for w in check_tiers_text(tiers, name="Fire hydrant (PartNet-Mobility 12)", category="sports",
                                                   captioner="stub")}
    assert found == kinds
