"""2,000 sampled scene specs against the configured distributions.

Tolerances are about 4 standard errors of each statistic for 2,000 scenes, so a correct sampler
fails with probability well below 1e-3 while a wrong parameter (a range off by 10 %, a probability
off by 0.05) fails reliably. Spawn rejection tries are set to 1 here: placement does not enter any
statistic tested and the full 30 tries only cost time (positions are tested in test_scene_sampler).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mixcount.config import load_config
from mixcount.scene.object_records import ObjectRecord, fallback_captions
from mixcount.scene.sampler import sample_scene

N_SCENES = 2000

pytestmark = pytest.mark.slow  # 2,000 sampled specs: not in the fast tier


def rich_pool() -> list[ObjectRecord]:
    """10 ordinary categories x 6 objects + containers, all in train, plus noise that must never be drawn."""
    pool = []
    oid = 1
    cats = [f"thing{c}" for c in range(10)] + ["plate", "tray", "bowl"]
    for c in cats:
        for j in range(6):
            dims = (0.25, 0.22, 0.03) if c in ("plate", "tray", "bowl") else (0.04 + 0.01 * j, 0.05, 0.03 + 0.004 * j)
            pool.append(ObjectRecord(oid, f"{c} {j}", c, dims, fallback_captions(f"{c} {j}", c), "train",
                                     f"/lib/{oid}.glb", f"h{oid:05d}", container=c in ("plate", "tray", "bowl")))
            oid += 1
    for j in range(5):  # other splits and excluded objects
        pool.append(ObjectRecord(oid, f"val {j}", "thing0", (0.05, 0.05, 0.05), fallback_captions("v", "thing0"),
                                 "val", f"/lib/{oid}.glb", f"h{oid:05d}"))
        oid += 1
        pool.append(ObjectRecord(oid, f"excl {j}", "thing1", (0.05, 0.05, 0.05), fallback_captions("x", "thing1"),
                                 "train", f"/lib/{oid}.glb", f"h{oid:05d}", status="excluded"))
        oid += 1
    return pool


@pytest.fixture(scope="module")
def samples():
    cfg = load_config([], ["scene.spawn_max_tries=1"])
    pool = rich_pool()
    specs = [sample_scene(seed, "train", cfg, pool) for seed in range(N_SCENES)]
    return cfg.scene, pool, specs


def test_counts_and_classes_follow_config(samples):
    conf, _pool, specs = samples
    n = np.array([s.n_counted for s in specs])
    lo, hi = conf.n_objects
    assert n.min() >= lo and n.max() <= hi
    assert n.min() <= lo + 5 and n.max() >= hi - 5  # the whole range is reached
    # UniformInteger[30, 200]: mean 115, sd 49.4 -> standard error 1.1
    assert abs(n.mean() - (lo + hi) / 2) < 4.5
    assert abs(n.std() - math.sqrt(((hi - lo + 1) ** 2 - 1) / 12)) < 3.0
    k = np.array([len(s.classes) for s in specs])
    assert set(k.tolist()) == set(range(conf.n_classes[0], conf.n_classes[1] + 1))
    for v in range(conf.n_classes[0], conf.n_classes[1] + 1):
        assert abs((k == v).mean() - 1 / 3) < 0.045
    for s in specs:
        assert sum(c.count for c in s.classes) == s.n_counted
        assert all(c.count >= 1 for c in s.classes)
        assert s.counts_per_class() == {c.class_index: c.count for c in s.classes}


def test_class_sizes_and_jitter(samples):
    conf, _pool, specs = samples
    lo, hi = conf.class_size[0] * conf.scale, conf.class_size[1] * conf.scale
    fresh = np.array([c.target_size_m for s in specs for c in s.classes if c.construction != "same_object_resized"])
    assert fresh.min() >= lo - 1e-6 and fresh.max() <= hi + 1e-6
    # U[0.45, 1.2] m: mean 0.825, sd 0.2165
    assert abs(fresh.mean() - (lo + hi) / 2) < 0.012
    assert abs(fresh.std() - (hi - lo) / math.sqrt(12)) < 0.01
    ratios = []
    for s in specs:
        sizes = {c.class_index: c.target_size_m for c in s.classes}
        for o in s.objects[:20]:
            j = o.size_m / sizes[o.class_index]
            assert conf.instance_jitter[0] - 1e-5 <= j <= conf.instance_jitter[1] + 1e-5
            ratios.append(j)
        for c in s.classes:
            if c.construction == "same_object_resized":
                base = s.classes[c.base_class_index]
                r = max(c.target_size_m, base.target_size_m) / min(c.target_size_m, base.target_size_m)
                assert r >= conf.resize_ratio[0] - 1e-4
                assert lo - 1e-6 <= c.target_size_m <= hi + 1e-6
                assert {c.size_qualifier, base.size_qualifier} == {"larger", "smaller"}
                bigger = c if c.target_size_m > base.target_size_m else base
                assert bigger.size_qualifier == "larger"
                for tier in ("short", "concise", "detailed"):
                    assert "larger" in getattr(bigger.captions, tier).lower().split()
                    assert "smaller" in getattr(smaller_of(c, base).captions, tier).lower().split()
    assert abs(np.mean(ratios) - 1.0) < 0.002


def smaller_of(a, b):
    return a if a.target_size_m < b.target_size_m else b


def test_class_construction_proportions(samples):
    conf, _pool, specs = samples
    # the second class always has all three options in this pool, so its construction follows the
    # configured probabilities exactly (later classes renormalise when an option is exhausted)
    second = [s.classes[1].construction for s in specs]
    expected = {"same_object_resized": conf.p_same_object_resized, "same_category": conf.p_same_category,
                "other_category": conf.p_other_category}
    total = sum(expected.values())
    for name, p in expected.items():
        assert abs(second.count(name) / len(second) - p / total) < 0.045, name
    for s in specs:
        first = s.classes[0]
        assert first.construction == "first"
        keys = {(c.object_id, c.target_size_m) for c in s.classes}
        assert len(keys) == len(s.classes)  # distinct objects or distinct sizes
        per_object: dict[int, int] = {}
        for c in s.classes:
            per_object[c.object_id] = per_object.get(c.object_id, 0) + 1
            if c.construction == "same_category":
                assert c.category in {d.category for d in s.classes if d.class_index < c.class_index}
            if c.construction == "other_category":
                assert c.category not in {d.category for d in s.classes if d.class_index < c.class_index}
        assert max(per_object.values()) <= 2


def test_container_distractors_and_eligibility(samples):
    conf, pool, specs = samples
    with_container = np.mean([s.container is not None for s in specs])
    assert abs(with_container - (1 - conf.no_container_probability)) < 0.04
    by_id = {o.object_id: o for o in pool}
    nd = []
    for s in specs:
        counted = {c.object_id for c in s.classes}
        ids = counted | {d.object_id for d in s.distractors}
        if s.container is not None:
            assert by_id[s.container.object_id].container
            assert s.container.object_id not in ids
            ids.add(s.container.object_id)
        for oid in ids:
            assert by_id[oid].split == "train" and by_id[oid].status == "active"
        dist_ids = [d.object_id for d in s.distractors]
        assert len(set(dist_ids)) == len(dist_ids) and not set(dist_ids) & counted
        assert all(d.class_index == -1 and d.role == "distractor" for d in s.distractors)
        lo = conf.distractor_base_size * conf.scale * conf.distractor_size_multiplier[0]
        hi = conf.distractor_base_size * conf.scale * conf.distractor_size_multiplier[1]
        assert all(lo - 1e-5 <= d.size_m <= hi + 1e-5 for d in s.distractors)
        nd.append(len(s.distractors))
    nd_arr = np.array(nd)
    assert nd_arr.max() <= conf.n_distractors[1]
    # a few distractors may find no free spot; the count stays close to UniformInteger[2, 8]
    assert abs(nd_arr.mean() - sum(conf.n_distractors) / 2) < 0.3


def test_cameras_follow_config(samples):
    conf, _pool, specs = samples
    elev = np.array([c.elevation_deg for s in specs for c in s.cameras])
    roll = np.array([c.roll_deg for s in specs for c in s.cameras])
    assert elev.min() >= conf.camera_elevation_deg[0] and elev.max() <= conf.camera_elevation_deg[1]
    assert abs(elev.mean() - sum(conf.camera_elevation_deg) / 2) < 1.5
    assert roll.min() >= conf.camera_roll_deg[0] and roll.max() <= conf.camera_roll_deg[1]
    for s in specs[:300]:
        assert len(s.cameras) == conf.n_cameras
        if s.container is not None:
            diag = float(np.linalg.norm(s.container.extent_m))
            for c in s.cameras:
                rel = c.distance / (conf.camera_distance_factor * diag)
                assert 1 - conf.camera_distance_jitter - 1e-6 <= rel <= 1 + conf.camera_distance_jitter + 1e-6
