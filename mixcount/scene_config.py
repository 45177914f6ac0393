"""Scene-sampling parameters: the ``[scene]`` config section as a frozen dataclass (built by
:func:`mixcount.config.load_config`; the sampler reads it as ``cfg.scene``).

Geometric values marked "·s" in ``configs/default.toml`` are stored here unscaled; the sampler
multiplies them by :attr:`SceneConfig.scale` when it uses them, so the spec holds metres of the scene.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

from mixcount.errors import ConfigError

# floor patterns and default lights the [scene] section may name (scene/environment_sampling.py draws them)
PATTERNS = ("tiles", "bricks", "planks", "checker", "dots", "noise")
BUNDLED_HDRI = "bundled_hdri"
SKY = "sky"
DEFAULT_ENVIRONMENTS = (BUNDLED_HDRI, SKY)  # scene.default_environment: the light without ingested HDRIs
SIZE_PAPER, SIZE_REAL = "paper", "real"
SIZE_RULES = (SIZE_PAPER, SIZE_REAL)  # scene.size_rule: the paper's drawn sizes, or every object's real size

# where Cycles renders (compose.device, rerender.device; mixcount.engine.devices): the one list of the names
DEVICES = ("cpu", "gpu", "auto")
# how the views of a scene rendered from more cameras are annotated (rerender.annotation_rule)
RULE_ALL_CAMERAS = "all_cameras"  # the paper's rule: kept when occluded less than v_t in every view (others removed)
RULE_PER_VIEW = "per_view"  # each view annotates the objects occluded less than v_t in it (none removed)
ANNOTATION_RULES = (RULE_ALL_CAMERAS, RULE_PER_VIEW)


# ``[cycles]``: the RGB render's Cycles settings, recorded in every spec as they are (RenderSpec.cycles)
DENOISING_QUALITIES = ("HIGH", "BALANCED", "FAST")
TEXTURE_LIMITS = ("OFF", "128", "256", "512", "1024", "2048", "4096", "8192")
PIXEL_FILTERS = ("BLACKMAN_HARRIS", "GAUSSIAN", "BOX")
SAMPLING_PATTERNS = ("TABULATED_SOBOL", "BLUE_NOISE", "AUTOMATIC")
WORLD_SAMPLING = ("AUTOMATIC", "MANUAL", "NONE")


@dataclass(frozen=True)
class CyclesSpec:
    """Every Cycles setting of the RGB render that shapes the image, besides RenderSpec's samples, denoiser
    switch and prefilter (``[cycles]``, chosen with ``bench/render_quality.py``, docs/performance.md).

    The field names are Blender 5.0's ``scene.cycles`` properties except ``adaptive_threshold`` (0 = adaptive
    sampling off, else ``use_adaptive_sampling`` with this ``adaptive_threshold``), ``light_tree``
    (``use_light_tree``), ``texture_limit`` (``texture_limit_render``), ``pixel_filter`` (the pixel filter
    type) and the two ``world_*`` fields (the world's ``cycles`` settings). Specs written before it existed read as :data:`CYCLES_BEFORE`, the settings of that time."""

    adaptive_threshold: float
    adaptive_min_samples: int  # 0 = Cycles' own minimum, ceil(16 / threshold ** 0.3) (64 at 0.01)
    max_bounces: int
    diffuse_bounces: int
    glossy_bounces: int
    transmission_bounces: int
    transparent_max_bounces: int
    volume_bounces: int
    light_tree: bool
    caustics_reflective: bool
    caustics_refractive: bool
    blur_glossy: float
    sample_clamp_direct: float
    sample_clamp_indirect: float
    denoising_quality: str  # OIDN: HIGH | BALANCED | FAST
    texture_limit: str  # OFF | 128 ... 8192: largest texture side Cycles keeps
    pixel_filter: str  # BLACKMAN_HARRIS | GAUSSIAN | BOX
    filter_width: float  # pixels
    sampling_pattern: str  # TABULATED_SOBOL | BLUE_NOISE | AUTOMATIC
    world_sampling: str  # the world light's importance sampling (world.cycles.sampling_method): AUTOMATIC | MANUAL | NONE
    world_map_resolution: int  # its map's size with MANUAL (world.cycles.sample_map_resolution)

    def validate(self) -> None:
        """Raise ConfigError naming the first value Blender would refuse or misread (``[cycles]``)."""
        from mixcount.errors import ConfigError

        choices = {"denoising_quality": DENOISING_QUALITIES, "texture_limit": TEXTURE_LIMITS,
                   "pixel_filter": PIXEL_FILTERS, "sampling_pattern": SAMPLING_PATTERNS,
                   "world_sampling": WORLD_SAMPLING}
        for key, allowed in choices.items():
            if getattr(self, key) not in allowed:
                raise ConfigError(f"cycles.{key} must be one of {', '.join(allowed)}, got {getattr(self, key)!r}")
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("int", "float") and value < 0:
                raise ConfigError(f"cycles.{f.name} must be >= 0, got {value!r}")
        if self.adaptive_threshold >= 1:
            raise ConfigError(f"cycles.adaptive_threshold must be < 1 (0 = off), got {self.adaptive_threshold!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CyclesSpec":
        kinds = {f.name: f.type for f in fields(cls)}
        cast = {"float": float, "int": int, "bool": bool, "str": str}
        unknown = sorted(set(d) - set(kinds))
        if unknown:
            raise ValueError(f"unknown Cycles setting(s) {unknown}; known: {sorted(kinds)}")
        missing = sorted(set(kinds) - set(d))
        if missing:
            raise ValueError(f"the Cycles record lacks setting(s) {missing} (written by another mixcount version?)")
        return cls(**{k: cast[str(kinds[k])](d[k]) for k in kinds})


# the RGB render's settings before [cycles] existed (adaptive sampling off, 8 bounces, Blender's defaults
# for the rest): what a stage without a ``cycles`` record renders with


CyclesConfig = CyclesSpec

Range = tuple[float, float]
IntRange = tuple[int, int]


def _range(key: str, value: Any, *, integer: bool = False) -> Any:
    try:
        lo, hi = value
    except (TypeError, ValueError):
        raise ConfigError(f"config key scene.{key} must be [low, high], got {value!r}") from None
    if integer:
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (lo, hi)):
            raise ConfigError(f"config key scene.{key} must hold integers, got {value!r}")
        lo, hi = int(lo), int(hi)
    else:
        lo, hi = float(lo), float(hi)
    if lo > hi:
        raise ConfigError(f"config key scene.{key}: low {lo} > high {hi}")
    return (lo, hi)


@dataclass(frozen=True)
class SceneConfig:
    """Every parameter the sampler and the stage writer read (see configs/default.toml for meaning)."""

    scale: float
    size_rule: str
    floor_shapes: tuple[str, ...]
    floor_half_extent: Range
    floor_thickness: float
    floor_uv_scale: Range
    floor_patterns: tuple[str, ...]
    floor_texture_px: int
    procedural_floor_probability: float
    no_container_probability: float
    container_scale_jitter: Range
    container_other_split_fallback: bool
    container_pile_area: Range
    floor_pile_margin: float
    n_objects: IntRange
    n_classes: IntRange
    count_target: str  # paper | uniform:A-B | histogram:PATH [,imbalance:R1-R2] (counts/targets.py)
    count_spawn_factor: tuple[float, float]  # spawned per visible target: floor scenes, container scenes
    count_container_need: float  # x target per class: the pile a target's container (floor: camera) is fitted to
    count_spawn_extra: int
    count_spawn_size_exponent: float  # x (largest class size / class size) ** this
    count_spawn_sqrt: float  # + ceil(this x sqrt(target)) per class
    count_spawn_elevation: float  # x 1 / (1 - this x cos(lowest camera elevation))
    count_reserve: tuple[float, float]  # per class ceil(a x target) + b bodies held out for a top-up
    count_topup_rounds: int
    count_rest_frames: int  # the rest check after the take-out (frames at most)
    count_rest_tolerance: float  # x size: a body moving more in the rest check takes that pose
    count_rest_verify: bool  # benches: one more whole-pile check by the settle's rule at the end, recorded only
    count_short_tolerance: tuple[float, float]  # kept when short by <= max(a, b x total)
    count_class_short_tolerance: int
    count_min_object_px: float
    class_size: Range
    instance_jitter: Range
    random_orientation: bool
    counted_exclude_categories: tuple[str, ...]
    p_same_object_resized: float
    p_same_category: float
    p_other_category: float
    p_colour_variant: float
    resize_ratio: Range
    spawn_margin: float
    spawn_min_semi_axis: float
    spawn_height: Range
    spawn_xy_no_container: Range
    spawn_max_tries: int
    spawn_stack: bool
    spawn_release_waves: bool
    spawn_wave_interval_frames: int
    spawn_wave_clearance: float
    n_distractors: IntRange
    distractor_base_size: float
    distractor_size_multiplier: Range
    distractor_margin: float
    distractor_ring: Range
    distractor_max_tries: int
    distractor_max_overlap: float
    physics_frames: int
    physics_substeps: int
    physics_solver_iterations: int
    collision_shape: str
    gravity: float
    settle_below_floor_fraction: float
    settle_penetration_fraction: float
    collision_proxies: bool
    physics_rest_speed: float
    physics_floor_collider_depth: float
    n_cameras: int
    camera_elevation_deg: Range
    camera_roll_deg: Range
    camera_distance_factor: float
    camera_distance_jitter: float
    camera_lookat_jitter: float
    camera_framing: str
    camera_fit_share: float
    camera_frame_margin: float
    focal_length_mm: float
    sensor_width_mm: float
    clip_range: Range
    environment_strength: Range
    sky_sun_elevation_deg: Range
    sky_sun_strength: Range
    sky_turbidity: Range
    default_environment: str

    @classmethod
    def from_section(cls, scene: Mapping[str, Any]) -> "SceneConfig":
        """Build from the merged ``[scene]`` values: ranges become checked (low, high) tuples."""
        int_ranges = {"n_objects", "n_classes", "n_distractors"}
        values: dict[str, Any] = {}
        for f in fields(cls):
            value = scene[f.name]
            if f.type in ("Range", "IntRange"):
                value = _range(f.name, value, integer=f.name in int_ranges)
            elif isinstance(value, (list, tuple)):
                value = tuple(value)
            values[f.name] = value
        return cls(**values)

    def validate(self) -> None:
        """Reject values the sampler cannot honour (they would fail later, less clearly)."""
        probs = (self.p_same_object_resized, self.p_same_category, self.p_other_category)
        if any(p < 0 for p in probs) or sum(probs) <= 0:
            raise ConfigError(f"scene class-construction probabilities must be >= 0 with a positive sum: {probs}")
        if not 0.0 <= self.p_colour_variant < 1.0:
            raise ConfigError(f"scene.p_colour_variant must lie in [0, 1), got {self.p_colour_variant}")
        if not 0.0 <= self.no_container_probability <= 1.0:
            raise ConfigError("scene.no_container_probability must lie in [0, 1]")
        if self.n_objects[0] < 1 or self.n_classes[0] < 1:
            raise ConfigError("scene.n_objects and scene.n_classes must be >= 1")
        if self.n_objects[1] < self.n_classes[1]:
            raise ConfigError("scene.n_objects high must be >= scene.n_classes high (one instance per class)")
        if self.count_container_need < 1.0:
            raise ConfigError("scene.count_container_need must be >= 1 (bodies per visible target object)")
        if not 0.0 <= self.count_spawn_elevation < 1.0:
            raise ConfigError("scene.count_spawn_elevation must lie in [0, 1)")
        if min(self.count_spawn_factor) < 1.0 or self.count_spawn_extra < 0 or min(self.count_short_tolerance) < 0:
            raise ConfigError("scene.count_spawn_factor must be >= 1, count_spawn_extra and the tolerances >= 0")
        if min(self.count_reserve) < 0 or self.count_topup_rounds < 0 or self.count_rest_frames < 0 \
                or self.count_rest_tolerance <= 0:
            raise ConfigError("scene.count_reserve, count_topup_rounds and count_rest_frames must be >= 0, "
                              "count_rest_tolerance > 0")
        if self.n_cameras < 1:
            raise ConfigError("scene.n_cameras must be >= 1")
        if self.size_rule not in SIZE_RULES:
            raise ConfigError(f"scene.size_rule must be one of {', '.join(SIZE_RULES)}, got {self.size_rule!r}")
        if self.camera_framing not in ("paper", "fit"):
            raise ConfigError(f"scene.camera_framing must be paper or fit, got {self.camera_framing!r}")
        if not 0.0 < self.camera_fit_share <= 1.0 or not 0.0 <= self.camera_frame_margin < 0.5:
            raise ConfigError("scene.camera_fit_share must lie in (0, 1] and scene.camera_frame_margin in [0, 0.5)")
        if self.container_pile_area[0] <= 0:
            raise ConfigError("scene.container_pile_area must be positive (container area / pile footprint)")
        if self.spawn_wave_interval_frames < 5 or self.spawn_wave_clearance < 0:
            # a held body is moved to its spot 3 frames before its release, parked before that
            raise ConfigError("scene.spawn_wave_interval_frames must be >= 5 and scene.spawn_wave_clearance >= 0")
        if self.resize_ratio[0] <= 1.0:
            raise ConfigError("scene.resize_ratio must be > 1 (a clearly different size)")
        unknown = set(self.floor_shapes) - {"cube", "cylinder"}
        if unknown or not self.floor_shapes:
            raise ConfigError(f"scene.floor_shapes must be cube and/or cylinder, got {self.floor_shapes}")
        bad = set(self.floor_patterns) - set(PATTERNS)
        if bad or not self.floor_patterns:
            raise ConfigError(f"scene.floor_patterns: unknown {sorted(bad)}; known {list(PATTERNS)}")
        if self.collision_shape not in ("convexHull", "convexDecomposition", "boundingCube", "boundingSphere", "none"):
            raise ConfigError(f"scene.collision_shape {self.collision_shape!r} is not a UsdPhysics approximation")
        if self.default_environment not in DEFAULT_ENVIRONMENTS:
            raise ConfigError(f"scene.default_environment must be one of {list(DEFAULT_ENVIRONMENTS)}, "
                              f"got {self.default_environment!r}")


@dataclass(frozen=True)
class RerenderConfig:
    """``[rerender]``: ``mixcount render`` (a finished scene rendered again from its settled stage, no
    physics; mixcount/run/rerender.py). ``resolution`` / ``samples`` 0 and ``denoise`` "scene" keep each
    scene's own values; ``device`` is where Cycles renders (run time only, never in a scene's spec)."""

    resolution: int
    samples: int
    denoise: str  # scene | on | off
    new_views: int  # new cameras by the paper's camera rule around the settled pile, besides the scene's own
    trajectory: str  # none | orbit
    frames: int  # orbit: cameras along it
    orbit_elevation_deg: float
    orbit_distance_factor: float  # x the scene's first camera's distance to the pile centre
    seed: int  # the new views' draw: default_rng([seed, scene seed])
    annotation_rule: str  # all_cameras (the paper's) | per_view
    device: str  # cpu | gpu | auto
    persistent_data: bool  # keep Cycles' scene data between the views' RGB renders
    timeout_s: float  # one scene's re-render, all views

    @property
    def adds_views(self) -> bool:
        """Whether it adds cameras to a scene (``new_views`` or an orbit): without, compose renders each
        scene's own cameras only and builds no view plan."""
        return self.new_views > 0 or self.trajectory == "orbit"

    def validate(self) -> None:
        from mixcount.errors import ConfigError

        checks = {"denoise": (self.denoise, ("scene", "on", "off")), "trajectory": (self.trajectory, ("none", "orbit")),
                  "annotation_rule": (self.annotation_rule, ANNOTATION_RULES), "device": (self.device, DEVICES)}
        for key, (value, allowed) in checks.items():
            if value not in allowed:
                raise ConfigError(f"rerender.{key} = {value!r}: choose one of {', '.join(allowed)}")
        if self.new_views < 0 or self.frames < 1 or self.resolution < 0 or self.samples < 0:
            raise ConfigError("rerender.new_views, resolution and samples must be >= 0 and rerender.frames >= 1")
