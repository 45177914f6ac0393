"""What each stored split holds, what crosses splits, and which crossings the split's mode forbids.

The report (``catalog split --report``, and always under ``report`` in ``--json``): per split the objects,
categories (:func:`mixcount.catalog.split_units.category_key`), FSC-147 classes, variant and copy pairs
inside it, and how many of its categories train holds too; then every category, variant pair, copy pair
and look-alike pair that crosses splits.

Leaks (:func:`leaks`), by the mode stored with the splits:

- every mode: an active object without a split, an unknown split name, a variant / copy / collision group
  in two splits; a ``test_categories`` category found in any other split; a ``test_objects`` category
  that train does not hold;
- ``paper`` and ``categories``: an object matched to an FSC-147 val / test class in a less held-out split;
- ``objects``: a val / test category that train does not hold;
- ``categories``: a category in two of train / val / test / test_categories, a look-alike pair of one
  category in two of those (train and ``test_objects`` may share a kind: that split is unseen objects).
"""

from __future__ import annotations

from typing import Any, Mapping

from mixcount.catalog.split_classes import HELD_OUT_RANK, FscTable
from mixcount.catalog.split_units import PAIR_KINDS, SplitFacts
from mixcount.config import SPLIT_NAMES

UNSEEN_KINDS = ("train", "val", "test", "test_categories")  # categories mode: each category in one of these


def _by_split(facts: SplitFacts, split_of: Mapping[int, str]) -> dict[str, dict[str, int]]:
    """category -> split -> objects."""
    out: dict[str, dict[str, int]] = {}
    for i in facts.ids:
        if i in split_of:
            per = out.setdefault(facts.keys[i], {})
            per[split_of[i]] = per.get(split_of[i], 0) + 1
    return out


def _names(facts: SplitFacts, pair: frozenset[int]) -> list[str]:
    return [facts.names.get(i, f"#{i} (not active)") for i in sorted(pair)]


def leaks(facts: SplitFacts, split_of: Mapping[int, str], mode: str, table: FscTable | None,
          fsc_of: Mapping[int, str | None]) -> list[str]:
    """One message per leak the stored splits hold under ``mode`` (empty list = clean)."""
    problems = [f"object {i} has no split" for i in facts.ids if i not in split_of]
    problems += [f"object {i} has unknown split {s!r}" for i, s in sorted(split_of.items()) if s not in SPLIT_NAMES]
    for group in facts.groups([i for i in facts.ids if i in split_of]):
        found = sorted({split_of[i] for i in group})
        if len(found) > 1:
            problems.append(f"duplicate group {group} spans splits {found}")
    if table is not None and mode != "objects":
        for i, fsc in sorted(fsc_of.items()):
            want = table.classes.get(fsc or "")
            if want is not None and i in split_of and HELD_OUT_RANK.get(split_of[i], 2) < HELD_OUT_RANK[want]:
                problems.append(f"object {i} matches FSC-147 {want} class {fsc!r} but is in {split_of[i]}")
    for key, per in sorted(_by_split(facts, split_of).items()):
        if "test_categories" in per and len(per) > 1:
            problems.append(f"category {key!r} of test_categories is also in {', '.join(sorted(set(per) - {'test_categories'}))}")
        unseen = [s for s in ("val", "test", "test_objects") if s in per and (mode == "objects" or s == "test_objects")]
        if unseen and "train" not in per:
            problems.append(f"category {key!r} is in {', '.join(unseen)} but not in train (mode {mode}: unseen objects "
                            "of trained categories)")
        if mode == "categories":
            held = [s for s in UNSEEN_KINDS if s in per]
            if len(held) > 1 and "test_categories" not in per:
                problems.append(f"category {key!r} spans {', '.join(held)} (mode categories: one split per category)")
    if mode == "categories":
        for pair in sorted(facts.pairs.get("look_alike", ()), key=sorted):
            a, b = sorted(pair)
            if (a in split_of and b in split_of and split_of[a] != split_of[b] and facts.keys[a] == facts.keys[b]
                    and {split_of[a], split_of[b]} <= set(UNSEEN_KINDS)):
                problems.append(f"look-alike pair {a}/{b} of one category {facts.keys[a]!r} spans "
                                f"{split_of[a]} and {split_of[b]}")
    return problems


def report(facts: SplitFacts, split_of: Mapping[int, str], fsc_of: Mapping[int, str | None],
           mode: str | None) -> dict[str, Any]:
    """The split report (module docstring) as one JSON-ready document."""
    cats = _by_split(facts, split_of)
    train_cats = {k for k, per in cats.items() if "train" in per}
    splits: dict[str, Any] = {}
    for s in [n for n in SPLIT_NAMES if n in set(split_of.values())] + sorted(set(split_of.values()) - set(SPLIT_NAMES)):
        members = [i for i in facts.ids if split_of.get(i) == s]
        keys = sorted({facts.keys[i] for i in members})
        inside = {k: sum(1 for p in facts.pairs.get(k, ()) if all(split_of.get(i) == s for i in p))
                  for k in ("variant", "copy")}
        splits[s] = {
            "objects": len(members), "categories": len(keys), "category_names": keys,
            "fsc147_classes": sorted({str(fsc_of[i]) for i in members if fsc_of.get(i)}),
            "variant_pairs": inside["variant"], "copy_pairs": inside["copy"],
            "categories_shared_with_train": 0 if s == "train" else len(set(keys) & train_cats),
        }
    crossing: dict[str, Any] = {"categories": [
        {"category": k, "splits": dict(sorted(per.items()))} for k, per in sorted(cats.items()) if len(per) > 1]}
    for kind in PAIR_KINDS:
        rows = []
        for pair in sorted(facts.pairs.get(kind, ()), key=sorted):
            a, b = sorted(pair)
            if a in split_of and b in split_of and split_of[a] != split_of[b]:
                rows.append({"ids": [a, b], "names": _names(facts, pair), "splits": [split_of[a], split_of[b]],
                             "same_category": facts.keys[a] == facts.keys[b]})
        crossing[f"{kind}_pairs"] = rows
    pair_totals = {kind: sum(1 for p in facts.pairs.get(kind, ()) if all(i in split_of for i in p)) for kind in PAIR_KINDS}
    return {"mode": mode, "objects": len(split_of), "categories": len(cats), "pairs": pair_totals,
            "splits": splits, "crossing": crossing}
