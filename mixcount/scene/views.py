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

:class:`ViewPlan` is which new cameras a pile gets (``[rerender]``'s views, trajectory and seed, and the
``[scene]`` camera rule as a :class:`CameraRule`), and :func:`plan_views` the one place they are drawn from
a settled pile: by ``mixcount render`` from a finished scene's metadata.json, and inside the bpy worker by
``compose --views K`` from the pile it just settled (the same values, so the same cameras).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.scene.framing import camera_position, frame_camera, look_at_rotation, pile_centre, rotation_of
from mixcount.scene.spec import CameraSpec
from mixcount.scene_config import RerenderConfig, SceneConfig


@dataclass(frozen=True)
class CameraRule:
    """The paper's camera rule as ``[scene]`` configures it (the fields :func:`paper_views` draws from)."""

    scale: float
    camera_elevation_deg: tuple[float, float]
    camera_roll_deg: tuple[float, float]
    camera_distance_factor: float
    camera_distance_jitter: float
    camera_lookat_jitter: float
    camera_framing: str
    camera_fit_share: float
    camera_frame_margin: float

    @classmethod
    def of(cls, scene: SceneConfig) -> "CameraRule":
        return cls(**{f.name: getattr(scene, f.name) for f in fields(cls)})

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["camera_elevation_deg"], d["camera_roll_deg"] = list(self.camera_elevation_deg), list(self.camera_roll_deg)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CameraRule":
        v = {f.name: d[f.name] for f in fields(cls)}
        for k in ("camera_elevation_deg", "camera_roll_deg"):
            v[k] = (float(v[k][0]), float(v[k][1]))
        return cls(**v)


@dataclass(frozen=True)
class ViewPlan:
    """Which new cameras a settled pile gets: ``new_views`` by the paper's camera rule (``camera_rule``,
    drawn from ``default_rng([seed, scene seed])``) and, with ``trajectory`` "orbit", ``frames`` cameras on
    a circle (``orbit_elevation_deg``, radius ``orbit_distance_factor`` x the first camera's distance)."""

    new_views: int
    trajectory: str  # none | orbit
    frames: int
    orbit_elevation_deg: float
    orbit_distance_factor: float
    seed: int
    camera_rule: CameraRule

    @classmethod
    def from_config(cls, rerender: RerenderConfig, scene: SceneConfig) -> "ViewPlan":
        return cls(new_views=rerender.new_views, trajectory=rerender.trajectory, frames=rerender.frames,
                   orbit_elevation_deg=rerender.orbit_elevation_deg,
                   orbit_distance_factor=rerender.orbit_distance_factor, seed=rerender.seed,
                   camera_rule=CameraRule.of(scene))

    @property
    def adds_views(self) -> bool:
        return self.new_views > 0 or self.trajectory == "orbit"

    def to_dict(self) -> dict[str, Any]:
        return {**{f.name: getattr(self, f.name) for f in fields(self) if f.name != "camera_rule"},
                "camera_rule": self.camera_rule.to_dict()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ViewPlan":
        return cls(new_views=int(d["new_views"]), trajectory=str(d["trajectory"]), frames=int(d["frames"]),
                   orbit_elevation_deg=float(d["orbit_elevation_deg"]),
                   orbit_distance_factor=float(d["orbit_distance_factor"]), seed=int(d["seed"]),
                   camera_rule=CameraRule.from_dict(d["camera_rule"]))


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


def paper_views(template: CameraSpec, config: CameraRule | SceneConfig, counted: NDArray[Any], sizes: NDArray[Any],
                container_diagonal: Optional[float], *, k: int, seed: int, scene_seed: int,
                first_index: int) -> list[NewView]:
    """``k`` cameras drawn by the paper's camera rule (the sampler's draw, ``config``'s ranges) and framed
    on the settled counted origins ``counted`` (N, 3) with largest sides ``sizes``; named
    ``cam_<first_index>``, ``cam_<first_index + 1>``, ... ``template`` gives lens, sensor, clip range."""
    config = config if isinstance(config, CameraRule) else CameraRule.of(config)
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


def plan_views(plan: ViewPlan, template: CameraSpec, container_diagonal: Optional[float], scene_seed: int,
               counted: NDArray[Any], sizes: NDArray[Any], first_cam_to_world: Sequence[Sequence[float]],
               first_index: int) -> list[NewView]:
    """The cameras ``plan`` adds to a settled pile: the settled counted origins ``counted`` (N, 3) with
    largest sides ``sizes``, the scene's first camera at ``first_cam_to_world`` (the orbit's radius and
    start); named from ``cam_<first_index>`` on. None for a pile without counted objects."""
    counted = np.asarray(counted, dtype=np.float64).reshape(-1, 3)
    if not len(counted) or not plan.adds_views:
        return []
    out: list[NewView] = []
    if plan.new_views:
        out += paper_views(template, plan.camera_rule, counted, np.asarray(sizes, dtype=np.float64),
                           container_diagonal, k=plan.new_views, seed=plan.seed, scene_seed=scene_seed,
                           first_index=first_index)
    if plan.trajectory == "orbit":
        centre = pile_centre(counted)
        cam0 = np.asarray(first_cam_to_world, dtype=np.float64)[:3, 3]
        radius = plan.orbit_distance_factor * float(np.linalg.norm(cam0 - centre))
        start = math.degrees(math.atan2(cam0[1] - centre[1], cam0[0] - centre[0]))
        out += orbit_views(template, counted, frames=plan.frames, elevation_deg=plan.orbit_elevation_deg,
                           radius=radius, start_azimuth_deg=start, first_index=first_index + len(out))
    return out
