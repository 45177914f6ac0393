"""`catalog review import FILE`: apply a person's accept/reject decisions exported from the HTML sheet.

File format (``mixcount-review-v1``, written by the sheet's export button)::

    {"format": "mixcount-review-v1", "reviewer": "ana", "exported_at": "2026-11-23T14:00:00.000Z",
     "decisions": [{"id": 12, "name": "Mug_B0CR7ZL940_Mint", "decision": "reject",
                    "note": "same mug", "decided_at": "2026-11-23T13:59:41.120Z"},
                   {"id": 31, "name": "Serving_Board_03", "container": true,
                    "decided_at": "2026-11-23T13:59:50.000Z"}]}

An entry carries a ``decision`` (accept / reject), a ``container`` (true / false), or both. A file may
also hold ``pairs``, the review page's pair decisions::

     "pairs": [{"a": 12, "b": 31, "a_name": "Mug_B0CR7ZL940_Mint", "b_name": "mug_mint_scan",
                "decision": "same", "note": "", "decided_at": "2026-11-23T14:00:02.000Z"}]

``same`` (one object: the pair joins a duplicate group, the filter keeps the better one and excludes
the other), ``variants`` (keep both: one object in two versions, both stay active) or ``different``
(two objects: the filter's pairing of them excludes neither). A pair decision is stored as a
``review_decisions`` row of object ``a`` with ``pair_object_id`` ``b``, applied at once (statuses, and
the pair's flags marked as decided, which makes them *info*) and again by every ``catalog filter``.

The whole file is checked before anything is written (unknown ids, a name that does not match the id, unknown
decisions, a container that is not true/false are errors: a file from another catalog is refused).
Each decision becomes a ``review_decisions`` row (reviewer, time, note; a container setting is stored as
decision ``container`` / ``not_container``) and applies at once: accept -> active, reject -> excluded (a
broken object stays broken); container sets ``objects.container`` with the review as its reason. The
latest accept/reject per object outranks automatic flags and is re-applied by every ``catalog filter``;
the latest container decision outranks the container rules
(:mod:`mixcount.catalog.containers`). Importing the same file again adds nothing.
"""

from __future__ import annotations

import getpass
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any, Iterable, Iterator, cast

from sqlalchemy import Table, bindparam, insert, select, update
from sqlalchemy.orm import Session

from mixcount.catalog.db import Catalog
from mixcount.catalog.decisions import (
    CONTAINER_DECISIONS,
    PAIR_DECISIONS,
    SCAN_ABOVE,
    STATUS_DECISIONS,
    chunks,
    latest_by_object,
)
from mixcount.catalog.models import STATUS_ACTIVE, STATUS_BROKEN, STATUS_EXCLUDED, CatalogObject, ReviewDecision, utcnow
from mixcount.curation.review.decisions_file import (
    check_catalog,
    entry_lines,
    is_id,
    load_decisions,
    parse_time,
    short,
    where,
)
from mixcount.errors import CatalogError

__all__ = ["ReviewSummary", "import_decisions"]

OBJECTS = cast(Table, CatalogObject.__table__)  # Core tables: bulk statements without ORM objects
DECISIONS = cast(Table, ReviewDecision.__table__)
NOTE_CHARS = 4000
SHOWN_PROBLEMS = 5
Problem = tuple[str, int, str | None, str]  # (list: decisions | pairs, index, the field at fault, what)


@dataclass
class ReviewSummary:
    file: str
    reviewer: str
    decisions: int = 0
    recorded: int = 0
    already_recorded: int = 0
    status_changes: list[dict[str, Any]] = field(default_factory=list)
    container_changes: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class _Obj:
    name: str
    status: str
    container: bool


def _objects(session: Session, ids: Iterable[int]) -> dict[int, _Obj]:
    """id -> (name, status, container) of the catalog objects among ``ids`` (one query per chunk)."""
    found: dict[int, _Obj] = {}
    t = CatalogObject.__table__.c
    query = select(t.id, t.name, t.status, t.container)  # Core rows: no ORM objects for 200,000 ids
    conn, wanted = session.connection(), set(ids)
    if len(wanted) > SCAN_ABOVE:
        for oid, name, status, container in conn.execute(query):
            if oid in wanted:
                found[oid] = _Obj(name, status, bool(container))
        return found
    for part in chunks(sorted(wanted)):
        for oid, name, status, container in conn.execute(query.where(t.id.in_(part))):
            found[oid] = _Obj(name, status, bool(container))
    return found


def _when(entry: dict[str, Any], default: datetime, now: datetime) -> datetime:
    return parse_time(entry.get("decided_at"), now=now) or default


def _note(entry: dict[str, Any]) -> str:
    note = entry.get("note") or ""
    if not isinstance(note, str):
        raise CatalogError("note is not a string")
    return note[:NOTE_CHARS]


def _objects_in(entries: list[Any], section: str, problems: list[Problem]) -> Iterator[tuple[int, dict[str, Any]]]:
    """(index, entry) for every entry of the file's ``section`` that is a JSON object; each other entry
    is a problem (appended as the loop reaches it, so problems keep the file's order)."""
    for k, entry in enumerate(entries):
        if isinstance(entry, dict):
            yield k, entry
        else:
            problems.append((section, k, None, "is not an object"))


def _note_and_time(entry: dict[str, Any], section: str, k: int, default: datetime, now: datetime,
                   problems: list[Problem]) -> tuple[str, datetime] | None:
    """The entry's note and decision time; None, with the problem appended, where either is wrong."""
    try:
        return _note(entry), _when(entry, default, now)
    except CatalogError as exc:
        problems.append((section, k, "decided_at" if "time" in str(exc) else "note", str(exc)))
        return None


def _check_entries(entries: list[Any], objects: dict[int, _Obj], default: datetime, now: datetime,
                   problems: list[Problem]) -> list[tuple[int, str, str, datetime]]:
    """The file's object decisions, checked (problems appended), as (id, decision, note, time)."""
    planned = []
    for k, entry in _objects_in(entries, "decisions", problems):
        oid, decision, container = entry.get("id"), entry.get("decision"), entry.get("container")
        if not is_id(oid):
            what = "is out of range" if isinstance(oid, int) and not isinstance(oid, bool) else "is not an integer"
            problems.append(("decisions", k, "id", f"id {short(oid)} {what}"))
            continue
        if decision is None and container is None:
            problems.append(("decisions", k, None, "neither a decision nor a container setting"))
            continue
        if decision is not None and decision not in STATUS_DECISIONS:
            problems.append(("decisions", k, "decision", f"decision {short(decision)} is not accept or reject"))
            continue
        if container is not None and not isinstance(container, bool):
            problems.append(("decisions", k, "container", f"container {short(container)} is not true or false"))
            continue
        obj = objects.get(oid)
        if obj is None:
            problems.append(("decisions", k, "id", f"no catalog object with id {oid}"))
            continue
        name = entry.get("name")
        if name is not None and name != obj.name:
            problems.append(("decisions", k, "name", f"id {oid} is {short(obj.name)} here, the file says {short(name)}"))
            continue
        got = _note_and_time(entry, "decisions", k, default, now, problems)
        if got is None:
            continue
        note, when = got
        if decision is not None:
            planned.append((oid, str(decision), note, when))
        if container is not None:
            planned.append((oid, "container" if container else "not_container", note, when))
    return planned


def _check_pairs(entries: list[Any], objects: dict[int, _Obj], default: datetime, now: datetime,
                 problems: list[Problem]) -> list[tuple[int, int, str, str, datetime]]:
    """The file's pair decisions, checked (problems appended), as (a, b, decision, note, time)."""
    planned = []
    for k, entry in _objects_in(entries, "pairs", problems):
        a, b, decision = entry.get("a"), entry.get("b"), entry.get("decision")
        if not (is_id(a) and is_id(b)) or a == b:
            problems.append(("pairs", k, "a", f"a {short(a)} and b {short(b)} are not two object ids"))
            continue
        if decision not in PAIR_DECISIONS:
            problems.append(("pairs", k, "decision", f"decision {short(decision)} is not one of {', '.join(PAIR_DECISIONS)}"))
            continue
        missing = [v for v in (a, b) if v not in objects]
        if missing:
            problems.append(("pairs", k, "a", f"no catalog object with id {missing[0]}"))
            continue
        wrong = [(v, entry.get(key)) for v, key in ((a, "a_name"), (b, "b_name"))
                 if entry.get(key) is not None and entry.get(key) != objects[v].name]
        if wrong:
            oid, said = wrong[0]
            problems.append(("pairs", k, "a_name" if oid == a else "b_name",
                             f"id {oid} is {short(objects[oid].name)} here, the file says {short(said)}"))
            continue
        got = _note_and_time(entry, "pairs", k, default, now, problems)
        if got is None:
            continue
        note, when = got
        planned.append((int(a), int(b), str(decision), note, when))  # type: ignore[arg-type]
    return planned


def _rejected(path: Path, text: str, problems: list[Problem]) -> CatalogError:
    """One line naming the first problems, each with the line of the file that holds it."""
    spans = entry_lines(text)
    shown = []
    for key, k, fld, what in problems[:SHOWN_PROBLEMS]:
        label = "entry" if key == "decisions" else "pair"
        shown.append(f"{label} {k}{where(text, spans, key, k, fld)}: {what}")
    more = f"; ... ({len(problems)} problems)" if len(problems) > SHOWN_PROBLEMS else ""
    return CatalogError(f"decisions file {path} rejected, nothing applied: " + "; ".join(shown) + more)


def _record(session: Session, who: str, planned: list[tuple[int, str, str, datetime]],
            pair_plan: list[tuple[int, int, str, str, datetime]], summary: ReviewSummary) -> None:
    """Insert every decision not recorded yet (same object, pair, decision, reviewer and time), in bulk."""
    t = ReviewDecision.__table__.c
    query = select(t.object_id, t.pair_object_id, t.decision, t.decided_at).where(t.reviewer == who)
    seen = {tuple(r) for r in session.connection().execute(query)}
    rows = []
    for oid, pair, decision, note, when in [(o, None, d, n, w) for o, d, n, w in planned] + pair_plan:
        key = (oid, pair, decision, when)
        if key in seen:
            summary.already_recorded += 1
            continue
        seen.add(key)
        rows.append({"object_id": oid, "pair_object_id": pair, "decision": decision, "reviewer": who,
                     "note": note, "decided_at": when})
    if rows:  # Core executemany: the ORM's bulk path costs several times more per row
        session.connection().execute(insert(DECISIONS), rows)
    summary.recorded += len(rows)


def _apply_latest(session: Session, touched: list[int], objects: dict[int, _Obj], summary: ReviewSummary) -> None:
    """The latest decision per touched object and kind onto its status and container flag (a file may
    hold older decisions than the catalog); a broken object stays broken. ``objects``: their state now."""
    newest_status = latest_by_object(session, touched, STATUS_DECISIONS, details=False)
    newest_container = latest_by_object(session, touched, CONTAINER_DECISIONS)
    statuses, containers = [], []
    for oid in touched:
        obj = objects[oid]
        status = newest_status.get(oid)
        if status is not None and obj.status != STATUS_BROKEN:
            want = STATUS_ACTIVE if status[0] == "accept" else STATUS_EXCLUDED
            if obj.status != want:
                summary.status_changes.append({"id": oid, "name": obj.name, "from": obj.status, "to": want})
                statuses.append({"oid": oid, "status": want, "updated_at": utcnow()})
        marked = newest_container.get(oid)
        if marked is not None:
            decision, reviewer, decided_at = marked
            value = CONTAINER_DECISIONS[decision]
            if obj.container != value:
                summary.container_changes.append({"id": oid, "name": obj.name, "container": value})
            at = decided_at.isoformat() if decided_at is not None else "?"
            containers.append({"oid": oid, "container": value,
                               "container_reason": f"review: {decision} by {reviewer or 'someone'} at {at}Z"})
    for rows in (statuses, containers):
        if rows:  # one executemany per kind of change
            columns: dict[str, Any] = {c: bindparam(c) for c in rows[0] if c != "oid"}
            query = update(OBJECTS).where(OBJECTS.c.id == bindparam("oid")).values(columns)
            session.connection().execute(query, rows)


def import_decisions(catalog: Catalog, path: Path, *, reviewer: str | None = None,
                     other_catalog: bool = False) -> ReviewSummary:
    """Validate every decision in ``path``, then record them all and apply the statuses (atomic).
    ``other_catalog``: the file may come from another catalog (its ids and names are still checked)."""
    data, text = load_decisions(path)
    check_catalog(data, path, catalog.url, other_catalog=other_catalog)
    now = utcnow()
    who = (reviewer or str(data.get("reviewer") or "").strip() or getpass.getuser())[:128]
    try:
        default_time = parse_time(data.get("exported_at"), now=now) or now
    except CatalogError as exc:
        raise CatalogError(f"decisions file {path} rejected, nothing applied: exported_at: {exc}") from None
    entries, pairs = data["decisions"], data.get("pairs", [])
    summary = ReviewSummary(file=str(path), reviewer=who, decisions=len(entries))
    ids: set[int] = {e["id"] for e in entries if isinstance(e, dict) and is_id(e.get("id"))}
    ids |= {e[s] for e in pairs if isinstance(e, dict) for s in ("a", "b") if is_id(e.get(s))}
    with catalog.session() as session:
        objects = _objects(session, ids)
        problems: list[Problem] = []
        planned = _check_entries(entries, objects, default_time, now, problems)
        pair_plan = _check_pairs(pairs, objects, default_time, now, problems)
        summary.decisions += len(pair_plan)
        if problems:
            raise _rejected(path, text, problems)
        _record(session, who, planned, pair_plan, summary)
        session.flush()
        touched = sorted({oid for oid, *_ in planned})
        if pair_plan:
            from mixcount.curation.review.apply_pair_decisions import apply_pair_decisions

            summary.status_changes.extend(apply_pair_decisions(session))
            session.flush()
            objects = _objects(session, touched)  # the pairs may have changed some
        _apply_latest(session, touched, objects, summary)
        session.commit()
    return summary
