"""Cameras and distractors placed after physics, from the settled pile (engine-free, no bpy).

The paper: "The camera rotation is dynamically set to look at the center of the objects to count, then
slightly jittered", at a distance of 1.2 x the container's box diagonal (+-15 %). Before physics the
pile's centre is unknown, so the sampler draws each camera's angles and jitters (a
:class:`~mixcount.scene.spec.CameraSpec` with a provisional pose) and the worker calls
:func:`frame_camera` on the settled counted objects: look-at = their robust centre + the drawn jitter,
distance by the camera's ``framing`` rule:

* ``paper``: ``distance_factor`` x ||diag AABB(container)|| x ``distance_scale`` (the drawn +-15 %);
  without a container the diagonal of the settled pile's footprint (:func:`footprint_diagonal`).
* ``fit``: the smallest distance at which ``fit_share`` of the settled counted origins project into the
  frame (inside ``margin`` of each border), times 1 + |distance_scale - 1| (the same jitter, never
  closer than the fit).
* ``pile``: ``distance_factor`` x the diagonal of a square of ``pile_area`` x the settled pile's one-layer
  footprint (the sum of the counted objects' largest sides squared) x ``distance_scale``: the container a
  paper scene fits to its pile (``container_pile_area``), so a real-size scene, whose container keeps its
  real size, shows its objects at the paper's pixels per object (issue 70); never closer than ``fit``
  (parts spread over a tray much larger than their pile stay in the frame, at fewer pixels).
* ``fixed``: the spec's pose as it is (specs written before framing existed, or a user's own camera).

Distractors are not simulated: :func:`place_distractors` puts each on the floor where every camera sees
its origin, its footprint clear of the settled pile, the container and the other distractors, and its
image box clear of the counted objects' boxes, so the paper's 2-8 distractors are 2-8 in the image
(minus those the visibility filter still finds hidden).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.annotate.raster import PinholeCamera
from mixcount.scene.rotation import matrix_from_quat, quat_from_matrix
from mixcount.scene.spec import CameraSpec, FloorSpec

FRAMINGS = ("paper", "fit", "pile", "fixed")
_R = 6
_FIT_STEPS = 48  # bisection steps of the fit distance (relative precision ~1e-12 of the bracket)


def look_at_rotation(position: NDArray[Any], target: NDArray[Any], roll_deg: float) -> NDArray[Any]:
    """Camera-to-world rotation: local -Z towards target, +Y up-ish, then ``roll_deg`` about the view axis."""
    f = target - position
    f = f / np.linalg.norm(f)
    right = np.cross(f, np.array([0.0, 0.0, 1.0]))
    if np.linalg.norm(right) < 1e-9:  # looking straight down: any horizontal right vector
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    rot = np.stack([right, up, -f], axis=1)
    r = math.radians(roll_deg)
    rz = np.array([[math.cos(r), -math.sin(r), 0.0], [math.sin(r), math.cos(r), 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(rot @ rz)


def camera_position(target: NDArray[Any], elevation_deg: float, azimuth_deg: float, distance: float) -> NDArray[Any]:
    """A point on the hemisphere of radius ``distance`` around ``target``."""
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.asarray(target + distance * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a),
                                                   math.sin(e)]))


def pinhole(cam: CameraSpec, position: NDArray[Any], rotation: NDArray[Any]) -> PinholeCamera:
    """The pixel model of ``cam`` (horizontal sensor fit, square pixels) at a pose."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rotation, position
    return PinholeCamera.from_physical(cam.focal_length_mm, cam.sensor_width_mm, cam.resolution[0],
                                       cam.resolution[1], m, near=cam.clip_range[0])


def pinhole_of(cam: CameraSpec) -> PinholeCamera:
    """The pixel model of a camera spec at its own pose."""
    return pinhole(cam, np.asarray(cam.position, dtype=np.float64), rotation_of(cam))


def rotation_of(cam: CameraSpec) -> NDArray[Any]:
    """Camera-to-world rotation of the spec's orientation quaternion (w, x, y, z)."""
    return matrix_from_quat(cam.orientation)


def in_frame(camera: PinholeCamera, points: NDArray[Any], margin: float) -> NDArray[Any]:
    """Bool per world point (N, 3): in front of the camera and inside the image shrunk by ``margin``
    (a fraction of the width / height) on every side."""
    px, depth = camera.project(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    mx, my = margin * camera.width, margin * camera.height
    return np.asarray((depth > camera.near) & (px[:, 0] >= mx) & (px[:, 0] < camera.width - mx)
                      & (px[:, 1] >= my) & (px[:, 1] < camera.height - my))


def pile_centre(points: NDArray[Any]) -> NDArray[Any]:
    """The counted objects' centre at rest, robust to a few strays: the per-axis median."""
    return np.asarray(np.median(np.asarray(points, dtype=np.float64).reshape(-1, 3), axis=0))


def footprint_diagonal(points: NDArray[Any], sizes: NDArray[Any]) -> float:
    """The settled pile's box diagonal without a container: the 5-95 % range of the origins per axis
    (a few strays do not count), grown by the median object size."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = np.percentile(p, 5, axis=0), np.percentile(p, 95, axis=0)
    return float(np.linalg.norm(hi - lo + float(np.median(sizes))))


@dataclass(frozen=True)
class Framing:
    """A framed camera and how it was derived (recorded in metadata.json and settled.usda)."""

    camera: CameraSpec
    derivation: dict[str, Any]


def fit_distance(cam: CameraSpec, target: NDArray[Any], points: NDArray[Any], share: float, margin: float) -> float:
    """The smallest distance (along the camera's drawn direction, roll included) at which ``share`` of
    ``points`` lies in the frame (:func:`in_frame` with ``margin``). Bisection on a bracket that is
    doubled until it holds enough; the in-frame share grows with distance for points around the target."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    need = math.ceil(share * len(pts) - 1e-9)

    def enough(d: float) -> bool:
        pos = camera_position(target, cam.elevation_deg, cam.azimuth_deg, d)
        return int(in_frame(pinhole(cam, pos, look_at_rotation(pos, target, cam.roll_deg)), pts, margin).sum()) >= need

    spread = float(np.max(np.linalg.norm(pts - target, axis=1))) if len(pts) else 1.0
    lo, hi = 0.0, max(spread, 1e-3)
    far = float(cam.clip_range[1]) * 0.5
    while not enough(hi):
        if hi >= far:
            return far
        lo, hi = hi, min(hi * 2.0, far)
    for _ in range(_FIT_STEPS):
        mid = 0.5 * (lo + hi)
        if enough(mid):
            hi = mid
        else:
            lo = mid
    return hi


def frame_camera(cam: CameraSpec, counted: NDArray[Any], sizes: NDArray[Any], container_diagonal: Optional[float],
                 *, margin: float, footprint_scale: float = 1.0) -> Framing:
    """``cam`` re-aimed at the settled counted objects (origins ``counted`` (N, 3), largest sides ``sizes``)
    by its framing rule (module docstring); ``container_diagonal``: ||diag AABB(container)|| or None.
    ``footprint_scale`` (<= 1) scales the settled pile's footprint diagonal of the ``paper`` rule without a
    container: a count target's first settle holds more bodies than it will keep, and its camera is
    framed on the footprint of its expected need (``sqrt(need / settled)``, engine/cameras.py)."""
    pts = np.asarray(counted, dtype=np.float64).reshape(-1, 3)
    if cam.framing == "fixed" or len(pts) == 0:
        return Framing(cam, {"framing": cam.framing if len(pts) else f"{cam.framing} (no settled counted object)",
                             "look_at": list(cam.look_at), "distance": cam.distance})
    centre = pile_centre(pts)
    target = centre + np.asarray(cam.lookat_offset, dtype=np.float64)
    derivation: dict[str, Any] = {"framing": cam.framing, "pile_centre": [round(float(v), _R) for v in centre],
                                  "pile_centre_rule": f"per-axis median of {len(pts)} settled counted origins",
                                  "lookat_offset": list(cam.lookat_offset), "distance_scale": cam.distance_scale}
    if cam.framing == "paper":
        if container_diagonal is not None:
            base, rule = float(container_diagonal), "container box diagonal"
        else:
            base, rule = footprint_diagonal(pts, sizes), "settled pile footprint diagonal (5-95 % of origins + median size)"
            if footprint_scale < 1.0:
                base *= float(footprint_scale)
                rule += f" x {footprint_scale:.4f} (the count target's expected need / settled, square root)"
                derivation["footprint_scale"] = round(float(footprint_scale), _R)
        dist = cam.distance_factor * base * cam.distance_scale
        derivation.update(distance_rule=f"{cam.distance_factor} x {rule} x distance_scale", base_diagonal=round(base, _R))
    elif cam.framing == "pile":
        area = float(cam.pile_area or 1.0) * float(np.sum(np.square(np.asarray(sizes, dtype=np.float64))))
        base = math.sqrt(2.0 * area) * (float(footprint_scale) if footprint_scale < 1.0 else 1.0)
        d_pile = cam.distance_factor * base * cam.distance_scale
        d_fit = fit_distance(cam, target, pts, cam.fit_share, margin) * (1.0 + abs(cam.distance_scale - 1.0))
        dist = max(d_pile, d_fit)
        derivation.update(distance_rule=f"{cam.distance_factor} x diagonal of a square of {cam.pile_area} x the "
                                        f"settled pile's footprint ({len(pts)} objects) x distance_scale, never "
                                        f"closer than {cam.fit_share:.0%} of the settled counted origins in the frame",
                          base_diagonal=round(base, _R), pile_distance=round(d_pile, _R), fit_distance=round(d_fit, _R))
    elif cam.framing == "fit":
        d_fit = fit_distance(cam, target, pts, cam.fit_share, margin)
        dist = d_fit * (1.0 + abs(cam.distance_scale - 1.0))
        derivation.update(distance_rule=f"smallest distance with {cam.fit_share:.0%} of the settled counted origins "
                                        f"in the frame (margin {margin}) x (1 + |distance_scale - 1|)",
                          fit_distance=round(d_fit, _R))
    else:
        raise ValueError(f"unknown camera framing {cam.framing!r}; choose from {', '.join(FRAMINGS)}")
    pos = camera_position(target, cam.elevation_deg, cam.azimuth_deg, dist)
    rot = look_at_rotation(pos, target, cam.roll_deg)
    framed = replace(cam, position=_vec(pos), look_at=_vec(target), orientation=quat_from_matrix(rot),
                     distance=round(float(dist), _R))
    derivation["distance"] = framed.distance
    inside = in_frame(pinhole_of(framed), pts, 0.0)
    derivation["counted_origins_in_frame"] = f"{int(inside.sum())}/{len(pts)}"
    return Framing(framed, derivation)


def _vec(v: Sequence[float] | NDArray[Any]) -> tuple[float, float, float]:
    return (round(float(v[0]), _R), round(float(v[1]), _R), round(float(v[2]), _R))


# ------------------------------------------------------------------------------------ distractors


@dataclass(frozen=True)
class DistractorShape:
    """A distractor at its drawn size and yaw, relative to its origin: world-axis box (lo, hi) (3,)."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]


def _on_floor(floor: FloorSpec, lo_xy: NDArray[Any], hi_xy: NDArray[Any]) -> bool:
    hx, hy = floor.half_extent
    if floor.shape == "cylinder":
        corners = np.array([[lo_xy[0], lo_xy[1]], [lo_xy[0], hi_xy[1]], [hi_xy[0], lo_xy[1]], [hi_xy[0], hi_xy[1]]])
        return bool((np.hypot(corners[:, 0], corners[:, 1]) <= hx).all())
    return bool(lo_xy[0] >= -hx and hi_xy[0] <= hx and lo_xy[1] >= -hy and hi_xy[1] <= hy)


def _box_corners(lo: NDArray[Any], hi: NDArray[Any]) -> NDArray[Any]:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def image_box(camera: PinholeCamera, lo: NDArray[Any], hi: NDArray[Any]) -> Optional[NDArray[Any]]:
    """The image box (x0, y0, x1, y1) of a world box's corners, clipped to the image; None when a
    corner is behind the camera or the box misses the image."""
    px, depth = camera.project(_box_corners(lo, hi))
    if (depth <= camera.near).any():
        return None
    x0, y0 = max(0.0, float(px[:, 0].min())), max(0.0, float(px[:, 1].min()))
    x1, y1 = min(float(camera.width), float(px[:, 0].max())), min(float(camera.height), float(px[:, 1].max()))
    if x1 <= x0 or y1 <= y0:
        return None
    return np.array([x0, y0, x1, y1])


def _overlap_share(box: NDArray[Any], others: NDArray[Any]) -> float:
    """Share of ``box`` covered by the boxes ``others`` (M, 4) (summed pairwise, capped at 1)."""
    if len(others) == 0:
        return 0.0
    w = np.clip(np.minimum(others[:, 2], box[2]) - np.maximum(others[:, 0], box[0]), 0, None)
    h = np.clip(np.minimum(others[:, 3], box[3]) - np.maximum(others[:, 1], box[1]), 0, None)
    area = max(float((box[2] - box[0]) * (box[3] - box[1])), 1e-9)
    return min(1.0, float((w * h).sum()) / area)


def _floor_hit(camera: PinholeCamera, px: NDArray[Any]) -> Optional[NDArray[Any]]:
    """Where the ray through pixel ``px`` (x, y) meets the floor's top (z = 0), or None."""
    d_cam = np.array([(px[0] - camera.cx) / camera.fx, -(px[1] - camera.cy) / camera.fy, -1.0])
    m = camera.cam_to_world
    d = m[:3, :3] @ d_cam
    o = m[:3, 3]
    if d[2] >= -1e-9:
        return None
    t = -o[2] / d[2]
    return np.asarray(o + t * d)


def place_distractors(rng: np.random.Generator, shapes: Sequence[DistractorShape], cameras: Sequence[PinholeCamera],
                      floor: FloorSpec, occupied: NDArray[Any], counted_boxes: Sequence[NDArray[Any]], *,
                      centre: NDArray[Any], max_radius: float, margin: float, frame_margin: float,
                      tries: int, max_overlap: float) -> list[Optional[tuple[float, float, float]]]:
    """An origin (x, y, z) per distractor resting on the floor (its lowest point at z = 0), or None when
    no spot was found in ``tries`` candidates.

    Candidates are floor points under uniformly random pixels of the first camera, within ``max_radius``
    of ``centre`` (x, y). A candidate is valid when its origin is in every camera's frame (inside
    ``frame_margin``), its footprint lies on the floor and misses the world boxes ``occupied`` (M, 4:
    x0, y0, x1, y1 of the settled pile and the container) and the distractors placed before, each grown by
    ``margin``. Of the valid ones the first whose image box is clear of the counted objects' image boxes
    (``counted_boxes``: per camera (N, 4)) is taken, else the least covered one when at most
    ``max_overlap`` of it is covered (it would hide counted objects or be hidden by them)."""
    occ = [np.asarray(b, dtype=np.float64) for b in np.asarray(occupied, dtype=np.float64).reshape(-1, 4)]
    out: list[Optional[tuple[float, float, float]]] = []
    cam0 = cameras[0]
    for shape in shapes:
        lo, hi = np.asarray(shape.lo, dtype=np.float64), np.asarray(shape.hi, dtype=np.float64)
        best: Optional[tuple[float, NDArray[Any]]] = None
        for _ in range(tries):
            hit = _floor_hit(cam0, np.array([rng.uniform(0, cam0.width), rng.uniform(0, cam0.height)]))
            if hit is None or math.hypot(hit[0] - centre[0], hit[1] - centre[1]) > max_radius:
                continue
            origin = np.array([hit[0], hit[1], -lo[2]])
            wlo, whi = origin + lo, origin + hi
            if not _on_floor(floor, wlo[:2], whi[:2]):
                continue
            if any(wlo[0] - margin < b[2] and whi[0] + margin > b[0] and wlo[1] - margin < b[3]
                   and whi[1] + margin > b[1] for b in occ):
                continue
            if not all(bool(in_frame(c, origin[None, :], frame_margin)[0]) for c in cameras):
                continue
            cover = 0.0
            for c, boxes in zip(cameras, counted_boxes):
                box = image_box(c, wlo, whi)
                cover = max(cover, 1.0 if box is None else _overlap_share(box, np.asarray(boxes).reshape(-1, 4)))
            if best is None or cover < best[0]:
                best = (cover, origin)
            if cover <= 0.0:
                break
        if best is None or best[0] > max_overlap:
            out.append(None)
            continue
        origin = best[1]
        occ.append(np.array([origin[0] + lo[0], origin[1] + lo[1], origin[0] + hi[0], origin[1] + hi[1]]))
        out.append((float(origin[0]), float(origin[1]), float(origin[2])))
    return out
