"""The typed contract between the parent process and the bpy worker (imports neither bpy nor pxr).

* :class:`SceneRequest` - what the parent sends for one scene: the stage and the output folder plus
  RUN-TIME settings only (render threads, whether to run the one-render-per-object reference). Everything
  that describes the scene (samples, denoise, visibility threshold, physics frames / substeps / solver
  iterations / gravity, settle fractions) travels in the stage (its SceneSpec), never here.
* :class:`SceneResult` - what the worker answers (also written as ``worker.json`` in the scene folder):
  status, camera, lights, the physics values actually used, diagnostics, timings and one
  :class:`ObjectResult` per counted object / distractor.

All three are frozen dataclasses with a JSON round-trip (``to_dict`` / ``from_dict``, ``to_json`` /
``from_json``); ``dataset.scene_writer.finalize_scene`` reads the typed fields.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Mapping, Optional

STATUS_OK = "ok"
STATUS_EMPTY = "empty"  # no counted object survived: the caller regenerates from the next seed
STATUS_REJECTED = "rejected"  # the final visibility re-check failed

KEPT = "kept"
DROPPED = "dropped"

Matrix = tuple[tuple[float, ...], ...]

# how the worker keeps imported asset meshes between scenes (mixcount.blender.mesh_cache): a compressed
# or uncompressed .blend beside each converted asset, or no cache (every scene imports from USD)
MESH_CACHE_MODES = ("zstd", "raw", "off")


def _matrix(m: Any) -> Optional[Matrix]:
    return None if m is None else tuple(tuple(float(v) for v in row) for row in m)


@dataclass(frozen=True)
class SceneRequest:
    """One ``scene`` request: render ``stage`` into ``out_dir``."""

    stage: str
    out_dir: str
    threads: int  # Cycles threads (0 = Blender's automatic choice)
    oracle: bool  # also run the one-render-per-object reference and write oracle_masks.npz
    # which of depth / normal to write and how (mixcount.annotate.passes); the id map is always written
    passes: tuple[str, ...] = ("instance", "class", "depth", "normal")
    depth_format: str = "png16"
    normal_format: str = "png8"
    mesh_cache: str = "zstd"  # one of MESH_CACHE_MODES

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["passes"] = list(self.passes)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SceneRequest":
        extra = {k: d[k] for k in ("depth_format", "normal_format", "mesh_cache") if k in d}
        if "passes" in d:
            extra["passes"] = tuple(d["passes"])
        return cls(stage=str(d["stage"]), out_dir=str(d["out_dir"]), threads=int(d["threads"]),
                   oracle=bool(d["oracle"]), **extra)


@dataclass(frozen=True)
class ObjectResult:
    """One counted object or distractor as the worker saw it (``status`` kept / dropped + ``reason``)."""

    name: str
    path: str
    role: str  # "counted" | "distractor"
    instance_id: int
    object_id: int
    class_index: int
    asset: str
    size_m: float
    spawn_matrix: Matrix  # 4x4, column-vector convention
    status: str = KEPT
    reason: Optional[str] = None  # why it was dropped
    matrix_world: Optional[Matrix] = None  # settled pose (None when physics left it non-finite)
    min_z: Optional[float] = None  # lowest settled vertex
    origin_px: Optional[tuple[float, float]] = None  # projected origin (x = column, y = row)
    unoccluded_px: Optional[int] = None  # pixels of its rasterised silhouette (in the frame)
    visible_px: Optional[int] = None  # pixels of its id in the id pass
    amodal_px: Optional[int] = None  # pixels of silhouette | visible (the amodal mask, in the frame)
    visibility: Optional[float] = None  # visible / amodal (BOP's visib_fract)
    oracle_unoccluded_px: Optional[int] = None
    oracle_iou: Optional[float] = None
    oracle_visibility: Optional[float] = None
    # per camera, in stage order: {"camera", "origin_px", "unoccluded_px", "visible_px", "amodal_px",
    # "visibility", oracle_* when run}; the fields above are cam_0's, but ``visibility`` is the minimum
    # over cameras (the paper's max occlusion over cameras), the value the keep rule used
    views: tuple[dict[str, Any], ...] = ()

    @property
    def kept(self) -> bool:
        return self.status == KEPT

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k in ("spawn_matrix", "matrix_world"):
            if d[k] is not None:
                d[k] = [list(r) for r in d[k]]
        if d["origin_px"] is not None:
            d["origin_px"] = list(d["origin_px"])
        d["views"] = [dict(v) for v in self.views]
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ObjectResult":
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown ObjectResult fields {sorted(unknown)}")
        v = dict(d)
        v["spawn_matrix"] = _matrix(v["spawn_matrix"])
        v["matrix_world"] = _matrix(v.get("matrix_world"))
        if v.get("origin_px") is not None:
            v["origin_px"] = (float(v["origin_px"][0]), float(v["origin_px"][1]))
        v["views"] = tuple(dict(x) for x in v.get("views", ()))
        return cls(**v)


@dataclass(frozen=True)
class SceneResult:
    """The worker's answer for one scene (see module docstring)."""

    status: str  # STATUS_OK | STATUS_EMPTY | STATUS_REJECTED
    stage: str
    scene_id: str
    seed: int
    visibility_threshold: float
    id_pass_rounds: int
    physics: dict[str, Any]  # the values used: frames, substeps, solver_iterations, gravity, settle fractions
    camera: dict[str, Any]
    lights: dict[str, Any]
    objects: tuple[ObjectResult, ...]
    diagnostics: tuple[dict[str, Any], ...] = ()
    timings: dict[str, float] = field(default_factory=dict)
    # one per camera, in stage order: {"name", "suffix" (file-name suffix: "" for cam_0, "_cam_1", ...),
    # "camera" (the record, as ``camera`` for cam_0), "framing" (how the settled pile framed it),
    # "passes" (written depth / normal records)}
    views: tuple[dict[str, Any], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["objects"] = [o.to_dict() for o in self.objects]
        d["diagnostics"] = [dict(x) for x in self.diagnostics]
        d["views"] = [dict(x) for x in self.views]
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SceneResult":
        v = dict(d)
        v["objects"] = tuple(ObjectResult.from_dict(o) for o in d["objects"])
        v["diagnostics"] = tuple(dict(x) for x in d.get("diagnostics", ()))
        v["timings"] = dict(d.get("timings", {}))
        v["views"] = tuple(dict(x) for x in d.get("views", ()))
        return cls(**v)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_json(cls, text: str) -> "SceneResult":
        return cls.from_dict(json.loads(text))


def view_suffix(k: int) -> str:
    """File-name suffix of camera ``k``'s outputs: cam_0 writes ``rgb.png``, camera k ``rgb_cam_<k>.png``
    (the export reader's image key, mixcount.export.reader.DatasetImage.key, reads it the same way)."""
    return "" if k == 0 else f"_cam_{k}"
