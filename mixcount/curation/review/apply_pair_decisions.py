"""A person's pair decisions applied at once by `catalog review import` (the filter applies them again on
every run, :func:`mixcount.curation.finding.catalog_filter.run_filter`): ``same`` excludes the worse of the two in the
filter's quality order, ``variants`` / ``different`` re-activate a side the filter or the caption step had
excluded for this pairing (an exact duplicate, a caption collision: a person's word that the two differ
keeps both as classes of their own, issue 70), unless a person rejected that side; the pair's flags are
marked as decided (severity *info*)."""

from __future__ import annotations

from typing import Any

from sqlalchemy import or_, select
from sqlalchemy.orm import Session

from mixcount.catalog.decisions import latest_decisions, latest_pair_decisions
from mixcount.catalog.models import STATUS_ACTIVE, STATUS_EXCLUDED, CatalogObject, Flag
from mixcount.catalog.records import ingest_appearance
from mixcount.curation.flag_kinds import (
    APPEARANCE_RANK,
    CAPTION_COLLISION,
    DECIDED_MARK,
    EXCLUDED_MARK,
    POSSIBLE_COPY,
    QUALITY_KINDS,
    decided_mark,
)


def _rank(session: Session, obj: CatalogObject, accepted: set[int]) -> tuple:
    """The filter's quality order (smaller is better), from the flags in the catalog."""
    quality = len(session.scalars(select(Flag.id).where(Flag.object_id == obj.id, Flag.kind.in_(QUALITY_KINDS))).all())
    return (0 if obj.id in accepted else 1, quality, APPEARANCE_RANK.get(ingest_appearance(obj), 3), -(obj.face_count or 0), obj.id)


def apply_pair_decisions(session: Session) -> list[dict[str, Any]]:
    """Apply every latest pair decision to statuses and flags; returns the status changes."""
    changes: list[dict[str, Any]] = []
    decisions = latest_decisions(session)
    accepted = {oid for oid, rd in decisions.items() if rd.decision == "accept"}
    rejected = {oid for oid, rd in decisions.items() if rd.decision == "reject"}
    for pair, rd in latest_pair_decisions(session).items():
        a, b = (session.get(CatalogObject, i) for i in sorted(pair))
        if a is None or b is None:
            continue
        flags = session.scalars(select(Flag).where(or_(
            (Flag.object_id == a.id) & (Flag.pair_object_id == b.id),
            (Flag.object_id == b.id) & (Flag.pair_object_id == a.id)))).all()
        mark = decided_mark(rd.decision, rd.reviewer)
        for f in flags:
            if DECIDED_MARK not in (f.reason or ""):
                f.reason = f"{f.reason or ''} {mark}".strip()
        if rd.decision == "same":
            keep, drop = sorted((a, b), key=lambda o: _rank(session, o, accepted))
            if drop.status == STATUS_ACTIVE and drop.id not in accepted:
                changes.append({"id": drop.id, "name": drop.name, "from": drop.status, "to": STATUS_EXCLUDED})
                drop.status = STATUS_EXCLUDED
                note = f"{EXCLUDED_MARK} the same object as #{keep.id} {keep.name!r} (review)"
                own = [f for f in flags if f.object_id == drop.id]
                if not own:
                    for x, y in ((drop, keep), (keep, drop)):
                        flag = Flag(object_id=x.id, kind=POSSIBLE_COPY, score=1.0, pair_object_id=y.id,
                                    reason=f"the same object, by a person's review; pair #{y.id} {y.name!r} {mark}")
                        session.add(flag)
                        if x is drop:
                            own = [flag]
                for f in own:
                    f.reason = f"{f.reason} {note}"
        else:
            for x in (a, b):
                # excluded for this pairing: by the filter (its mark), or by the caption step's dedupe of
                # equal captions (which marks nothing; captioning tells the two apart by name next time)
                marked = any(f.object_id == x.id and (EXCLUDED_MARK in (f.reason or "") or f.kind == CAPTION_COLLISION)
                             for f in flags)
                if x.status == STATUS_EXCLUDED and marked and x.id not in rejected:
                    changes.append({"id": x.id, "name": x.name, "from": x.status, "to": STATUS_ACTIVE})
                    x.status = STATUS_ACTIVE
    session.flush()
    return changes
