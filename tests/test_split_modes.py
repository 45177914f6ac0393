"""Split modes (issue 59) on small catalogs: one category whatever the spelling, unseen categories share no
category with train, unseen objects keep every category in train, the two extra test splits, what stays
together (variants, a person's same / variants decisions, look-alikes of one kind), the mode-aware check and
the report. Real captures: tests/test_split_library.py."""

from __future__ import annotations

import json

import pytest
from sqlalchemy import select

from mixcount.catalog.models import CatalogObject, ReviewDecision, Split
from mixcount.catalog.split_classes import FscTable
from mixcount.catalog.split_units import category_key
from mixcount.catalog.splits import assign_splits, check_splits, split_report
from mixcount.cli import main
from mixcount.config import load_config

TABLE = FscTable.load()

# (category, name): 12 kinds, most of them repeated; three spellings of mug, two of teddy bear
ROWS = [
    ("Mug", "Red mug"), ("mugs", "Blue mug"), ("coffee mug", "Tall mug"), ("cup", "Tea cup"),
    ("Teddy bear", "Teddy"), ("teddy bears", "Brown teddy"), ("bear", "Plush bear"),
    ("duck", "Rubber duck"), ("Duck", "Duck genesis"), ("ducks", "Yellow duck"),
    ("bunny", "Stanford bunny"), ("Bunny", "Bunny genesis"), ("ring", "Tower ring 1"), ("ring", "Tower ring 2"),
    ("rings", "Tower ring 3"), ("ring", "Tower ring 4"), ("wheel", "Wheel"), ("wheel", "Fancy wheel"),
    ("dragon", "Dragon"), ("dragon", "Dragon 2"), ("tray", "Tray red"), ("tray", "Tray green"),
    ("tray", "Tray blue"), ("bolt", "Bolt"), ("nut", "Nut"), ("boat", "Boat"), ("torus", "Torus"),
    ("lego", "Lego brick"), ("Legos", "Lego 2x4"), ("marker", "Red marker"), ("markers", "Blue marker"),
    ("sphere", "Sphere"), ("sphere", "Smooth sphere"), ("ball", "Soccer ball"), ("balls", "Wooden ball"),
]


def conf(**values):
    return load_config(values={f"split.{k}": v for k, v in values.items()}).split


def _library(catalog) -> dict[str, int]:
    ids = {}
    with catalog.session() as s:
        for i, (cat, name) in enumerate(ROWS):
            obj = CatalogObject(source="folder", source_id=f"{i}", name=name, category=cat, model_path=f"/x/{i}.glb")
            s.add(obj)
            s.flush()
            ids[name] = obj.id
        s.commit()
    return ids


def _pair(catalog, a: int, b: int, kind: str) -> None:
    from mixcount.catalog.models import Flag

    with catalog.session() as s:
        s.add_all([Flag(object_id=a, kind=kind, pair_object_id=b, reason="t"),
                   Flag(object_id=b, kind=kind, pair_object_id=a, reason="t")])
        s.commit()


def _decide(catalog, a: int, b: int, decision: str) -> None:
    with catalog.session() as s:
        s.add(ReviewDecision(object_id=a, pair_object_id=b, decision=decision, reviewer="ana"))
        s.commit()


@pytest.fixture
def library(catalog):
    ids = _library(catalog)
    _pair(catalog, ids["Tray red"], ids["Tray green"], "colour_variant")
    _pair(catalog, ids["Tray green"], ids["Tray blue"], "colour_variant")
    _pair(catalog, ids["Rubber duck"], ids["Duck genesis"], "possible_copy")
    _pair(catalog, ids["Sphere"], ids["Soccer ball"], "look_alike")  # other kinds: may cross in every mode
    _pair(catalog, ids["Tower ring 1"], ids["Tower ring 2"], "look_alike")
    _decide(catalog, ids["Stanford bunny"], ids["Bunny genesis"], "same")
    _decide(catalog, ids["Red marker"], ids["Tall mug"], "variants")  # a person's call binds across kinds
    return ids


def _rows(catalog) -> dict[int, Split]:
    with catalog.session() as s:
        return {r.object_id: r for r in s.scalars(select(Split))}


def _keys(catalog) -> dict[int, str]:
    with catalog.session() as s:
        return {o.id: category_key(TABLE, category=o.category, name=o.name, short=None)
                for o in s.scalars(select(CatalogObject))}


def test_one_category_whatever_the_spelling():
    key = lambda c: category_key(TABLE, category=c, name="x", short=None)  # noqa: E731
    assert key("Mug") == key("mugs") == key("coffee mug") == key("Cups") == "cup"
    assert key("Teddy bear") == key("teddy bears") == key("BEAR") == "bear"
    assert key("ToyCar") == key("toy cars") != key("bottle caps")
    assert category_key(TABLE, category="", name="Rubber duck", short=None) == "duck"
    assert category_key(TABLE, category="3763", name="", short="a red bottle") == "bottle"
    # a shelf label gives way to the captioner's noun; a generic caption noun to the category
    assert category_key(TABLE, category="toy", name="Rubber duck", short="yellow rubber duck") == "duck"
    assert category_key(TABLE, category="tool", name="Hammer", short="brown and black hammer") == "hammer"
    assert category_key(TABLE, category="misc", name="Random object 17", short="maroon object") == "misc"
    assert category_key(TABLE, category="sports", name="Soccer ball", short=None) == "ball"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_categories_mode_holds_out_whole_kinds(library, catalog, seed):
    summary = assign_splits(catalog, conf(mode="categories", seed=seed), table=TABLE)
    assert summary.leaks == []
    rows, keys = _rows(catalog), _keys(catalog)
    per_key: dict[str, set[str]] = {}
    for oid, row in rows.items():
        per_key.setdefault(keys[oid], set()).add(row.split)
    assert all(len(s) == 1 for s in per_key.values()), per_key  # every kind in one split
    splits = summary.report["splits"]
    assert {"train", "val", "test"} <= set(splits)
    assert all(splits[s]["categories_shared_with_train"] == 0 for s in splits if s != "train")
    assert summary.report["crossing"]["categories"] == []
    # FSC-147's class split is kept: markers are a test class, cups and balls train classes
    assert rows[library["Red marker"]].split == "test" and rows[library["Tall mug"]].split == "test"
    assert rows[library["Soccer ball"]].split == "train"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_objects_mode_keeps_every_category_in_train(library, catalog, seed):
    summary = assign_splits(catalog, conf(mode="objects", seed=seed, val_fraction=0.3, test_fraction=0.3),
                            table=TABLE)
    assert summary.leaks == []
    rows, keys = _rows(catalog), _keys(catalog)
    train = {keys[o] for o, r in rows.items() if r.split == "train"}
    held = {keys[o] for o, r in rows.items() if r.split != "train"}
    assert held and held <= train
    assert rows[library["Boat"]].split == "train"  # a kind of one object cannot be held out
    assert summary.totals()["val"] + summary.totals()["test"] >= 6


def test_two_extra_test_splits_at_once(library, catalog):
    summary = assign_splits(catalog, conf(mode="paper", seed=3, test_objects_fraction=0.15,
                                          test_categories_fraction=0.15), table=TABLE)
    assert summary.leaks == [], summary.leaks
    rows, keys = _rows(catalog), _keys(catalog)
    by_split: dict[str, set[str]] = {}
    for oid, row in rows.items():
        by_split.setdefault(row.split, set()).add(keys[oid])
    assert by_split["test_objects"] and by_split["test_categories"]
    assert by_split["test_objects"] <= by_split["train"]
    others = set().union(*(v for s, v in by_split.items() if s != "test_categories"))
    assert not by_split["test_categories"] & others
    # no FSC-147 train / val class reaches the unseen categories
    assert not {TABLE.classes[r.fsc_class] for r in rows.values() if r.split == "test_categories" and r.fsc_class} - {"test"}
    assert 3 <= summary.totals()["test_objects"] <= 8 and 3 <= summary.totals()["test_categories"] <= 8


@pytest.mark.parametrize("mode", ["paper", "objects", "categories"])
def test_pairs_that_must_stay_together_do(library, catalog, mode):
    for seed in range(4):
        summary = assign_splits(catalog, conf(mode=mode, seed=seed, test_objects_fraction=0.1,
                                              test_categories_fraction=0.1), table=TABLE)
        assert summary.leaks == [], (mode, seed, summary.leaks)
        rows = _rows(catalog)
        for a, b in (("Tray red", "Tray green"), ("Tray green", "Tray blue"), ("Rubber duck", "Duck genesis"),
                     ("Stanford bunny", "Bunny genesis"), ("Red marker", "Tall mug")):
            assert rows[library[a]].split == rows[library[b]].split, (mode, seed, a, b)
        cross = summary.report["crossing"]
        assert cross["variant_pairs"] == [] and cross["copy_pairs"] == []
        if mode == "categories":  # look-alikes of one kind cross only into test_objects (unseen objects, seen kinds)
            assert all(not r["same_category"] or sorted(r["splits"]) == ["test_objects", "train"]
                       for r in cross["look_alike_pairs"])


def _set(catalog, **changes) -> None:
    """Edit every stored split row: ``mode=...``, or ``split={object_id: split}``."""
    with catalog.session() as s:
        for row in s.scalars(select(Split)):
            row.mode = changes.get("mode", row.mode)
            row.split = changes.get("split", {}).get(row.object_id, row.split)
        s.commit()


def test_check_fails_only_on_what_the_mode_forbids(library, catalog):
    assign_splits(catalog, conf(mode="categories", seed=0), table=TABLE)
    assert check_splits(catalog, table=TABLE) == []
    wheel = sorted(o for o, k in _keys(catalog).items() if k == "wheel")
    home = _rows(catalog)[wheel[0]].split
    other = next(s for s in ("train", "val", "test") if s != home)
    _set(catalog, split={wheel[1]: other})  # the two wheels apart: a leak for categories, fine for paper
    assert check_splits(catalog, table=TABLE) == [
        f"category 'wheel' spans {', '.join(s for s in ('train', 'val', 'test') if s in (home, other))} "
        "(mode categories: one split per category)"]
    _set(catalog, mode="paper")
    assert check_splits(catalog, table=TABLE) == []
    with catalog.session() as s:
        s.get(Split, wheel[0]).mode = "categories"
        s.commit()
    assert any("mix modes" in x for x in check_splits(catalog, table=TABLE))
    # objects mode: a held-out kind that train does not hold
    _set(catalog, mode="objects", split={o: ("test" if o in wheel else "train") for o in _keys(catalog)})
    assert check_splits(catalog, table=TABLE) == [
        "category 'wheel' is in test but not in train (mode objects: unseen objects of trained categories)"]
    _set(catalog, split={library["Tray red"]: "val"})  # a variant pair apart: a leak in every mode
    assert any("duplicate group" in x for x in check_splits(catalog, table=TABLE))


def test_cli_modes_report_and_errors(library, catalog, db_url, capsys):
    db = db_url
    assert main(["--db", db, "catalog", "split", "--mode", "categories", "--test-unseen-objects", "0.1",
                 "--test-unseen-categories", "0.1", "--report"]) == 0
    text = capsys.readouterr().out
    assert "mode categories" in text and "split report" in text and "test_categories categories:" in text
    assert main(["--db", db, "catalog", "split", "--check", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out.splitlines()[0])
    assert doc["leaks"] == [] and doc["report"]["mode"] == "categories"
    assert set(doc["report"]["splits"]) == {"train", "val", "test", "test_objects", "test_categories"}
    assert doc["report"] == split_report(catalog, table=TABLE)
    assert main(["--db", db, "catalog", "split", "--mode", "kinds"]) == 2
    err = capsys.readouterr().err
    assert "split.mode must be one of paper, objects, categories" in err and "Traceback" not in err
    assert main(["--db", db, "catalog", "split", "--test-unseen-categories", "1.2"]) == 2


def test_every_split_name_is_composable_and_bad_ones_say_which_are():
    from mixcount.config import SPLIT_NAMES
    from mixcount.errors import ConfigError

    for name in SPLIT_NAMES:
        assert load_config(values={"compose.split": name}).compose.split == name
    with pytest.raises(ConfigError, match="test_objects, test_categories"):
        load_config(values={"compose.split": "test_kinds"})
