"""A person's review decisions: the latest one per object and kind outranks every automatic rule.

Three kinds of decision share the ``review_decisions`` table: keep or drop the object (``accept`` /
``reject``, which outranks duplicate and quality flags), whether it is a container (``container`` /
``not_container``, which outranks the ``[containers]`` rules), and what a *pair* is (``same`` object,
``variants`` to keep both, ``different`` objects; ``pair_object_id`` names the other one), which
outranks the filter's pairing of the two. Each kind has its own latest decision (per object, or per
unordered pair).
"""

from __future__ import annotations

from datetime import datetime
from typing import Iterable, Iterator, Optional, Sequence, TypeVar

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.models import ReviewDecision

STATUS_DECISIONS = ("accept", "reject")
CONTAINER_DECISIONS = {"container": True, "not_container": False}
PAIR_DECISIONS = ("same", "variants", "different")
# ids per ``IN (...)``: SQLite before 3.32 allows 999 bound values per statement (later ones 32,766); a
# statement per 900 ids costs little next to reading the rows (200,000 ids: 223 statements)
IN_CHUNK = 900
SCAN_ABOVE = 20 * IN_CHUNK  # more ids than this: one scan of the table, filtered here, beats the IN lists

T = TypeVar("T")


def chunks(items: Sequence[T], size: int = IN_CHUNK) -> Iterator[Sequence[T]]:
    """``items`` in runs of ``size`` (for ``IN`` lists that must stay under the database's variable limit)."""
    for k in range(0, len(items), size):
        yield items[k:k + size]


def latest_decisions(session: Session, object_ids: Optional[Iterable[int]] = None, *,
                     kinds: Iterable[str] = STATUS_DECISIONS) -> dict[int, ReviewDecision]:
    """object id -> its latest decision among ``kinds`` (by decision time, then insertion order),
    optionally only for ``object_ids``."""
    query = (select(ReviewDecision).where(ReviewDecision.decision.in_(list(kinds)))
             .order_by(ReviewDecision.decided_at, ReviewDecision.id))
    latest: dict[int, ReviewDecision] = {}
    if object_ids is None:
        for rd in session.scalars(query):
            latest[rd.object_id] = rd
        return latest
    for part in chunks(sorted(set(object_ids))):  # an object's rows all fall in one chunk: order holds
        for rd in session.scalars(query.where(ReviewDecision.object_id.in_(part))):
            latest[rd.object_id] = rd
    return latest


def latest_by_object(session: Session, object_ids: Sequence[int], kinds: Iterable[str], *,
                     details: bool = True) -> dict[int, tuple[str, str, datetime | None]]:
    """object id -> (decision, reviewer, decided_at) of its latest decision among ``kinds``, in the order
    of :func:`latest_decisions`, read as plain rows (an import of 200,000 decisions reads them all: no ORM
    objects, and with ``details=False`` no times parsed: reviewer "" and time None)."""
    t = ReviewDecision.__table__.c
    cols = (t.object_id, t.decision, t.reviewer, t.decided_at) if details else (t.object_id, t.decision)
    query = select(*cols).where(t.decision.in_(list(kinds))).order_by(t.decided_at, t.id)
    latest: dict[int, tuple[str, str, datetime | None]] = {}
    conn, wanted = session.connection(), set(object_ids)
    parts: Iterable[Sequence[int] | None] = [None] if len(wanted) > SCAN_ABOVE else chunks(sorted(wanted))
    for part in parts:  # an object's rows all fall in one part: the order holds
        for row in conn.execute(query if part is None else query.where(t.object_id.in_(part))):
            if row[0] in wanted:
                latest[row[0]] = (row[1], row[2], row[3]) if details else (row[1], "", None)
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
