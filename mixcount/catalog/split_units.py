"""What `catalog split` calls one category, and what it keeps together (docs/splits.md).

A **category** (a kind) is what the FSC-147 matching makes of the object (:meth:`FscTable.match`: its
category, then its name, then its short caption, each through :func:`mixcount.catalog.split_classes.normalise`:
lower case, singular, synonyms): the matched class when there is one (so "Mug", "mugs" and "coffee mug" are
all the class "cups", key ``cup``, and a "Soccer ball" filed under the broad category "sports" is a
``ball`` like the one filed under "ball"). Else the head noun of the active short caption (the captioner
names the object by its own noun, never by the shelf label: "brown and black hammer" under "tool" ->
``hammer``; not a generic one such as "maroon object"), else of the catalog's category ("Teddy bears" ->
``bear``), else of the name. An object with none of these is a kind of its own (``#<id>``). Why not the
category text alone: real libraries file objects under shelf labels ("toy", "tool", "kitchenware"), and a
rubber duck under "toy" and a duck under "duck" would be two kinds, free to sit in train and in test.

Pairs come from the catalog's pair flags and a person's pair decisions, sorted by what they mean:

- ``variant``: one object in two looks (``colour_variant`` flags, a person's ``variants`` decision);
- ``copy``: maybe or surely the same object (every ``*duplicate*`` kind, ``possible_copy``, a person's
  ``same`` decision);
- ``collision``: two objects captioned alike (``caption_collision``);
- ``look_alike``: different objects that look alike (information). In ``categories`` mode a look-alike pair
  of one category is bound by its category: it never spans train / val / test / test_categories; the
  extra ``test_objects`` split (unseen objects of trained kinds) may hold one of the two, by design.

The first three always share one split (:meth:`SplitFacts.groups`: connected components, linked through
excluded objects too, so A and B that both copy an excluded X share a split). ``categories`` mode binds
whole categories on top (:meth:`SplitFacts.category_components`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.decisions import latest_pair_decisions
from mixcount.catalog.grouping import connected_groups
from mixcount.catalog.models import STATUS_ACTIVE, CaptionSet, CatalogObject, Flag
from mixcount.catalog.naming import GENERIC_STEMS
from mixcount.catalog.split_classes import FscTable, normalise

TOGETHER_KINDS = ("variant", "copy", "collision")  # pair kinds that must never cross splits
PAIR_KINDS = TOGETHER_KINDS + ("look_alike",)


def pair_kind(flag_kind: str) -> str | None:
    """The split's kind of a pair flag (module docstring), None for a flag that pairs nothing here."""
    if flag_kind == "colour_variant":
        return "variant"
    if "duplicate" in flag_kind or flag_kind == "possible_copy":
        return "copy"
    if flag_kind == "caption_collision":
        return "collision"
    if flag_kind == "look_alike":
        return "look_alike"
    return None


DECISION_KINDS = {"variants": "variant", "same": "copy"}  # a person's pair decision -> pair kind


def category_key(table: FscTable, *, category: str | None, name: str | None, short: str | None) -> str | None:
    """The normalised category of one object (module docstring); None when no text has a word."""
    found, _ = table.match(category=category or "", name=name or "", short=short)
    if found is not None:
        return " ".join(normalise(found, synonyms=False))
    caption = normalise(short or "")
    if caption and caption[-1] not in GENERIC_STEMS:  # the captioner's noun (never the shelf label, docs/captions.md)
        return caption[-1]
    for text in (category, name):
        words = normalise(text or "")
        if words:
            return words[-1]
    return None


@dataclass
class SplitFacts:
    """The catalog facts a split is drawn from and checked against."""

    ids: list[int]  # active objects, sorted
    names: dict[int, str]
    keys: dict[int, str]  # object -> category key
    fsc: dict[int, str]  # object -> matched FSC-147 class (empty when matching is off)
    pairs: dict[str, set[frozenset[int]]] = field(default_factory=dict)  # kind -> pairs (excluded ends too)

    def together_pairs(self) -> list[tuple[int, int]]:
        return sorted(tuple(sorted(p)) for k in TOGETHER_KINDS for p in self.pairs.get(k, ()))  # type: ignore[misc]

    def groups(self, members: list[int] | None = None) -> list[list[int]]:
        """Connected components of the together pairs, restricted to ``members`` (default: every active object)."""
        ids = set(self.ids if members is None else members)
        found = ([i for i in g if i in ids] for g in connected_groups(self.together_pairs(), members=ids))
        return [g for g in found if g]

    def category_components(self, members: list[int] | None = None) -> list[list[int]]:
        """Groups joined with every object of their categories: the units `categories` mode moves whole."""
        ids = sorted(self.ids if members is None else members)
        first: dict[str, int] = {}
        links = list(self.together_pairs())
        for i in ids:
            key = self.keys[i]
            if key in first:
                links.append((first[key], i))
            else:
                first[key] = i
        found = ([i for i in g if i in set(ids)] for g in connected_groups(links, members=ids))
        return [g for g in found if g]


def load_facts(session: Session, table: FscTable, *, match_fsc: bool) -> SplitFacts:
    """Active objects, their category keys and FSC-147 matches, and every pair of the catalog."""
    objects = list(session.scalars(
        select(CatalogObject).where(CatalogObject.status == STATUS_ACTIVE).order_by(CatalogObject.id)))
    shorts = {cs.object_id: cs.short for cs in session.scalars(select(CaptionSet).where(CaptionSet.active.is_(True)))}
    keys: dict[int, str] = {}
    fsc: dict[int, str] = {}
    for obj in objects:
        short = shorts.get(obj.id)
        keys[obj.id] = category_key(table, category=obj.category, name=obj.name, short=short) or f"#{obj.id}"
        if match_fsc:
            cls_name, _ = table.match(category=obj.category, name=obj.name, short=short)
            if cls_name is not None:
                fsc[obj.id] = cls_name
    pairs: dict[str, set[frozenset[int]]] = {k: set() for k in PAIR_KINDS}
    for flag in session.scalars(select(Flag).where(Flag.pair_object_id.is_not(None))):
        kind = pair_kind(flag.kind)
        if kind is not None and flag.object_id != flag.pair_object_id:
            pairs[kind].add(frozenset((flag.object_id, int(flag.pair_object_id))))  # type: ignore[arg-type]
    for pair, decision in latest_pair_decisions(session).items():
        kind = DECISION_KINDS.get(decision.decision)
        if kind is not None and len(pair) == 2:
            pairs[kind].add(pair)
    for kind in ("variant", "collision", "look_alike"):  # a pair is reported under its strongest kind
        pairs[kind] -= pairs["copy"]
    pairs["look_alike"] -= pairs["variant"] | pairs["collision"]
    return SplitFacts(ids=[o.id for o in objects], names={o.id: o.name for o in objects}, keys=keys, fsc=fsc,
                      pairs=pairs)
