"""Engine-free checks of the after-physics placement (mixcount.scene.framing) and the container's pile fit."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_scene_distributions import rich_pool

from mixcount.config import load_config
from mixcount.scene.framing import (
    DistractorShape,
    frame_camera,
    image_box,
    in_frame,
    pinhole_of,
    place_distractors,
    rotation_of,
)
from mixcount.scene.sampler import pile_fit_factor, sample_scene
from mixcount.scene.spec import CameraSpec, FloorSpec, MaterialSpec


def _camera(framing: str, **kw: object) -> CameraSpec:
    base = dict(name="cam_0", position=(0.0, -10.0, 10.0), look_at=(0.0, 0.0, 0.0), orientation=(1.0, 0.0, 0.0, 0.0),
                elevation_deg=45.0, azimuth_deg=30.0, roll_deg=5.0, distance=14.0, focal_length_mm=50.0,
                sensor_width_mm=36.0, sensor_height_mm=36.0, resolution=(256, 256), clip_range=(0.01, 1000.0),
                framing=framing, lookat_offset=(0.1, -0.2, 0.05), distance_scale=1.1, distance_factor=1.2,
                fit_share=0.9)
    base.update(kw)
    return CameraSpec(**base)  # type: ignore[arg-type]


def _pile(rng: np.random.Generator, n: int = 80) -> np.ndarray:
    pts = np.c_[rng.normal(3.0, 2.0, n), rng.normal(-1.0, 1.5, n), rng.uniform(0.2, 0.6, n)]
    pts[:3] = [[40.0, 40.0, 0.3], [-35.0, 5.0, 0.3], [0.0, 50.0, 0.3]]  # strays
    return pts


def test_paper_framing_aims_at_the_settled_median_at_the_container_rule() -> None:
    pts = _pile(np.random.default_rng(0))
    framed = frame_camera(_camera("paper"), pts, np.full(len(pts), 0.8), 7.5, margin=0.02)
    cam = framed.camera
    np.testing.assert_allclose(cam.look_at, np.median(pts, axis=0) + np.array([0.1, -0.2, 0.05]), atol=1e-5)
    assert cam.distance == pytest.approx(1.2 * 7.5 * 1.1, rel=1e-6)
    # the pose looks at the look-at point from the drawn angles
    pos, target = np.asarray(cam.position), np.asarray(cam.look_at)
    assert np.linalg.norm(pos - target) == pytest.approx(cam.distance, rel=1e-6)
    assert math.degrees(math.asin((pos[2] - target[2]) / cam.distance)) == pytest.approx(45.0, abs=1e-4)
    forward = -rotation_of(cam)[:, 2]
    np.testing.assert_allclose(forward, (target - pos) / cam.distance, atol=1e-5)
    assert framed.derivation["framing"] == "paper" and "container" in framed.derivation["distance_rule"]
    # without a container the settled footprint's diagonal: the strays do not stretch it
    free = frame_camera(_camera("paper"), pts, np.full(len(pts), 0.8), None, margin=0.02)
    assert free.camera.distance < 1.2 * 1.1 * 20.0
    # a count target's floor pile framed on its expected need's footprint: the distance scales with it,
    # a container scene's does not (its container is fitted to the need instead)
    need = frame_camera(_camera("paper"), pts, np.full(len(pts), 0.8), None, margin=0.02, footprint_scale=0.8)
    assert need.camera.distance == pytest.approx(0.8 * free.camera.distance, rel=1e-6)
    assert need.derivation["footprint_scale"] == 0.8 and "expected need" in need.derivation["distance_rule"]
    boxed = frame_camera(_camera("paper"), pts, np.full(len(pts), 0.8), 7.5, margin=0.02, footprint_scale=0.8)
    assert boxed.camera.distance == pytest.approx(cam.distance, rel=1e-6)


def test_fit_framing_is_the_smallest_distance_holding_the_share() -> None:
    pts = _pile(np.random.default_rng(1))
    cam = _camera("fit", distance_scale=1.0)
    framed = frame_camera(cam, pts, np.full(len(pts), 0.8), None, margin=0.05)
    inside = in_frame(pinhole_of(framed.camera), pts, 0.05)
    assert inside.sum() >= math.ceil(0.9 * len(pts))
    closer = dataclasses.replace(framed.camera, distance=framed.camera.distance * 0.97)
    target = np.asarray(closer.look_at)
    back = (np.asarray(framed.camera.position) - target) * 0.97 + target
    closer = dataclasses.replace(closer, position=tuple(back))
    assert in_frame(pinhole_of(closer), pts, 0.05).sum() < math.ceil(0.9 * len(pts))
    # jitter moves the camera back, never closer than the fit
    jittered = frame_camera(_camera("fit", distance_scale=0.9), pts, np.full(len(pts), 0.8), None, margin=0.05)
    assert jittered.camera.distance == pytest.approx(framed.camera.distance * 1.1, rel=1e-6)


def test_fixed_framing_keeps_the_pose() -> None:
    cam = _camera("fixed")
    assert frame_camera(cam, _pile(np.random.default_rng(2)), np.ones(80), 5.0, margin=0.0).camera == cam


def _floor() -> FloorSpec:
    return FloorSpec("cube", (30.0, 30.0), 0.5, 1.0, MaterialSpec("procedural", "tiles"))


def test_distractors_land_in_every_view_clear_of_the_pile_and_each_other() -> None:
    rng = np.random.default_rng(3)
    pts = rng.normal(0.0, 1.2, (60, 3)) * [1, 1, 0] + [0, 0, 0.4]
    cams = [frame_camera(_camera("paper", azimuth_deg=a, elevation_deg=e), pts, np.full(60, 0.8), 10.0,
                         margin=0.02).camera for a, e in ((30.0, 45.0), (150.0, 60.0))]
    pinholes = [pinhole_of(c) for c in cams]
    half = 0.4
    occupied = np.c_[pts[:, :2] - half, pts[:, :2] + half]
    boxes = [np.array([b for p in pts if (b := image_box(c, p - half, p + half)) is not None]) for c in pinholes]
    shapes = [DistractorShape((-0.3, -0.2, -0.4), (0.3, 0.2, 0.4)) for _ in range(6)]
    spots = place_distractors(np.random.default_rng(7), shapes, pinholes, _floor(), occupied, boxes,
                              centre=np.zeros(2), max_radius=20.0, margin=0.2, frame_margin=0.02, tries=200,
                              max_overlap=0.25)
    placed = [s for s in spots if s is not None]
    assert len(placed) >= 4
    feet = []
    for x, y, z in placed:
        assert z == pytest.approx(0.4)  # its lowest point on the floor's top
        for c in pinholes:
            assert in_frame(c, np.array([[x, y, z]]), 0.02)[0]
        foot = np.array([x - 0.3, y - 0.2, x + 0.3, y + 0.2])
        for b in list(occupied) + feet:
            assert foot[0] - 0.2 >= b[2] or foot[2] + 0.2 <= b[0] or foot[1] - 0.2 >= b[3] or foot[3] + 0.2 <= b[1]
        feet.append(foot)
    again = place_distractors(np.random.default_rng(7), shapes, pinholes, _floor(), occupied, boxes,
                              centre=np.zeros(2), max_radius=20.0, margin=0.2, frame_margin=0.02, tries=200,
                              max_overlap=0.25)
    assert again == spots  # seeded: the same spots


def test_no_room_means_no_distractor() -> None:
    pts = np.zeros((1, 3))
    cam = pinhole_of(frame_camera(_camera("paper"), pts, np.ones(1), 1.0, margin=0.0).camera)
    everything = np.array([[-100.0, -100.0, 100.0, 100.0]])
    spots = place_distractors(np.random.default_rng(0), [DistractorShape((-0.1, -0.1, 0.0), (0.1, 0.1, 0.2))], [cam],
                              _floor(), everything, [np.zeros((0, 4))], centre=np.zeros(2), max_radius=50.0,
                              margin=0.0, frame_margin=0.0, tries=50, max_overlap=0.25)
    assert spots == [None]


def test_pile_fit_factor_brings_the_area_into_range() -> None:
    sizes = np.full(100, 0.8)  # footprint 64 m^2
    assert pile_fit_factor((2.5, 2.5), sizes, (1.5, 3.0)) ** 2 * 6.25 == pytest.approx(1.5 * 64)
    assert pile_fit_factor((20.0, 20.0), sizes, (1.5, 3.0)) ** 2 * 400 == pytest.approx(3.0 * 64)
    assert pile_fit_factor((10.0, 12.0), sizes, (1.5, 3.0)) == 1.0


def test_specs_carry_the_framing_draws_and_the_placement() -> None:
    conf = load_config([], ["scene.n_cameras=2", "scene.camera_framing=fit"])
    spec = sample_scene(5, "train", conf, rich_pool())
    assert spec.placement is not None and spec.placement.distractor_tries == conf.scene.distractor_max_tries
    assert [c.name for c in spec.cameras] == ["cam_0", "cam_1"]
    for c in spec.cameras:
        assert c.framing == "fit" and c.fit_share == conf.scene.camera_fit_share
        assert 1 - conf.scene.camera_distance_jitter <= c.distance_scale <= 1 + conf.scene.camera_distance_jitter
        assert max(abs(v) for v in c.lookat_offset) <= conf.scene.camera_lookat_jitter * conf.scene.scale + 1e-9
    assert type(spec).from_json(spec.to_json()) == spec


def test_matrix_from_quat_inverts_quat_from_matrix() -> None:
    from mixcount.scene.rotation import matrix_from_quat, quat_from_matrix

    rng = np.random.default_rng(4)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        m = matrix_from_quat(q)
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(matrix_from_quat(quat_from_matrix(m)), m, atol=1e-8)
