"""Spawn order and initial height are independent of class index (a random class per spawn position).

The test: 500 dry-run specs (pure sampler) at the default config from a catalog-shaped pool. Per scene,
the Spearman rank correlation between the instances' class index and (a) their spawn order, (b) their
initial height. Scenes are independent, so under independence the mean of the per-scene correlations
is 0 with standard error sd / sqrt(n); the test asks |mean| / se < 4 (two-sided p ~ 6e-5 for a correct
sampler) and |mean| < 0.05. Class-by-class spawning gave mean correlations of 0.82 (order, t = 129)
and 0.32 (height, t = 22) here; a random class per spawn position gives 0.004 (t = 0.8) and -0.001
(t = -0.1).

Class sizes are made exchangeable across class indices (``p_same_object_resized = 0``): a resized copy's
size is drawn relative to its base class and is smaller on average, and larger objects find fewer free
spots and start higher. That is an effect of size, not of class order; with it switched off, the only
way class index could reach height is through the order of placement.
"""

from __future__ import annotations

import numpy as np
import pytest
from library_pool import library_pool
from scipy import stats

from mixcount.config import load_config
from mixcount.scene.sampler import sample_scene

N_SCENES = 500
T_MAX = 4.0
MEAN_MAX = 0.05


@pytest.fixture(scope="module")
def specs():
    conf = load_config([], ["scene.p_same_object_resized=0.0"])
    pool = library_pool()
    return [sample_scene(seed, "train", conf, pool) for seed in range(N_SCENES)]


def _mean_and_t(values: list[float]) -> tuple[float, float]:
    v = np.asarray(values)
    return float(v.mean()), float(v.mean() / (v.std(ddof=1) / np.sqrt(len(v))))


def _per_scene_correlations(specs) -> tuple[list[float], list[float]]:
    order, height = [], []
    for s in specs:
        if len(s.classes) < 2:
            continue
        cls = np.array([o.class_index for o in s.objects])
        z = np.array([o.position[2] for o in s.objects])
        order.append(stats.spearmanr(cls, np.arange(len(cls))).statistic)
        height.append(stats.spearmanr(cls, z).statistic)
    return order, height


def test_spawn_order_and_height_do_not_depend_on_class_index(specs):
    order, height = _per_scene_correlations(specs)
    assert len(order) >= 0.95 * N_SCENES
    for name, values in (("spawn order", order), ("initial height", height)):
        mean, t = _mean_and_t(values)
        assert abs(t) < T_MAX and abs(mean) < MEAN_MAX, (name, mean, t)


def test_every_class_index_reaches_the_top_of_the_pile(specs):
    """Each class index spawns highest in about its share of scenes (the last class no longer always does)."""
    top = {k: 0 for k in range(4)}
    expected = {k: 0.0 for k in range(4)}
    for s in specs:
        highest = max(s.objects, key=lambda o: o.position[2])
        top[highest.class_index] += 1
        for c in s.classes:
            expected[c.class_index] += c.count / s.n_counted
    for k in top:
        if expected[k] >= 20:
            # binomial-ish count: within 4.5 sd of its expectation
            assert abs(top[k] - expected[k]) < 4.5 * np.sqrt(expected[k]) + 2, (k, top, expected)


def test_instances_interleave_classes(specs):
    s = next(s for s in specs if len(s.classes) >= 3 and s.n_counted >= 60)
    labels = [o.class_index for o in s.objects]
    runs = 1 + sum(a != b for a, b in zip(labels, labels[1:]))
    assert runs > len(s.classes) * 3  # class by class would give exactly one run per class
    assert sorted(labels) == sorted(i for c in s.classes for i in [c.class_index] * c.count)
    assert [o.instance_id for o in s.objects] == list(range(1, s.n_counted + 1))
