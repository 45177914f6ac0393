"""`catalog split`: train / val / test per object, matched to FSC-147 classes where one fits.

1. Every active object is matched to an FSC-147 class (``mixcount/data/fsc147_class_splits.csv``) from, in
   order, its category, its name and its active short caption. Each text is normalised (lower case, words,
   plurals to singular, the synonym table below) and a class matches when its normalised words are the
   *last* words of the text: the head noun decides, so "orange ball" is a ball, not an orange. The longest
   matching class wins ("bottle cap" over "cap").
2. Duplicate groups: objects linked by any ``*duplicate*`` flag (exact or near, from curation), a
   ``colour_variant`` or ``possible_copy`` flag (one object in two colours; maybe one object from two
   sources) or a ``caption_collision`` flag form one group (connected components) that always shares one
   split: a class seen in train must not reach test in another colour. If its
   matched members disagree, the most held-out split wins (test > val > train): an object of a test class
   must never reach train.
3. Groups without a match are drawn at random (numpy Generator from ``seed``), each with probabilities
   proportional to how far each split still is below its target fraction, so the totals approach
   ``[split]`` fractions. Same catalog + same seed = same assignment.
4. :func:`check_splits` then looks for leaks: a duplicate group spanning splits, an active object without
   a split, or an object matched to a val/test class sitting in a less held-out split.

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
from mixcount.catalog.models import STATUS_ACTIVE, CaptionSet, CatalogObject, Flag, Split
from mixcount.config import SplitConfig
from mixcount.errors import CatalogError

SPLITS = ("train", "val", "test")
HELD_OUT_RANK = {"train": 0, "val": 1, "test": 2}

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
    counts: dict[str, dict[str, int]] = field(default_factory=dict)  # split -> method -> n
    matched_classes: dict[str, int] = field(default_factory=dict)  # fsc class -> n objects
    conflicts: list[dict[str, Any]] = field(default_factory=list)
    leaks: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # e.g. a split left empty by a small library

    def totals(self) -> dict[str, int]:
        return {s: sum(self.counts.get(s, {}).values()) for s in SPLITS}

    def as_dict(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
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


def _short_captions(session: Session) -> dict[int, str]:
    rows = session.scalars(select(CaptionSet).where(CaptionSet.active.is_(True)))
    return {cs.object_id: cs.short for cs in rows}


def assign_splits(catalog: Catalog, config: SplitConfig, *, table: FscTable | None = None) -> SplitSummary:
    """Assign every active object a split (replacing previous ones) and check for leaks."""
    table = table or FscTable.load()
    summary = SplitSummary(seed=config.seed, targets=dict(zip(SPLITS, config.fractions)))
    rng = np.random.default_rng(config.seed)
    with catalog.session() as session:
        objects = list(
            session.scalars(select(CatalogObject).where(CatalogObject.status == STATUS_ACTIVE).order_by(CatalogObject.id))
        )
        by_id = {o.id: o for o in objects}
        shorts = _short_captions(session)
        matches: dict[int, str] = {}
        if config.use_fsc147:
            for obj in objects:
                cls_name, _ = table.match(category=obj.category, name=obj.name, short=shorts.get(obj.id))
                if cls_name is not None:
                    matches[obj.id] = cls_name
        groups = duplicate_groups(session, by_id)

        decided: dict[int, tuple[str, str, str | None]] = {}  # id -> (split, method, fsc class)
        counts = {s: 0 for s in SPLITS}
        unmatched: list[list[int]] = []
        for group in groups:
            wanted = {table.classes[matches[i]] for i in group if i in matches}
            if not wanted:
                unmatched.append(group)
                continue
            split = max(wanted, key=HELD_OUT_RANK.__getitem__)
            if len(wanted) > 1:
                summary.conflicts.append(
                    {"group": group, "classes": sorted({matches[i] for i in group if i in matches}), "split": split}
                )
            for i in group:
                own = table.classes.get(matches.get(i, ""), None)
                method = "fsc147" if own == split else "group"
                decided[i] = (split, method, matches.get(i))
                counts[split] += 1

        # Random part: shuffle the unmatched groups, then draw each one's split with probabilities
        # proportional to each split's remaining deficit against its target.
        n_total = len(objects)
        targets = np.array(config.fractions) * n_total
        order = rng.permutation(len(unmatched))
        for k in order:
            group = unmatched[int(k)]
            deficit = np.maximum(targets - np.array([counts[s] for s in SPLITS]), 0.0)
            p = deficit / deficit.sum() if deficit.sum() > 0 else np.array(config.fractions)
            split = SPLITS[int(rng.choice(len(SPLITS), p=p))]
            for i in group:
                decided[i] = (split, "random", None)
                counts[split] += 1

        session.execute(delete(Split))
        for oid in sorted(decided):
            split, method, fsc = decided[oid]
            session.add(Split(object_id=oid, split=split, method=method, fsc_class=fsc, seed=config.seed))
            summary.counts.setdefault(split, {}).setdefault(method, 0)
            summary.counts[split][method] += 1
            if fsc:
                summary.matched_classes[fsc] = summary.matched_classes.get(fsc, 0) + 1
        session.commit()
    summary.leaks = check_splits(catalog, table=table if config.use_fsc147 else None)
    totals = summary.totals()
    for name in SPLITS:
        if totals[name] == 0 and summary.targets[name] > 0 and objects:
            summary.warnings.append(
                f"split {name!r} has 0 objects (target {summary.targets[name]:.0%} of {len(objects)} active objects): "
                f"`mixcount compose --split {name}` will find nothing; add objects, or change split.fractions")
    return summary


def check_splits(catalog: Catalog, *, table: FscTable | None = None) -> list[str]:
    """Leaks in the stored splits: one message per problem (empty list = clean)."""
    problems: list[str] = []
    with catalog.session() as session:
        active = [o.id for o in session.scalars(select(CatalogObject).where(CatalogObject.status == STATUS_ACTIVE))]
        splits = {s.object_id: s for s in session.scalars(select(Split))}
        for oid in sorted(active):
            if oid not in splits:
                problems.append(f"object {oid} has no split")
        for oid, row in splits.items():
            if row.split not in SPLITS:
                problems.append(f"object {oid} has unknown split {row.split!r}")
        for group in duplicate_groups(session, [o for o in active if o in splits]):
            found = sorted({splits[o].split for o in group})
            if len(found) > 1:
                problems.append(f"duplicate group {group} spans splits {found}")
        if table is not None:
            for oid, row in splits.items():
                fsc = row.fsc_class
                if fsc and fsc in table.classes:
                    want = table.classes[fsc]
                    if HELD_OUT_RANK.get(row.split, -1) < HELD_OUT_RANK[want]:
                        problems.append(f"object {oid} matches FSC-147 {want} class {fsc!r} but is in {row.split}")
    return problems


def split_object_ids(session: Session, split: str) -> list[int]:
    """Ids of the active objects in ``split`` (what the scene sampler draws from), sorted."""
    if split not in SPLITS:
        raise CatalogError(f"unknown split {split!r} (train | val | test)")
    rows = session.scalars(
        select(Split.object_id)
        .join(CatalogObject, CatalogObject.id == Split.object_id)
        .where(Split.split == split, CatalogObject.status == STATUS_ACTIVE)
        .order_by(Split.object_id)
    )
    return list(rows)
