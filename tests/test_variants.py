"""Colour variants are classes, not duplicates (issue 34):

* in the catalog (real SQLite, real GLB files, `catalog filter` then `catalog split`): both members of
  a recolour stay active, carry a ``colour_variant`` flag both ways with the figures, share one split,
  and reach the sampler's pool as each other's ``variants`` (carried through duplicate groups);
* in the sampler: the construction "a colour variant of a class already in the scene" is taken with
  ``scene.p_colour_variant`` where the split has one (500 dry-run specs, within 3 points), dropped
  where it has none, and never puts two variants with one caption into a scene."""

from __future__ import annotations

import numpy as np
import pytest
from test_curate_support import library_catalog, quick_config

from mixcount.catalog.models import Flag
from mixcount.catalog.pool_loader import colour_variants, load_pool
from mixcount.catalog.splits import assign_splits, check_splits
from mixcount.config import load_config
from mixcount.curation.finding.catalog_filter import run_filter
from mixcount.errors import ConfigError
from mixcount.scene.class_draws import CONSTRUCTIONS, caption_keys, construction_weights
from mixcount.scene.object_records import ObjectRecord
from mixcount.scene.sampler import sample_scene
from mixcount.scene.spec import Captions

N_SPECS = 500


def variant_pool(*, same_captions: bool = False, with_variants: bool = True) -> list[ObjectRecord]:
    """8 categories x 3 shapes, each shape in two colours (a variant pair), all in train."""
    pool = []
    oid = 1
    colours = ("red", "blue")
    for c in range(8):
        for shape in range(3):
            pair = (oid, oid + 1)
            for k, colour in enumerate(colours):
                word = "" if same_captions else f"{colour} "
                caps = Captions(f"{word}shape{shape} thing{c}", f"a {word}shape{shape} thing{c}",
                                f"a {word}shape{shape} thing{c} with a handle")
                variants = (pair[1 - k],) if with_variants else ()
                pool.append(ObjectRecord(oid, f"thing{c} {shape} {colour}", f"thing{c}",
                                         (0.05 + 0.01 * shape, 0.04, 0.03), caps, "train", f"/lib/{oid}.glb",
                                         f"h{oid:05d}", variants=variants))
                oid += 1
    return pool


def specs(overrides: list[str], pool: list[ObjectRecord]):
    cfg = load_config([], ["scene.spawn_max_tries=1", *overrides])
    return cfg, [sample_scene(seed, "train", cfg, pool) for seed in range(N_SPECS)]


def has_variant_pair(spec, pool_by_id) -> bool:
    ids = [c.object_id for c in spec.classes]
    return any(b in pool_by_id[a].variants for a in ids for b in ids)


def test_share_of_scenes_with_a_variant_pair_follows_the_configured_probability():
    pool = variant_pool()
    by_id = {o.object_id: o for o in pool}
    # two classes: one construction step, on which every option is feasible here
    cfg, two = specs(["scene.n_classes=[2, 2]"], pool)
    p = cfg.scene.p_colour_variant
    assert p > 0  # the default configures the option
    share = np.mean([has_variant_pair(s, by_id) for s in two])
    assert abs(share - p) <= 0.03, (share, p)
    for s in two:
        second = s.classes[1]
        if second.construction == "colour_variant":
            base = s.classes[second.base_class_index]
            assert second.object_id in by_id[base.object_id].variants and second.category == base.category
            assert caption_keys(second.captions).isdisjoint(caption_keys(base.captions))
    # any class count: the share of construction steps that are colour variants, where one was free
    _, default = specs([], pool)
    steps = [c.construction for s in default for c in s.classes[1:]]
    variant_share = steps.count("colour_variant") / len(steps)
    assert abs(variant_share - p) <= 0.03, (variant_share, p)
    # the paper's three keep their proportions among the rest
    w = construction_weights(cfg.scene)
    assert w[-1] == pytest.approx(p) and w.sum() == pytest.approx(1.0)
    paper = [steps.count(name) / len(steps) for name in CONSTRUCTIONS[:3]]
    for got, want in zip(paper, w[:3]):
        assert abs(got - want) <= 0.045


def test_option_dropped_without_variants_and_off_at_zero():
    _, none = specs([], variant_pool(with_variants=False))
    assert not any(c.construction == "colour_variant" for s in none for c in s.classes)
    pool = variant_pool()
    _, off = specs(["scene.p_colour_variant=0.0"], pool)
    assert not any(c.construction == "colour_variant" for s in off for c in s.classes)
    with pytest.raises(ConfigError, match="p_colour_variant"):
        load_config([], ["scene.p_colour_variant=1.0"])


def test_two_variants_with_one_caption_never_share_a_scene():
    """Captions of variant members must differ; where a captioner failed them, the unique-prompt rule
    keeps the pair apart (the option is then infeasible for that class)."""
    pool = variant_pool(same_captions=True)
    by_id = {o.object_id: o for o in pool}
    cfg, all_specs = specs(["scene.p_colour_variant=0.9"], pool)
    for s in all_specs:
        objects = [c.object_id for c in s.classes] + [d.object_id for d in s.distractors]
        assert not any(b in by_id[a].variants for a in objects for b in objects), s.scene_id
        assert not any(c.construction == "colour_variant" for c in s.classes)


def test_catalog_variants_stay_active_share_a_split_and_reach_the_pool(catalog, tmp_path):
    objs = library_catalog(catalog, tmp_path)
    ids = {k: o.id for k, o in objs.items()}
    run_filter(catalog, quick_config())
    summary = assign_splits(catalog, quick_config("split.train_fraction=0.4", "split.val_fraction=0.3").split)
    assert sum(summary.totals().values()) >= 8 and not summary.leaks
    assert check_splits(catalog) == []
    with catalog.session() as s:
        flags = {(f.object_id, f.pair_object_id) for f in s.query(Flag).filter(Flag.kind == "colour_variant")}
        pool = {o.object_id: o for o in load_pool(s)}
    cyl, other = ids["cyl"], ids["cyl_recolour"]
    assert flags == {(cyl, other), (other, cyl)}
    assert pool[cyl].split == pool[other].split  # one group, one split
    assert pool[cyl].variants == (other,) and pool[other].variants == (cyl,)
    assert all(not o.variants for k, o in pool.items() if k not in (cyl, other))
    # a scene of that split may hold the pair as two classes
    cfg = load_config([], ["scene.spawn_max_tries=1", "scene.p_colour_variant=0.9", "scene.n_classes=[2, 2]",
                           "scene.n_objects=[4, 8]"])
    split = pool[cyl].split
    pairs = 0
    for seed in range(200):
        spec = sample_scene(seed, split, cfg, list(pool.values()))
        classes = {c.object_id for c in spec.classes}
        pairs += {cyl, other} <= classes
        for c in spec.classes:
            if c.construction == "colour_variant":
                assert {c.object_id, spec.classes[c.base_class_index].object_id} == {cyl, other}
    assert pairs > 0


def test_variants_carry_through_duplicate_groups(catalog, tmp_path):
    """A recolour of an excluded copy is a recolour of the object kept in its place."""
    objs = library_catalog(catalog, tmp_path)
    a, b, c = objs["cone"].id, objs["capsule"].id, objs["ring"].id
    with catalog.session() as s:
        s.add_all([Flag(object_id=a, kind="near_duplicate_appearance", score=1.0, reason="t", pair_object_id=b),
                   Flag(object_id=b, kind="near_duplicate_appearance", score=1.0, reason="t", pair_object_id=a),
                   Flag(object_id=b, kind="colour_variant", score=1.0, reason="t", pair_object_id=c),
                   Flag(object_id=c, kind="colour_variant", score=1.0, reason="t", pair_object_id=b)])
        s.commit()
        found = colour_variants(s)
    assert found[a] == {c} and found[b] == {c} and found[c] == {a, b}
