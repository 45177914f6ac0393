"""The ``rerender`` and ``devices`` worker operations' contract (imports neither bpy nor pxr).

* ``rerender`` - :class:`RerenderRequest` -> :class:`~mixcount.worker.contract.SceneResult`: a settled stage
  rendered again from recorded poses and cameras (``mixcount render``), each camera a :class:`RenderView`;
  its ``rule`` is one of :data:`mixcount.scene_config.ANNOTATION_RULES` and its ``device`` one of
  :data:`mixcount.scene_config.DEVICES` (the one definition of both).
* ``devices`` - :class:`DevicesRequest` -> :class:`DevicesResult`: which Cycles devices a setting gives here.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, ClassVar, Mapping, Optional

from mixcount.scene.views import NewView
from mixcount.worker.contract import Matrix, SceneRequest, as_matrix, known_fields


@dataclass(frozen=True)
class RenderView:
    """One camera of a re-render: its pose (4x4 camera-to-world, Blender's -Z forward) and lens."""

    name: str
    cam_to_world: Matrix
    focal_length_mm: float
    sensor_width_mm: float
    clip_range: tuple[float, float]
    framing: dict[str, Any]  # how it was chosen ("stage", "paper", "orbit"), recorded in metadata.json

    @classmethod
    def of(cls, view: NewView) -> "RenderView":
        """A drawn camera (:class:`mixcount.scene.views.NewView`) as the worker places it."""
        m = as_matrix(view.cam_to_world)
        assert m is not None
        return cls(name=view.name, cam_to_world=m, focal_length_mm=view.focal_length_mm,
                   sensor_width_mm=view.sensor_width_mm, clip_range=view.clip_range, framing=view.framing)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "cam_to_world": [list(r) for r in self.cam_to_world],
                "focal_length_mm": self.focal_length_mm, "sensor_width_mm": self.sensor_width_mm,
                "clip_range": list(self.clip_range), "framing": dict(self.framing)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "RenderView":
        v = known_fields(cls, d)
        m = as_matrix(v["cam_to_world"])
        assert m is not None
        return cls(name=str(v["name"]), cam_to_world=m, focal_length_mm=float(v["focal_length_mm"]),
                   sensor_width_mm=float(v["sensor_width_mm"]),
                   clip_range=(float(v["clip_range"][0]), float(v["clip_range"][1])), framing=dict(v["framing"]))


@dataclass(frozen=True)
class RerenderRequest:
    """One ``rerender`` request: render a settled stage again (no physics, no placement) -> SceneResult.

    ``poses`` are the settled matrices by instance prim path as the source scene's metadata.json holds them
    (float64; settled.usda's orientations are float32 quaternions), ``views`` every camera to render (the
    scene's own first, at their recorded poses, then any new ones). ``resolution`` / ``samples`` 0 and
    ``denoise`` "scene" keep the stage's values."""

    OP: ClassVar[str] = "rerender"

    stage: str
    out_dir: str
    threads: int
    oracle: bool
    passes: tuple[str, ...]
    depth_format: str
    normal_format: str
    mesh_cache: str
    poses: dict[str, Matrix]
    views: tuple[RenderView, ...]
    resolution: int
    samples: int
    denoise: str  # "scene" | "on" | "off"
    rule: str  # one of mixcount.scene_config.ANNOTATION_RULES
    device: str  # one of mixcount.scene_config.DEVICES
    persistent_data: bool  # keep Cycles' scene data (BVH, images) between the views' RGB renders

    def scene_request(self) -> SceneRequest:
        """The fields the stage loader shares with a ``scene`` request."""
        return SceneRequest(stage=self.stage, out_dir=self.out_dir, threads=self.threads, oracle=self.oracle,
                            passes=self.passes, depth_format=self.depth_format, normal_format=self.normal_format,
                            mesh_cache=self.mesh_cache, settled_poses_file="", more_views=None)

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["passes"] = list(self.passes)
        d["poses"] = {p: [list(r) for r in m] for p, m in self.poses.items()}
        d["views"] = [v.to_dict() for v in self.views]
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "RerenderRequest":
        v = known_fields(cls, d)
        poses = {str(p): as_matrix(m) for p, m in v["poses"].items()}
        return cls(stage=str(v["stage"]), out_dir=str(v["out_dir"]), threads=int(v["threads"]),
                   oracle=bool(v["oracle"]), passes=tuple(str(p) for p in v["passes"]),
                   depth_format=str(v["depth_format"]), normal_format=str(v["normal_format"]),
                   mesh_cache=str(v["mesh_cache"]), poses={p: m for p, m in poses.items() if m is not None},
                   views=tuple(RenderView.from_dict(x) for x in v["views"]), resolution=int(v["resolution"]),
                   samples=int(v["samples"]), denoise=str(v["denoise"]), rule=str(v["rule"]),
                   device=str(v["device"]), persistent_data=bool(v["persistent_data"]))


@dataclass(frozen=True)
class DevicesRequest:
    """One ``devices`` request: which Cycles devices ``device`` ("cpu" | "gpu" | "auto") gives here."""

    OP: ClassVar[str] = "devices"

    device: str
    # the setting asked about, named in the error line ("compose.device": answered by
    # mixcount.engine.devices; None: ``mixcount render``'s rerender.device, mixcount.engine.rerender_job)
    setting: Optional[str] = None

    def to_dict(self) -> dict[str, Any]:
        return {"device": self.device, "setting": self.setting}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "DevicesRequest":
        v = known_fields(cls, d)
        return cls(device=str(v["device"]), setting=None if v.get("setting") is None else str(v["setting"]))


@dataclass(frozen=True)
class DevicesResult:
    """What Cycles would render on: ``used`` "CPU" or "GPU", the backend (CUDA / OPTIX / ...), the devices
    enabled, and every device Cycles found (``found``, "TYPE: name"). ``error`` is non-empty when ``gpu`` was
    asked for and none exists (one line naming what was found)."""

    used: str
    backend: str
    devices: tuple[str, ...]
    found: tuple[str, ...]
    error: str

    def to_dict(self) -> dict[str, Any]:
        return {"used": self.used, "backend": self.backend, "devices": list(self.devices), "found": list(self.found),
                "error": self.error}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "DevicesResult":
        v = known_fields(cls, d)
        return cls(used=str(v["used"]), backend=str(v["backend"]), devices=tuple(str(x) for x in v["devices"]),
                   found=tuple(str(x) for x in v["found"]), error=str(v["error"]))
