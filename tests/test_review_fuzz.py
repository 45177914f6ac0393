"""Property-based tests of the decisions-file reader (`catalog review import`), with hypothesis: any file
(arbitrary bytes, arbitrary JSON, files shaped like decisions files with every field of any type or
value) is imported or refused with one CatalogError line, never another exception, and a refused file
changes nothing; valid files give the statuses a plain reading of the rule gives. Bounded: a fixed
number of examples each, no deadline, no example database written."""

from __future__ import annotations

import json
import re
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from sqlalchemy import delete, func, insert, select, update

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CatalogObject, ReviewDecision
from mixcount.curation.review.decisions_file import FORMAT
from mixcount.curation.review.import_decisions import import_decisions
from mixcount.errors import CatalogError

N = 6  # objects o1..o6 in the catalog
BOUNDED = settings(deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def fuzz_catalog(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    folder = tmp_path_factory.mktemp("review_fuzz")
    catalog = open_catalog(f"sqlite:///{folder / 'catalog.db'}", data_dir=str(folder))
    with catalog.session() as s:
        s.execute(insert(CatalogObject), [{"id": i, "source": "folder", "source_id": f"/l/o{i}.glb", "name": f"o{i}",
                                           "category": "mug", "model_path": f"/l/o{i}.glb", "status": "active"}
                                          for i in range(1, N + 1)])
        s.commit()
    yield catalog, folder
    catalog.close()


def state(catalog) -> tuple:  # type: ignore[no-untyped-def]
    with catalog.session() as s:
        n = s.scalar(select(func.count()).select_from(ReviewDecision))
        objs = tuple(s.execute(select(CatalogObject.id, CatalogObject.status, CatalogObject.container)
                               .order_by(CatalogObject.id)).all())
    return n, objs


def reset(catalog) -> None:  # type: ignore[no-untyped-def]
    with catalog.session() as s:
        s.execute(delete(ReviewDecision))
        s.execute(update(CatalogObject).values(status="active", container=False))
        s.commit()


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-2**80, max_value=2**80) | st.floats(allow_nan=False)
    | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=8)
times = st.one_of(
    st.datetimes(min_value=datetime(1, 1, 2), max_value=datetime(9999, 12, 30),
                 timezones=st.sampled_from([timezone.utc, timezone(timedelta(hours=14)),
                                            timezone(timedelta(hours=-12))])).map(lambda d: d.isoformat()),
    st.sampled_from(["9999-12-31T23:59:59Z", "9999-12-31T23:59:59-05:00", "0001-01-01T00:00:00+01:00",
                     "2026-11-23T10:00:00.000Z", "", "yesterday", "2026-13-01T00:00:00Z"]),
    json_values)
past = st.integers(min_value=0, max_value=10**6).map(
    lambda m: (datetime(2025, 1, 1) + timedelta(minutes=m)).isoformat(timespec="milliseconds") + "Z")


def mostly(good: st.SearchStrategy, bad: st.SearchStrategy) -> st.SearchStrategy:
    """``good`` about seven times in eight: files mostly shaped right, so the checks past the first are
    reached and some files pass whole (the bulk apply runs too)."""
    return st.sampled_from([True] * 7 + [False]).flatmap(lambda ok: good if ok else bad)


bad_ids = st.one_of(st.integers(min_value=-2**90, max_value=2**90), st.sampled_from([0, 2**63 - 1, 2**63, 10**30, True]),
                    json_values)
ids = mostly(st.integers(min_value=1, max_value=N + 1), bad_ids)
names = st.one_of(st.sampled_from([f"o{i}" for i in range(1, N + 1)]), st.text(max_size=10), json_values)
optional = {"name": names, "container": mostly(st.booleans(), json_values),
            "note": mostly(st.text(max_size=20), json_values), "decided_at": mostly(past, times)}
entries = mostly(
    st.fixed_dictionaries({"id": ids, "decision": mostly(st.sampled_from(["accept", "reject"]), json_values)},
                          optional=optional),
    st.one_of(st.fixed_dictionaries({}, optional={"id": ids, **optional}), json_values))
pairs = st.fixed_dictionaries(
    {"a": ids, "b": ids, "decision": mostly(st.sampled_from(["same", "variants", "different"]), json_values)},
    optional={"a_name": names, "b_name": names, "note": st.text(max_size=5), "decided_at": mostly(past, times)})
documents = st.fixed_dictionaries(
    {"format": mostly(st.just(FORMAT), json_values),
     "decisions": mostly(st.lists(entries, max_size=4), json_values)},
    optional={"pairs": mostly(st.lists(mostly(pairs, json_values), max_size=3), json_values),
              "reviewer": st.one_of(st.text(max_size=10), json_values), "exported_at": mostly(past, times),
              "catalog": st.one_of(st.text(max_size=20), json_values)})


def check_import(catalog, path: Path) -> str:  # type: ignore[no-untyped-def]
    """Import ``path``: "ok", or "refused: <what>" with the catalog unchanged and a one-line message."""
    before = state(catalog)
    try:
        import_decisions(catalog, path, other_catalog=True)  # the catalog check is tested on its own
    except CatalogError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 3000, str(exc)[:300]
        assert state(catalog) == before
        what = str(exc).split("nothing applied: ")[-1].split(" (line")[0].split(":")[0]
        return "refused: " + re.sub(r"\d+", "N", what)[:40] if "nothing applied" in str(exc) else "refused: file"
    return "ok"


@settings(BOUNDED, max_examples=250)
@given(doc=documents, indent=st.sampled_from([None, 1, 2]))
def test_any_decisions_shaped_file_is_imported_or_refused_in_one_line(fuzz_catalog, doc, indent) -> None:  # type: ignore[no-untyped-def]
    catalog, folder = fuzz_catalog
    path = folder / "doc.json"
    path.write_text(json.dumps(doc, indent=indent), encoding="utf-8")
    event(f"file {check_import(catalog, path)}")


@settings(BOUNDED, max_examples=150)
@given(data=st.one_of(st.binary(max_size=200), st.text(max_size=200).map(str.encode),
                      json_values.map(lambda v: json.dumps(v).encode())))
def test_any_bytes_are_refused_in_one_line(fuzz_catalog, data: bytes) -> None:  # type: ignore[no-untyped-def]
    catalog, folder = fuzz_catalog
    path = folder / "raw.json"
    path.write_bytes(data)
    assert check_import(catalog, path).startswith("refused")


valid_entries = st.lists(st.fixed_dictionaries(
    {"id": st.integers(min_value=1, max_value=N), "decision": st.sampled_from(["accept", "reject"]),
     "decided_at": st.integers(min_value=0, max_value=20).map(
         lambda m: (datetime(2026, 11, 1) + timedelta(minutes=m)).isoformat() + "Z")},
    optional={"container": st.booleans()}), min_size=1, max_size=25)


@settings(BOUNDED, max_examples=120)
@given(first=valid_entries, second=valid_entries)
def test_valid_files_give_the_latest_decision_per_object(fuzz_catalog, first, second) -> None:  # type: ignore[no-untyped-def]
    catalog, folder = fuzz_catalog
    reset(catalog)
    for k, batch in enumerate((first, second)):
        doc = {"format": FORMAT, "reviewer": "fuzz", "exported_at": "2026-11-02T00:00:00Z", "decisions": batch}
        (folder / f"v{k}.json").write_text(json.dumps(doc), encoding="utf-8")
        import_decisions(catalog, folder / f"v{k}.json")
    latest: dict[int, tuple] = {}
    boxes: dict[int, tuple] = {}
    recorded: set[tuple] = set()
    order = 0
    for e in first + second:  # rows in insertion order; a row already recorded is not added again
        for kind in [e["decision"]] + (["container" if e["container"] else "not_container"] if "container" in e else []):
            key = (e["id"], kind, e["decided_at"])
            if key in recorded:
                continue
            recorded.add(key)
            order += 1
            table = boxes if "container" in kind else latest
            if e["id"] not in table or (e["decided_at"], order) >= table[e["id"]][:2]:
                table[e["id"]] = (e["decided_at"], order, kind)
    _, objs = state(catalog)
    got = {oid: (status, bool(container)) for oid, status, container in objs}
    for oid in range(1, N + 1):
        want_status = {"accept": "active", "reject": "excluded"}[latest[oid][2]] if oid in latest else "active"
        want_box = boxes[oid][2] == "container" if oid in boxes else False
        assert got[oid] == (want_status, want_box), (oid, latest.get(oid), boxes.get(oid))
