"""Object splits: FSC-147 matches follow the shipped table, the random part is reproducible from its seed,
duplicate groups never span two splits, and `catalog split` fails on a leak."""

from __future__ import annotations

import json

import pytest
from sqlalchemy import select

from mixcount.catalog.models import CaptionSet, CatalogObject, Flag, Split
from mixcount.catalog.split_classes import FscTable, normalise, singular
from mixcount.catalog.splits import assign_splits, check_splits
from mixcount.cli import main
from mixcount.config import load_config

TABLE = FscTable.load()


def split_conf(seed: int):
    """default.toml's ``[split]`` section (70/15/15, FSC-147 on) with ``seed``."""
    return load_config(values={"split.seed": seed}).split

def _add(catalog, rows: list[tuple[str, str, str | None]]) -> list[int]:
    """Objects (category, name, short caption or None); returns their ids in order."""
    ids = []
    with catalog.session() as s:
        for i, (cat, name, short) in enumerate(rows):
            obj = CatalogObject(source="folder", source_id=f"{i}-{name}", name=name, category=cat,
                                model_path=f"/nowhere/{i}.glb")
            s.add(obj)
            s.flush()
            if short:
                s.add(CaptionSet(object_id=obj.id, captioner="stub", provider="offline", model="stub",
                                 prompt_version="t", short=short, concise=short + " c", detailed=short + " d.",
                                 response_hash="0" * 64, active=True))
            ids.append(obj.id)
        s.commit()
    return ids


def _flag(catalog, a: int, b: int, kind: str) -> None:
    with catalog.session() as s:
        s.add(Flag(object_id=a, kind=kind, pair_object_id=b, reason="test"))
        s.add(Flag(object_id=b, kind=kind, pair_object_id=a, reason="test"))
        s.commit()


def _splits(catalog) -> dict[int, Split]:
    with catalog.session() as s:
        return {r.object_id: r for r in s.scalars(select(Split))}


def test_table_is_complete_and_every_class_matches_itself():
    assert len(TABLE.classes) == 147
    counts = {s: sum(1 for v in TABLE.classes.values() if v == s) for s in ("train", "val", "test")}
    assert counts == {"train": 89, "val": 29, "test": 29}
    for name in TABLE.classes:
        assert TABLE.match(category=name, name="", short=None)[0] == name


@pytest.mark.parametrize(
    "category,name,short,expected",
    [
        ("ball", "Ball_B07X_Volleyball", None, "balls"),  # category, plural-insensitive
        ("toy", "Toy_B01_SoccerBall", None, "balls"),  # name, camel case split
        ("sports", "Sports_B02_Football", None, "balls"),  # synonym
        ("marker", "", None, "markers"),
        ("mug", "", None, "cups"),  # synonym
        ("fruit", "Fruit_A1_Strawberries", None, "strawberries"),
        ("toy", "Toy_B03_Figure", "red skateboard", "skateboard"),  # short caption
        ("object", "Misc_B04_BottleCaps", None, "bottle caps"),  # longest class wins over "caps"
        ("toy", "Toy_B05_OrangeCar", "orange toy car", "cars"),  # head noun decides, not the colour
        ("figure", "Figure_B06_Dinosaur", "grey dinosaur figure", None),
        ("tray", "", None, None),  # "cupcake tray" / "donuts tray" need their first word
    ],
)
def test_matching_rules(category, name, short, expected):
    assert TABLE.match(category=category, name=name, short=short)[0] == expected


def test_normalisation():
    assert singular("strawberries") == "strawberry" and singular("geese") == "goose"
    assert singular("glass") == "glass" and singular("tomatoes") == "tomato"
    assert normalise("CashewNuts") == ["cashew", "nut"]
    assert normalise("Ball_B07XYZ_v2") == ["ball"]


def test_matched_objects_take_the_table_split_and_assignment_is_reproducible(catalog):
    matched = [("ball", "B", None), ("marker", "M", None), ("bottle cap", "C", None), ("apple", "A", None),
               ("mug", "U", None), ("sea shell", "S", None)]
    ids = _add(catalog, matched + [("widget", f"Widget_{i}", None) for i in range(60)])
    conf = split_conf(5)
    summary = assign_splits(catalog, conf, table=TABLE)
    assert summary.leaks == []
    first = {k: (v.split, v.method, v.fsc_class) for k, v in _splits(catalog).items()}
    assert len(first) == len(ids)
    for oid, (cat, _, _) in zip(ids, matched):
        split, method, fsc = first[oid]
        assert method == "fsc147" and fsc is not None and split == TABLE.classes[fsc], (cat, first[oid])
    assert [first[i][0] for i in ids[:6]] == ["train", "test", "val", "test", "train", "test"]
    assert all(first[i][1] == "random" for i in ids[6:])
    totals = summary.totals()
    for split, frac in zip(("train", "val", "test"), conf.fractions):
        assert abs(totals[split] - frac * len(ids)) <= 3, totals

    assign_splits(catalog, conf, table=TABLE)
    again = {k: (v.split, v.method, v.fsc_class) for k, v in _splits(catalog).items()}
    assert again == first
    assign_splits(catalog, split_conf(6), table=TABLE)
    other = {k: v.split for k, v in _splits(catalog).items()}
    assert other != {k: v[0] for k, v in first.items()}
    assert all(other[i] == first[i][0] for i in ids[:6])  # matched ones never move


def test_duplicate_groups_never_span_splits(catalog, db_url, capsys):
    ids = _add(catalog, [("ball", "Ball", None), ("widget", "W1", None), ("marker", "Marker", None),
                         ("ball", "Ball2", None), ("widget", "W2", None), ("widget", "W3", None)]
               + [("widget", f"Filler_{i}", None) for i in range(20)])
    ball, w1, marker, ball2, w2, w3 = ids[:6]
    _flag(catalog, ball, w1, "exact_duplicate")  # unmatched copy of a train-class object -> train
    _flag(catalog, marker, ball2, "near_duplicate_geometry")  # test class + train class -> test wins
    _flag(catalog, w2, w3, "caption_collision")  # unmatched pair -> one random split
    summary = assign_splits(catalog, split_conf(1), table=TABLE)
    sp = _splits(catalog)
    assert sp[ball].split == sp[w1].split == "train" and sp[w1].method == "group"
    assert sp[marker].split == sp[ball2].split == "test" and sp[ball2].method == "group"
    assert sp[w2].split == sp[w3].split
    assert len(summary.conflicts) == 1 and summary.leaks == []

    db = db_url.removeprefix("sqlite:///")
    assert main(["--db", db, "catalog", "split", "--check"]) == 0
    capsys.readouterr()
    with catalog.session() as s:  # tamper: move one copy to another split
        row = s.get(Split, w1)
        row.split = "val"
        s.commit()
    leaks = check_splits(catalog, table=TABLE)
    assert any("spans splits" in leak for leak in leaks)
    assert main(["--db", db, "catalog", "split", "--check", "--json"]) != 0
    assert json.loads(capsys.readouterr().out)["leaks"] == leaks

    with catalog.session() as s:  # a test-class object in train is a leak too
        s.get(Split, w1).split = "train"
        s.get(Split, marker).split = "train"
        s.get(Split, ball2).split = "train"
        s.commit()
    assert any("matches FSC-147 test class" in leak for leak in check_splits(catalog, table=TABLE))

    # a fresh `catalog split` repairs it, prints the table and exits 0
    assert main(["--db", db, "catalog", "split", "--seed", "1"]) == 0
    captured = capsys.readouterr()
    assert "object splits" in captured.out and "no leaks" in captured.out  # the result: on stdout
    assert main(["--db", db, "catalog", "split", "--seed", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["leaks"] == []


def test_excluded_and_broken_objects_get_no_split(catalog):
    ids = _add(catalog, [("ball", "B", None), ("widget", "W", None), ("widget", "X", None)])
    with catalog.session() as s:
        s.get(CatalogObject, ids[1]).status = "excluded"
        s.get(CatalogObject, ids[2]).status = "broken"
        s.commit()
    assign_splits(catalog, split_conf(0), table=TABLE)
    assert set(_splits(catalog)) == {ids[0]}


def test_split_object_ids(catalog):
    from mixcount.catalog.splits import split_object_ids
    from mixcount.errors import CatalogError

    ids = _add(catalog, [("ball", "B", None), ("marker", "M", None)])
    assign_splits(catalog, split_conf(0), table=TABLE)
    with catalog.session() as s:
        assert split_object_ids(s, "train") == [ids[0]] and split_object_ids(s, "test") == [ids[1]]
        with pytest.raises(CatalogError):
            split_object_ids(s, "dev")


def test_objects_linked_only_through_an_excluded_duplicate_share_a_split(catalog):
    # A and B are each a near-copy of X; X was excluded by curation. A and B must still be one group.
    a, b, x = _add(catalog, [("widget", "Widget_A", None), ("widget", "Widget_B", None), ("widget", "Widget_X", None)])
    with catalog.session() as s:
        s.get(CatalogObject, x).status = "excluded"
        s.commit()
    _flag(catalog, a, x, "exact_duplicate")
    _flag(catalog, b, x, "near_duplicate_geometry")
    from mixcount.catalog.splits import duplicate_groups

    with catalog.session() as s:
        assert duplicate_groups(s, [a, b]) == [[a, b]]
    for seed in range(6):
        assign_splits(catalog, split_conf(seed), table=TABLE)
        rows = _splits(catalog)
        assert rows[a].split == rows[b].split
