"""The drawing of `catalog split`, per mode (docs/splits.md "Modes").

Targets: the two extra test splits take ``test_objects_fraction`` and ``test_categories_fraction`` of the
active objects; train / val / test share the rest in the ``[split]`` fractions. Then, in this order:

1. ``test_categories`` (when asked): whole category components (:meth:`SplitFacts.category_components`),
   shuffled, each taken while it brings the split closer to its target. A component holding an FSC-147
   train or val class is never taken (its class would reach an unseen split only by dropping out of train).
2. train / val / test over the rest, per mode:
   - ``paper``: groups; a group with FSC-147 matches takes the most held-out of its classes' splits, the
     others are drawn at random with probabilities proportional to each split's deficit (the paper's rule,
     the assignment of mixcount before modes, draw for draw);
   - ``categories``: the same over category components: whole kinds go to val or test;
   - ``objects``: groups drawn as in ``paper`` with FSC-147 ignored, but a group goes to val / test only
     while each of its categories keeps another group in train (method ``kept`` when that held it back).
3. ``test_objects`` (when asked): groups of train, shuffled, each moved while each of its categories keeps
   another group in train and it brings the split closer to its target. Step 2's train target includes
   this share, so train ends near its own fraction.

Same catalog + same seed = same assignment; with no extra split, ``paper`` draws exactly as before.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from mixcount.catalog.split_classes import HELD_OUT_RANK, SPLITS, FscTable
from mixcount.catalog.split_units import SplitFacts
from mixcount.config import SplitConfig

Decision = tuple[str, str, "str | None"]  # (split, method, FSC-147 class)


def targets(config: SplitConfig, n: int) -> dict[str, float]:
    """Objects wanted per split (fractions of ``n``); step 2's train target still holds test_objects'."""
    fo, fc = config.test_objects_fraction, config.test_categories_fraction
    main = np.array(config.fractions) * (1.0 - fo - fc) * n
    return {"train": float(main[0]), "val": float(main[1]), "test": float(main[2]),
            "test_objects": fo * n, "test_categories": fc * n}


def _draw(rng: np.random.Generator, names: tuple[str, ...], counts: dict[str, int], want: dict[str, float],
          fallback: Iterable[float]) -> str:
    """One split of ``names``, with probabilities proportional to each one's remaining deficit."""
    deficit = np.maximum(np.array([want[s] for s in names]) - np.array([counts[s] for s in names]), 0.0)
    p = deficit / deficit.sum() if deficit.sum() > 0 else np.array(list(fallback))
    return names[int(rng.choice(len(names), p=p))]


def _closer(count: int, size: int, target: float) -> bool:
    return abs(count + size - target) < abs(count - target)


def assign(facts: SplitFacts, config: SplitConfig, table: FscTable, rng: np.random.Generator
           ) -> tuple[dict[int, Decision], list[dict]]:
    """Every active object's (split, method, class) by ``config.mode``; and the FSC-147 conflicts."""
    mode = config.mode
    want = targets(config, len(facts.ids))
    want["train"] += want["test_objects"]
    counts = {s: 0 for s in want}
    decided: dict[int, Decision] = {}
    conflicts: list[dict] = []
    fsc = facts.fsc if mode != "objects" else {}

    def put(members: list[int], split: str, method: str) -> None:
        for i in members:
            own = table.classes.get(fsc.get(i, ""))
            decided[i] = (split, "fsc147" if own == split and method != "random" else method, facts.fsc.get(i))
            counts[split] += 1

    if config.test_categories_fraction > 0:
        comps = facts.category_components()
        # FSC-147 train / val kinds are no unseen kinds to a model trained on FSC-147, whatever the mode
        eligible = [c for c in comps if {table.classes[facts.fsc[i]] for i in c if i in facts.fsc} <= {"test"}]
        taken = 0
        for k in rng.permutation(len(eligible)):
            comp = eligible[int(k)]
            # never every category: train keeps at least one
            if taken < len(comps) - 1 and _closer(counts["test_categories"], len(comp), want["test_categories"]):
                put(comp, "test_categories", "category")
                taken += 1
    rest = [i for i in facts.ids if i not in decided]
    units = facts.category_components(rest) if mode == "categories" else facts.groups(rest)

    unmatched: list[list[int]] = []
    for unit in units:
        wanted = {table.classes[fsc[i]] for i in unit if i in fsc}
        if not wanted:
            unmatched.append(unit)
            continue
        split = max(wanted, key=HELD_OUT_RANK.__getitem__)
        if len(wanted) > 1:
            conflicts.append({"group": unit, "classes": sorted({fsc[i] for i in unit if i in fsc}), "split": split})
        put(unit, split, "category" if mode == "categories" else "group")

    in_train: dict[str, int] = {}  # category -> groups that may still stay in train (objects mode)
    if mode == "objects":
        for unit in unmatched:
            for key in {facts.keys[i] for i in unit}:
                in_train[key] = in_train.get(key, 0) + 1
    for k in rng.permutation(len(unmatched)):
        unit = unmatched[int(k)]
        split = _draw(rng, SPLITS, counts, want, config.fractions)
        method = "random"
        if mode == "objects":
            unit_keys = {facts.keys[i] for i in unit}
            if split != "train" and any(in_train[key] <= 1 for key in unit_keys):
                split, method = "train", "kept"
            elif split != "train":
                for key in unit_keys:
                    in_train[key] -= 1
        put(unit, split, method)

    if config.test_objects_fraction > 0:
        train_groups = [g for g in facts.groups(rest) if all(decided[i][0] == "train" for i in g)]
        per_key: dict[str, int] = {}
        for g in train_groups:
            for key in {facts.keys[i] for i in g}:
                per_key[key] = per_key.get(key, 0) + 1
        for k in rng.permutation(len(train_groups)):
            g = train_groups[int(k)]
            g_keys = {facts.keys[i] for i in g}
            if all(per_key[key] > 1 for key in g_keys) and _closer(counts["test_objects"], len(g), want["test_objects"]):
                counts["train"] -= len(g)
                put(g, "test_objects", "random")
                for key in g_keys:
                    per_key[key] -= 1
    return decided, conflicts
