"""`catalog review import`, strict and in bulk: times in the future refused with the line that holds them,
the file's ``catalog`` field checked (``--other-catalog`` to say a file is meant), absurd input (an id of
10**30, JSON nested 100,000 deep, a file over the size limit) one line and exit 2, and the bulk import
giving the statuses a plain reading of the rules gives (the IN-list and the table-scan paths both)."""

from __future__ import annotations

import json
import os
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from sqlalchemy import func, insert, select

import mixcount.catalog.decisions as decisions_mod
import mixcount.curation.review.import_decisions as review_mod
from mixcount.catalog.models import CatalogObject, ReviewDecision
from mixcount.cli import main
from mixcount.curation.review.decisions_file import FORMAT, MAX_FILE_MB, same_catalog
from mixcount.curation.review.import_decisions import import_decisions
from mixcount.errors import CatalogError

N_OBJECTS = 40


def add_objects(catalog, n: int = N_OBJECTS) -> None:  # type: ignore[no-untyped-def]
    rows = [{"id": i, "source": "folder", "source_id": f"/lib/o{i}.glb", "name": f"o{i}", "category": "mug",
             "model_path": f"/lib/o{i}.glb", "status": "active"} for i in range(1, n + 1)]
    with catalog.session() as s:
        s.execute(insert(CatalogObject), rows)
        s.commit()


@pytest.fixture
def cat(catalog):  # type: ignore[no-untyped-def]
    add_objects(catalog)
    return catalog


def write(path: Path, decisions: list, *, catalog: str | None = None, indent: int | None = 2, **extra) -> Path:  # type: ignore[no-untyped-def]
    doc = {"format": FORMAT, "reviewer": "ana", "exported_at": "2026-11-23T10:00:00.000Z", **extra,
           "decisions": decisions}
    if catalog is not None:
        doc["catalog"] = catalog
    path.write_text(json.dumps(doc, indent=indent) + "\n", encoding="utf-8")
    return path


def rows(catalog) -> int:  # type: ignore[no-untyped-def]
    with catalog.session() as s:
        return int(s.scalar(select(func.count()).select_from(ReviewDecision)))


def line_of(path: Path, needle: str) -> int:
    text = path.read_text()
    return text.count("\n", 0, text.index(needle)) + 1


def iso(dt: datetime) -> str:
    return dt.isoformat(timespec="milliseconds") + "Z"


FUTURE = {  # how a time can lie in the future
    "the issue's": "9999-12-31T23:59:59Z",
    "next year": iso(datetime.now(timezone.utc).replace(tzinfo=None) + timedelta(days=365)),
    "an hour ahead": iso(datetime.now(timezone.utc).replace(tzinfo=None) + timedelta(hours=1)),
    "local time ahead of UTC, said as such": (datetime.now(timezone.utc) + timedelta(hours=2)).astimezone(
        timezone(timedelta(hours=-3))).isoformat(),
}


@pytest.mark.parametrize("when", sorted(FUTURE))
def test_a_decision_dated_in_the_future_is_refused_with_its_line(cat, tmp_path: Path, when: str) -> None:  # type: ignore[no-untyped-def]
    path = write(tmp_path / "d.json", [{"id": 1, "name": "o1", "decision": "accept", "decided_at": "2026-11-23T09:00:00Z"},
                                       {"id": 2, "name": "o2", "decision": "reject", "decided_at": FUTURE[when]}])
    with pytest.raises(CatalogError) as err:
        import_decisions(cat, path)
    message = str(err.value)
    assert f"entry 1 (line {line_of(path, FUTURE[when])}): time" in message and "in the future" in message
    assert "nothing applied" in message and "\n" not in message and rows(cat) == 0


def test_a_pinned_object_stays_decidable_and_a_clock_a_little_ahead_passes(cat, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    soon = iso(datetime.now(timezone.utc).replace(tzinfo=None) + timedelta(minutes=3))  # a fast clock
    import_decisions(cat, write(tmp_path / "a.json", [{"id": 3, "decision": "reject", "decided_at": soon}]))
    later = datetime.now(timezone.utc).replace(tzinfo=None) + timedelta(minutes=5)
    summary = import_decisions(cat, write(tmp_path / "b.json", [{"id": 3, "decision": "accept", "decided_at": iso(later)}]))
    assert [c["to"] for c in summary.status_changes] == ["active"]


def test_a_future_export_time_and_a_pair_in_the_future_are_refused(cat, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(CatalogError, match="exported_at: time '9999-01-01T00:00:00Z' is in the future"):
        import_decisions(cat, write(tmp_path / "e.json", [{"id": 1, "decision": "accept"}], exported_at="9999-01-01T00:00:00Z"))
    pairs = [{"a": 1, "b": 2, "decision": "same", "decided_at": "9999-12-31T23:59:59Z"}]
    path = write(tmp_path / "p.json", [], pairs=pairs)
    with pytest.raises(CatalogError, match=rf"pair 0 \(line {line_of(path, '9999')}\): time .* in the future"):
        import_decisions(cat, path)
    assert rows(cat) == 0


def test_the_catalog_field_is_checked(cat, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    entry = [{"id": 4, "name": "o4", "decision": "reject"}]
    other = write(tmp_path / "o.json", entry, catalog=f"sqlite:///{tmp_path / 'elsewhere' / 'catalog.db'}")
    with pytest.raises(CatalogError, match="was exported from catalog .*elsewhere.*, not this one .*--other-catalog"):
        import_decisions(cat, other)
    with pytest.raises(CatalogError, match="is not a catalog URL"):
        import_decisions(cat, write(tmp_path / "n.json", entry, catalog=7))  # type: ignore[arg-type]
    assert rows(cat) == 0
    assert import_decisions(cat, other, other_catalog=True).recorded == 1  # the user says it is meant
    here = cat.url
    db = Path(here.split("///", 1)[1])
    os.symlink(db.parent, tmp_path / "alias")
    for named in (here, f"sqlite:///{tmp_path / 'alias' / db.name}", f"sqlite:///{db.parent.name}/{db.name}", None, ""):
        assert import_decisions(cat, write(tmp_path / "s.json", entry, catalog=named)).decisions == 1, named
    assert not same_catalog("postgresql://u:p@host/db", here) and not same_catalog("not a url at all", here)


def test_cli_refuses_another_catalog_in_one_line_and_takes_the_flag(cat, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    path = write(tmp_path / "o.json", [{"id": 5, "decision": "reject"}], catalog="sqlite:////somewhere/else.db")
    db = ["--db", cat.url.split("///", 1)[1], "catalog", "review", "import", str(path)]
    assert main(db) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and "--other-catalog" in err
    assert main([*db, "--other-catalog", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["status_changes"][0]["to"] == "excluded"


ABSURD = {  # (file text, what the one line says)
    "an id of 10**30": ('{"format": "%s", "decisions": [{"id": %d, "decision": "accept"}]}' % (FORMAT, 10**30),
                        "entry 0 (line 1): id 1000000000000000000000000000000 is out of range"),
    "an id of 0": ('{"format": "%s", "decisions": [{"id": 0, "decision": "accept"}]}' % FORMAT, "id 0 is out of range"),
    "a pair id of -2**70": ('{"format": "%s", "decisions": [], "pairs": [{"a": 1, "b": %d, "decision": "same"}]}'
                            % (FORMAT, -2**70), "are not two object ids"),
    "an id of 5000 digits": ('{"format": "%s", "decisions": [{"id": 1%s}]}' % (FORMAT, "0" * 5000),
                             "cannot read decisions file"),
    "JSON nested 100,000 deep": ('{"format": "%s", "decisions": %s1%s}' % (FORMAT, "[" * 100000, "]" * 100000),
                                 "nested too deeply"),
    "a time past year 9999": ('{"format": "%s", "decisions": [{"id": 1, "decision": "accept", '
                              '"decided_at": "9999-12-31T23:59:59-05:00"}]}' % FORMAT, "is not an ISO-8601 time"),
    "bytes that are not UTF-8": (b'{"format": "\xff"}', "cannot read decisions file"),
}


@pytest.mark.parametrize("kind", sorted(ABSURD))
def test_absurd_files_are_one_line_exit_2(cat, tmp_path: Path, capsys, kind: str) -> None:  # type: ignore[no-untyped-def]
    text, says = ABSURD[kind]
    path = tmp_path / "absurd.json"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    assert main(["--db", cat.url.split("///", 1)[1], "catalog", "review", "import", str(path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and says in " ".join(err.split()), err[-500:]
    assert rows(cat) == 0


def test_a_file_over_the_limit_is_refused_before_it_is_read(cat, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "huge.json"
    with path.open("wb") as f:  # sparse: no disk used, and never read
        f.truncate((MAX_FILE_MB + 1) * 2**20)
    with pytest.raises(CatalogError, match=f"more than the {MAX_FILE_MB} MB"):
        import_decisions(cat, path)


def planned_keys(entries: list[dict]) -> list[tuple]:
    """What makes a recorded row the same: object, decision (or container setting) and time."""
    keys = [(e["id"], e["decision"], e["decided_at"]) for e in entries]
    keys += [(e["id"], "container" if e["container"] else "not_container", e["decided_at"]) for e in entries
             if "container" in e]
    return keys


def expected_statuses(entries: list[dict]) -> dict[int, str]:
    """The rule read plainly: per object, the latest accept/reject by time, then by file order."""
    latest: dict[int, tuple[str, int, str]] = {}
    for k, e in enumerate(entries):
        if "decision" in e:
            key = (e["decided_at"], k)
            if e["id"] not in latest or key >= latest[e["id"]][:2]:
                latest[e["id"]] = (e["decided_at"], k, e["decision"])
    return {oid: "active" if v[2] == "accept" else "excluded" for oid, v in latest.items()}


@pytest.mark.parametrize("scan_above", [decisions_mod.SCAN_ABOVE, 3], ids=["in-lists", "table-scan"])
def test_bulk_import_gives_the_plain_rule(catalog, tmp_path: Path, monkeypatch, scan_above: int) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setattr(decisions_mod, "SCAN_ABOVE", scan_above)
    monkeypatch.setattr(review_mod, "SCAN_ABOVE", scan_above)
    monkeypatch.setattr(decisions_mod, "IN_CHUNK", 7)  # many chunks, an object's rows never split
    add_objects(catalog, 300)
    base = datetime(2026, 11, 1)
    entries = []
    for k in range(1500):  # several decisions per object, out of time order, some identical twice
        oid = 1 + (k * 37) % 300
        when = iso(base + timedelta(minutes=(k * 7919) % 1000))
        entry = {"id": oid, "name": f"o{oid}", "decision": "accept" if (k * 13) % 3 else "reject", "decided_at": when}
        if k % 11 == 0:
            entry["container"] = bool(k % 2)
        entries.append(entry)
        if k % 97 == 0:
            entries.append(dict(entry))
    first = import_decisions(catalog, write(tmp_path / "a.json", entries[:900], indent=None))
    second = import_decisions(catalog, write(tmp_path / "b.json", entries[600:], indent=None))
    keys_a, keys_b = planned_keys(entries[:900]), planned_keys(entries[600:])
    assert (first.recorded, first.already_recorded) == (len(set(keys_a)), len(keys_a) - len(set(keys_a)))
    assert second.recorded == len(set(keys_b) - set(keys_a)) and second.already_recorded > 300
    with catalog.session() as s:
        got = dict(s.execute(select(CatalogObject.id, CatalogObject.status)).all())
        containers = dict(s.execute(select(CatalogObject.id, CatalogObject.container)).all())
    want = expected_statuses(entries)
    assert {oid: got[oid] for oid in want} == want and len(want) == 300
    last_container: dict[int, tuple[str, int, bool]] = {}
    for k, e in enumerate(entries):
        if "container" in e and (e["id"] not in last_container or (e["decided_at"], k) >= last_container[e["id"]][:2]):
            last_container[e["id"]] = (e["decided_at"], k, e["container"])
    assert {oid: containers[oid] for oid in last_container} == {oid: v[2] for oid, v in last_container.items()}
