"""Scene sampler rules on a plain pool (no database): determinism, placement, cameras, config checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_scene_distributions import rich_pool

from mixcount.config import Config, load_config
from mixcount.errors import CompositionError, ConfigError
from mixcount.scene.object_records import ObjectRecord
from mixcount.scene.sampler import qualify, sample_scene
from mixcount.scene.spec import Captions, SceneSpec


def quat_rotate(q, v):
    w, x, y, z = q
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    return r @ np.asarray(v, dtype=float)


@pytest.fixture(scope="module")
def conf() -> Config:
    return load_config()


def test_same_seed_same_spec_and_json_round_trip(conf):
    pool = rich_pool()
    a = sample_scene(11, "train", conf, pool)
    b = sample_scene(11, "train", conf, list(reversed(pool)))  # pool order must not matter
    c = sample_scene(12, "train", conf, pool)
    assert a.to_json() == b.to_json()
    assert a.to_json() != c.to_json()
    back = SceneSpec.from_json(a.to_json())
    assert back == a
    assert a.scene_id == "scene_000011" and a.seed == 11 and a.config_hash == conf.hash


def test_scale_is_applied_consistently(conf):
    pool = rich_pool()
    by_id = {o.object_id: o for o in pool}
    for seed in range(30):
        s = sample_scene(seed, "train", conf, pool)
        for o in s.objects + s.distractors:
            # asset (real metres) x scale = size in the scene
            assert max(by_id[o.object_id].dims) * o.scale[0] == pytest.approx(o.size_m, rel=1e-4)
        if s.container is not None:
            real = np.asarray(by_id[s.container.object_id].dims)
            # per-axis jitter x s, then the pile fit on X and Y only
            f = s.container.pile_fit
            fit = np.array([f, f, min(f, 1.0)])  # shrunk whole, widened in X and Y (issue 48)
            ratio = np.asarray(s.container.extent_m) / real / conf.scene.scale / fit
            assert np.all(ratio >= conf.scene.container_scale_jitter[0] - 1e-4)
            assert np.all(ratio <= conf.scene.container_scale_jitter[1] + 1e-4)
            # the fitted box holds its pile: area / sum of counted sizes squared within the configured range
            footprint = sum(o.size_m ** 2 for o in s.objects)
            area_ratio = s.container.extent_m[0] * s.container.extent_m[1] / footprint
            lo, hi = conf.scene.container_pile_area
            assert lo * (1 - 1e-3) <= area_ratio <= hi * (1 + 1e-3)
            # the floor reaches past the container's corners by the margin
            reach = float(np.hypot(*s.container.extent_m[:2])) / 2 + conf.scene.floor_pile_margin * conf.scene.scale
            assert min(s.floor.half_extent) >= reach - 1e-3
        assert s.floor.uv_scale_m / conf.scene.scale == pytest.approx(
            np.clip(s.floor.uv_scale_m / conf.scene.scale, *conf.scene.floor_uv_scale), rel=1e-6)


@pytest.mark.parametrize("waves", [True, False])
def test_spawn_positions_inside_ellipse_and_height_range(conf, waves):
    """With spawn waves (the default) every spot lies in the height range (later waves plus the
    clearance) and bodies that found no room are released later; without them they are stacked above."""
    pool = rich_pool()
    s_ = conf.scene.scale
    # containers at their real size x jitter (no pile fit), so dense scenes must stack or wait
    real_size = ["scene.container_pile_area=[0.0001, 1e9]"]
    conf = load_config([], real_size + ([] if waves else ["scene.spawn_release_waves=false"]))
    clearance, interval = conf.scene.spawn_wave_clearance * s_, conf.scene.spawn_wave_interval_frames
    checked = stacked = later = 0
    for seed in range(60):
        s = sample_scene(seed, "train", conf, pool)
        if s.container is None:
            lo, hi = conf.scene.spawn_xy_no_container[0] * s_, conf.scene.spawn_xy_no_container[1] * s_
            for o in s.objects:
                assert lo - 1e-6 <= o.position[0] <= hi + 1e-6 and lo - 1e-6 <= o.position[1] <= hi + 1e-6
                assert conf.scene.spawn_height[0] * s_ - 1e-6 <= o.position[2]
            continue
        c = s.container
        yaw = 2 * math.atan2(c.orientation[3], c.orientation[0])
        a = max(c.extent_m[0] / 2 - conf.scene.spawn_margin * s_, conf.scene.spawn_min_semi_axis * s_)
        b = max(c.extent_m[1] / 2 - conf.scene.spawn_margin * s_, conf.scene.spawn_min_semi_axis * s_)
        top = c.extent_m[2]
        for o in s.objects:
            x, y = o.position[0], o.position[1]
            lx = math.cos(yaw) * x + math.sin(yaw) * y  # into the container's frame
            ly = -math.sin(yaw) * x + math.cos(yaw) * y
            assert (lx / a) ** 2 + (ly / b) ** 2 <= 1 + 1e-4
            assert top + conf.scene.spawn_height[0] * s_ - 1e-5 <= o.position[2]
            assert (o.release_frame - 1) % interval == 0 and (waves or o.release_frame == 1)
            if o.release_frame > 1:
                later += 1  # no free spot in the range: a later wave, lowered into the range
                assert o.position[2] <= top + conf.scene.spawn_height[1] * s_ + clearance + 1e-5
            elif o.position[2] > top + conf.scene.spawn_height[1] * s_ + 1e-5:
                stacked += 1  # no free spot in the range: lifted above its column (spawn_stack)
            checked += 1
        # distractors stand outside the container's box and apart from each other
        for i, d in enumerate(s.distractors):
            lx = math.cos(yaw) * d.position[0] + math.sin(yaw) * d.position[1]
            ly = -math.sin(yaw) * d.position[0] + math.cos(yaw) * d.position[1]
            assert (lx / (c.extent_m[0] / 2)) ** 2 + (ly / (c.extent_m[1] / 2)) ** 2 > 1
            for e in s.distractors[i + 1:]:
                assert math.dist(d.position[:2], e.position[:2]) > 0.5 * (d.size_m + e.size_m) * 0.5
    # dense default scenes do need the stacking, as waves or as height
    assert checked > 0 and (later > 0 and stacked == 0 if waves else stacked > 0 and later == 0)


def test_spawn_spheres_do_not_overlap(conf):
    """Bodies in the air together (one release wave) never start overlapping (containers at their real
    size, so dense scenes need waves)."""
    conf = load_config([], ["scene.container_pile_area=[0.0001, 1e9]"])
    waves = 0
    for seed in range(15):
        s = sample_scene(seed, "train", conf, rich_pool())
        for frame in sorted({o.release_frame for o in s.objects}):
            wave = [o for o in s.objects if o.release_frame == frame]
            pos = np.array([o.position for o in wave])
            r = np.array([o.size_m / 2 for o in wave])
            gap = np.linalg.norm(pos[:, None] - pos[None], axis=2) - (r[:, None] + r[None])
            np.fill_diagonal(gap, 1.0)
            assert gap.min() >= -1e-5, (seed, frame, len(pos))
            waves += frame > 1
    assert waves > 0
    loose = load_config([], ["scene.spawn_stack=false", "scene.n_objects=[200, 200]"])
    s = sample_scene(0, "train", loose, rich_pool())
    assert max(o.position[2] for o in s.objects) <= (s.container.extent_m[2] if s.container else 0) + 15.0 + 1e-5


def test_instance_ids_unique_and_ordered(conf):
    s = sample_scene(5, "train", conf, rich_pool())
    ids = [o.instance_id for o in s.objects] + [d.instance_id for d in s.distractors]
    if s.container is not None:
        ids.append(s.container.instance_id)
    assert ids == list(range(1, len(ids) + 1))
    assert all(o.role == "counted" and o.class_index >= 0 for o in s.objects)
    for o in s.objects:
        assert np.linalg.norm(o.orientation) == pytest.approx(1.0, abs=1e-5)


def test_camera_looks_at_target_with_roll_and_distance(conf):
    for seed in range(40):
        s = sample_scene(seed, "train", conf, rich_pool())
        for cam in s.cameras:
            pos, target = np.asarray(cam.position), np.asarray(cam.look_at)
            forward = quat_rotate(cam.orientation, [0, 0, -1])
            want = (target - pos) / np.linalg.norm(target - pos)
            assert np.dot(forward, want) == pytest.approx(1.0, abs=1e-5)
            assert np.linalg.norm(target - pos) == pytest.approx(cam.distance, rel=1e-5)
            elev = math.degrees(math.asin(want[2] * -1))
            assert elev == pytest.approx(cam.elevation_deg, abs=1e-3)
            # roll: angle between the camera's up and the world-up projection on the image plane
            up = quat_rotate(cam.orientation, [0, 1, 0])
            right = quat_rotate(cam.orientation, [1, 0, 0])
            assert abs(right[2]) == pytest.approx(abs(math.sin(math.radians(cam.roll_deg))) * math.cos(
                math.asin(-want[2])), abs=1e-4)
            assert up[2] > 0  # never upside down
            assert cam.resolution == (conf.compose.resolution, conf.compose.resolution)


def test_split_and_status_are_respected(conf):
    pool = rich_pool()
    for seed in range(40):
        s = sample_scene(seed, "val", conf, pool)
        ids = {c.object_id for c in s.classes} | {d.object_id for d in s.distractors}
        assert all(o.split == "val" for o in pool if o.object_id in ids)
    with pytest.raises(CompositionError):
        sample_scene(0, "test", conf, pool)  # nothing in test


def test_tiny_pool_degrades_gracefully(conf):
    pool = [ObjectRecord(1, "lonely cube", "cube", (0.05, 0.05, 0.05), Captions("cube", "a cube", "a cube"),
                         "train", "/x.glb", "h1")]
    s = sample_scene(3, "train", conf, pool)
    # one object can still give two classes (two sizes) but never a distractor or a container
    assert 1 <= len(s.classes) <= 2 and not s.distractors and s.container is None
    assert sum(c.count for c in s.classes) == s.n_counted


def test_qualifier_replaces_the_size_word():
    assert qualify("golden yellow apple", "smaller") == "smaller golden yellow apple"
    assert qualify("Fancy tomato ketchup toy", "larger") == "Larger fancy tomato ketchup toy"
    assert qualify("LEGO brick", "larger") == "Larger LEGO brick"
    assert qualify("A large white bottle", "smaller") == "A smaller white bottle"
    assert qualify("apple", None) == "apple"


def test_config_rejects_bad_values():
    with pytest.raises(ConfigError):
        load_config([], ["scene.no_such_key=1"])
    with pytest.raises(ConfigError):
        load_config([], ["scene.p_same_category=-1.0"])
    with pytest.raises(ConfigError):
        load_config([], ["scene.n_classes=[3, 2]"])
    with pytest.raises(ConfigError):
        load_config([], ['scene.floor_patterns=["zigzag"]'])
    quick = load_config(["quick"])
    assert quick.scene.n_objects == (6, 14) and quick.compose.resolution == 128 and quick.compose.samples == 4
    assert quick.scene.physics_frames == 60
    full = load_config()
    assert full.scene.scale == 10.0 and full.scene.n_objects == (30, 200) and full.scene.n_classes == (2, 4)
    assert full.scene.class_size == (0.045, 0.12) and full.compose.visibility_threshold == 0.4
    assert full.compose.resolution == 1024


def test_several_cameras_share_the_scene():
    conf = load_config([], ["scene.n_cameras=3"])
    s = sample_scene(4, "train", conf, rich_pool())
    assert [c.name for c in s.cameras] == ["cam_0", "cam_1", "cam_2"]
    assert len({c.position for c in s.cameras}) == 3
    one = sample_scene(4, "train", load_config(), rich_pool())
    assert one.classes == s.classes and one.objects == s.objects  # cameras are drawn last
