"""`catalog caption`: caption every active object, record the sets, flag and optionally drop collisions.

Resumable: an object that already has a caption set from the same captioner, provider, model and prompt
version is skipped (that set is made the active one) unless ``force``. Each object's result is committed as
soon as it arrives, so an interrupted run loses at most the requests in flight. Several caption sets may
exist per object; exactly one is active (the newest one written or re-activated by a run).

Uniqueness: after captioning, active objects whose active captions are identical at any tier (case- and
whitespace-insensitive, trailing full stop ignored) get a ``caption_collision`` flag per pair, in both
directions. ``dedupe`` (the default, the paper's rule: prompts must tell objects apart) keeps one object
per collision group (one a person accepted, else the lowest id) and sets the others' status to
``excluded``; ``dedupe=False`` only flags them for a person to review.
"""

from __future__ import annotations

import hashlib
import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from mixcount.captions.base import TIERS, Captioner, CaptionInput, CaptionResult
from mixcount.catalog.db import Catalog
from mixcount.catalog.decisions import accepted_ids, latest_pair_decisions
from mixcount.catalog.grouping import connected_groups
from mixcount.catalog.models import (
    STATUS_ACTIVE,
    STATUS_EXCLUDED,
    CaptionFailure,
    CaptionSet,
    CatalogObject,
    Flag,
)
from mixcount.catalog.step_executor import ray_tasks
from mixcount.errors import CaptionError, CaptionRequestError
from mixcount.progress import ProgressReporter, as_reporter
from mixcount.scene.caption_text import normalise_caption

log = logging.getLogger("mixcount.captions.captioning")

COLLISION_KIND = "caption_collision"


@dataclass
class CaptionSummary:
    captioner: str
    provider: str
    model: str
    prompt_version: str
    objects: int = 0
    captioned: int = 0
    skipped: int = 0
    failed: int = 0
    collision_pairs: int = 0
    objects_in_collision: int = 0
    excluded: int = 0
    collisions_by_tier: dict[str, int] = field(default_factory=dict)
    failures: list[dict[str, Any]] = field(default_factory=list)
    # the caption check (mixcount.captions.check) over every active object's active captions after the run
    caption_check: dict[str, Any] = field(default_factory=dict)
    variants_toned: int = 0  # colour-variant members re-captioned with "darker"/"lighter" (same colour names)
    warnings: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def render_path_for(session: Session, object_id: int) -> Path | None:
    """The canonical render of an object, if one was made (``catalog render``)."""
    from mixcount.curation.renders import canonical_render_path

    found = canonical_render_path(session, object_id)
    return Path(found) if found else None


def response_hash(raw: str) -> str:
    return hashlib.sha256(raw.encode("utf-8")).hexdigest()


def _same_key(cs: CaptionSet, captioner: Captioner) -> bool:
    return (
        cs.captioner == captioner.name
        and cs.provider == captioner.provider
        and cs.model == captioner.model
        and cs.prompt_version == captioner.prompt_version
    )


def _activate(obj: CatalogObject, chosen: CaptionSet) -> None:
    for cs in obj.caption_sets:
        cs.active = cs is chosen


def caption_catalog(
    catalog: Catalog,
    captioner: Captioner,
    *,
    force: bool = False,
    dedupe: bool = True,
    object_ids: Iterable[int] | None = None,
    concurrency: int,
    colour_source: str,
    progress: ProgressReporter | bool | None = None,
    redact: Callable[[str], str] | None = None,
    palette: Any = None,
) -> CaptionSummary:
    """Caption active objects with ``captioner``; record sets and failures; flag (and dedupe) collisions.

    ``concurrency`` (threads) and ``colour_source`` are ``captions.concurrency`` / ``captions.colour_source``;
    ``palette`` (``[palette]``): untextured objects are captioned in the colour they render with.
    """
    summary = CaptionSummary(captioner.name, captioner.provider, captioner.model, captioner.prompt_version)
    scrub = redact or getattr(captioner, "redact", None) or (lambda s: s)
    workers = max(1, concurrency)

    with catalog.session() as session:
        query = select(CatalogObject).where(CatalogObject.status == STATUS_ACTIVE).order_by(CatalogObject.id)
        if object_ids is not None:
            query = query.where(CatalogObject.id.in_(list(object_ids)))
        objects = list(session.scalars(query))
        summary.objects = len(objects)
        todo: list[CatalogObject] = []
        for obj in objects:
            existing = [cs for cs in obj.caption_sets if _same_key(cs, captioner)]
            if existing and not force:
                newest = max(existing, key=lambda cs: (cs.created_at, cs.id))
                if not newest.active:
                    _activate(obj, newest)
                summary.skipped += 1
            else:
                todo.append(obj)
        session.commit()

        bar = as_reporter(progress)
        bar.start(f"captioning ({captioner.name})", len(todo))
        with ThreadPoolExecutor(max_workers=workers) as pool:
            # Inputs (colours read from the render / model) are built in the workers too: they cost
            # more than a stub caption.
            futures: dict[Any, CatalogObject] = {}
            inputs = [CaptionInput.from_object(obj, render_path=render_path_for(session, obj.id), palette=palette)
                      for obj in todo]
            if ray_tasks() is not None:  # --executor ray: each caption a Ray task, recorded here as it comes, in order
                done: Iterable[tuple[Any, CatalogObject]] = zip(_ray_captions(captioner, inputs, colour_source), todo)
            else:
                for obj, item in zip(todo, inputs):
                    futures[pool.submit(_measure_and_caption, captioner, item, colour_source)] = obj
                done = ((fut, futures[fut]) for fut in _as_completed_in_order(futures))
            for fut, obj in done:
                try:
                    result = fut.result()
                except Exception as exc:  # noqa: BLE001 - one object's failure (bad file, bad answer) is recorded; the batch goes on
                    attempts = int(getattr(exc, "attempts", 1))
                    message = scrub(str(exc) if isinstance(exc, CaptionError) else f"{type(exc).__name__}: {exc}")
                    session.add(
                        CaptionFailure(
                            object_id=obj.id,
                            captioner=captioner.name,
                            provider=captioner.provider,
                            model=captioner.model,
                            prompt_version=captioner.prompt_version,
                            attempts=attempts,
                            error=message,
                        )
                    )
                    summary.failed += 1
                    summary.failures.append({"object_id": obj.id, "attempts": attempts, "error": message})
                    log.warning("caption failed for object %d: %s", obj.id, message)
                else:
                    new = CaptionSet(
                        object_id=obj.id,
                        captioner=captioner.name,
                        provider=captioner.provider,
                        model=captioner.model,
                        prompt_version=captioner.prompt_version,
                        short=result.short,
                        concise=result.concise,
                        detailed=result.detailed,
                        response_hash=response_hash(result.raw),
                        active=True,
                    )
                    obj.caption_sets.append(new)
                    _activate(obj, new)
                    summary.captioned += 1
                session.commit()
                bar.advance()
        bar.stop()

    summary.variants_toned = separate_variants(catalog, captioner, colour_source=colour_source, palette=palette)
    flag_collisions(catalog, summary=summary)
    if dedupe:
        summary.excluded = dedupe_collisions(catalog)
    run_caption_check(catalog, summary)
    return summary


TONE_MIN_DIFFERENCE = 0.02  # mean luminance apart (0..1) before "darker"/"lighter" is a fact, not noise
# (CaptionInput.tell, say the shade) tried in order on a group of equal captions until they differ
TELL_STEPS = ((1, False), (0, True), (1, True), (2, False), (2, True))


def _colliding_groups(captions: dict[int, CaptionSet]) -> list[list[int]]:
    """Groups of objects whose active captions are identical at some tier (connected components)."""
    return collision_groups(find_collisions(captions))


def separate_variants(catalog: Catalog, captioner: Captioner, *, colour_source: str, palette: Any = None) -> int:
    """Tell apart different objects whose captions by this captioner came out equal at some tier, before any
    collision is flagged: each group is captioned again with more telling words, in the order of
    :data:`TELL_STEPS` (``CaptionInput.tell`` 1: the measured colours and pattern beside the name's colours;
    for a pair, ``tone`` = "darker" / "lighter" from the measured mean luminance, at least
    :data:`TONE_MIN_DIFFERENCE` apart; ``tell`` 2: the proportion word), until the group's captions differ. Objects nothing seen tells apart (same content hash, or the same
    name words, colours, shade and proportions) stay equal: true duplicates, flagged and excluded as before.
    An http captioner is asked again instead (``HttpCaptioner.tell_apart``: told the captions to differ
    from). Returns the objects re-captioned (colour variants and other objects alike)."""
    if captioner.name != "stub":
        return _tell_apart_by_asking(catalog, captioner)
    changed: set[int] = set()
    with catalog.session() as session:
        captions = {oid: cs for oid, cs in active_captions(session).items() if _same_key(cs, captioner)}
        items: dict[int, CaptionInput] = {}

        def item_of(oid: int) -> CaptionInput:
            if oid not in items:
                obj = session.get(CatalogObject, oid)
                items[oid] = CaptionInput.from_object(obj, render_path=render_path_for(session, oid), palette=palette) \
                    .with_measured_colours(colour_source)
            return items[oid]

        def write(oid: int, item: CaptionInput) -> None:
            result = captioner.caption(item)
            cs = captions[oid]
            if (cs.short, cs.concise, cs.detailed) != (result.short, result.concise, result.detailed):
                cs.short, cs.concise, cs.detailed = result.short, result.concise, result.detailed
                cs.response_hash = response_hash(result.raw)
                changed.add(oid)

        apart = kept_apart(session)
        for group in _colliding_groups(captions):
            hashes = {oid: (session.get(CatalogObject, oid).content_hash or f"#{oid}") for oid in group}
            if len(set(hashes.values())) == 1:
                if any(frozenset((a, b)) in apart for a in group for b in group if a < b):
                    changed |= _tell_apart_by_name(session, {oid: captions[oid] for oid in group})
                continue  # one file twice: a true duplicate, unless a person said they differ
            lum = {oid: item_of(oid).colours.luminance for oid in group}
            toned = len(group) == 2 and abs(lum[group[0]] - lum[group[1]]) >= TONE_MIN_DIFFERENCE
            for level, use_tone in TELL_STEPS:
                if use_tone and not toned:
                    continue
                for oid in group:
                    other = lum[group[1] if oid == group[0] else group[0]] if use_tone else 0.0
                    tone = ("darker" if lum[oid] < other else "lighter") if use_tone else None
                    write(oid, replace(item_of(oid), tell=level, tone=tone))
                if not _colliding_groups({oid: captions[oid] for oid in group}):
                    break
            else:  # nothing seen tells them apart: a true duplicate, left with its plain captions
                for oid in group:
                    write(oid, item_of(oid))
                changed |= _tell_apart_by_pins(session, {oid: captions[oid] for oid in group})
        session.commit()
    return len(changed)


separate_collisions = separate_variants

KEPT_APART = ("different", "variants")  # a person's pair decisions that keep both objects as classes of their own


def kept_apart(session: Session) -> set[frozenset[int]]:
    """Pairs a person decided are two objects (``different``) or two versions to keep (``variants``)."""
    return {pair for pair, rd in latest_pair_decisions(session).items() if rd.decision in KEPT_APART}


_NUMBER_WORDS = ("zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten", "eleven",
                 "twelve", "thirteen", "fourteen", "fifteen", "sixteen", "seventeen", "eighteen", "nineteen", "twenty")


def _tell_apart_by_pins(session: Session, group: dict[int, CaptionSet]) -> set[int]:
    """Parts of one family that nothing seen told apart (a 2- and a 3-pin terminal block in one colour):
    when every name states a pin count (:func:`mixcount.catalog.naming.pin_count`) and the counts differ, each
    caption starts with it ("two-pin green terminal block"), a count a person sees. Returns the changed ids."""
    from mixcount.catalog.naming import pin_count

    counts = {oid: pin_count(session.get(CatalogObject, oid).name or "") for oid in group}
    if None in counts.values() or len(set(counts.values())) < len(counts):
        return set()
    for oid, cs in group.items():
        n = int(counts[oid])  # type: ignore[arg-type]
        number = _NUMBER_WORDS[n] if n < len(_NUMBER_WORDS) else str(n)
        word = f"{number}-pin"
        cs.short, cs.concise = f"{word} {cs.short}", f"{word[:1].upper()}{word[1:]} {cs.concise[:1].lower()}{cs.concise[1:]}"
        cs.detailed = f"{cs.detailed} It has {number} pins."
    return set(group)


def _tell_apart_by_name(session: Session, group: dict[int, CaptionSet]) -> set[int]:
    """One file under several names that a person said are different objects (a 1k and a 10k resistor drawn
    alike): nothing seen tells them apart, so each caption gets the words of its name the others' lack
    ("green resistor 1k" / "green resistor 10k"). Returns the objects whose captions changed."""
    import re

    # the name's tokens as typed ("1k", "10k": a value is one token); the caption check may call such a
    # token an id (id_fragment), and it is still the only thing the person's names tell apart
    words = {oid: [t for t in re.split(r"[\s_]+", (session.get(CatalogObject, oid).name or "").lower()) if t]
             for oid in group}
    changed: set[int] = set()
    for oid, cs in group.items():
        others = set().union(*(set(w) for o, w in words.items() if o != oid))
        own = [w for w in words[oid] if w not in others]
        if not own:
            continue
        tail = " ".join(own)
        cs.short, cs.concise = f"{cs.short} {tail}", f"{cs.concise} {tail}"
        cs.detailed = f"{cs.detailed.rstrip('. ')}, marked {tail}."
        changed.add(oid)
    return changed


def _tell_apart_by_asking(catalog: Catalog, captioner: Captioner) -> int:
    """For a captioner that can be asked again (``tell_apart``: the http one): in each group of different
    objects (different content hashes) with equal captions, every member after the first is captioned
    again, told the captions it must differ from; an answer that is invalid or still equal leaves the
    collision to the flags. Returns the objects re-captioned."""
    ask = getattr(captioner, "tell_apart", None)
    if ask is None:
        return 0
    changed = 0
    with catalog.session() as session:
        captions = {oid: cs for oid, cs in active_captions(session).items() if _same_key(cs, captioner)}
        for group in _colliding_groups(captions):
            if len({session.get(CatalogObject, oid).content_hash or f"#{oid}" for oid in group}) == 1:
                continue  # one file twice: a true duplicate
            for oid in group[1:]:
                others = [{t: getattr(captions[o], t) for t in TIERS} for o in group if o != oid]
                item = CaptionInput.from_object(session.get(CatalogObject, oid), render_path=render_path_for(session, oid))
                result = ask(item, others)
                if result is None:
                    continue
                cs = captions[oid]
                cs.short, cs.concise, cs.detailed = result.short, result.concise, result.detailed
                cs.response_hash = response_hash(result.raw)
                changed += 1
            session.commit()
    return changed


def run_caption_check(catalog: Catalog, summary: CaptionSummary) -> None:
    """Fill ``summary.caption_check`` (counts per kind) and ``summary.warnings`` (per warned object)."""
    from mixcount.captions.check import check_catalog, summarise_warnings

    with catalog.session() as session:
        found = check_catalog(session)
        names = {oid: name for oid, name in session.execute(
            select(CatalogObject.id, CatalogObject.name).where(CatalogObject.id.in_(list(found))))}
    summary.caption_check = summarise_warnings(found)
    summary.warnings = [{"object_id": oid, "name": names.get(oid), "warnings": ws}
                        for oid, ws in sorted(found.items()) if ws]


def _measure_and_caption(captioner: Captioner, item: CaptionInput, colour_source: str) -> CaptionResult:
    result = captioner.caption(item.with_measured_colours(colour_source))
    return checked_result(captioner, item, result)


def checked_result(captioner: Captioner, item: CaptionInput, result: CaptionResult) -> CaptionResult:
    """``result`` when it passes the caption check's blocking rules (:data:`mixcount.captions.check.
    ANSWER_BLOCKING`: no mesh facts, no sizes, the name's colours kept, ...), else a CaptionError naming
    each broken rule (recorded in ``caption_failures``). The same check the http captioner runs on answers."""
    from mixcount.captions.check import blocking, reasons

    found = blocking(result.tiers(), name=item.name, category=item.category, captioner=captioner.name)
    if found:
        raise CaptionRequestError(f"caption check: {reasons(found)}", attempts=result.attempts)
    return result


class _Done:
    """A caption a Ray task made (or the error that stopped it), read as a finished future is read."""

    def __init__(self, got: Any) -> None:
        self.got = got

    def result(self) -> CaptionResult:
        from mixcount.catalog.step_executor import TaskFailed

        if isinstance(self.got, TaskFailed):
            raise CaptionRequestError(self.got.error, attempts=0)
        result, error, attempts = self.got
        if error is not None:
            raise CaptionRequestError(error, attempts=attempts)
        return result


def caption_task(captioner: Captioner, item: CaptionInput, colour_source: str) -> tuple[Any, str | None, int]:
    """Ray task of ``catalog caption --executor ray``: (result, None, attempts) or (None, the error as the
    local path records it, attempts); never raises for one object's failure (it is not retried)."""
    try:
        return _measure_and_caption(captioner, item, colour_source), None, 0
    except Exception as exc:  # noqa: BLE001 - recorded by the driver as the local path records it
        message = str(exc) if isinstance(exc, CaptionError) else f"{type(exc).__name__}: {exc}"
        return None, message, int(getattr(exc, "attempts", 1))


def _ray_captions(captioner: Captioner, inputs: list[CaptionInput], colour_source: str) -> Iterator[_Done]:
    """Each input's caption from a Ray task, as it comes back (in order): a stopped run keeps those recorded."""
    cluster = ray_tasks()
    assert cluster is not None
    for got in cluster.map(caption_task, [(captioner, it, colour_source) for it in inputs]):
        yield _Done(got)


def _as_completed_in_order(futures: dict[Any, CatalogObject]) -> Iterable[Any]:
    """Completed futures in submission order: commits (and the DB) stay deterministic."""
    return list(futures)


def active_captions(session: Session, *, include_excluded: bool = False) -> dict[int, CaptionSet]:
    """object id -> active caption set, for active objects (and excluded ones if asked)."""
    statuses = (STATUS_ACTIVE, STATUS_EXCLUDED) if include_excluded else (STATUS_ACTIVE,)
    rows = session.execute(
        select(CaptionSet)
        .join(CatalogObject, CatalogObject.id == CaptionSet.object_id)
        .where(CaptionSet.active.is_(True), CatalogObject.status.in_(statuses))
        .order_by(CaptionSet.object_id, CaptionSet.id)
    ).scalars()
    return {cs.object_id: cs for cs in rows}


def find_collisions(captions: dict[int, CaptionSet]) -> dict[tuple[int, int], list[str]]:
    """(a, b) with a < b -> tiers on which the two objects' captions are identical."""
    pairs: dict[tuple[int, int], list[str]] = {}
    for tier in TIERS:
        groups: dict[str, list[int]] = {}
        for oid, cs in captions.items():
            groups.setdefault(normalise_caption(getattr(cs, tier)), []).append(oid)
        for ids in groups.values():
            ids.sort()
            for i, a in enumerate(ids):
                for b in ids[i + 1 :]:
                    pairs.setdefault((a, b), []).append(tier)
    return pairs


def flag_collisions(catalog: Catalog, *, summary: CaptionSummary | None = None) -> dict[tuple[int, int], list[str]]:
    """Replace all ``caption_collision`` flags with the current collisions (both directions per pair).

    Excluded objects take part, so an object excluded by deduplication keeps the flag that says why; the
    summary counts only pairs of two active objects (the ones still to resolve).
    """
    with catalog.session() as session:
        captions = active_captions(session, include_excluded=True)
        active = {oid for oid, in session.execute(select(CatalogObject.id).where(CatalogObject.status == STATUS_ACTIVE))}
        pairs = find_collisions(captions)
        session.execute(delete(Flag).where(Flag.kind == COLLISION_KIND))
        for (a, b), tiers in sorted(pairs.items()):
            for oid, other in ((a, b), (b, a)):
                text = getattr(captions[oid], tiers[0])
                reason = f"identical {'/'.join(tiers)} caption with object {other}: {text!r}"
                session.add(
                    Flag(object_id=oid, kind=COLLISION_KIND, score=len(tiers) / len(TIERS), reason=reason,
                         pair_object_id=other)
                )
        session.commit()
    if summary is not None:
        live = {pair: tiers for pair, tiers in pairs.items() if pair[0] in active and pair[1] in active}
        summary.collision_pairs = len(live)
        summary.objects_in_collision = len({o for pair in live for o in pair})
        summary.collisions_by_tier = {t: sum(1 for ts in live.values() if t in ts) for t in TIERS}
    return pairs


def collision_groups(pairs: Iterable[tuple[int, int]]) -> list[list[int]]:
    """Connected components of the collision graph (sorted ids, groups sorted by first id)."""
    return connected_groups(pairs)


def dedupe_collisions(catalog: Catalog) -> int:
    """Keep one active object per collision group (a person-accepted one first, else the lowest id) and
    exclude the group's other active objects, except one a person decided is a different object from the
    kept one, or a variant to keep (:data:`KEPT_APART`). Never re-activates anything."""
    with catalog.session() as session:
        flags = session.scalars(select(Flag).where(Flag.kind == COLLISION_KIND)).all()
        pairs = {(min(f.object_id, f.pair_object_id), max(f.object_id, f.pair_object_id))
                 for f in flags if f.pair_object_id is not None}
        accepted = accepted_ids(session)
        apart = kept_apart(session)  # a person said the two differ: both stay (issue 70)
        excluded = 0
        for group in collision_groups(pairs):
            members = [session.get(CatalogObject, oid) for oid in group]
            live = [o for o in members if o is not None and o.status == STATUS_ACTIVE]
            if not live:
                continue
            keep = next((o for o in live if o.id in accepted), live[0])
            for obj in live:
                if obj is not keep and frozenset((obj.id, keep.id)) not in apart:
                    obj.status = STATUS_EXCLUDED
                    excluded += 1
        session.commit()
    return excluded
