"""`catalog split`: train / val / test (and two extra test splits) per object, by one of three modes.

1. Every active object is matched to an FSC-147 class (``mixcount/data/fsc147_class_splits.csv``) from, in
   order, its category, its name and its active short caption. Each text is normalised (lower case, words,
   plurals to singular, the synonym table below) and a class matches when its normalised words are the
   *last* words of the text: the head noun decides, so "orange ball" is a ball, not an orange. The longest
   matching class wins ("bottle cap" over "cap"). The same normalisation names each object's category
   (:mod:`mixcount.catalog.split_units`), so "Mug", "mugs" and "coffee mug" are one category.
2. Groups: objects linked by any ``*duplicate*`` flag, a ``colour_variant`` or ``possible_copy`` flag, a
   ``caption_collision`` flag or a person's ``same`` / ``variants`` pair decision always share one split.
3. Modes (:mod:`mixcount.catalog.split_assign`): ``paper`` (FSC-147 class matches take their class's split,
   the rest drawn at random to the ``[split]`` fractions: the paper's rule and the default), ``objects``
   (every category keeps objects in train; val / test hold out objects: unseen assets), ``categories``
   (whole categories go to one split: unseen kinds, FSC-147's class split kept). The extra splits
   ``test_objects`` and ``test_categories`` hold out unseen objects and unseen categories in any mode.
   Same catalog + same seed = same assignment.
4. :func:`check_splits` then looks for the leaks the stored mode forbids
   (:func:`mixcount.catalog.split_report.leaks`); :func:`split_report` says what each split holds.

The split names, the normalisation and the FSC-147 table are in :mod:`mixcount.catalog.split_classes`; see
docs/splits.md for the synonym table and its reasons.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from mixcount.catalog.db import Catalog
from mixcount.catalog.grouping import connected_groups
from mixcount.catalog.models import STATUS_ACTIVE, CatalogObject, Flag, Split
from mixcount.catalog.split_classes import SPLITS, FscTable
from mixcount.config import SPLIT_NAMES, SplitConfig
from mixcount.errors import CatalogError


@dataclass
class SplitSummary:
    seed: int
    targets: dict[str, float]
    mode: str  # paper | objects | categories
    counts: dict[str, dict[str, int]] = field(default_factory=dict)  # split -> method -> n
    matched_classes: dict[str, int] = field(default_factory=dict)  # fsc class -> n objects
    conflicts: list[dict[str, Any]] = field(default_factory=list)
    leaks: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # e.g. a split left empty by a small library
    report: dict[str, Any] = field(default_factory=dict)  # :func:`mixcount.catalog.split_report.report`

    def totals(self) -> dict[str, int]:
        """Objects per split: train / val / test always, an extra test split when it was asked for or holds any."""
        names = [s for s in SPLIT_NAMES if s in SPLITS or self.targets.get(s, 0) > 0 or s in self.counts]
        return {s: sum(self.counts.get(s, {}).values()) for s in names}

    def as_dict(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "mode": self.mode,
            "report": self.report,
            "targets": self.targets,
            "totals": self.totals(),
            "counts": self.counts,
            "matched_classes": self.matched_classes,
            "conflicts": self.conflicts,
            "leaks": self.leaks,
            "warnings": self.warnings,
        }


def duplicate_groups(session: Session, object_ids: Iterable[int]) -> list[list[int]]:
    """Connected components over duplicate and caption-collision flags, restricted to ``object_ids``.

    Links run through every flagged object, excluded ones included: A and B that are both duplicates of
    an excluded X form one group, so they can never land in two splits.
    """
    ids = set(object_ids)
    pairs = [
        (flag.object_id, int(flag.pair_object_id))  # type: ignore[arg-type]
        for flag in session.scalars(select(Flag).where(Flag.pair_object_id.is_not(None)))
        if is_group_flag(flag.kind)
    ]
    groups = ([i for i in group if i in ids] for group in connected_groups(pairs, members=ids))
    return [g for g in groups if g]


GROUP_KINDS = ("caption_collision", "colour_variant", "possible_copy")  # besides every *duplicate* kind


def is_group_flag(kind: str) -> bool:
    """Whether a pair flag of ``kind`` binds its two objects to one split."""
    return "duplicate" in kind or kind in GROUP_KINDS


def assign_splits(catalog: Catalog, config: SplitConfig, *, table: FscTable | None = None) -> SplitSummary:
    """Assign every active object a split by ``config.mode`` (replacing previous ones) and check for leaks.

    The drawing is :func:`mixcount.catalog.split_assign.assign`; the facts it reads (categories, pairs)
    :func:`mixcount.catalog.split_units.load_facts`."""
    from mixcount.catalog.split_assign import assign, targets
    from mixcount.catalog.split_report import report
    from mixcount.catalog.split_units import load_facts

    table = table or FscTable.load()
    n_extra = config.test_objects_fraction + config.test_categories_fraction
    summary = SplitSummary(seed=config.seed, targets={}, mode=config.mode)
    rng = np.random.default_rng(config.seed)
    with catalog.session() as session:
        facts = load_facts(session, table, match_fsc=config.use_fsc147)
        n = len(facts.ids)
        summary.targets = {s: (v / n if n else (dict(zip(SPLITS, config.fractions)).get(s, 0.0) * (1 - n_extra)))
                           for s, v in targets(config, n).items()}
        decided, summary.conflicts = assign(facts, config, table, rng)
        session.execute(delete(Split))
        for oid in sorted(decided):
            split, method, fsc = decided[oid]
            session.add(Split(object_id=oid, split=split, method=method, fsc_class=fsc, seed=config.seed,
                              mode=config.mode))
            summary.counts.setdefault(split, {}).setdefault(method, 0)
            summary.counts[split][method] += 1
            if fsc:
                summary.matched_classes[fsc] = summary.matched_classes.get(fsc, 0) + 1
        session.commit()
        summary.report = report(facts, {i: d[0] for i, d in decided.items()}, {i: d[2] for i, d in decided.items()},
                                config.mode)
    summary.leaks = check_splits(catalog, table=table if config.use_fsc147 else None)
    totals = summary.totals()
    for name in SPLIT_NAMES:
        if totals.get(name, 0) == 0 and summary.targets.get(name, 0) > 0 and n:
            summary.warnings.append(
                f"split {name!r} has 0 objects (target {summary.targets[name]:.0%} of {n} active objects): "
                f"`mixcount compose --split {name}` will find nothing; add objects, or change the split fractions")
    return summary


def stored_splits(session: Session) -> tuple[dict[int, str], dict[int, str | None], str]:
    """(object -> split, object -> stored FSC-147 class, the mode that assigned them; ``paper`` before modes)."""
    rows = list(session.scalars(select(Split)))
    modes = sorted({r.mode or "paper" for r in rows})
    return ({r.object_id: r.split for r in rows}, {r.object_id: r.fsc_class for r in rows},
            modes[0] if len(modes) == 1 else ",".join(modes) if modes else "paper")


def check_splits(catalog: Catalog, *, table: FscTable | None = None, mode: str | None = None) -> list[str]:
    """Leaks in the stored splits under their stored mode (or ``mode``): one message per problem (empty = clean).

    The rules per mode: :func:`mixcount.catalog.split_report.leaks`."""
    from mixcount.catalog.split_report import leaks
    from mixcount.catalog.split_units import load_facts

    with catalog.session() as session:
        split_of, fsc_of, stored = stored_splits(session)
        facts = load_facts(session, table or FscTable.load(), match_fsc=False)
    problems = [] if "," not in stored else [f"the stored splits mix modes ({stored}): run `mixcount catalog split` again"]
    return problems + leaks(facts, split_of, mode or stored.split(",")[0], table, fsc_of)


def split_report(catalog: Catalog, *, table: FscTable | None = None) -> dict[str, Any]:
    """The report of the stored splits (:func:`mixcount.catalog.split_report.report`)."""
    from mixcount.catalog.split_report import report
    from mixcount.catalog.split_units import load_facts

    with catalog.session() as session:
        split_of, fsc_of, stored = stored_splits(session)
        facts = load_facts(session, table or FscTable.load(), match_fsc=False)
    return report(facts, split_of, fsc_of, stored)


def split_object_ids(session: Session, split: str) -> list[int]:
    """Ids of the active objects in ``split`` (what the scene sampler draws from), sorted."""
    if split not in SPLIT_NAMES:
        raise CatalogError(f"unknown split {split!r} ({' | '.join(SPLIT_NAMES)})")
    rows = session.scalars(
        select(Split.object_id)
        .join(CatalogObject, CatalogObject.id == Split.object_id)
        .where(Split.split == split, CatalogObject.status == STATUS_ACTIVE)
        .order_by(Split.object_id)
    )
    return list(rows)
