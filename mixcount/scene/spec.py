"""Frozen, JSON-able description of one scene: what the sampler decides and every engine consumes.

Units are metres of the *scene* (already multiplied by the scene scale s), Z is up, angles in degrees,
quaternions are (w, x, y, z). ``SceneSpec.to_dict()`` is stored verbatim (sorted-key JSON) in the stage's
``customLayerData["mixcount:spec"]``; ``SceneSpec.from_dict`` reads it back.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any, Mapping, Optional

from mixcount.scene_config import DENOISING_QUALITIES as DENOISING_QUALITIES  # [cycles] vocabulary and settings

# live in the foundation, beside the config that reads them
from mixcount.scene_config import PIXEL_FILTERS as PIXEL_FILTERS
from mixcount.scene_config import SAMPLING_PATTERNS as SAMPLING_PATTERNS
from mixcount.scene_config import TEXTURE_LIMITS as TEXTURE_LIMITS
from mixcount.scene_config import WORLD_SAMPLING as WORLD_SAMPLING
from mixcount.scene_config import CyclesSpec as CyclesSpec

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

ROLE_COUNTED = "counted"
ROLE_DISTRACTOR = "distractor"
ROLE_CONTAINER = "container"
ROLE_FLOOR = "floor"


def _t(v: Any) -> tuple[Any, ...]:
    return tuple(float(x) for x in v)


TIERS = ("short", "concise", "detailed")  # the three caption tiers, shortest first


@dataclass(frozen=True)
class Captions:
    short: str
    concise: str
    detailed: str

    def to_dict(self) -> dict[str, str]:
        return {"short": self.short, "concise": self.concise, "detailed": self.detailed}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Captions":
        return cls(str(d["short"]), str(d["concise"]), str(d["detailed"]))


@dataclass(frozen=True)
class AssetRef:
    """One catalog object used by the scene: where its model is and its real size (metres, Z-up)."""

    object_id: int
    name: str
    category: str
    model_path: str
    content_hash: str
    dims_m: Vec3
    collision_path: Optional[str] = None
    proxy_path: Optional[str] = None  # convex collision proxy (catalog/proxies.py)
    source_units: Optional[str] = None  # only meaningful for OBJ/PLY/STL (formats without units)
    source_up_axis: Optional[str] = None
    source: Optional[str] = None  # provenance (ATTRIBUTION.json): ingest source, its key, licence text
    source_id: Optional[str] = None
    license: Optional[str] = None
    look: Optional[tuple[float, ...]] = None  # (sRGB r, g, b, metallic, roughness) of parts without a colour

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["dims_m"] = list(self.dims_m)
        if self.look is None:
            del d["look"]  # specs of coloured assets stay as they were
        else:
            d["look"] = list(self.look)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "AssetRef":
        return cls(
            object_id=int(d["object_id"]), name=str(d["name"]), category=str(d["category"]),
            model_path=str(d["model_path"]), content_hash=str(d["content_hash"]), dims_m=_t(d["dims_m"]),
            collision_path=d.get("collision_path"), proxy_path=d.get("proxy_path"), source_units=d.get("source_units"),
            source_up_axis=d.get("source_up_axis"), source=d.get("source"), source_id=d.get("source_id"),
            license=d.get("license"), look=None if d.get("look") is None else tuple(float(v) for v in d["look"]),
        )


@dataclass(frozen=True)
class ObjectClass:
    """One class to count. ``construction``: first | same_object_resized | same_category | other_category.

    ``captions`` already carry the "Larger"/"Smaller" qualifier when the object appears at two sizes
    (both classes of the pair get one); ``base_class_index`` names the class a resized copy came from.
    """

    class_index: int
    object_id: int
    name: str
    category: str
    captions: Captions
    size_qualifier: Optional[str]  # "larger" | "smaller" | None
    target_size_m: float  # d_max in scene metres: the largest side of the normalised template
    count: int
    construction: str
    base_class_index: Optional[int] = None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["captions"] = self.captions.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ObjectClass":
        return cls(
            class_index=int(d["class_index"]), object_id=int(d["object_id"]), name=str(d["name"]),
            category=str(d["category"]), captions=Captions.from_dict(d["captions"]),
            size_qualifier=d.get("size_qualifier"), target_size_m=float(d["target_size_m"]),
            count=int(d["count"]), construction=str(d["construction"]),
            base_class_index=None if d.get("base_class_index") is None else int(d["base_class_index"]),
        )


@dataclass(frozen=True)
class PlacedObject:
    """One instance at its spawn pose: counted (class_index >= 0) or distractor (class_index -1).

    ``scale`` multiplies the asset (whose origin is its bounding-box centre, in real metres) and
    ``size_m`` is the resulting largest side in the scene.
    """

    instance_id: int
    role: str
    object_id: int
    class_index: int
    position: Vec3
    orientation: Quat
    scale: Vec3
    size_m: float
    # the simulation frame the body is let go at (spawn waves, docs/scene.md); 1 = at the start, which
    # specs written before waves existed mean
    release_frame: int = 1

    def to_dict(self) -> dict[str, Any]:
        return {
            "instance_id": self.instance_id, "role": self.role, "object_id": self.object_id,
            "class_index": self.class_index, "position": list(self.position),
            "orientation": list(self.orientation), "scale": list(self.scale), "size_m": self.size_m,
            "release_frame": self.release_frame,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "PlacedObject":
        return cls(
            instance_id=int(d["instance_id"]), role=str(d["role"]), object_id=int(d["object_id"]),
            class_index=int(d["class_index"]), position=_t(d["position"]), orientation=_t(d["orientation"]),
            scale=_t(d["scale"]), size_m=float(d["size_m"]), release_frame=int(d.get("release_frame", 1)),
        )


@dataclass(frozen=True)
class ContainerSpec:
    """The container instance: per-axis scale (jitter·s), resting on the floor, random yaw."""

    instance_id: int
    object_id: int
    position: Vec3
    orientation: Quat
    scale: Vec3
    extent_m: Vec3  # scaled AABB size in the scene (before yaw)
    pile_fit: float  # XY factor (and Z when < 1) applied after the jitter so the container holds its pile (1 = none)

    def to_dict(self) -> dict[str, Any]:
        return {
            "instance_id": self.instance_id, "object_id": self.object_id, "position": list(self.position),
            "orientation": list(self.orientation), "scale": list(self.scale), "extent_m": list(self.extent_m),
            "pile_fit": self.pile_fit,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ContainerSpec":
        return cls(
            instance_id=int(d["instance_id"]), object_id=int(d["object_id"]), position=_t(d["position"]),
            orientation=_t(d["orientation"]), scale=_t(d["scale"]), extent_m=_t(d["extent_m"]),
            pile_fit=float(d.get("pile_fit", 1.0)),
        )


@dataclass(frozen=True)
class MaterialSpec:
    """Floor material. kind "procedural": ``params`` holds pattern, colours, seed, ... and the stage
    writer renders them to a seamless PNG (``mixcount.scene.environment_sampling.render_pattern``);
    kind "pbr": ``maps`` names map -> absolute file (base_color, roughness, normal, ...)."""

    kind: str
    name: str
    params: Mapping[str, Any] = field(default_factory=dict)
    maps: Mapping[str, str] = field(default_factory=dict)
    material_id: Optional[int] = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind, "name": self.name, "params": json.loads(json.dumps(dict(self.params))),
            "maps": dict(sorted(self.maps.items())), "material_id": self.material_id,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "MaterialSpec":
        return cls(
            kind=str(d["kind"]), name=str(d["name"]), params=dict(d.get("params") or {}),
            maps=dict(d.get("maps") or {}), material_id=d.get("material_id"),
        )


@dataclass(frozen=True)
class FloorSpec:
    """A cube (``size`` = half side x, half side y) or cylinder (``size`` = radius, radius); top at z = 0.
    ``uv_scale_m``: one texture repeat spans this many scene metres (u·s)."""

    shape: str
    half_extent: tuple[float, float]
    thickness: float
    uv_scale_m: float
    material: MaterialSpec

    def to_dict(self) -> dict[str, Any]:
        return {
            "shape": self.shape, "half_extent": list(self.half_extent), "thickness": self.thickness,
            "uv_scale_m": self.uv_scale_m, "material": self.material.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "FloorSpec":
        return cls(
            shape=str(d["shape"]), half_extent=_t(d["half_extent"]), thickness=float(d["thickness"]),
            uv_scale_m=float(d["uv_scale_m"]), material=MaterialSpec.from_dict(d["material"]),
        )


@dataclass(frozen=True)
class EnvironmentSpec:
    """kind "hdri": an ingested map (``path``) turned by ``rotation_deg`` about Z, times ``strength``.
    kind "sky": procedural sky with a sun (elevation/azimuth in degrees, strengths, turbidity)."""

    kind: str
    strength: float
    rotation_deg: float = 0.0
    environment_id: Optional[int] = None
    path: Optional[str] = None
    sun_elevation_deg: Optional[float] = None
    sun_azimuth_deg: Optional[float] = None
    sun_strength: Optional[float] = None
    turbidity: Optional[float] = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "EnvironmentSpec":
        return cls(**{k: d.get(k) for k in cls.__dataclass_fields__})  # type: ignore[arg-type]


@dataclass(frozen=True)
class CameraSpec:
    """A pinhole camera. ``orientation`` is the USD/Blender camera convention (looks down local -Z,
    +Y up), roll included. Sensor is square when the image is (focal length and sensor in mm)."""

    name: str
    position: Vec3
    look_at: Vec3
    orientation: Quat
    elevation_deg: float
    azimuth_deg: float
    roll_deg: float
    distance: float
    focal_length_mm: float
    sensor_width_mm: float
    sensor_height_mm: float
    resolution: tuple[int, int]
    clip_range: tuple[float, float]
    # How the worker frames the settled pile (mixcount.scene.framing): "paper" | "fit" | "fixed" (the pose
    # above as it is). position / look_at / orientation / distance are then the provisional pose before
    # physics; the drawn jitters below are applied to the settled pile's centre and distance rule.
    framing: str
    lookat_offset: Vec3  # look-at jitter added to the settled pile's centre
    distance_scale: float  # 1 + U(-camera_distance_jitter, +camera_distance_jitter)
    distance_factor: float  # "paper": distance = factor x ||diag AABB(container)|| x distance_scale
    fit_share: float  # "fit": share of settled counted origins the frame must hold
    # "pile": the base diagonal is that of a square of pile_area x the settled pile's one-layer footprint (the
    # container a paper scene fits to its pile), so a real-size scene shows the paper's pixels per object
    pile_area: Optional[float] = None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if d["pile_area"] is None:
            del d["pile_area"]  # paper scenes keep their bytes
        for k in ("position", "look_at", "orientation", "resolution", "clip_range", "lookat_offset"):
            d[k] = list(d[k])
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CameraSpec":
        return cls(
            name=str(d["name"]), position=_t(d["position"]), look_at=_t(d["look_at"]),
            orientation=_t(d["orientation"]), elevation_deg=float(d["elevation_deg"]),
            azimuth_deg=float(d["azimuth_deg"]), roll_deg=float(d["roll_deg"]), distance=float(d["distance"]),
            focal_length_mm=float(d["focal_length_mm"]), sensor_width_mm=float(d["sensor_width_mm"]),
            sensor_height_mm=float(d["sensor_height_mm"]),
            resolution=(int(d["resolution"][0]), int(d["resolution"][1])), clip_range=_t(d["clip_range"]),
            # specs written before post-physics framing: the pose is final ("fixed")
            framing=str(d.get("framing", "fixed")), lookat_offset=_t(d.get("lookat_offset", (0.0, 0.0, 0.0))),
            distance_scale=float(d.get("distance_scale", 1.0)), distance_factor=float(d.get("distance_factor", 0.0)),
            fit_share=float(d.get("fit_share", 1.0)),
            pile_area=None if d.get("pile_area") is None else float(d["pile_area"]),
        )


@dataclass(frozen=True)
class PhysicsSpec:
    frames: int
    substeps: int
    solver_iterations: int
    collision_shape: str
    gravity: float
    settle_below_floor_fraction: float  # the worker's settle checks (see mixcount.scene_decisions)
    settle_penetration_fraction: float
    collision_proxies: bool  # counted objects / distractors collide through their convex proxy
    rest_speed: float  # m/s: stop the simulation once every body is slower (0 = all frames)
    floor_collider_depth: float  # m below the floor's top that the floor collides (0 = its thickness)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "PhysicsSpec":
        return cls(frames=int(d["frames"]), substeps=int(d["substeps"]), solver_iterations=int(d["solver_iterations"]),
                   collision_shape=str(d["collision_shape"]), gravity=float(d["gravity"]),
                   settle_below_floor_fraction=float(d["settle_below_floor_fraction"]),
                   settle_penetration_fraction=float(d["settle_penetration_fraction"]),
                   collision_proxies=bool(d.get("collision_proxies", True)),
                   rest_speed=float(d.get("rest_speed", 0.0)),
                   floor_collider_depth=float(d.get("floor_collider_depth", 0.0)))


CYCLES_BEFORE = CyclesSpec(
    adaptive_threshold=0.0, adaptive_min_samples=0, max_bounces=8, diffuse_bounces=3, glossy_bounces=3,
    transmission_bounces=4, transparent_max_bounces=8, volume_bounces=0, light_tree=True,
    caustics_reflective=True, caustics_refractive=True, blur_glossy=1.0, sample_clamp_direct=0.0,
    sample_clamp_indirect=10.0, denoising_quality="HIGH", texture_limit="OFF", pixel_filter="BLACKMAN_HARRIS",
    filter_width=1.5, sampling_pattern="TABULATED_SOBOL", world_sampling="AUTOMATIC", world_map_resolution=1024)


@dataclass(frozen=True)
class RenderSpec:
    resolution: int
    samples: int
    denoise: bool
    visibility_threshold: float
    denoise_prefilter: str  # Cycles' OIDN prefilter (specs written before it existed read as "ACCURATE")
    cycles: CyclesSpec  # the rest of the RGB render's settings (specs without it read as CYCLES_BEFORE)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "RenderSpec":
        return cls(resolution=int(d["resolution"]), samples=int(d["samples"]), denoise=bool(d["denoise"]),
                   visibility_threshold=float(d["visibility_threshold"]),
                   denoise_prefilter=str(d.get("denoise_prefilter", "ACCURATE")),
                   cycles=CyclesSpec.from_dict(d["cycles"]) if "cycles" in d else CYCLES_BEFORE)


@dataclass(frozen=True)
class PlacementSpec:
    """What the worker places after physics (mixcount.scene.framing): every camera framed on the settled
    pile, and the distractors (not simulated) put on free floor in view. Specs written before it have
    none: their cameras and distractors stay where the sampler put them, distractors simulated."""

    frame_margin: float  # image border kept clear (fraction per side): fit framing, distractor origins
    distractor_margin: float  # m between a distractor's footprint and the pile, container, other distractors
    distractor_tries: int  # candidate spots per distractor
    distractor_max_overlap: float  # share of its image box that counted objects' boxes may cover
    view_radius: float  # m: bodies farther from the pile's centre are not waited for by the early stop

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "PlacementSpec":
        return cls(float(d["frame_margin"]), float(d["distractor_margin"]), int(d["distractor_tries"]),
                   float(d["distractor_max_overlap"]), float(d["view_radius"]))


@dataclass(frozen=True)
class SceneSpec:
    """One scene. ``objects`` are the counted instances (instance ids 1..n), then ``distractors``,
    then the container; ``assets`` lists every catalog object used, sorted by object_id."""

    scene_id: str
    seed: int
    split: str
    scale: float
    config_hash: str
    classes: tuple[ObjectClass, ...]
    objects: tuple[PlacedObject, ...]
    distractors: tuple[PlacedObject, ...]
    container: Optional[ContainerSpec]
    floor: FloorSpec
    environment: EnvironmentSpec
    cameras: tuple[CameraSpec, ...]
    physics: PhysicsSpec
    render: RenderSpec
    assets: tuple[AssetRef, ...]
    version: int = 1
    placement: Optional[PlacementSpec] = None  # None: a spec written before after-physics placement
    # the visible counts asked for (counts/targets.py target_record); None: the paper's spawned-count rule
    count_target: Optional[Mapping[str, Any]] = None
    # "real": every object at its real size, ``scale`` chosen for this scene (docs/scene.md); None: the paper's
    size_rule: Optional[str] = None

    @property
    def n_counted(self) -> int:
        return len(self.objects)

    def asset(self, object_id: int) -> AssetRef:
        for a in self.assets:
            if a.object_id == object_id:
                return a
        raise KeyError(object_id)

    def counts_per_class(self) -> dict[int, int]:
        counts = {c.class_index: 0 for c in self.classes}
        for o in self.objects:
            counts[o.class_index] += 1
        return counts

    def to_dict(self) -> dict[str, Any]:
        return {
            "version": self.version, "scene_id": self.scene_id, "seed": self.seed, "split": self.split,
            "scale": self.scale, "config_hash": self.config_hash,
            "classes": [c.to_dict() for c in self.classes],
            "objects": [o.to_dict() for o in self.objects],
            "distractors": [o.to_dict() for o in self.distractors],
            "container": None if self.container is None else self.container.to_dict(),
            "floor": self.floor.to_dict(), "environment": self.environment.to_dict(),
            "cameras": [c.to_dict() for c in self.cameras], "physics": self.physics.to_dict(),
            "render": self.render.to_dict(), "assets": [a.to_dict() for a in self.assets],
            "placement": None if self.placement is None else self.placement.to_dict(),
            # only with a target: the paper's specs keep their bytes (and config hash) as before
            **({} if self.count_target is None else {"count_target": dict(self.count_target)}),
            **({} if self.size_rule is None else {"size_rule": self.size_rule}),
        }

    def to_json(self) -> str:
        """Canonical JSON (sorted keys, no whitespace): identical bytes for identical specs."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SceneSpec":
        return cls(
            scene_id=str(d["scene_id"]), seed=int(d["seed"]), split=str(d["split"]), scale=float(d["scale"]),
            config_hash=str(d["config_hash"]),
            classes=tuple(ObjectClass.from_dict(c) for c in d["classes"]),
            objects=tuple(PlacedObject.from_dict(o) for o in d["objects"]),
            distractors=tuple(PlacedObject.from_dict(o) for o in d["distractors"]),
            container=None if d.get("container") is None else ContainerSpec.from_dict(d["container"]),
            floor=FloorSpec.from_dict(d["floor"]), environment=EnvironmentSpec.from_dict(d["environment"]),
            cameras=tuple(CameraSpec.from_dict(c) for c in d["cameras"]),
            physics=PhysicsSpec.from_dict(d["physics"]), render=RenderSpec.from_dict(d["render"]),
            assets=tuple(AssetRef.from_dict(a) for a in d["assets"]), version=int(d.get("version", 1)),
            placement=None if d.get("placement") is None else PlacementSpec.from_dict(d["placement"]),
            count_target=None if d.get("count_target") is None else dict(d["count_target"]),
            size_rule=None if d.get("size_rule") is None else str(d["size_rule"]),
        )

    @classmethod
    def from_json(cls, text: str) -> "SceneSpec":
        return cls.from_dict(json.loads(text))
