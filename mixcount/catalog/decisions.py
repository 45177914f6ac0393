"""A person's review decisions: the latest one per object and kind outranks every automatic rule.

Three kinds of decision share the ``review_decisions`` table: keep or drop the object (``accept`` /
``reject``, which outranks duplicate and quality flags), whether it is a container (``container`` /
``not_container``, which outranks the ``[containers]`` rules), and what a *pair* is (``same`` object,
``variants`` to keep both, ``different`` objects; ``pair_object_id`` names the other one), which
outranks the filter's pairing of the two. Each kind has its own latest decision (per object, or per
unordered pair).
"""

from __future__ import annotations

from typing import Iterable, Optional

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.models import ReviewDecision

STATUS_DECISIONS = ("accept", "reject")
CONTAINER_DECISIONS = {"container": True, "not_container": False}
PAIR_DECISIONS = ("same", "variants", "different")


def latest_decisions(session: Session, object_ids: Optional[Iterable[int]] = None, *,
                     kinds: Iterable[str] = STATUS_DECISIONS) -> dict[int, ReviewDecision]:
    """object id -> its latest decision among ``kinds`` (by decision time, then insertion order),
    optionally only for ``object_ids``."""
    query = (select(ReviewDecision).where(ReviewDecision.decision.in_(list(kinds)))
             .order_by(ReviewDecision.decided_at, ReviewDecision.id))
    if object_ids is not None:
        query = query.where(ReviewDecision.object_id.in_(list(object_ids)))
    latest: dict[int, ReviewDecision] = {}
    for rd in session.scalars(query):
        latest[rd.object_id] = rd
    return latest


def latest_container_decisions(session: Session,
                               object_ids: Optional[Iterable[int]] = None) -> dict[int, ReviewDecision]:
    """object id -> its latest ``container`` / ``not_container`` decision."""
    return latest_decisions(session, object_ids, kinds=CONTAINER_DECISIONS)


def accepted_ids(session: Session) -> set[int]:
    """Objects whose latest keep/drop decision is "accept"."""
    return {oid for oid, rd in latest_decisions(session).items() if rd.decision == "accept"}


def latest_pair_decisions(session: Session) -> dict[frozenset[int], ReviewDecision]:
    """Unordered pair of object ids -> its latest pair decision (``same`` / ``variants`` / ``different``)."""
    query = (select(ReviewDecision).where(ReviewDecision.decision.in_(list(PAIR_DECISIONS)),
                                          ReviewDecision.pair_object_id.is_not(None))
             .order_by(ReviewDecision.decided_at, ReviewDecision.id))
    latest: dict[frozenset[int], ReviewDecision] = {}
    for rd in session.scalars(query):
        latest[frozenset((rd.object_id, int(rd.pair_object_id)))] = rd  # type: ignore[arg-type]
    return latest
