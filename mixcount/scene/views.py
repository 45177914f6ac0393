"""New cameras around a settled pile (no engine): the paper's camera rule drawn again, or an orbit.

A finished scene is rendered again from more viewpoints by ``mixcount render --views K`` /
``--trajectory orbit --frames F`` (mixcount/run/rerender.py). The piles do not move; only cameras are
added. :func:`paper_views` draws K cameras exactly as the sampler draws a scene's own (elevation, azimuth,
roll, look-at and distance jitters from ``[scene]``) from ``default_rng([seed, scene seed])`` and frames
each on the settled counted objects by the scene's framing rule (:func:`mixcount.scene.framing.frame_camera`,
the worker's own rule after physics). :func:`orbit_views` puts F cameras on a circle around the pile centre
(elevation and radius as configured, evenly spaced azimuths, no roll), for video-like sequences.

Each camera is returned as a plain record: name, 4x4 camera-to-world (Blender / USD: looks down -Z, +Y up),
lens, sensor, clip range and how it was chosen.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from mixcount.scene.framing import camera_position, frame_camera, look_at_rotation, pile_centre, rotation_of
from mixcount.scene.spec import CameraSpec
from mixcount.scene_config import SceneConfig


@dataclass(frozen=True)
class NewView:
    """One camera to render: pose and lens (what the worker's RenderView carries)."""

    name: str
    cam_to_world: NDArray[Any]
    focal_length_mm: float
    sensor_width_mm: float
    clip_range: tuple[float, float]
    framing: dict[str, Any]


def _pose(rotation: NDArray[Any], position: NDArray[Any]) -> NDArray[Any]:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rotation, position
    return m


def _view(name: str, cam: CameraSpec, framing: dict[str, Any]) -> NewView:
    return NewView(name=name, cam_to_world=_pose(rotation_of(cam), np.asarray(cam.position, dtype=np.float64)),
                   focal_length_mm=cam.focal_length_mm, sensor_width_mm=cam.sensor_width_mm,
                   clip_range=(float(cam.clip_range[0]), float(cam.clip_range[1])), framing=framing)


def paper_views(template: CameraSpec, config: SceneConfig, counted: NDArray[Any], sizes: NDArray[Any],
                container_diagonal: Optional[float], *, k: int, seed: int, scene_seed: int,
                first_index: int) -> list[NewView]:
    """``k`` cameras drawn by the paper's camera rule (the sampler's draw, ``config``'s ranges) and framed
    on the settled counted origins ``counted`` (N, 3) with largest sides ``sizes``; named
    ``cam_<first_index>``, ``cam_<first_index + 1>``, ... ``template`` gives lens, sensor, clip range."""
    rng = np.random.default_rng([seed, scene_seed])
    s = config.scale
    views = []
    for j in range(k):
        offset = rng.uniform(-1, 1, 3) * config.camera_lookat_jitter * s
        elev = float(rng.uniform(*config.camera_elevation_deg))
        azim = float(rng.uniform(0.0, 360.0))
        roll = float(rng.uniform(*config.camera_roll_deg))
        scale = 1 + float(rng.uniform(-config.camera_distance_jitter, config.camera_distance_jitter))
        drawn = replace(template, name=f"cam_{first_index + j}", elevation_deg=elev, azimuth_deg=azim, roll_deg=roll,
                        lookat_offset=(float(offset[0]), float(offset[1]), float(offset[2])), distance_scale=scale,
                        framing=config.camera_framing, distance_factor=config.camera_distance_factor,
                        fit_share=config.camera_fit_share)
        framed = frame_camera(drawn, counted, sizes, container_diagonal, margin=config.camera_frame_margin)
        views.append(_view(drawn.name, framed.camera, {**framed.derivation, "rule": "paper camera rule (rerender)",
                                                       "elevation_deg": elev, "azimuth_deg": azim, "roll_deg": roll}))
    return views


def orbit_views(template: CameraSpec, counted: NDArray[Any], *, frames: int, elevation_deg: float, radius: float,
                start_azimuth_deg: float, first_index: int) -> list[NewView]:
    """``frames`` cameras on a circle around the pile centre (per-axis median of ``counted``), at
    ``elevation_deg`` and distance ``radius``, azimuths evenly spaced from ``start_azimuth_deg``, no roll."""
    centre = pile_centre(np.asarray(counted, dtype=np.float64).reshape(-1, 3))
    views = []
    for f in range(frames):
        azim = start_azimuth_deg + 360.0 * f / frames
        pos = camera_position(centre, elevation_deg, azim, radius)
        rot = look_at_rotation(pos, centre, 0.0)
        name = f"cam_{first_index + f}"
        views.append(NewView(name=name, cam_to_world=_pose(rot, pos), focal_length_mm=template.focal_length_mm,
                             sensor_width_mm=template.sensor_width_mm,
                             clip_range=(float(template.clip_range[0]), float(template.clip_range[1])),
                             framing={"framing": "orbit", "frame": f, "azimuth_deg": azim,
                                      "elevation_deg": elevation_deg, "distance": radius,
                                      "look_at": centre.tolist()}))
    return views
