"""The paper's scene sampler: one seed -> one :class:`~mixcount.scene.spec.SceneSpec`, always the same.

Order of decisions (each from the one ``numpy.random.Generator`` built from the seed): environment,
floor, container, number of instances and classes, class construction, per-class counts, counted
spawn poses, distractors, cameras. Everything geometric is in scene metres (real size x scale s).

Class construction (paper, section 3 and supplementary): the first class is an eligible object of the
split; each further class is (a) an existing class's object at a clearly different size (ratio in
``resize_ratio``; both classes of the pair get a "larger"/"smaller" qualifier in place of their
captions' size word), (b) another object of an existing class's category, or (c) an object of a
category not yet in the scene, with the configured probabilities; infeasible options are dropped and
the rest renormalised.

Unique prompts: no two objects of one scene (counted classes and distractors) share a caption at any
tier (compared by :func:`~mixcount.scene.caption_text.normalise_caption`), so every prompt names one class.
An object whose captions collide with one already in the scene is never drawn for it.

Spawn order: the counted instances' class labels are shuffled before placement, so each spawn
position gets a random class and class order never decides which class ends up on top of the pile.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.errors import CompositionError
from mixcount.scene.caption_text import normalise_caption, size_qualified
from mixcount.scene.config import SceneConfig
from mixcount.scene.environments import sample_environment, sample_floor_material
from mixcount.scene.pool import EnvironmentRecord, MaterialRecord, ObjectRecord
from mixcount.scene.rotation import quat_from_matrix

if TYPE_CHECKING:
    from mixcount.config import Config
from mixcount.scene.spec import (
    ROLE_COUNTED,
    ROLE_DISTRACTOR,
    TIERS,
    AssetRef,
    CameraSpec,
    Captions,
    ContainerSpec,
    FloorSpec,
    ObjectClass,
    PhysicsSpec,
    PlacedObject,
    RenderSpec,
    SceneSpec,
)

CONSTRUCTIONS = ("same_object_resized", "same_category", "other_category")
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


def _vec(v: Sequence[float]) -> tuple[float, float, float]:
    return tuple(round(float(x), _R) for x in v)  # type: ignore[return-value]


def qualify(caption: str, qualifier: Optional[str]) -> str:
    """'a large white bottle' + 'smaller' -> 'a smaller white bottle' (see :func:`size_qualified`)."""
    return size_qualified(caption, qualifier)


def caption_keys(captions: Captions) -> frozenset[tuple[str, str]]:
    """(tier, normalised caption) of each tier: two objects whose keys intersect share a prompt."""
    return frozenset((tier, normalise_caption(getattr(captions, tier))) for tier in TIERS)


def look_at_rotation(position: NDArray[Any], target: NDArray[Any], roll_deg: float) -> NDArray[Any]:
    """Camera-to-world rotation: local -Z towards target, +Y up-ish, then ``roll_deg`` about the view axis."""
    f = target - position
    f = f / np.linalg.norm(f)
    right = np.cross(f, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    rot = np.stack([right, up, -f], axis=1)
    r = math.radians(roll_deg)
    rz = np.array([[math.cos(r), -math.sin(r), 0.0], [math.sin(r), math.cos(r), 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(rot @ rz)


# ---------------------------------------------------------------------------------------------------
# class construction


class _ClassDraft:
    def __init__(self, obj: ObjectRecord, size: float, construction: str, base: Optional[int] = None):
        self.obj = obj
        self.size = size
        self.construction = construction
        self.base = base
        self.qualifier: Optional[str] = None


def _resize_options(drafts: list[_ClassDraft], lo: float, hi: float, rmin: float) -> list[int]:
    uses: dict[int, int] = {}
    for d in drafts:
        uses[d.obj.object_id] = uses.get(d.obj.object_id, 0) + 1
    return [
        i for i, d in enumerate(drafts)
        if uses[d.obj.object_id] == 1 and (d.size * rmin <= hi or d.size / rmin >= lo)
    ]


def _resized_size(rng: np.random.Generator, base: float, lo: float, hi: float,
                  ratio: tuple[float, float]) -> tuple[float, str]:
    r = _u(rng, ratio)
    direction = "larger" if rng.random() < 0.5 else "smaller"
    for dirn in (direction, "smaller" if direction == "larger" else "larger"):
        size = base * r if dirn == "larger" else base / r
        if lo <= size <= hi:
            return size, dirn
    # the drawn ratio overshoots both ends: use the largest ratio that fits (still >= ratio[0])
    up, down = hi / base, base / lo
    if up >= down:
        return hi, "larger"
    return lo, "smaller"


def _build_classes(rng: np.random.Generator, config: SceneConfig, eligible: list[ObjectRecord],
                   n_classes: int) -> list[_ClassDraft]:
    s = config.scale
    lo, hi = config.class_size[0] * s, config.class_size[1] * s
    first = eligible[int(rng.integers(len(eligible)))]
    drafts = [_ClassDraft(first, _u(rng, (lo, hi)), "first")]
    probs = np.array([config.p_same_object_resized, config.p_same_category, config.p_other_category], dtype=float)
    while len(drafts) < n_classes:
        used = {d.obj.object_id for d in drafts}
        cats = {d.obj.category for d in drafts}
        taken = frozenset().union(*(caption_keys(d.obj.captions) for d in drafts))
        free = [o for o in eligible if o.object_id not in used and not caption_keys(o.captions) & taken]
        resizable = _resize_options(drafts, lo, hi, config.resize_ratio[0])
        same_cat = [o for o in free if o.category in cats]
        other_cat = [o for o in free if o.category not in cats]
        feasible = np.array([bool(resizable), bool(same_cat), bool(other_cat)], dtype=float)
        p = probs * feasible
        if p.sum() <= 0:
            break  # the split cannot provide another distinct class
        choice = CONSTRUCTIONS[int(rng.choice(3, p=p / p.sum()))]
        if choice == "same_object_resized":
            bi = resizable[int(rng.integers(len(resizable)))]
            base = drafts[bi]
            size, direction = _resized_size(rng, base.size, lo, hi, config.resize_ratio)
            draft = _ClassDraft(base.obj, size, choice, base=bi)
            draft.qualifier = direction
            base.qualifier = "smaller" if direction == "larger" else "larger"
        elif choice == "same_category":
            by_cat = sorted({o.category for o in same_cat})
            cat = by_cat[int(rng.integers(len(by_cat)))]
            cands = [o for o in same_cat if o.category == cat]
            draft = _ClassDraft(cands[int(rng.integers(len(cands)))], _u(rng, (lo, hi)), choice)
        else:
            by_cat = sorted({o.category for o in other_cat})
            cat = by_cat[int(rng.integers(len(by_cat)))]
            cands = [o for o in other_cat if o.category == cat]
            draft = _ClassDraft(cands[int(rng.integers(len(cands)))], _u(rng, (lo, hi)), choice)
        drafts.append(draft)
    return drafts


def _distinct_caption_picks(rng: np.random.Generator, free: list[ObjectRecord], n: int,
                            taken: frozenset[tuple[str, str]]) -> list[ObjectRecord]:
    """Up to ``n`` objects of ``free`` drawn one by one, uniformly among those whose captions collide with
    no caption already ``taken`` (by the classes or an earlier pick): the first fitting ones of a random
    permutation, which is the same distribution."""
    picks: list[ObjectRecord] = []
    if n <= 0:
        return picks
    for i in rng.permutation(len(free)).tolist():
        keys = caption_keys(free[i].captions)
        if keys & taken:
            continue
        picks.append(free[i])
        taken = taken | keys
        if len(picks) == n:
            break
    return picks


def _split_counts(rng: np.random.Generator, n: int, k: int) -> list[int]:
    """n instances over k classes, every class >= 1, uniform over all such compositions."""
    if k == 1:
        return [n]
    cuts = np.sort(rng.choice(np.arange(1, n), size=k - 1, replace=False))
    return [int(c) for c in np.diff(np.concatenate([[0], cuts, [n]]))]


# ---------------------------------------------------------------------------------------------------
# placement


def _spawn_positions(rng: np.random.Generator, radii: NDArray[Any], centre: NDArray[Any], semi: tuple[float, float],
                     yaw: float, z_range: tuple[float, float], tries: int, ellipse: bool,
                     stack: bool = True) -> NDArray[Any]:
    """Uniform points in the (rotated) ellipse or square, heights in z_range; each instance takes the
    first of ``tries`` candidates whose bounding sphere misses the ones placed so far, else the
    candidate with the most clearance, lifted (``stack``) above the spheres already in its column."""
    n = len(radii)
    out = np.zeros((n, 3))
    if n == 0:
        return out
    c, s_ = math.cos(yaw), math.sin(yaw)
    if ellipse:
        r = np.sqrt(rng.random((n, tries)))
        t = rng.random((n, tries)) * 2 * math.pi
        lx, ly = semi[0] * r * np.cos(t), semi[1] * r * np.sin(t)
    else:
        lx = rng.uniform(-semi[0], semi[0], (n, tries))
        ly = rng.uniform(-semi[1], semi[1], (n, tries))
    cand = np.stack([centre[0] + c * lx - s_ * ly, centre[1] + s_ * lx + c * ly,
                     rng.uniform(z_range[0], z_range[1], (n, tries))], axis=2)
    out[0] = cand[0, 0]
    for i in range(1, n):
        # squared centre distances against squared sums of radii: no square roots unless no spot is free
        need = (radii[:i] + radii[i]) ** 2
        first = out[:i] - cand[i, 0]
        if (np.einsum("ij,ij->i", first, first) >= need).all():
            out[i] = cand[i, 0]
            continue
        diff = cand[i][:, None, :] - out[None, :i, :]
        d2 = np.einsum("tij,tij->ti", diff, diff)
        ok = np.flatnonzero((d2 >= need).all(axis=1))
        if len(ok):
            out[i] = cand[i, ok[0]]
            continue
        clearance = (np.sqrt(d2) - radii[:i]).min(axis=1) - radii[i]
        best = cand[i, int(np.argmax(clearance))].copy()
        if stack:
            # no free spot in the height range: stack above whatever this column already holds, so
            # dense scenes do not start interpenetrated (the physics engine would explode them)
            dxy = np.hypot(out[:i, 0] - best[0], out[:i, 1] - best[1])
            column = dxy < radii[:i] + radii[i]
            if column.any():
                best[2] = max(best[2], float((out[:i, 2][column] + radii[:i][column]).max() + radii[i]) * 1.0001)
        out[i] = best
    return out


def _release_waves(positions: NDArray[Any], z_range: tuple[float, float], clearance: float,
                   interval: int) -> tuple[NDArray[Any], NDArray[Any]]:
    """Stacked spawn spots -> spots in the height range, released in waves.

    A body that :func:`_spawn_positions` stacked ``w`` bands (a band = the height range) above the range
    is moved down ``w`` bands and up ``clearance`` (over the pile the earlier waves left), and released
    at frame ``1 + w * interval``; the others are released at frame 1. Bodies of one wave keep their
    relative positions, so they stay as clear of each other as the stacking made them; earlier waves
    have fallen away by the time a later one is released. Returns the new positions and release frames.
    """
    band = z_range[1] - z_range[0]
    out = np.array(positions, dtype=np.float64)
    if band <= 0 or len(out) == 0:
        return out, np.ones(len(out), dtype=int)
    wave = np.where(out[:, 2] > z_range[1], np.ceil((out[:, 2] - z_range[1]) / band), 0).astype(int)
    out[:, 2] -= wave * band - np.where(wave > 0, clearance, 0.0)
    return out, 1 + wave * int(interval)


def _ellipse_radius(a: float, b: float, theta: float) -> float:
    return a * b / math.sqrt((b * math.cos(theta)) ** 2 + (a * math.sin(theta)) ** 2)


# ---------------------------------------------------------------------------------------------------


def eligible_objects(pool: Sequence[ObjectRecord], split: str) -> list[ObjectRecord]:
    return sorted(
        (o for o in pool if o.split == split and o.status == "active" and min(o.dims) > 0),
        key=lambda o: o.object_id,
    )


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


def sample_scene(seed: int, split: str, cfg: "Config", pool: Sequence[ObjectRecord], *,
                 environments: Sequence[EnvironmentRecord] = (), materials: Sequence[MaterialRecord] = (),
                 scene_id: Optional[str] = None) -> SceneSpec:
    """Sample one scene of ``split`` from ``pool``; the same arguments always give the same spec.

    Reads ``cfg.scene`` (everything sampled) and ``cfg.compose`` (image size and render settings the spec
    records); ``cfg.hash`` goes into the spec.
    """
    config, compose = cfg.scene, cfg.compose
    rng = np.random.default_rng(seed)
    s = config.scale
    in_split = eligible_objects(pool, split)

    environment = sample_environment(rng, config, environments)

    shape = str(config.floor_shapes[int(rng.integers(len(config.floor_shapes)))])
    hx = _u(rng, config.floor_half_extent) * s
    hy = hx if shape == "cylinder" else _u(rng, config.floor_half_extent) * s
    floor = FloorSpec(
        shape=shape, half_extent=(round(hx, _R), round(hy, _R)), thickness=round(config.floor_thickness * s, _R),
        uv_scale_m=round(_u(rng, config.floor_uv_scale) * s, _R),
        material=sample_floor_material(rng, config.floor_patterns, materials, config.procedural_floor_probability,
                                       config.floor_texture_px),
    )

    # container (never also a counted class or a distractor)
    container_obj: Optional[ObjectRecord] = None
    if rng.random() >= config.no_container_probability:
        cands = [o for o in in_split if o.container]
        if not cands and config.container_other_split_fallback:
            cands = sorted((o for o in pool if o.status == "active" and o.container and min(o.dims) > 0),
                           key=lambda o: o.object_id)
        if cands:
            container_obj = cands[int(rng.integers(len(cands)))]
    cont_scale = np.array([_u(rng, config.container_scale_jitter) * s for _ in range(3)])
    yaw = _u(rng, (0.0, 2 * math.pi))

    exclude = set(config.counted_exclude_categories)
    eligible = [o for o in in_split if o.category not in exclude
                and (container_obj is None or o.object_id != container_obj.object_id)]
    if not eligible:
        raise CompositionError(f"no eligible objects in split {split!r} (active, with a split and valid size)")

    n = _ui(rng, config.n_objects)
    n_classes = min(_ui(rng, config.n_classes), n)
    drafts = _build_classes(rng, config, eligible, n_classes)
    counts = _split_counts(rng, n, len(drafts))

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

    # counted instances in a random class order (a random class per spawn position), sizes, then spawn
    # poses above the ellipse inscribed in the container's box
    inst_class = rng.permutation(np.repeat(np.arange(len(counts)), counts)).astype(int)
    jitter = rng.uniform(config.instance_jitter[0], config.instance_jitter[1], len(inst_class))
    sizes = np.array([drafts[c].size for c in inst_class]) * jitter
    if container_obj is not None:
        extent = np.asarray(container_obj.dims) * cont_scale
        centre = np.array([0.0, 0.0])
        semi = (max(extent[0] / 2 - config.spawn_margin * s, config.spawn_min_semi_axis * s),
                max(extent[1] / 2 - config.spawn_margin * s, config.spawn_min_semi_axis * s))
        base_z = float(extent[2])
        ellipse = True
        pile_semi = (float(extent[0] / 2), float(extent[1] / 2))
        pile_yaw = yaw
    else:
        extent = None
        lo_xy, hi_xy = config.spawn_xy_no_container[0] * s, config.spawn_xy_no_container[1] * s
        centre = np.array([(lo_xy + hi_xy) / 2, (lo_xy + hi_xy) / 2])
        semi = ((hi_xy - lo_xy) / 2, (hi_xy - lo_xy) / 2)
        base_z = 0.0
        ellipse = False
        pile_semi = semi
        pile_yaw = 0.0
    z_range = (base_z + config.spawn_height[0] * s, base_z + config.spawn_height[1] * s)
    positions = _spawn_positions(rng, sizes / 2, centre, semi, pile_yaw, z_range, config.spawn_max_tries, ellipse,
                                 config.spawn_stack)
    release = np.ones(n, dtype=int)
    if config.spawn_stack and config.spawn_release_waves:
        positions, release = _release_waves(positions, z_range, config.spawn_wave_clearance * s,
                                            config.spawn_wave_interval_frames)
    if config.random_orientation:
        orients = _random_quats(rng, n).tolist()
    else:
        orients = [[1.0, 0.0, 0.0, 0.0]] * n
    pos_r = np.round(positions, _R).tolist()
    sizes_r = np.round(sizes, _R).tolist()
    factors = np.round(sizes / np.array([drafts[c].obj.max_dim for c in inst_class]), _R).tolist()
    objects = []
    for i, ci in enumerate(inst_class.tolist()):
        f = factors[i]
        objects.append(PlacedObject(
            instance_id=i + 1, role=ROLE_COUNTED, object_id=drafts[ci].obj.object_id, class_index=ci,
            position=tuple(pos_r[i]), orientation=tuple(orients[i]), scale=(f, f, f),
            size_m=sizes_r[i], release_frame=int(release[i]),
        ))

    # distractors: other objects of the split, each once, resting upright around the pile
    used = {d.obj.object_id for d in drafts} | ({container_obj.object_id} if container_obj else set())
    # (never sharing a caption with a class, in its own or its size-qualified form, or with each other)
    taken = frozenset().union(*(caption_keys(d.obj.captions) for d in drafts),
                              *(caption_keys(c.captions) for c in classes))
    free = [o for o in in_split if o.object_id not in used and not caption_keys(o.captions) & taken]
    n_dist = min(_ui(rng, config.n_distractors), len(free))
    picks = _distinct_caption_picks(rng, free, n_dist, taken)
    distractors: list[PlacedObject] = []
    placed_xy: list[tuple[float, float, float]] = []
    margin = config.distractor_margin * s
    for obj in picks:
        size = config.distractor_base_size * s * _u(rng, config.distractor_size_multiplier)
        f = size / obj.max_dim
        ext = np.asarray(obj.dims) * f
        rho = float(math.hypot(ext[0], ext[1]) / 2)
        for _ in range(config.distractor_max_tries):
            theta = _u(rng, (0.0, 2 * math.pi))
            dist = (_ellipse_radius(pile_semi[0], pile_semi[1], theta) + rho + margin
                    + _u(rng, config.distractor_ring) * s)
            lx, ly = dist * math.cos(theta), dist * math.sin(theta)
            x = centre[0] + math.cos(pile_yaw) * lx - math.sin(pile_yaw) * ly
            y = centre[1] + math.sin(pile_yaw) * lx + math.cos(pile_yaw) * ly
            if all(math.hypot(x - px, y - py) >= rho + pr + margin for px, py, pr in placed_xy):
                break
        else:
            continue  # no free spot: fewer distractors rather than overlapping ones
        placed_xy.append((x, y, rho))
        dyaw = _u(rng, (0.0, 2 * math.pi))
        distractors.append(PlacedObject(
            instance_id=n + len(distractors) + 1, role=ROLE_DISTRACTOR, object_id=obj.object_id, class_index=-1,
            position=_vec((x, y, ext[2] / 2 + 0.01 * s)), orientation=_yaw_quat(dyaw), scale=_vec((f, f, f)),
            size_m=round(size, _R),
        ))

    container = None
    if container_obj is not None:
        container = ContainerSpec(
            instance_id=n + len(distractors) + 1, object_id=container_obj.object_id,
            position=_vec((0.0, 0.0, extent[2] / 2)), orientation=_yaw_quat(yaw),
            scale=_vec(cont_scale), extent_m=_vec(extent),  # type: ignore[arg-type]
        )
        diag = float(np.linalg.norm(extent))
    else:
        diag = float(math.hypot(2 * semi[0], 2 * semi[1]))

    # cameras on the hemisphere around the counted objects' expected centre
    target0 = np.array([centre[0], centre[1], base_z + float(np.mean(sizes)) / 2])
    cameras = []
    for k in range(config.n_cameras):
        target = target0 + rng.uniform(-1, 1, 3) * config.camera_lookat_jitter * s
        elev = _u(rng, config.camera_elevation_deg)
        azim = _u(rng, (0.0, 360.0))
        roll = _u(rng, config.camera_roll_deg)
        dist = config.camera_distance_factor * diag * (1 + _u(rng, (-config.camera_distance_jitter,
                                                                       config.camera_distance_jitter)))
        e, a = math.radians(elev), math.radians(azim)
        pos = target + dist * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        rot = look_at_rotation(pos, target, roll)
        res = (compose.resolution, compose.resolution)
        cameras.append(CameraSpec(
            name=f"cam_{k}", position=_vec(pos), look_at=_vec(target), orientation=quat_from_matrix(rot),
            elevation_deg=round(elev, _R), azimuth_deg=round(azim, _R), roll_deg=round(roll, _R),
            distance=round(dist, _R), focal_length_mm=config.focal_length_mm,
            sensor_width_mm=config.sensor_width_mm, sensor_height_mm=config.sensor_width_mm * res[1] / res[0],
            resolution=res, clip_range=(config.clip_range[0], config.clip_range[1]),
        ))

    used_objs = {o.object_id: o for o in [d.obj for d in drafts] + picks
                 + ([container_obj] if container_obj else [])}
    assets = tuple(
        AssetRef(object_id=o.object_id, name=o.name, category=o.category, model_path=o.model_path,
                 content_hash=o.content_hash, dims_m=_vec(o.dims), collision_path=o.collision_path,
                 proxy_path=o.proxy_path, source_units=o.source_units, source_up_axis=o.source_up_axis,
                 source=o.source, source_id=o.source_id, license=o.license)
        for _, o in sorted(used_objs.items())
    )
    return SceneSpec(
        scene_id=scene_id or scene_id_for(seed), seed=int(seed), split=split, scale=s,
        config_hash=cfg.hash, classes=tuple(classes), objects=tuple(objects),
        distractors=tuple(distractors), container=container, floor=floor, environment=environment,
        cameras=tuple(cameras),
        physics=PhysicsSpec(config.physics_frames, config.physics_substeps, config.physics_solver_iterations,
                            config.collision_shape, config.gravity, config.settle_below_floor_fraction,
                            config.settle_penetration_fraction, bool(config.collision_proxies),
                            round(float(config.physics_rest_speed) * s, 6),
                            round(float(config.physics_floor_collider_depth) * s, 6)),
        render=RenderSpec(compose.resolution, compose.samples, compose.denoise, compose.visibility_threshold,
                          compose.denoise_prefilter),
        assets=assets,
    )
