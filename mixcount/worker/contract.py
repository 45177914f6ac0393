"""The typed contract of the ``scene``, ``settle`` and ``cache_meshes`` operations between the parent
process and the bpy worker (imports neither bpy nor pxr); the ``canonical`` op's pair is in
:mod:`mixcount.worker.canonical_contract`, the ``rerender`` and ``devices`` ops' in
:mod:`mixcount.worker.rerender_contract` (split by operation so each file holds one concern).

One frozen request / result pair per worker operation, each with a JSON round-trip (``to_dict`` /
``from_dict``, fields checked by :func:`known_fields`); :class:`~mixcount.worker.client.BlenderWorker`
sends ``{"op": <request>.OP, "request": ...}`` and the worker answers ``{"ok": true, "result": ...}``
(:mod:`mixcount.engine.worker_main`):

* ``scene`` - :class:`SceneRequest` -> :class:`SceneResult`. The request carries the stage and the output
  folder plus RUN-TIME settings only (render threads, the one-render-per-object reference, which passes
  in which formats, the mesh cache). Everything that describes the scene (samples, denoise, visibility
  threshold, physics) travels in the stage (its SceneSpec), never here. The result (answered over the
  pipe; the parent keeps it in metadata.json) holds status, camera, lights, the physics values actually used,
  one :class:`ObjectResult` per counted object / distractor, one :class:`CameraView` per camera with the
  pass files it wrote, diagnostics and timings. A ``scene`` request with ``more_views`` (:class:`MoreViews`,
  ``compose --views``) renders the new cameras in the same request, right after the scene's own.
* ``settle`` - :class:`SceneRequest` -> :class:`SettleResult`: only the scene's rigid-body settle, its
  poses written to ``settled.json`` in the request's out_dir, so a second bpy process can settle the next
  scene while the first renders (``compose.settle_ahead``, :class:`~mixcount.worker.settle_ahead.SettleAheadWorker`);
  a ``scene`` request whose ``settled_poses_file`` names that file applies the poses instead of simulating.
* ``cache_meshes`` - :class:`MeshCacheRequest` -> :class:`MeshCacheResult`: each converted asset's .blend
  mesh cache made ahead of the scenes.

No request field has a default: every setting comes from the caller (from the configuration, read once).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar, Mapping, Optional

from mixcount.config import MESH_CACHE_MODES as MESH_CACHE_MODES  # re-exported for the worker side
from mixcount.config import ComposeConfig
from mixcount.errors import CompositionError
from mixcount.scene.views import ViewPlan
from mixcount.scene_config import RerenderConfig, SceneConfig
from mixcount.scene_decisions import STATUS_EMPTY as STATUS_EMPTY  # defined beside the rule that decides them
from mixcount.scene_decisions import STATUS_OK as STATUS_OK
from mixcount.scene_decisions import STATUS_REJECTED as STATUS_REJECTED

KEPT = "kept"
DROPPED = "dropped"

Matrix = tuple[tuple[float, ...], ...]


def as_matrix(m: Any) -> Optional[Matrix]:
    """A 4x4 (or any nested sequence) as a tuple of float tuples; None stays None."""
    return None if m is None else tuple(tuple(float(v) for v in row) for row in m)


def known_fields(cls: type, d: Mapping[str, Any]) -> dict[str, Any]:
    """``d`` checked against ``cls``'s fields: a missing or unknown one is a ValueError that names it."""
    names = [f.name for f in fields(cls)]
    missing, unknown = [n for n in names if n not in d], sorted(set(d) - set(names))
    if missing or unknown:
        raise ValueError(f"{cls.__name__}: missing fields {missing}, unknown fields {unknown}")
    return {n: d[n] for n in names}


@dataclass(frozen=True)
class SceneOutputs:
    """What a scene writes besides rgb, and how: the passes (canonical order), their file formats and the
    worker's mesh cache. :meth:`from_config` is the one place ``[compose]`` (or ``--passes``) becomes them;
    a :class:`SceneRequest` carries them to the worker."""

    passes: tuple[str, ...]
    depth_format: str  # mixcount.annotate.passes.DEPTH_FORMATS
    normal_format: str  # mixcount.annotate.passes.NORMAL_FORMATS
    mesh_cache: str  # one of MESH_CACHE_MODES

    @classmethod
    def from_config(cls, compose: ComposeConfig, passes: Optional[str | list[str] | tuple[str, ...]] = None
                    ) -> "SceneOutputs":
        """``[compose]``'s passes (or ``passes``), pass formats and mesh cache, checked: a bad value is a
        CompositionError that names it."""
        from mixcount.annotate.passes import DEPTH_FORMATS, NORMAL_FORMATS, parse_passes

        try:
            chosen = parse_passes(compose.passes if passes is None else passes)
        except ValueError as exc:
            raise CompositionError(str(exc)) from None
        if compose.depth_format not in DEPTH_FORMATS or compose.normal_format not in NORMAL_FORMATS:
            raise CompositionError(f"compose.depth_format must be one of {', '.join(DEPTH_FORMATS)} and "
                                   f"compose.normal_format one of {', '.join(NORMAL_FORMATS)}")
        return cls(passes=chosen, depth_format=compose.depth_format, normal_format=compose.normal_format,
                   mesh_cache=compose.mesh_cache)


@dataclass(frozen=True)
class SceneRequest:
    """One ``scene`` request: render ``stage`` into ``out_dir``."""

    OP: ClassVar[str] = "scene"

    stage: str
    out_dir: str
    threads: int  # Cycles threads (0 = Blender's automatic choice)
    oracle: bool  # also run the one-render-per-object reference and write oracle_masks.npz
    # which of depth / normal to write and how (compose.passes / depth_format / normal_format, formats of
    # mixcount.annotate.passes); the id map is always written
    passes: tuple[str, ...]
    depth_format: str
    normal_format: str
    mesh_cache: str  # compose.mesh_cache, one of MESH_CACHE_MODES
    # the settled.json a ``settle`` request wrote for this stage: poses by prim path ("" = simulate here)
    settled_poses_file: str
    # new cameras rendered after the scene's own, in this request (``compose --views``; None: none)
    more_views: Optional["MoreViews"]
    # where Cycles renders: "cpu" | "gpu" | "auto" (``compose.device`` as the run resolved it; None: the CPU)
    device: Optional[str] = None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["passes"] = list(self.passes)
        d["more_views"] = None if self.more_views is None else self.more_views.to_dict()
        return d

    @classmethod
    def for_outputs(cls, outputs: SceneOutputs, *, stage: str, out_dir: str, threads: int, oracle: bool,
                    settled_poses_file: str = "", more_views: Optional["MoreViews"] = None,
                    device: Optional[str] = None) -> "SceneRequest":
        """The request that renders ``stage`` into ``out_dir`` writing ``outputs`` (and ``more_views``)."""
        return cls(stage=stage, out_dir=out_dir, threads=threads, oracle=oracle, passes=tuple(outputs.passes),
                   depth_format=outputs.depth_format, normal_format=outputs.normal_format,
                   mesh_cache=outputs.mesh_cache, settled_poses_file=settled_poses_file,
                   more_views=more_views, device=device)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SceneRequest":
        v = known_fields(cls, d)
        return cls(stage=str(v["stage"]), out_dir=str(v["out_dir"]), threads=int(v["threads"]),
                   oracle=bool(v["oracle"]), passes=tuple(str(p) for p in v["passes"]),
                   depth_format=str(v["depth_format"]), normal_format=str(v["normal_format"]),
                   mesh_cache=str(v["mesh_cache"]), settled_poses_file=str(v["settled_poses_file"]),
                   more_views=None if v["more_views"] is None else MoreViews.from_dict(v["more_views"]),
                   device=None if v.get("device") is None else str(v["device"]))


@dataclass(frozen=True)
class MoreViews:
    """``compose --views K``: the cameras ``plan`` adds to a scene once its own are rendered, in the same
    ``scene`` request (the pile settled and imported once), annotated over all views by ``rule`` (one of
    mixcount.scene_config.ANNOTATION_RULES), with Cycles' scene data kept between the views' RGB renders when ``persistent_data``."""

    plan: ViewPlan
    rule: str
    persistent_data: bool

    @classmethod
    def from_config(cls, rerender: RerenderConfig, scene: SceneConfig) -> Optional["MoreViews"]:
        """``[rerender]``'s views, rule and persistent data (``[scene]``'s camera rule); None when it adds no view."""
        if not rerender.adds_views:
            return None
        return cls(plan=ViewPlan.from_config(rerender, scene), rule=rerender.annotation_rule,
                   persistent_data=rerender.persistent_data)

    def to_dict(self) -> dict[str, Any]:
        return {"plan": self.plan.to_dict(), "rule": self.rule, "persistent_data": self.persistent_data}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "MoreViews":
        v = known_fields(cls, d)
        return cls(plan=ViewPlan.from_dict(v["plan"]), rule=str(v["rule"]), persistent_data=bool(v["persistent_data"]))


SETTLED_FILE = "settled.json"  # what a ``settle`` request writes into its out_dir


@dataclass(frozen=True)
class SettleResult:
    """What a ``settle`` request did: the poses file it wrote and how the simulation went."""

    OP: ClassVar[str] = "settle"

    poses_file: str  # path of the settled.json (stage, poses by instance prim path, the rest diagnostic)
    frames_run: int
    seconds: dict[str, float]  # import, physics

    def to_dict(self) -> dict[str, Any]:
        return {"poses_file": self.poses_file, "frames_run": self.frames_run, "seconds": dict(self.seconds)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SettleResult":
        v = known_fields(cls, d)
        return cls(poses_file=str(v["poses_file"]), frames_run=int(v["frames_run"]),
                   seconds={str(k): float(x) for k, x in v["seconds"].items()})


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
        v["spawn_matrix"] = as_matrix(v["spawn_matrix"])
        v["matrix_world"] = as_matrix(v.get("matrix_world"))
        if v.get("origin_px") is not None:
            v["origin_px"] = (float(v["origin_px"][0]), float(v["origin_px"][1]))
        v["views"] = tuple(dict(x) for x in v.get("views", ()))
        return cls(**v)


@dataclass(frozen=True)
class CameraView:
    """What one camera of a scene gave: its record, how the settled pile framed it, the files it wrote."""

    name: str  # the camera prim's name (cam_0, cam_1, ...)
    suffix: str  # file-name suffix of its outputs: "" for cam_0, "_cam_1", ... (view_suffix)
    camera: dict[str, Any]  # the camera record (K, cam_to_world, lens, clip range); cam_0's is SceneResult.camera
    framing: dict[str, Any]  # how the settled pile framed it ({"framing": "fixed"} for an unmoved camera)
    passes: dict[str, dict[str, Any]]  # written depth / normal pass -> its record (file, format, unit, ...)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "suffix": self.suffix, "camera": dict(self.camera), "framing": dict(self.framing),
                "passes": {k: dict(v) for k, v in self.passes.items()}}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CameraView":
        v = known_fields(cls, d)
        return cls(name=str(v["name"]), suffix=str(v["suffix"]), camera=dict(v["camera"]),
                   framing=dict(v["framing"]), passes={str(k): dict(r) for k, r in dict(v["passes"]).items()})


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
    views: tuple[CameraView, ...]  # one per camera, in stage order
    diagnostics: tuple[dict[str, Any], ...]  # what happened: drops, cache events, physics rest, ...
    timings: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["objects"] = [o.to_dict() for o in self.objects]
        d["diagnostics"] = [dict(x) for x in self.diagnostics]
        d["views"] = [v.to_dict() for v in self.views]
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SceneResult":
        v = known_fields(cls, d)
        v["objects"] = tuple(ObjectResult.from_dict(o) for o in d["objects"])
        v["diagnostics"] = tuple(dict(x) for x in d["diagnostics"])
        v["timings"] = dict(d["timings"])
        v["views"] = tuple(CameraView.from_dict(x) for x in d["views"])
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


# ------------------------------------------------------------------------------ mesh-cache warm-up


# ------------------------------------------------------------------------------ mesh-cache warm-up


@dataclass(frozen=True)
class MeshCacheRequest:
    """One ``cache_meshes`` request: make each converted asset's .blend mesh cache in ``mode`` now."""

    OP: ClassVar[str] = "cache_meshes"

    assets: tuple[str, ...]  # converted asset files (.usdc)
    mode: str  # compose.mesh_cache, one of MESH_CACHE_MODES ("off": nothing to do)

    def to_dict(self) -> dict[str, Any]:
        return {"assets": list(self.assets), "mode": self.mode}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "MeshCacheRequest":
        v = known_fields(cls, d)
        return cls(assets=tuple(str(a) for a in v["assets"]), mode=str(v["mode"]))


@dataclass(frozen=True)
class MeshCacheResult:
    assets: dict[str, str]  # asset file name -> "hit" | "written" | why not

    def to_dict(self) -> dict[str, Any]:
        return {"assets": dict(self.assets)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "MeshCacheResult":
        return cls(assets=dict(known_fields(cls, d)["assets"]))
