"""Camera records and poses in the worker (bpy): the one home of the camera code the scene job, the count
target's steps and the re-render share (issue 48: before, :mod:`mixcount.engine.rerender_job` imported the
scene job's private helpers and the engine's files imported each other in a circle).

:func:`set_matrix` puts a 4 x 4 world matrix on a Blender object, :func:`camera_record` is what a result
records of a camera (pixel model, pose, lens, clip range), :func:`frame_cameras` re-aims every camera of a
scene at its settled counted objects by the framing rule of :mod:`mixcount.scene.framing`, and
:class:`Placement` is where the cameras ended up after physics. Imports no other engine step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from mixcount.annotate.raster import PinholeCamera
from mixcount.engine.scene_build import SceneState


def set_matrix(obj: Any, matrix: np.ndarray) -> None:
    """A 4 x 4 world matrix (numpy) onto a Blender object."""
    import mathutils

    obj.matrix_world = mathutils.Matrix(np.asarray(matrix).tolist())


def camera_record(cam_obj: Any, camera: PinholeCamera) -> dict[str, Any]:
    """What a result records of a camera: its pixel model, pose, lens, sensor, clip range and convention."""
    return {
        "name": cam_obj.name, "width": camera.width, "height": camera.height, "K": camera.K.tolist(),
        "cam_to_world": camera.cam_to_world.tolist(), "focal_length_mm": float(cam_obj.data.lens),
        "sensor_width_mm": float(cam_obj.data.sensor_width),
        "clip_range": [float(cam_obj.data.clip_start), float(cam_obj.data.clip_end)],
        "convention": "camera looks down -Z, +Y up (Blender/USD); K maps to pixel x right, y down",
    }


@dataclass(frozen=True)
class Placement:
    """Where the cameras ended up after physics: each camera's pixel model and how it was framed (empty
    for a spec without after-physics placement: the stage's cameras, unmoved)."""

    cameras: list[PinholeCamera]
    framings: list[dict[str, Any]]

    def framing(self, k: int) -> dict[str, Any]:
        return self.framings[k] if self.framings else {"framing": "fixed"}


def need_scale(state: SceneState, settled: int) -> float:
    """A count target's floor pile is framed on the footprint of its expected need, not of its first
    settle (about 1.65 x the target, where a paper scene settles about 1.2 x what it keeps): the square
    root of need / settled counted bodies (``count_target["frame_need"]``: the need, never below the paper's
    smallest spawn), at most 1; 1 for a paper scene (issue 48)."""
    target = state.spec.count_target
    if target is None or not target.get("frame_need") or settled <= 0:
        return 1.0
    return float(min(1.0, math.sqrt(int(target["frame_need"]) / float(settled))))


def frame_cameras(state: SceneState) -> list[dict[str, Any]]:
    """Every camera re-aimed at the settled counted objects by its framing rule
    (:func:`mixcount.scene.framing.frame_camera`); the Blender cameras move there. Returns how each
    camera was framed (its derivation and the framed camera)."""
    from mixcount.scene.framing import frame_camera, rotation_of

    kept = state.kept("counted")
    centres = np.array([np.asarray(state.objects[i].matrix_world)[:3, 3] for i in kept]).reshape(-1, 3)
    sizes = np.array([state.objects[i].size_m for i in kept])
    container = state.spec.container
    diag = float(np.linalg.norm(container.extent_m)) if container is not None else None
    margin = state.spec.placement.frame_margin if state.spec.placement is not None else 0.0
    scale = need_scale(state, len(kept))
    framings = []
    for cam_obj, cam in zip(state.cam_objs, state.spec.cameras):
        framed = frame_camera(cam, centres, sizes, diag, margin=margin, footprint_scale=scale)
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = rotation_of(framed.camera), framed.camera.position
        set_matrix(cam_obj, m)
        framings.append({**framed.derivation, "camera": framed.camera.to_dict()})
    return framings
