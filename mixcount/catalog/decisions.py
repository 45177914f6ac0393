"""A person's review decisions: the latest one per object outranks every automatic flag."""

from __future__ import annotations

from typing import Iterable, Optional

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.models import ReviewDecision


def latest_decisions(session: Session, object_ids: Optional[Iterable[int]] = None) -> dict[int, ReviewDecision]:
    """object id -> its latest review decision (by decision time, then insertion order), optionally
    only for ``object_ids``."""
    query = select(ReviewDecision).order_by(ReviewDecision.decided_at, ReviewDecision.id)
    if object_ids is not None:
        query = query.where(ReviewDecision.object_id.in_(list(object_ids)))
    latest: dict[int, ReviewDecision] = {}
    for rd in session.scalars(query):
        latest[rd.object_id] = rd
    return latest


def accepted_ids(session: Session) -> set[int]:
    """Objects whose latest decision is "accept"."""
    return {oid for oid, rd in latest_decisions(session).items() if rd.decision == "accept"}
