"""Unique prompts across a composed split: no scene holds two objects (counted classes or distractors) whose
captions are identical at any tier (case, whitespace and a trailing full stop ignored), although the pool
has colliding captions; size-qualified pairs get distinct, grammatical captions.

Spawn rejection tries are 1 here: placement does not enter any check and the full tries only cost time.
"""

from __future__ import annotations

from itertools import combinations

import pytest
from library_pool import library_pool

from mixcount.captions.base import TIERS
from mixcount.config import load_config
from mixcount.scene.caption_text import normalise_caption
from mixcount.scene.object_records import ObjectRecord
from mixcount.scene.sampler import sample_scene
from mixcount.scene.spec import Captions, SceneSpec

N_SCENES = 300
SIZE_WORDS = {"small", "large", "big", "tiny", "little", "hand-sized", "very"}


@pytest.fixture(scope="module")
def split():
    conf = load_config([], ["scene.spawn_max_tries=1"])
    pool = library_pool()
    return conf, pool, [sample_scene(seed, "train", conf, pool) for seed in range(N_SCENES)]


def _prompts(spec: SceneSpec, by_id: dict[int, ObjectRecord]) -> list[tuple[int, Captions]]:
    """(object id, captions) of every prompt of the scene: each class as captioned in the spec (a resized
    pair shares one object), each class object and distractor as captioned in the catalog."""
    out = [(c.object_id, c.captions) for c in spec.classes]
    out += [(oid, by_id[oid].captions) for oid in sorted({c.object_id for c in spec.classes})]
    out += [(d.object_id, by_id[d.object_id].captions) for d in spec.distractors]
    return out


def _collisions(spec: SceneSpec, by_id: dict[int, ObjectRecord]) -> list[tuple[int, int, str]]:
    """Pairs of different objects of the scene with an identical caption at some tier."""
    found = []
    for (a, ca), (b, cb) in combinations(_prompts(spec, by_id), 2):
        if a == b:
            continue  # one object (its catalog and qualified captions): see the size-qualified test
        for tier in TIERS:
            if normalise_caption(getattr(ca, tier)) == normalise_caption(getattr(cb, tier)):
                found.append((a, b, tier))
    return found


def test_pool_has_collisions_the_sampler_must_avoid(split):
    _conf, pool, _specs = split
    live = [o for o in pool if o.status == "active" and o.split == "train"]
    keys = {}
    shared = 0
    for o in live:
        for tier in TIERS:
            k = (tier, normalise_caption(getattr(o.captions, tier)))
            shared += k in keys
            keys.setdefault(k, o.object_id)
    assert shared >= 5  # twins at every tier and a short-only collision


def test_no_scene_shares_a_caption_between_two_objects(split):
    _conf, pool, specs = split
    by_id = {o.object_id: o for o in pool}
    bad = {s.scene_id: _collisions(s, by_id) for s in specs}
    assert not {k: v for k, v in bad.items() if v}
    # the rule still leaves same-category classes, resized pairs and distractors in the split
    constructions = {c.construction for s in specs for c in s.classes}
    assert {"same_category", "same_object_resized", "other_category"} <= constructions
    assert sum(len(s.distractors) for s in specs) >= 3 * len(specs)


def test_without_the_rule_the_same_pool_would_collide(split):
    """The check above can fail: the same checker finds collisions when objects that share captions are
    put into one scene (as the class-by-class sampler did)."""
    _conf, pool, specs = split
    by_id = {o.object_id: o for o in pool}
    twins = [(a, b) for a, b in combinations([o for o in pool if o.status == "active" and o.split == "train"], 2)
             if a.captions == b.captions]
    assert twins
    spec = specs[0]
    a, b = twins[0]
    forced = SceneSpec.from_dict({**spec.to_dict(), "distractors": [
        {**spec.distractors[0].to_dict(), "object_id": a.object_id},
        {**spec.distractors[0].to_dict(), "object_id": b.object_id, "instance_id": 999}]})
    assert _collisions(forced, by_id)


def test_size_qualified_pairs_are_grammatical_and_distinct(split):
    _conf, _pool, specs = split
    pairs = 0
    for s in specs:
        for c in s.classes:
            if c.construction != "same_object_resized":
                continue
            base = s.classes[c.base_class_index]
            pairs += 1
            for tier in TIERS:
                mine, theirs = getattr(c.captions, tier), getattr(base.captions, tier)
                assert normalise_caption(mine) != normalise_caption(theirs)
                for text, q in ((mine, c.size_qualifier), (theirs, base.size_qualifier)):
                    words = text.lower().replace(",", " ").replace(".", " ").split()
                    head = words[: words.index(q) + 2]
                    assert q in words and not SIZE_WORDS & set(head), text  # replaced, not stacked
                    assert not text.lower().startswith(("larger a ", "smaller a ", "larger an ", "a an ")), text
    assert pairs >= 30
