"""The paper's scene sampler: one seed -> one :class:`~mixcount.scene.spec.SceneSpec`, always the same.

Order of decisions (each from the one ``numpy.random.Generator`` built from the seed): environment,
floor, container, number of instances and classes, class construction, per-class counts, counted
spawn poses, distractors, cameras. Everything geometric is in scene metres (real size x scale s).

Class construction (paper, section 3 and supplementary): the first class is an eligible object of the
split; each further class is (a) an existing class's object at a clearly different size (ratio in
``resize_ratio``; both classes of the pair get a "larger"/"smaller" qualifier in place of their
captions' size word), (b) another object of an existing class's category, or (c) an object of a
category not yet in the scene, with the configured probabilities; infeasible options are dropped and
the rest renormalised. Beside the paper's three, (d) a colour variant of an existing class's object
(``ObjectRecord.variants``, from the catalog's ``colour_variant`` flags: one geometry in other colours,
told apart only by the prompt) is taken with probability ``p_colour_variant`` where one is free; the
paper's three share the rest in their own proportions (:func:`construction_weights`).

Unique prompts: no two objects of one scene (counted classes and distractors) share a caption at any
tier (compared by :func:`~mixcount.scene.caption_text.normalise_caption`), so every prompt names one class.
An object whose captions collide with one already in the scene is never drawn for it.

Spawn order: the counted instances' class labels are shuffled before placement, so each spawn
position gets a random class and class order never decides which class ends up on top of the pile.

Sizes (``scene.size_rule``): ``paper`` draws each class's size, the distractors' and fits the container
to its pile; ``real`` keeps every object at its real size (classes times the instance jitter, distractors
and the container at real size, no resized pair) and chooses the objects' scale per scene
(:func:`scene_scale`, the spec's ``scale``) so that the classes land at the paper's scene sizes; every
other length (spawn heights, margins, floor, camera jitter, rest speed) keeps ``scale``, so the simulation
sees a paper scene whatever the real sizes (2 mm parts or 50 cm boxes); objects without a trustworthy size
(:func:`trusted_size`) are left out.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.counts.targets import (
    PAPER,
    CountDistribution,
    count_distribution,
    draw_elevations,
    draw_total,
    elevation_factor,
    reserve_counts,
    spawn_counts,
    split_total,
    target_record,
)
from mixcount.errors import CompositionError
from mixcount.scene.class_draws import (
    ClassDraft,
    build_classes,
    caption_keys,
    distinct_caption_picks,
    qualify,
    split_counts,
)
from mixcount.scene.environment_sampling import sample_environment, sample_floor_material
from mixcount.scene.framing import camera_position, look_at_rotation
from mixcount.scene.object_records import EnvironmentRecord, MaterialRecord, ObjectRecord
from mixcount.scene.rotation import quat_from_matrix
from mixcount.scene.spawn_layout import ellipse_radius, release_waves, spawn_positions
from mixcount.scene_config import SIZE_REAL, SceneConfig
from mixcount.sizes import TRUSTED_SIZE_SOURCES

if TYPE_CHECKING:
    from mixcount.config import Config
from mixcount.scene.spec import (
    ROLE_COUNTED,
    ROLE_DISTRACTOR,
    AssetRef,
    CameraSpec,
    Captions,
    ContainerSpec,
    FloorSpec,
    ObjectClass,
    PhysicsSpec,
    PlacedObject,
    PlacementSpec,
    RenderSpec,
    SceneSpec,
)

_R = 6  # decimals kept for poses: readable stages, identical bytes


def scene_id_for(seed: int) -> str:
    return f"scene_{seed:06d}"


def _u(rng: np.random.Generator, r: Sequence[float]) -> float:
    return float(rng.uniform(r[0], r[1]))


def _ui(rng: np.random.Generator, r: Sequence[int]) -> int:
    return int(rng.integers(r[0], r[1] + 1))


def _yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    return (round(math.cos(yaw / 2), _R), 0.0, 0.0, round(math.sin(yaw / 2), _R))


def _random_quats(rng: np.random.Generator, n: int) -> NDArray[Any]:
    """n uniformly random unit quaternions (w, x, y, z), w >= 0, rounded."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return np.round(q, _R)


def _vec(v: Sequence[float] | NDArray[Any]) -> tuple[float, float, float]:
    return tuple(round(float(x), _R) for x in v)  # type: ignore[return-value]


# ---------------------------------------------------------------------------------------------------


def eligible_objects(pool: Sequence[ObjectRecord], split: str) -> list[ObjectRecord]:
    return sorted(
        (o for o in pool if o.split == split and o.status == "active" and min(o.dims) > 0),
        key=lambda o: o.object_id,
    )


def trusted_size(obj: ObjectRecord) -> bool:
    """True when an object's real size can be trusted (stated, the model's, its kind's typical size)."""
    return obj.size_source in TRUSTED_SIZE_SOURCES


def size_warning(pool: Sequence[ObjectRecord], split: str, config: SceneConfig) -> Optional[str]:
    """The one line that names the objects of a split a real-size scene refuses (no trustworthy size), or
    None (the paper's size rule, or every object has one)."""
    if config.size_rule != SIZE_REAL:
        return None
    refused = [o for o in eligible_objects(pool, split) if not trusted_size(o)]
    if not refused:
        return None
    names = ", ".join(f"{o.name} ({o.size_source or 'not recorded'})" for o in refused[:5])
    more = f" and {len(refused) - 5} more" if len(refused) > 5 else ""
    return (f"{len(refused)} object(s) of split {split!r} have no trustworthy real size and are left out of "
            f"real-size scenes (scene.size_rule = \"real\"): {names}{more}; give \"size\" in their metadata.json "
            "(e.g. \"size\": \"14 mm\") and run catalog ingest again")


def scene_scale(real_sizes: Sequence[float], config: SceneConfig) -> float:
    """The scene scale of a real-size scene: the classes' real largest sides (metres) times it lie in the
    paper's ``class_size`` x ``scale`` range as far as their spread allows: their geometric mean at the
    range's geometric middle, raised until the smallest class is at the range's low end (the small bodies
    are the ones that tunnel). Four significant digits (readable stages)."""
    sizes = np.asarray(real_sizes, dtype=np.float64)
    lo, hi = config.class_size[0] * config.scale, config.class_size[1] * config.scale
    s = math.sqrt(lo * hi) / float(np.exp(np.mean(np.log(sizes))))
    s = max(s, lo / float(sizes.min()))
    return float(f"{s:.4g}")


def _real_size_classes(drafts: list[ClassDraft], config: SceneConfig) -> float:
    """A real-size scene's classes (drafted at their real sizes) in scene metres; returns the objects' scale.

    Only the objects take it: the classes land in the paper's scene sizes, so every other length (spawn
    heights, margins, floor, camera jitter, rest speed: ·s of the paper's 4.5-12 cm objects) stays the
    paper's and physics sees a paper scene; the container and distractors keep their real proportions."""
    size_scale = scene_scale([d.size for d in drafts], config)
    for d in drafts:
        d.size *= size_scale
    return size_scale


def container_warning(pool: Sequence[ObjectRecord], split: str, config: SceneConfig) -> Optional[str]:
    """The one-line warning for a split without a container, or None when it has one (or never uses one)."""
    if config.no_container_probability >= 1.0 or any(o.container for o in eligible_objects(pool, split)):
        return None
    others = [o for o in pool if o.container and o.status == "active" and min(o.dims) > 0]
    if others and config.container_other_split_fallback:
        fallback = f"containers are drawn from other splits ({len(others)} there, scene.container_other_split_fallback)"
    else:
        fallback = "scenes get no container"
    return (f"no container in split {split!r}: {fallback}. An object is a container when its category is in "
            "containers.categories or its name or caption has a word of containers.keywords (configs/default.toml "
            "[containers]), or when a review marks it; set those keys and rerun `catalog filter`, or review "
            "objects as containers")


def _sample_floor(rng: np.random.Generator, config: SceneConfig, materials: Sequence[MaterialRecord]) -> FloorSpec:
    s = config.scale
    shape = str(config.floor_shapes[int(rng.integers(len(config.floor_shapes)))])
    hx = _u(rng, config.floor_half_extent) * s
    hy = hx if shape == "cylinder" else _u(rng, config.floor_half_extent) * s
    return FloorSpec(
        shape=shape, half_extent=(round(hx, _R), round(hy, _R)), thickness=round(config.floor_thickness * s, _R),
        uv_scale_m=round(_u(rng, config.floor_uv_scale) * s, _R),
        material=sample_floor_material(rng, config.floor_patterns, materials, config.procedural_floor_probability,
                                       config.floor_texture_px),
    )


def _floor_reaching(floor: FloorSpec, half_diagonal: float) -> FloorSpec:
    """``floor`` grown (never shrunk) so that it reaches ``half_diagonal`` from the centre in every direction."""
    hx, hy = floor.half_extent
    need = round(half_diagonal, _R)
    if floor.shape == "cylinder":
        grown = (max(hx, need), max(hx, need))
    else:  # a square of half side h reaches h along the axes: the corners of the pile box must fit
        grown = (max(hx, need), max(hy, need))
    return FloorSpec(floor.shape, grown, floor.thickness, floor.uv_scale_m, floor.material)


def _draw_container(rng: np.random.Generator, config: SceneConfig, pool: Sequence[ObjectRecord],
                    in_split: list[ObjectRecord]) -> tuple[Optional[ObjectRecord], NDArray[Any], float]:
    """The container object (or None), its per-axis jitter x s and its yaw."""
    s = config.scale
    container_obj: Optional[ObjectRecord] = None
    if rng.random() >= config.no_container_probability:
        cands = [o for o in in_split if o.container]
        if not cands and config.container_other_split_fallback:
            cands = sorted((o for o in pool if o.status == "active" and o.container and min(o.dims) > 0),
                           key=lambda o: o.object_id)
        if cands:
            container_obj = cands[int(rng.integers(len(cands)))]
    cont_scale = np.array([_u(rng, config.container_scale_jitter) * s for _ in range(3)])
    return container_obj, cont_scale, _u(rng, (0.0, 2 * math.pi))


def shown_area(draft: ClassDraft) -> float:
    """The area (m^2) one object of a class shows on average over orientations, as its scaled box's mean
    face area: ranks the classes for a count split taken from an annotation file's image."""
    a, b, c = np.asarray(draft.obj.dims, dtype=np.float64) * (draft.size / draft.obj.max_dim)
    return float(a * b + b * c + c * a) / 3.0


def need_sizes(sizes: NDArray[Any], inst_class: NDArray[Any], count_target: dict[str, Any],
               counts: Sequence[int]) -> NDArray[Any]:
    """The sizes a count target's container is fitted to: per class its first ``need`` bodies (the
    expected need, ``count_target["need"]``), then more of the first settle's bodies up to
    ``count_target["frame_need"]`` (never below the paper's smallest spawn, :func:`_target_spawn`), so a
    small target's container is never smaller than any paper scene's (issue 48)."""
    first = [sizes[inst_class == c][:n_c - r_c] for c, (n_c, r_c) in enumerate(zip(counts, count_target["reserve"]))]
    need = [f[:k] for f, k in zip(first, count_target["need"])]
    extra = np.concatenate([f[k:] for f, k in zip(first, count_target["need"])])
    return np.concatenate([*need, extra[:int(count_target["frame_need"]) - sum(len(n) for n in need)]])


def pile_fit_factor(extent_xy: tuple[float, float], sizes: NDArray[Any], area_range: Sequence[float]) -> float:
    """The XY factor that brings a container's box area into ``area_range`` x its pile's one-layer footprint
    (its height takes the factor too when it is below 1: a container shrunk to its pile shrinks whole).

    The footprint is the sum of the counted objects' largest sides squared (each at most a size x size
    square on the floor): a real 25 cm plate at s = 10 is 2.5 m across, and a hundred 0.8 m objects
    dropped on it spill over and out of the paper's camera. The factor is 1 inside the range."""
    footprint = float(np.sum(np.square(sizes)))
    area = float(extent_xy[0] * extent_xy[1])
    if footprint <= 0 or area <= 0:
        return 1.0
    ratio = area / footprint
    lo, hi = float(area_range[0]), float(area_range[1])
    if ratio < lo:
        return math.sqrt(lo / ratio)
    if ratio > hi:
        return math.sqrt(hi / ratio)
    return 1.0


def _build_object_classes(drafts: list[ClassDraft], counts: list[int]) -> list[ObjectClass]:
    classes = []
    for ci, (d, cnt) in enumerate(zip(drafts, counts)):
        caps = d.obj.captions
        classes.append(ObjectClass(
            class_index=ci, object_id=d.obj.object_id, name=d.obj.name, category=d.obj.category,
            captions=Captions(qualify(caps.short, d.qualifier), qualify(caps.concise, d.qualifier),
                              qualify(caps.detailed, d.qualifier)),
            size_qualifier=d.qualifier, target_size_m=round(d.size, _R), count=cnt,
            construction=d.construction, base_class_index=d.base,
        ))
    return classes


class _Pile:
    """Where the counted objects are dropped: the (yawed) spawn ellipse in the container, or the square."""

    def __init__(self, config: SceneConfig, extent: Optional[NDArray[Any]], yaw: float) -> None:
        s = config.scale
        if extent is not None:
            self.centre = np.array([0.0, 0.0])
            self.semi = (max(float(extent[0]) / 2 - config.spawn_margin * s, config.spawn_min_semi_axis * s),
                         max(float(extent[1]) / 2 - config.spawn_margin * s, config.spawn_min_semi_axis * s))
            self.base_z, self.ellipse = float(extent[2]), True
            self.outline = (float(extent[0] / 2), float(extent[1] / 2))
            self.yaw = yaw
        else:
            lo_xy, hi_xy = config.spawn_xy_no_container[0] * s, config.spawn_xy_no_container[1] * s
            self.centre = np.array([(lo_xy + hi_xy) / 2, (lo_xy + hi_xy) / 2])
            self.semi = ((hi_xy - lo_xy) / 2, (hi_xy - lo_xy) / 2)
            self.base_z, self.ellipse = 0.0, False
            self.outline = self.semi
            self.yaw = 0.0

    @property
    def half_diagonal(self) -> float:
        """Distance from the scene centre to the outline's farthest corner (the yawed box's corners)."""
        return float(math.hypot(abs(self.centre[0]) + self.outline[0], abs(self.centre[1]) + self.outline[1]))


def _place_counted(rng: np.random.Generator, config: SceneConfig, drafts: list[ClassDraft],
                   inst_class: NDArray[Any], sizes: NDArray[Any], pile: _Pile, real: bool = False) -> list[PlacedObject]:
    """Spawn poses above the pile's ellipse (or square), in waves when stacked; random orientations. A
    real-size scene's bodies never start with their bounding sphere below the pile's base (a class 10-40 x
    the paper's smallest is larger than the height range's low end)."""
    s, n = config.scale, len(inst_class)
    z_range = (pile.base_z + config.spawn_height[0] * s, pile.base_z + config.spawn_height[1] * s)
    positions = spawn_positions(rng, sizes / 2, pile.centre, pile.semi, pile.yaw, z_range, config.spawn_max_tries,
                                 pile.ellipse, config.spawn_stack, base_z=pile.base_z if real else None)
    release = np.ones(n, dtype=int)
    if config.spawn_stack and config.spawn_release_waves:
        # a real-size scene's bodies above the paper's largest leave a higher pile: a later wave clears it
        extra = 2.0 * max(0.0, float(sizes.max()) - config.class_size[1] * s) if real and n else 0.0
        positions, release = release_waves(positions, z_range, config.spawn_wave_clearance * s + extra,
                                            config.spawn_wave_interval_frames)
        if real:
            positions[:, 2] = np.maximum(positions[:, 2], pile.base_z + sizes / 2)
    if config.random_orientation:
        orients = _random_quats(rng, n).tolist()
    else:
        orients = [[1.0, 0.0, 0.0, 0.0]] * n
    pos_r = np.round(positions, _R).tolist()
    sizes_r = np.round(sizes, _R).tolist()
    factors = np.round(sizes / np.array([drafts[c].obj.max_dim for c in inst_class]), _R).tolist()
    return [PlacedObject(
        instance_id=i + 1, role=ROLE_COUNTED, object_id=drafts[ci].obj.object_id, class_index=ci,
        position=tuple(pos_r[i]), orientation=tuple(orients[i]), scale=(factors[i],) * 3,
        size_m=sizes_r[i], release_frame=int(release[i]),
    ) for i, ci in enumerate(inst_class.tolist())]


def _place_distractors(rng: np.random.Generator, config: SceneConfig, picks: list[ObjectRecord], pile: _Pile,
                       first_id: int, *, real_scale: Optional[float] = None) -> list[PlacedObject]:
    """Distractors at their drawn size (a real-size scene's: their real size x ``real_scale``) and yaw,
    provisionally in a ring around the pile (scene.usda); the worker moves them after physics to free floor
    in the camera's view (mixcount.scene.framing)."""
    s = config.scale
    distractors: list[PlacedObject] = []
    placed_xy: list[tuple[float, float, float]] = []
    margin = config.distractor_margin * s
    for obj in picks:
        size = (obj.max_dim * real_scale if real_scale is not None
                else config.distractor_base_size * s * _u(rng, config.distractor_size_multiplier))
        f = size / obj.max_dim
        ext = np.asarray(obj.dims) * f
        rho = float(math.hypot(ext[0], ext[1]) / 2)
        for _ in range(config.distractor_max_tries):
            theta = _u(rng, (0.0, 2 * math.pi))
            dist = (ellipse_radius(pile.outline[0], pile.outline[1], theta) + rho + margin
                    + _u(rng, config.distractor_ring) * s)
            lx, ly = dist * math.cos(theta), dist * math.sin(theta)
            x = pile.centre[0] + math.cos(pile.yaw) * lx - math.sin(pile.yaw) * ly
            y = pile.centre[1] + math.sin(pile.yaw) * lx + math.cos(pile.yaw) * ly
            if all(math.hypot(x - px, y - py) >= rho + pr + margin for px, py, pr in placed_xy):
                break
        else:
            continue  # no free spot: fewer distractors rather than overlapping ones
        placed_xy.append((x, y, rho))
        dyaw = _u(rng, (0.0, 2 * math.pi))
        distractors.append(PlacedObject(
            instance_id=first_id + len(distractors), role=ROLE_DISTRACTOR, object_id=obj.object_id, class_index=-1,
            position=_vec((x, y, ext[2] / 2 + 0.01 * s)), orientation=_yaw_quat(dyaw), scale=_vec((f, f, f)),
            size_m=round(size, _R),
        ))
    return distractors


def _draw_cameras(rng: np.random.Generator, config: SceneConfig, resolution: int, target0: NDArray[Any],
                  diag: float, elevations: Optional[Sequence[float]] = None) -> list[CameraSpec]:
    """Each camera's drawn angles and jitters, at a provisional pose around the expected pile (the
    worker re-frames it on the settled pile by ``camera_framing``, mixcount.scene.framing). ``elevations``
    (a count target's scene: drawn before the spawn, which depends on them) replace the elevation draws."""
    s = config.scale
    cameras = []
    for k in range(config.n_cameras):
        offset = rng.uniform(-1, 1, 3) * config.camera_lookat_jitter * s
        target = target0 + offset
        elev = _u(rng, config.camera_elevation_deg) if elevations is None else float(elevations[k])
        azim = _u(rng, (0.0, 360.0))
        roll = _u(rng, config.camera_roll_deg)
        scale = 1 + _u(rng, (-config.camera_distance_jitter, config.camera_distance_jitter))
        dist = config.camera_distance_factor * diag * scale
        pos = camera_position(target, elev, azim, dist)
        rot = look_at_rotation(pos, target, roll)
        res = (resolution, resolution)
        cameras.append(CameraSpec(
            name=f"cam_{k}", position=_vec(pos), look_at=_vec(target), orientation=quat_from_matrix(rot),
            elevation_deg=round(elev, _R), azimuth_deg=round(azim, _R), roll_deg=round(roll, _R),
            distance=round(dist, _R), focal_length_mm=config.focal_length_mm,
            sensor_width_mm=config.sensor_width_mm, sensor_height_mm=config.sensor_width_mm * res[1] / res[0],
            resolution=res, clip_range=(config.clip_range[0], config.clip_range[1]),
            framing=config.camera_framing, lookat_offset=_vec(offset), distance_scale=round(scale, _R),
            distance_factor=config.camera_distance_factor, fit_share=config.camera_fit_share,
        ))
    return cameras


def _asset_refs(objs: Sequence[ObjectRecord]) -> tuple[AssetRef, ...]:
    used = {o.object_id: o for o in objs}
    return tuple(
        AssetRef(object_id=o.object_id, name=o.name, category=o.category, model_path=o.model_path,
                 content_hash=o.content_hash, dims_m=_vec(o.dims), collision_path=o.collision_path,
                 proxy_path=o.proxy_path, source_units=o.source_units, source_up_axis=o.source_up_axis,
                 source=o.source, source_id=o.source_id, license=o.license, look=o.look)
        for _, o in sorted(used.items())
    )


def _physics_spec(config: SceneConfig, largest: float = 0.0) -> PhysicsSpec:
    """The stage's physics; ``largest`` (a real-size scene's largest counted body, scene metres): the floor
    collider is never shallower than it (a body larger than the collider's depth pushed through it)."""
    s = config.scale
    return PhysicsSpec(
        frames=config.physics_frames, substeps=config.physics_substeps,
        solver_iterations=config.physics_solver_iterations, collision_shape=config.collision_shape,
        gravity=config.gravity, settle_below_floor_fraction=config.settle_below_floor_fraction,
        settle_penetration_fraction=config.settle_penetration_fraction,
        collision_proxies=bool(config.collision_proxies), rest_speed=round(float(config.physics_rest_speed) * s, 6),
        floor_collider_depth=round(max(float(config.physics_floor_collider_depth) * s, largest), 6))


def _target_spawn(seed: int, config: SceneConfig, target: CountDistribution, n: int, drafts: list[ClassDraft],
                  in_container: bool) -> tuple[list[float], list[int], dict[str, Any]]:
    """A count target's draws: the cameras' elevations, the bodies spawned per class (reserve included)
    and the spec's ``count_target`` record (counts/targets.py; docs/scene.md "Count targets")."""
    aims, ratio = split_total(target, seed, n, len(drafts), [shown_area(d) for d in drafts])
    # the cameras' elevations first (their own stream): a low camera sees the pile from the side and
    # loses more to occlusion, so the spawn is sized for the lowest one
    elevations = draw_elevations(seed, config.n_cameras, config.camera_elevation_deg)
    factor = float(config.count_spawn_factor[1 if in_container else 0]) * elevation_factor(
        min(elevations), config.count_spawn_elevation)
    counts = spawn_counts(aims, factor, config.count_spawn_extra, [d.size for d in drafts],
                          config.count_spawn_size_exponent, config.count_spawn_sqrt)
    reserve = reserve_counts(aims, config.count_reserve)  # held out of the first settle, for a top-up
    counts = [c + r for c, r in zip(counts, reserve)]
    record = target_record(n, aims, ratio, target, factor, config.count_short_tolerance,
                           config.count_class_short_tolerance, config.count_min_object_px,
                           reserve=reserve, topup_rounds=config.count_topup_rounds,
                           rest_frames=config.count_rest_frames, rest_tolerance=config.count_rest_tolerance,
                           rest_verify=config.count_rest_verify)
    # the expected need per class (the paper-like pile the container is fitted to and a floor scene's
    # cameras framed on: engine/cameras.py), never below the paper's smallest spawn in all
    f_need = float(config.count_container_need)
    record["need"] = [min(c - r, int(math.ceil(f_need * a - 1e-9))) for c, r, a in zip(counts, reserve, aims)]
    record["frame_need"] = max(sum(record["need"]), min(int(config.n_objects[0]), sum(counts) - sum(reserve)))
    return elevations, counts, record


def sample_scene(seed: int, split: str, cfg: "Config", pool: Sequence[ObjectRecord], *,
                 environments: Sequence[EnvironmentRecord] = (), materials: Sequence[MaterialRecord] = (),
                 scene_id: Optional[str] = None) -> SceneSpec:
    """Sample one scene of ``split`` from ``pool``; the same arguments always give the same spec.

    Reads ``cfg.scene`` (everything sampled) and ``cfg.compose`` (image size and render settings the spec
    records); ``cfg.hash`` goes into the spec. Steps: environment, floor, container draw, classes and
    counts, instance sizes, the container fitted to its pile (:func:`pile_fit_factor`), the floor grown to
    reach past it, counted spawn poses, distractors, cameras, assets.
    """
    config, compose = cfg.scene, cfg.compose
    rng = np.random.default_rng(seed)
    s = config.scale
    real = config.size_rule == SIZE_REAL
    if real:  # an object without a trustworthy real size is never drawn (size_warning says which)
        pool = [o for o in pool if trusted_size(o)]
    in_split = eligible_objects(pool, split)

    environment = sample_environment(rng, config, environments)
    floor = _sample_floor(rng, config, materials)
    container_obj, cont_scale, yaw = _draw_container(rng, config, pool, in_split)

    exclude = set(config.counted_exclude_categories)
    eligible = [o for o in in_split if o.category not in exclude
                and (container_obj is None or o.object_id != container_obj.object_id)]
    if not eligible:
        raise CompositionError(f"no eligible objects in split {split!r} (active, with a split and valid size"
                               + (", and a trustworthy real size: scene.size_rule = \"real\")" if real else ")"))

    n = _ui(rng, config.n_objects)
    target = None if config.count_target == PAPER else count_distribution(config.count_target)
    if target is not None:  # a visible-count target (issue 37): n is drawn from its own stream instead
        n = draw_total(target, seed)
    n_classes = min(_ui(rng, config.n_classes), n)
    drafts = build_classes(rng, config, eligible, n_classes, real=real)
    size_scale = _real_size_classes(drafts, config) if real else s  # scene metres per real metre of an object
    if real:
        cont_scale = np.full(3, size_scale)  # the container at its real size: no per-axis jitter, no pile fit
    count_target = None
    elevations: Optional[list[float]] = None
    if target is None:
        counts = split_counts(rng, n, len(drafts))
    else:
        elevations, counts, count_target = _target_spawn(seed, config, target, n, drafts, container_obj is not None)
        n = sum(counts)
    classes = _build_object_classes(drafts, counts)

    # a random class per spawn position, sizes, then the container fitted to the pile it must hold
    inst_class = rng.permutation(np.repeat(np.arange(len(counts)), counts)).astype(int)
    jitter = rng.uniform(config.instance_jitter[0], config.instance_jitter[1], len(inst_class))
    sizes = np.array([drafts[c].size for c in inst_class]) * jitter
    extent: Optional[NDArray[Any]] = None
    fit = 1.0
    if container_obj is not None and real:
        extent = np.asarray(container_obj.dims) * cont_scale
    elif container_obj is not None:
        extent = np.asarray(container_obj.dims) * cont_scale
        # a count target's container holds its expected need (per class the first count_target["need"]
        # bodies, count_container_need x its target: neither the low camera's margin nor the reserve), as a
        # paper scene's holds its whole spawn, on average 1.28 x what it keeps (fitted to the whole first
        # settle, 1.65 x the target, its objects showed 0.48 x the paper's pixels). A container shrunk to
        # its pile shrinks whole (a shrunk tray is no deep pit); one widened keeps its real height (walls
        # grown with it hid the pile from low cameras) (issue 48)
        settled_sizes = sizes if count_target is None else need_sizes(sizes, inst_class, count_target, counts)
        fit = pile_fit_factor((float(extent[0]), float(extent[1])), settled_sizes, config.container_pile_area)
        cont_scale = cont_scale * np.array([fit, fit, min(fit, 1.0)])
        extent = np.asarray(container_obj.dims) * cont_scale
    pile = _Pile(config, extent, yaw)
    floor = _floor_reaching(floor, pile.half_diagonal + config.floor_pile_margin * s)
    objects = _place_counted(rng, config, drafts, inst_class, sizes, pile, real)

    # distractors: other objects of the split, each once (never sharing a caption with a class, in its
    # own or its size-qualified form, or with each other)
    used = {d.obj.object_id for d in drafts} | ({container_obj.object_id} if container_obj else set())
    taken = frozenset().union(*(caption_keys(d.obj.captions) for d in drafts),
                              *(caption_keys(c.captions) for c in classes))
    free = [o for o in in_split if o.object_id not in used and not caption_keys(o.captions) & taken]
    n_dist = min(_ui(rng, config.n_distractors), len(free))
    picks = distinct_caption_picks(rng, free, n_dist, taken)
    distractors = _place_distractors(rng, config, picks, pile, n + 1, real_scale=size_scale if real else None)

    container = None
    if container_obj is not None and extent is not None:
        container = ContainerSpec(
            instance_id=n + len(distractors) + 1, object_id=container_obj.object_id,
            position=_vec((0.0, 0.0, extent[2] / 2)), orientation=_yaw_quat(yaw),
            scale=_vec(cont_scale), extent_m=_vec(extent), pile_fit=round(fit, _R),
        )
        diag = float(np.linalg.norm(extent))
    else:
        diag = float(math.hypot(2 * pile.semi[0], 2 * pile.semi[1]))
    target0 = np.array([pile.centre[0], pile.centre[1], pile.base_z + float(np.mean(sizes)) / 2])
    cameras = _draw_cameras(rng, config, compose.resolution, target0, diag, elevations)
    if real and container is not None and config.camera_framing == "paper":
        # the real container does not grow with its pile: frame the pile as a paper scene's fitted
        # container would (the paper's pixels per object), mixcount.scene.framing "pile"
        area = round(math.sqrt(config.container_pile_area[0] * config.container_pile_area[1]), _R)
        cameras = [replace(c, framing="pile", pile_area=area) for c in cameras]

    return SceneSpec(
        scene_id=scene_id or scene_id_for(seed), seed=int(seed), split=split, scale=size_scale,
        config_hash=cfg.hash, classes=tuple(classes), objects=tuple(objects),
        distractors=tuple(distractors), container=container, floor=floor, environment=environment,
        cameras=tuple(cameras), physics=_physics_spec(config, float(sizes.max()) if real and len(sizes) else 0.0),
        render=RenderSpec(resolution=compose.resolution, samples=compose.samples, denoise=compose.denoise,
                          visibility_threshold=compose.visibility_threshold,
                          denoise_prefilter=compose.denoise_prefilter, cycles=cfg.cycles),
        assets=_asset_refs([d.obj for d in drafts] + picks + ([container_obj] if container_obj else [])),
        placement=PlacementSpec(
            frame_margin=config.camera_frame_margin, distractor_margin=round(config.distractor_margin * s, _R),
            distractor_tries=config.distractor_max_tries, distractor_max_overlap=config.distractor_max_overlap,
            # the early stop waits for bodies within 1.5 x the farthest provisional camera of the centre
            view_radius=round(1.5 * max(c.distance for c in cameras), _R)),
        count_target=count_target, size_rule=SIZE_REAL if real else None,
    )
