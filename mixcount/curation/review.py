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
import json
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from sqlalchemy import select

from mixcount.catalog.db import Catalog
from mixcount.catalog.decisions import (
    CONTAINER_DECISIONS,
    PAIR_DECISIONS,
    STATUS_DECISIONS,
    latest_container_decisions,
    latest_decisions,
)
from mixcount.catalog.models import STATUS_ACTIVE, STATUS_BROKEN, STATUS_EXCLUDED, CatalogObject, ReviewDecision, utcnow
from mixcount.errors import CatalogError

FORMAT = "mixcount-review-v1"


def _check_pairs(session: Any, entries: list[Any], default_time: datetime,
                 problems: list[str]) -> list[tuple[CatalogObject, CatalogObject, str, str, datetime]]:
    """The file's pair decisions, checked (problems appended), as (a, b, decision, note, time)."""
    planned = []
    for k, entry in enumerate(entries):
        if not isinstance(entry, dict):
            problems.append(f"pair {k} is not an object")
            continue
        a, b, decision = entry.get("a"), entry.get("b"), entry.get("decision")
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (a, b)) or a == b:
            problems.append(f"pair {k}: a {a!r} and b {b!r} are not two object ids")
            continue
        if decision not in PAIR_DECISIONS:
            problems.append(f"pair {k}: decision {decision!r} is not one of {', '.join(PAIR_DECISIONS)}")
            continue
        objs = [session.get(CatalogObject, v) for v in (a, b)]
        missing = [v for v, o in zip((a, b), objs) if o is None]
        if missing:
            problems.append(f"pair {k}: no catalog object with id {missing[0]}")
            continue
        wrong = [(o, entry.get(key)) for o, key in zip(objs, ("a_name", "b_name"))
                 if entry.get(key) is not None and entry.get(key) != o.name]
        if wrong:
            problems.append(f"pair {k}: id {wrong[0][0].id} is {wrong[0][0].name!r} here, the file says {wrong[0][1]!r}")
            continue
        note = entry.get("note") or ""
        if not isinstance(note, str):
            problems.append(f"pair {k}: note is not a string")
            continue
        planned.append((objs[0], objs[1], str(decision), note[:4000], _parse_time(entry.get("decided_at")) or default_time))
    return planned


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


def _parse_time(value: Any) -> datetime | None:
    if not value:
        return None
    if not isinstance(value, str):
        raise CatalogError(f"decision time {value!r} is not an ISO-8601 string")
    try:
        dt = datetime.fromisoformat(value.replace("Z", "+00:00"))
    except ValueError:
        raise CatalogError(f"decision time {value!r} is not an ISO-8601 time") from None
    if dt.tzinfo is not None:
        dt = dt.astimezone(timezone.utc).replace(tzinfo=None)
    return dt.replace(microsecond=(dt.microsecond // 1000) * 1000)


def load_decisions(path: Path) -> dict[str, Any]:
    """Read and shape-check a decisions file (raises CatalogError)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CatalogError(f"decisions file not found: {path}") from None
    except (OSError, ValueError) as exc:
        raise CatalogError(f"cannot read decisions file {path}: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("decisions"), list):
        raise CatalogError(f"{path} is not a {FORMAT} decisions file")
    if not isinstance(data.get("pairs", []), list):
        raise CatalogError(f"{path}: 'pairs' is not a list")
    return data


def import_decisions(catalog: Catalog, path: Path, *, reviewer: str | None = None) -> ReviewSummary:
    """Validate every decision in ``path``, then record them all and apply the statuses (atomic)."""
    data = load_decisions(path)
    who = (reviewer or str(data.get("reviewer") or "").strip() or getpass.getuser())[:128]
    default_time = _parse_time(data.get("exported_at")) or utcnow()
    summary = ReviewSummary(file=str(path), reviewer=who, decisions=len(data["decisions"]))
    with catalog.session() as session:
        planned: list[tuple[CatalogObject, str, str, datetime]] = []
        problems: list[str] = []
        for k, entry in enumerate(data["decisions"]):
            if not isinstance(entry, dict):
                problems.append(f"entry {k} is not an object")
                continue
            oid, decision, container = entry.get("id"), entry.get("decision"), entry.get("container")
            if not isinstance(oid, int) or isinstance(oid, bool):
                problems.append(f"entry {k}: id {oid!r} is not an integer")
                continue
            if decision is None and container is None:
                problems.append(f"entry {k}: neither a decision nor a container setting")
                continue
            if decision is not None and decision not in STATUS_DECISIONS:
                problems.append(f"entry {k}: decision {decision!r} is not accept or reject")
                continue
            if container is not None and not isinstance(container, bool):
                problems.append(f"entry {k}: container {container!r} is not true or false")
                continue
            obj = session.get(CatalogObject, oid)
            if obj is None:
                problems.append(f"entry {k}: no catalog object with id {oid}")
                continue
            name = entry.get("name")
            if name is not None and name != obj.name:
                problems.append(f"entry {k}: id {oid} is {obj.name!r} here, the file says {name!r}")
                continue
            note = entry.get("note") or ""
            if not isinstance(note, str):
                problems.append(f"entry {k}: note is not a string")
                continue
            when = _parse_time(entry.get("decided_at")) or default_time
            if decision is not None:
                planned.append((obj, decision, note[:4000], when))
            if container is not None:
                planned.append((obj, "container" if container else "not_container", note[:4000], when))
        pair_plan = _check_pairs(session, data.get("pairs", []), default_time, problems)
        summary.decisions += len(pair_plan)
        if problems:
            shown = "; ".join(problems[:5]) + (f"; ... ({len(problems)} problems)" if len(problems) > 5 else "")
            raise CatalogError(f"decisions file {path} rejected, nothing applied: {shown}")
        for obj, decision, note, when in planned:
            same = session.scalar(select(ReviewDecision).where(
                ReviewDecision.object_id == obj.id, ReviewDecision.decision == decision,
                ReviewDecision.reviewer == who, ReviewDecision.decided_at == when))
            if same is not None:
                summary.already_recorded += 1
            else:
                session.add(ReviewDecision(object_id=obj.id, decision=decision, reviewer=who, note=note, decided_at=when))
                summary.recorded += 1
        for a_obj, b_obj, decision, note, when in pair_plan:
            same = session.scalar(select(ReviewDecision).where(
                ReviewDecision.object_id == a_obj.id, ReviewDecision.pair_object_id == b_obj.id,
                ReviewDecision.decision == decision, ReviewDecision.reviewer == who, ReviewDecision.decided_at == when))
            if same is not None:
                summary.already_recorded += 1
            else:
                session.add(ReviewDecision(object_id=a_obj.id, pair_object_id=b_obj.id, decision=decision,
                                           reviewer=who, note=note, decided_at=when))
                summary.recorded += 1
        session.flush()
        if pair_plan:
            from mixcount.curation.pair_review import apply_pair_decisions

            summary.status_changes.extend(apply_pair_decisions(session))
        # the latest decision per object and kind applies (a file may hold older decisions than the DB)
        touched = {o.id: o for o, *_ in planned}
        newest_status = latest_decisions(session, touched)
        newest_container = latest_container_decisions(session, touched)
        for obj in touched.values():
            status = newest_status.get(obj.id)
            if status is not None and obj.status != STATUS_BROKEN:
                want = STATUS_ACTIVE if status.decision == "accept" else STATUS_EXCLUDED
                if obj.status != want:
                    summary.status_changes.append({"id": obj.id, "name": obj.name, "from": obj.status, "to": want})
                    obj.status = want
            marked = newest_container.get(obj.id)
            if marked is not None:
                value = CONTAINER_DECISIONS[marked.decision]
                reason = f"review: {marked.decision} by {marked.reviewer or 'someone'} at {marked.decided_at.isoformat()}Z"
                if bool(obj.container) != value:
                    summary.container_changes.append({"id": obj.id, "name": obj.name, "container": value})
                obj.container, obj.container_reason = value, reason
        session.commit()
    return summary
