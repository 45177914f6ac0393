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

See docs/splits.md for the synonym table and its reasons.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from mixcount.catalog.db import Catalog
from mixcount.catalog.grouping import connected_groups
from mixcount.catalog.models import STATUS_ACTIVE, CatalogObject, Flag, Split
from mixcount.config import SPLIT_NAMES, SplitConfig
from mixcount.errors import CatalogError

SPLITS = ("train", "val", "test")  # the paper's three; SPLIT_NAMES adds the two extra test splits
# how held out each split is: an object of an FSC-147 test class must never reach a lower rank
HELD_OUT_RANK = {"train": 0, "val": 1, "test": 2, "test_objects": 2, "test_categories": 2}

# Irregular plurals (and words that look plural but are not) for :func:`singular`.
IRREGULAR = {
    "geese": "goose", "people": "person", "sheep": "sheep", "mice": "mouse", "teeth": "tooth",
    "feet": "foot", "children": "child", "knives": "knife", "leaves": "leaf", "loaves": "loaf",
    "glasses": "glass", "sunglasses": "sunglass", "series": "series", "species": "species",
    "cactus": "cactus", "octopus": "octopus", "bus": "bus", "lens": "lens", "chess": "chess",
    "dice": "die", "matches": "match", "peaches": "peach", "boxes": "box", "shoes": "shoe",
    "canoes": "canoe", "toes": "toe", "oases": "oasis", "cookies": "cookie", "movies": "movie",
}

# Object words -> the FSC-147 word(s) they mean. Keys and values are singular. Kept short and documented
# in docs/splits.md; each entry is a word a DTC-style catalog uses for an object FSC-147 names differently.
SYNONYMS: dict[str, str] = {
    # balls: FSC-147 "balls" (train) covers every kind
    "football": "ball", "soccerball": "ball", "basketball": "ball", "volleyball": "ball",
    "baseball": "ball", "softball": "ball", "tennisball": "ball", "golfball": "ball",
    "beachball": "ball", "dodgeball": "ball", "handball": "ball", "rugbyball": "ball",
    # drinkware / tableware
    "mug": "cup", "teacup": "cup", "tumbler": "cup", "dish": "plate", "saucer": "plate", "platter": "plate",
    "flowerpot": "flower pot", "planter": "flower pot",
    # writing tools
    "highlighter": "marker", "sharpie": "marker", "biro": "pen", "ballpoint": "pen",
    # food
    "doughnut": "donut", "cookie": "biscuit", "tangerine": "orange", "mandarin": "orange",
    "clementine": "orange", "capsicum": "pepper", "chili": "pepper", "chilli": "pepper",
    "seashell": "sea shell", "cashew": "cashew nut", "walnut": "nut", "almond": "nut",
    "hazelnut": "nut", "peanut": "nut",
    # other
    "sneaker": "shoe", "boot": "shoe", "sandal": "shoe", "slipper": "shoe",
    "tin": "can", "wristwatch": "watch", "duplo": "lego", "tshirt": "shirt", "t-shirt": "shirt",
    "gem": "gemstone", "candlestick": "candle", "skewer": "meat skewer",
}

TOKEN = re.compile(r"[a-z0-9&]+(?:-[a-z0-9]+)*")


def singular(word: str) -> str:
    """A plural-insensitive key for one lower-case word (same rules on both sides is what matters)."""
    if word in IRREGULAR:
        return IRREGULAR[word]
    if len(word) <= 3 or word.endswith(("ss", "us", "ous", "sis", "xis")):
        return word
    if word.endswith("ies") and len(word) > 4:
        return word[:-3] + "y"
    if word.endswith(("ches", "shes", "xes", "zes", "sses")):
        return word[:-2]
    if word.endswith("oes") and len(word) > 4:
        return word[:-2]
    if word.endswith("s"):
        return word[:-1]
    return word


def normalise(text: str, *, synonyms: bool = True) -> list[str]:
    """Lower-case singular words, synonyms applied to object text (a synonym may expand to several words).

    FSC-147 class names are normalised without synonyms: they are the targets synonyms point at.
    """
    spaced = re.sub(r"(?<=[a-z])(?=[A-Z])", " ", text or "").lower().replace("_", " ")
    out: list[str] = []
    for raw in TOKEN.findall(spaced):
        if any(ch.isdigit() for ch in raw):
            continue  # ids and version numbers
        word = singular(raw)
        for w in (SYNONYMS.get(word, SYNONYMS.get(raw, word)) if synonyms else word).split():
            if not out or out[-1] != w:  # "cashew nuts" -> "cashew nut nut" -> "cashew nut"
                out.append(w)
    return out


@dataclass(frozen=True)
class FscTable:
    """FSC-147 class name -> split, with each class's normalised words."""

    classes: Mapping[str, str]
    keys: Mapping[tuple[str, ...], str]  # normalised words -> class name

    @classmethod
    def load(cls, path: Path | None = None) -> "FscTable":
        if path is None:
            text = resources.files("mixcount.data").joinpath("fsc147_class_splits.csv").read_text("utf-8")
        else:
            text = Path(path).read_text("utf-8")
        classes: dict[str, str] = {}
        keys: dict[tuple[str, ...], str] = {}
        for row in csv.DictReader(text.splitlines()):
            name, split = row["class_name"].strip(), row["split"].strip()
            if split not in SPLITS:
                raise CatalogError(f"FSC-147 table: class {name!r} has unknown split {split!r}")
            classes[name] = split
            key = tuple(normalise(name, synonyms=False))
            if key in keys and classes[keys[key]] != split:
                raise CatalogError(f"FSC-147 table: {name!r} and {keys[key]!r} normalise alike but differ in split")
            keys.setdefault(key, name)
        return cls(classes, keys)

    def match_words(self, words: list[str]) -> str | None:
        """The longest class whose words end ``words`` (the head noun decides)."""
        for n in range(min(len(words), 4), 0, -1):
            name = self.keys.get(tuple(words[-n:]))
            if name is not None:
                return name
        return None

    def match(self, *, category: str, name: str, short: str | None) -> tuple[str | None, str | None]:
        """(class, source) from category, then name, then short caption; (None, None) when nothing fits."""
        for source, text in (("category", category), ("name", name), ("short", short or "")):
            found = self.match_words(normalise(text))
            if found is not None:
                return found, source
        return None, None


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
