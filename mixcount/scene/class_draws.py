"""The counted classes of one scene, by the paper's class construction (see :mod:`mixcount.scene.sampler`).

A scene's first class is an eligible object of the split; each further class is (a) an existing class's
object at a clearly different size (``resize_ratio``; both get a "larger"/"smaller" qualifier), (b) another
object of an existing class's category, (c) an object of a new category, or (d) a colour variant of an
existing class's object, with the configured weights (:func:`construction_weights`). Every pick keeps the
scene's prompts unique (no two objects share a caption at any tier); :func:`split_counts` splits a total
count over the classes. Split out of the sampler so that it reads by concern.
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.scene.caption_text import normalise_caption, size_qualified
from mixcount.scene.object_records import ObjectRecord
from mixcount.scene.spec import TIERS, Captions
from mixcount.scene_config import SceneConfig

CONSTRUCTIONS = ("same_object_resized", "same_category", "other_category", "colour_variant")


def _u(rng: np.random.Generator, r: Sequence[float]) -> float:
    return float(rng.uniform(r[0], r[1]))


def qualify(caption: str, qualifier: Optional[str]) -> str:
    """'a large white bottle' + 'smaller' -> 'a smaller white bottle' (see :func:`size_qualified`)."""
    return size_qualified(caption, qualifier)


def caption_keys(captions: Captions) -> frozenset[tuple[str, str]]:
    """(tier, normalised caption) of each tier: two objects whose keys intersect share a prompt."""
    return frozenset((tier, normalise_caption(getattr(captions, tier))) for tier in TIERS)


# ---------------------------------------------------------------------------------------------------
# class construction


class ClassDraft:
    def __init__(self, obj: ObjectRecord, size: float, construction: str, base: Optional[int] = None):
        self.obj = obj
        self.size = size
        self.construction = construction
        self.base = base
        self.qualifier: Optional[str] = None


def _resize_options(drafts: list[ClassDraft], lo: float, hi: float, rmin: float) -> list[int]:
    uses: dict[int, int] = {}
    for d in drafts:
        uses[d.obj.object_id] = uses.get(d.obj.object_id, 0) + 1
    return [
        i for i, d in enumerate(drafts)
        if uses[d.obj.object_id] == 1 and (d.size * rmin <= hi or d.size / rmin >= lo)
    ]


def _resized_size(rng: np.random.Generator, base: float, lo: float, hi: float,
                  ratio: tuple[float, float]) -> tuple[float, str]:
    r = _u(rng, ratio)
    direction = "larger" if rng.random() < 0.5 else "smaller"
    for dirn in (direction, "smaller" if direction == "larger" else "larger"):
        size = base * r if dirn == "larger" else base / r
        if lo <= size <= hi:
            return size, dirn
    # the drawn ratio overshoots both ends: use the largest ratio that fits (still >= ratio[0])
    up, down = hi / base, base / lo
    if up >= down:
        return hi, "larger"
    return lo, "smaller"


def construction_weights(config: SceneConfig) -> NDArray[Any]:
    """Weights of :data:`CONSTRUCTIONS` before feasibility: the paper's three in their proportions share
    ``1 - p_colour_variant``, the colour variant takes ``p_colour_variant``."""
    paper = np.array([config.p_same_object_resized, config.p_same_category, config.p_other_category], dtype=float)
    pv = float(config.p_colour_variant)
    return np.append(paper / paper.sum() * (1.0 - pv), pv)


def _variant_options(drafts: list[ClassDraft], free: list[ObjectRecord]) -> list[tuple[int, list[ObjectRecord]]]:
    """(class index, its object's free colour variants) for every class that has one."""
    out = []
    for i, d in enumerate(drafts):
        ids = set(d.obj.variants)
        cands = [o for o in free if o.object_id in ids]
        if cands:
            out.append((i, cands))
    return out


def build_classes(rng: np.random.Generator, config: SceneConfig, eligible: list[ObjectRecord],
                   n_classes: int, *, real: bool = False) -> list[ClassDraft]:
    """The scene's classes. ``real`` (``scene.size_rule = "real"``): each class at its object's real largest
    side (metres, not yet scaled: the sampler chooses the scene's scale from them) and no resized pair (an
    object has one real size); no class size is drawn, so the draws that follow differ from a paper scene's."""
    s = config.scale
    lo, hi = config.class_size[0] * s, config.class_size[1] * s

    def size_of(obj: ObjectRecord) -> float:
        return obj.max_dim if real else _u(rng, (lo, hi))

    first = eligible[int(rng.integers(len(eligible)))]
    drafts = [ClassDraft(first, size_of(first), "first")]
    probs = construction_weights(config)
    while len(drafts) < n_classes:
        used = {d.obj.object_id for d in drafts}
        cats = {d.obj.category for d in drafts}
        taken = frozenset().union(*(caption_keys(d.obj.captions) for d in drafts))
        free = [o for o in eligible if o.object_id not in used and not caption_keys(o.captions) & taken]
        resizable = [] if real else _resize_options(drafts, lo, hi, config.resize_ratio[0])
        # a variant of a class in the scene comes only from option (d), so p_colour_variant is what
        # decides how often a scene holds the hard pair
        variant_ids = set().union(*(d.obj.variants for d in drafts))
        same_cat = [o for o in free if o.category in cats and o.object_id not in variant_ids]
        other_cat = [o for o in free if o.category not in cats]
        variants = _variant_options(drafts, free)
        feasible = np.array([bool(resizable), bool(same_cat), bool(other_cat), bool(variants)], dtype=float)
        p = probs * feasible
        if p.sum() <= 0:
            break  # the split cannot provide another distinct class
        choice = CONSTRUCTIONS[int(rng.choice(len(CONSTRUCTIONS), p=p / p.sum()))]
        if choice == "colour_variant":
            bi, cands = variants[int(rng.integers(len(variants)))]
            pick = cands[int(rng.integers(len(cands)))]
            draft = ClassDraft(pick, size_of(pick), choice, base=bi)
        elif choice == "same_object_resized":
            bi = resizable[int(rng.integers(len(resizable)))]
            base = drafts[bi]
            size, direction = _resized_size(rng, base.size, lo, hi, config.resize_ratio)
            draft = ClassDraft(base.obj, size, choice, base=bi)
            draft.qualifier = direction
            base.qualifier = "smaller" if direction == "larger" else "larger"
        elif choice == "same_category":
            by_cat = sorted({o.category for o in same_cat})
            cat = by_cat[int(rng.integers(len(by_cat)))]
            cands = [o for o in same_cat if o.category == cat]
            pick = cands[int(rng.integers(len(cands)))]
            draft = ClassDraft(pick, size_of(pick), choice)
        else:
            by_cat = sorted({o.category for o in other_cat})
            cat = by_cat[int(rng.integers(len(by_cat)))]
            cands = [o for o in other_cat if o.category == cat]
            pick = cands[int(rng.integers(len(cands)))]
            draft = ClassDraft(pick, size_of(pick), choice)
        drafts.append(draft)
    return drafts


def distinct_caption_picks(rng: np.random.Generator, free: list[ObjectRecord], n: int,
                            taken: frozenset[tuple[str, str]]) -> list[ObjectRecord]:
    """Up to ``n`` objects of ``free`` drawn one by one, uniformly among those whose captions collide with
    no caption already ``taken`` (by the classes or an earlier pick): the first fitting ones of a random
    permutation, which is the same distribution."""
    picks: list[ObjectRecord] = []
    if n <= 0:
        return picks
    for i in rng.permutation(len(free)).tolist():
        keys = caption_keys(free[i].captions)
        if keys & taken:
            continue
        picks.append(free[i])
        taken = taken | keys
        if len(picks) == n:
            break
    return picks


def split_counts(rng: np.random.Generator, n: int, k: int) -> list[int]:
    """n instances over k classes, every class >= 1, uniform over all such compositions."""
    if k == 1:
        return [n]
    cuts = np.sort(rng.choice(np.arange(1, n), size=k - 1, replace=False))
    return [int(c) for c in np.diff(np.concatenate([[0], cuts, [n]]))]


# ---------------------------------------------------------------------------------------------------
# placement
