"""Count targets (issue 37) without Blender: parsing and its errors, the draws (reproducible by seed, on their
own stream), the per-class split, the sampler's spawn for a target, the paper's rule untouched, the worker's
which-body-may-go decisions and the statistics. The worker path itself runs in tests/test_benches.py
(bench/counts.py --smoke: real bpy scenes brought to their target)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from library_pool import library_pool

from mixcount.config import load_config
from mixcount.counts import worker_decisions as C
from mixcount.counts.targets import (
    draw_elevations,
    draw_total,
    elevation_factor,
    parse_count_target,
    reserve_counts,
    reserve_instances,
    spawn_counts,
    split_total,
)
from mixcount.errors import ConfigError
from mixcount.evaluate.count_stats import count_lines, dataset_count_stats, ks_distance, plot_counts, summarise_counts
from mixcount.scene.sampler import sample_scene


@pytest.mark.parametrize("text, message", [
    ("uniform:5", "LOW-HIGH"), ("uniform:0-5", "start at 1"), ("uniform:9-3", "low end above"),
    ("poisson:4", "expected paper, uniform"), ("uniform:1-9,skew:2", "unknown part"),
    ("uniform:1-9,imbalance:0.5-2", ">= 1"), ("paper,imbalance:2-3", "needs a target"),
    ("histogram:/nonexistent/h.txt", "does not exist"),
])
def test_bad_targets_are_named(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_count_target(text)


def test_histogram_file(tmp_path: Path) -> None:
    path = tmp_path / "pairtally_like.txt"
    path.write_text("# count weight\n14 1\n112, 3\n\n1147 1  # the densest\n112 1\n")
    dist = parse_count_target(f"histogram:{path}")
    assert dist.counts == (14, 112, 1147) and dist.weights == (1.0, 4.0, 1.0)
    draws = [draw_total(dist, s) for s in range(600)]
    assert set(draws) == {14, 112, 1147}
    assert abs(draws.count(112) / 600 - 4 / 6) < 0.06
    bad = tmp_path / "bad.txt"
    bad.write_text("14 1\nmany 2\n")
    with pytest.raises(ConfigError, match=r"bad.txt:2: expected 'count weight'"):
        parse_count_target(f"histogram:{bad}")


def test_draws_reproducible_and_split() -> None:
    dist = parse_count_target("uniform:1-200")
    totals = [draw_total(dist, s) for s in range(2000)]
    assert totals == [draw_total(dist, s) for s in range(2000)]
    assert min(totals) == 1 and max(totals) == 200 and abs(np.mean(totals) - 100.5) < 4
    for s in range(200):
        counts, ratio = split_total(dist, s, 40, 3)
        assert sum(counts) == 40 and min(counts) >= 1 and ratio is None
    imb = parse_count_target("uniform:1-200,imbalance:3-5")
    for s in range(200):
        counts, ratio = split_total(imb, s, 120, 4)
        assert sum(counts) == 120 and min(counts) >= 1 and ratio is not None and 3 <= ratio <= 5
        assert abs(max(counts) / min(counts) - ratio) <= 0.5 * ratio / min(counts) + 0.15
    assert spawn_counts([1, 10], 1.5, 2) == [4, 17]
    assert elevation_factor(90.0, 0.45) == pytest.approx(1.0) and elevation_factor(20.0, 0.45) > 1.7
    # the smaller class (half the size) spawns sqrt(2) x more; + ceil(sqrt(target))
    assert spawn_counts([16, 16], 1.0, 0, [1.0, 0.5], 0.5, 1.0) == [16 + 4, 23 + 4]


def test_sampler_spawns_for_the_target_and_paper_rule_is_untouched() -> None:
    pool = library_pool()
    paper = load_config([], [])
    assert paper.scene.count_target == "paper"
    explicit = load_config([], ["scene.count_target=paper"])
    for seed in range(20):
        spec = sample_scene(seed, "train", paper, pool)
        assert "count_target" not in spec.to_dict() and spec.count_target is None
        assert 30 <= spec.n_counted <= 200
        assert spec.to_json() == sample_scene(seed, "train", explicit, pool).to_json()
    cfg = load_config([], ["scene.count_target=uniform:1-200,imbalance:2-4"])
    for seed in range(20):
        spec = sample_scene(seed, "train", cfg, pool)
        t = spec.count_target
        assert t is not None and t["total"] == draw_total(parse_count_target(t["distribution"]), seed)
        assert sum(t["per_class"]) == t["total"] and len(t["per_class"]) == len(spec.classes)
        elevations = draw_elevations(seed, cfg.scene.n_cameras, cfg.scene.camera_elevation_deg)
        assert [c.elevation_deg for c in spec.cameras] == pytest.approx(elevations, abs=1e-5)
        factor = cfg.scene.count_spawn_factor[1 if spec.container is not None else 0] * elevation_factor(
            min(elevations), cfg.scene.count_spawn_elevation)
        assert t["spawn_factor"] == factor
        sizes = [c.target_size_m for c in spec.classes]
        spawn = spawn_counts(t["per_class"], factor, cfg.scene.count_spawn_extra, sizes,
                             cfg.scene.count_spawn_size_exponent, cfg.scene.count_spawn_sqrt)
        assert t["reserve"] == reserve_counts(t["per_class"], cfg.scene.count_reserve)
        assert [c.count for c in spec.classes] == [a + r for a, r in zip(spawn, t["reserve"])]
        assert all(a >= n + cfg.scene.count_spawn_extra for a, n in zip(spawn, t["per_class"]))
        assert t["topup_rounds"] == cfg.scene.count_topup_rounds and t["rest_frames"] == cfg.scene.count_rest_frames
        assert t["short_total"] == max(2, int(0.05 * t["total"]))
        assert spec.to_json() == sample_scene(seed, "train", cfg, pool).to_json()  # reproducible by seed
        assert type(spec).from_json(spec.to_json()) == spec


def _box(x: float, y: float, z: float, s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    return np.array([x - s / 2, y - s / 2, z - s / 2]), np.array([x + s / 2, y + s / 2, z + s / 2])


def test_only_bodies_that_support_nothing_go() -> None:
    # a column of three boxes of class 0 and a box of class 1 beside it, all touching the floor's column
    boxes = [_box(0, 0, 0.5), _box(0, 0, 1.5), _box(0.1, 0, 2.5), _box(3, 0, 0.5)]
    lo = np.array([b[0] for b in boxes])
    hi = np.array([b[1] for b in boxes])
    resting = C.rests_on(lo, hi, np.full(4, 0.05))
    assert resting[0, 1] and resting[1, 2] and not resting[2, 1] and not resting[0, 3] and not resting[3, 0]
    removed, left = C.surplus_to_remove([0, 0, 0, 1], {0: 1, 1: 1}, resting, np.random.default_rng(0))
    assert removed == [2, 1] and left == {}  # top first, then the one it uncovered; the bottom one stays
    # class 1 stands on a box of class 0: that box cannot go, and its surplus is reported
    boxes = [_box(0, 0, 0.5), _box(0, 0, 1.5), _box(5, 0, 0.5)]
    lo, hi = np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes])
    removed, left = C.surplus_to_remove([0, 1, 0], {0: 0, 1: 1}, C.rests_on(lo, hi, np.full(3, 0.05)),
                                        np.random.default_rng(0))
    assert removed == [2] and left == {0: 1}


def test_hull_contact_is_tighter_than_boxes() -> None:
    # two unit cubes whose boxes overlap in XY, the upper one 0.3 above the lower one: boxes say "may
    # rest" (tolerance 0.5), the hulls are 0.3 apart, more than a tolerance of 0.1
    cube = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    from mixcount.scene_decisions import hull_equations

    eq = hull_equations(cube)
    mats = [np.eye(4), np.eye(4)]
    mats[1][:3, 3] = [0.2, 0.0, 1.3]
    pts = [cube + m[:3, 3] for m in mats]
    lo = np.array([p.min(0) for p in pts])
    hi = np.array([p.max(0) for p in pts])
    assert C.rests_on(lo, hi, np.full(2, 0.5))[0, 1]
    assert not C.rests_on_hulls(pts, mats, [eq, eq], lo, hi, np.full(2, 0.1))[0, 1]
    assert C.rests_on_hulls(pts, mats, [eq, eq], lo, hi, np.full(2, 0.35))[0, 1]
    assert C.hull_distance(pts[1], mats[0], eq) == pytest.approx(0.3)


def test_count_verdict_and_resolution_needed() -> None:
    assert C.count_verdict({0: 10, 1: 5}, {0: 10, 1: 5}, 2, 1) is None
    assert C.count_verdict({0: 10, 1: 5}, {0: 10, 1: 4}, 2, 1) is None
    assert C.count_verdict({0: 10, 1: 5}, {0: 10, 1: 3}, 2, 1) == "count_short"
    assert C.count_verdict({0: 10, 1: 5}, {0: 14, 1: 5}, 2, 1) == "count_over"
    assert C.pixels_needed(100.0, 512, 64.0) is None
    assert C.pixels_needed(16.0, 512, 64.0) == 1024


def test_stats_of_a_dataset(tmp_path: Path) -> None:
    scenes = tmp_path / "scenes"
    for i, (target, kept) in enumerate([(10, 10), (50, 50), (120, 118)]):
        d = scenes / f"scene_{i:06d}"
        d.mkdir(parents=True)
        per_t = {"101": target - target // 3, "202": target // 3}
        per_k = {"101": per_t["101"] - (target - kept), "202": per_t["202"]}
        objects = [{"role": "counted", "status": "kept"}] * kept + [{"role": "counted", "reason": "count_surplus"}] * 3
        meta = {"scene_id": d.name, "seed": i, "counts": per_k, "objects": objects,
                "count_target": {"total": target, "per_class": per_t, "distribution": "uniform:1-200",
                                 "imbalance": 2.0},
                "diagnostics": [{"kind": "count_target", "median_visible_px": 30.0,
                                 "too_small": {"min_object_px": 64.0, "resolution_needed": 188}}]}
        if i:  # scenes 1 and 2 checked once more, whole (scene.count_rest_verify)
            meta["diagnostics"].append({"kind": "count_rest_verify", "bodies": kept, "fell": i - 1,
                                        "fell_over_half_size": 0, "largest_drop_x_size": 0.05 * i})
        (d / "metadata.json").write_text(json.dumps(meta))
    (scenes / ".rejected").mkdir()
    (scenes / ".rejected" / "scene_000009.json").write_text(json.dumps({
        "scene_id": "scene_000009", "seed": 9, "status": "rejected",
        "diagnostics": [{"kind": "count_target", "verdict": "count_short", "kept": 80, "total": 95}]}))
    stats = dataset_count_stats(tmp_path)
    assert stats is not None
    assert (stats["scenes"], stats["exact"], stats["within_tolerance"], stats["max_abs_miss"]) == (3, 2, 3, 2)
    assert stats["regenerated_scenes"][0]["why"] == "count_short: kept 80 of 95"
    assert stats["per_class"] == {"classes": 6, "within_one": 5, "exact": 5, "max_off": 2}
    assert stats["surplus_removed"] == 9 and len(stats["too_small"]) == 3
    assert stats["rest_verified"] == {"scenes": 2, "scenes_with_a_fall": 1, "fell": 1, "fell_over_half_size": 0,
                                      "largest_drop_x_size": 0.1}
    assert "rest_verified" not in summarise_counts(stats["rows"][:1], [])  # no scene checked: no figure
    text = "\n".join(count_lines(stats))
    assert "2 of 3 scenes kept exactly their target" in text and "count_short: kept 80 of 95" in text
    assert "188 px per side" in text
    assert "verified (the finished pile simulated again, whole): 1 of 2 scenes" in text
    png = plot_counts(stats, stats["rows"], tmp_path / "stats" / "count_target.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000
    # KS: kept equal to a point mass target -> 0; half the mass off -> 0.5
    assert ks_distance([5, 5], lambda xs: (np.asarray(xs) >= 5).astype(float)) == 0.0
    assert ks_distance([5, 9], lambda xs: (np.asarray(xs) >= 5).astype(float)) == 0.5
    assert summarise_counts([], [])["scenes"] == 0


def test_reserve_is_each_class_top_instances() -> None:
    assert reserve_counts([10, 1], [0.6, 3]) == [9, 4]
    classes = [0, 1, 0, 0, 1, 0]
    ids = [1, 2, 3, 4, 5, 6]
    assert reserve_instances(classes, ids, [2, 1]) == [4, 5, 6]
    assert reserve_instances(classes, ids, [0, 0]) == []


def test_topup_draw_and_short_classes() -> None:
    short = C.short_classes({0: 10, 1: 5, 2: 3}, {0: 10, 1: 2, 2: 1})
    assert short == {1: 3, 2: 2}
    # ceil(1.5 x lacking) + 1, capped by the reserve; a class with no reserve left gets nothing
    assert C.topup_draw(short, {1: 20, 2: 2}, 1.5) == {1: 6, 2: 2}
    assert C.topup_draw(short, {1: 0}, 1.5) == {}
    # per class: ceil(3 x 3) + 1 = 10 for class 1, class 2 at the default 1.5 is capped by its 2
    assert C.topup_draw(short, {1: 20, 2: 2}, {1: 3.0, 2: 1.5}) == {1: 10, 2: 2}


def test_topup_factors_follow_each_class_yield() -> None:
    """A class that kept 1 of 4 bodies dropped for it gets 4 per lacking object; one that kept them all
    still gets the floor factor; a class with no yield yet (or a zero yield) the cap."""
    short = {0: 5, 1: 5, 2: 5, 3: 5}
    f = C.topup_factors(short, {0: 0.25, 1: 1.0, 2: 0.0, 3: 0.5}, 1.5, 4.0)
    assert f == {0: 4.0, 1: 1.5, 2: 4.0, 3: 2.0}
    assert C.topup_factors(short, {}, 1.5, 4.0) == {c: 1.5 for c in short}  # unknown yield: the floor
    assert C.topup_factors({0: 2}, {0: 0.1}, 1.5, 4.0) == {0: 4.0}  # capped


def test_a_local_rest_check_wakes_the_bodies_near_what_changed() -> None:
    """near_boxes: bodies whose AABB overlaps a changed body's box grown by its margin (beside it, under
    it, on it) are woken; bodies farther than the margin are not."""
    from types import SimpleNamespace

    from mixcount.engine.count_topup import changed_boxes, near_boxes

    def box(x, z=0.0):  # a unit cube at (x, 0, z)
        return np.array([x - 0.5, -0.5, z - 0.5]), np.array([x + 0.5, 0.5, z + 0.5])

    # 0 changed (at x=0); 1 beside it, touching; 2 on it; 3 a gap of 0.4 (< margin 0.5 x size 1); 4 far away
    bounds = {0: box(0.0), 1: box(1.0), 2: box(0.0, 1.0), 3: box(1.4), 4: box(5.0)}
    objects = [SimpleNamespace(size_m=1.0) for _ in range(5)]
    state = SimpleNamespace(bounds=bounds, objects=objects)
    boxes = changed_boxes(state, [0])
    assert len(boxes) == 1 and boxes[0][2] == 0.5
    assert near_boxes(state, [1, 2, 3, 4], boxes) == [1, 2, 3]
    assert near_boxes(state, [1, 2, 3, 4], []) == []
    assert changed_boxes(state, [7]) == []  # no box recorded: nothing to wake around


def test_drop_spots_fall_onto_the_pile_without_overlap() -> None:
    rng = np.random.default_rng(4)
    sizes = [0.05] * 30 + [0.08] * 5
    box = (np.array([-0.2, -0.1]), np.array([0.2, 0.1]))
    spots = C.drop_spots(*box, 0.3, sizes, rng, room=box)
    assert spots.shape == (35, 3)
    assert (spots[:, 2] > 0.3).all()  # above the pile's top
    assert (np.abs(spots[:, 0]) <= 0.2).all() and (np.abs(spots[:, 1]) <= 0.1).all()  # inside its room
    d = np.linalg.norm(spots[:, None, :] - spots[None, :, :], axis=2) + np.eye(35)
    assert d.min() >= 0.8 * 1.2 * 0.08  # one cell (1.2 x the largest) apart, less the jitter
    again = C.drop_spots(*box, 0.3, sizes, np.random.default_rng(4), room=box)
    assert np.array_equal(spots, again)
    # a footprint smaller than a cell, no room to grow: a column over its centre
    tiny = (np.array([0.0, 0.0]), np.array([0.01, 0.01]))
    col = C.drop_spots(*tiny, 0.0, [0.05] * 3, rng, room=tiny)
    assert np.allclose(col[:, :2], 0.005, atol=0.1 * 0.06 + 1e-9) and len(set(np.round(col[:, 2], 6))) == 3
    # with room (on the floor, or a wide container) the box grows about its centre to one layer: no tower
    free = C.drop_spots(*tiny, 0.0, [0.05] * 5, rng)
    assert len(set(np.round(free[:, 2], 6))) == 1
    assert np.allclose(free[:, :2].mean(axis=0), 0.005, atol=0.06)
    walls = (np.array([-0.06, -0.06]), np.array([0.07, 0.07]))  # a container's room: the box stops at it
    held = C.drop_spots(*tiny, 0.0, [0.05] * 5, rng, room=walls)
    assert (held[:, :2] >= -0.06 - 0.01).all() and (held[:, :2] <= 0.07 + 0.01).all()


def test_displacements() -> None:
    a = np.stack([np.eye(4)] * 2)
    b = a.copy()
    b[1, :3, 3] = [0.0, 0.3, 0.4]
    assert C.displacements(a, b).tolist() == pytest.approx([0.0, 0.5])


def test_a_target_container_holds_its_expected_need_and_shrinks_whole() -> None:
    """Issue 48: the container of a target scene is fitted to its expected need, per class the first
    ceil(count_container_need x target) bodies (neither the low camera's margin nor the reserve), as a paper
    scene's to its whole spawn; a container shrunk to its pile shrinks whole (no deep pit), one widened
    keeps its real height."""
    from test_scene_distributions import rich_pool

    pool = rich_pool()
    by_id = {o.object_id: o for o in pool}
    seen, fits = 0, []
    for seed, target in [(s, t) for t in ("uniform:20-200", "uniform:1-3") for s in range(40)]:
        cfg = load_config([], [f"scene.count_target={target}"])
        lo, hi = cfg.scene.container_pile_area
        spec = sample_scene(seed, "train", cfg, pool)
        if spec.container is None:
            continue
        seen += 1
        t = spec.count_target
        assert t is not None
        f_need = cfg.scene.count_container_need
        assert t["need"] == [min(sum(1 for o in spec.objects if o.class_index == c) - r, math.ceil(f_need * a - 1e-9))
                             for c, (r, a) in enumerate(zip(t["reserve"], t["per_class"]))]
        per_class = [sorted((o for o in spec.objects if o.class_index == c), key=lambda o: o.instance_id)
                     for c in range(len(t["need"]))]
        first = [o for c, need in enumerate(t["need"]) for o in per_class[c][:need]]
        # a need below the paper's smallest spawn is made up from the rest of the first settle
        rest = [o for c, (need, r) in enumerate(zip(t["need"], t["reserve"])) for o in per_class[c][need:len(per_class[c]) - r]]
        first += rest[: max(0, cfg.scene.n_objects[0] - len(first))]
        assert t["frame_need"] == len(first)
        area = spec.container.extent_m[0] * spec.container.extent_m[1]
        assert lo * (1 - 1e-3) <= area / sum(o.size_m ** 2 for o in first) <= hi * (1 + 1e-3)
        ratio = np.asarray(spec.container.extent_m) / np.asarray(by_id[spec.container.object_id].dims)
        f = spec.container.pile_fit
        fits.append(f)
        ratio = ratio / cfg.scene.scale / np.array([f, f, min(f, 1.0)])  # what is left is the per-axis jitter
        assert np.all(ratio >= cfg.scene.container_scale_jitter[0] - 1e-4)
        assert np.all(ratio <= cfg.scene.container_scale_jitter[1] + 1e-4)
    assert seen >= 5 and min(fits) < 1.0 < max(fits)  # both shrunk and widened containers were checked
