"""Configuration: ``configs/default.toml`` is the schema and the only place a default lives.

Every key mixcount knows is in ``default.toml``. Other files (``quick.toml``, a user's ``--config``)
and ``--set section.key=value`` overrides may only change keys that exist there; an unknown key or a
value of the wrong type is a :class:`ConfigError`. :func:`load_config` merges them once and returns a
:class:`Config`: frozen, with one frozen dataclass per TOML section (``cfg.compose.samples``,
``cfg.scene.n_objects``). Section fields carry no defaults: a key missing from ``default.toml`` or a field
missing from a dataclass is an error at load time, and code never supplies its own fallback value.
The CLI builds the Config once per invocation and passes it (or one of its sections) down.
"""

from __future__ import annotations

import copy
import difflib
import hashlib
import json
import re
import tomllib
from dataclasses import dataclass, fields
from functools import cached_property
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, Optional, Sequence

from mixcount.errors import ConfigError
from mixcount.resources import data_dir
from mixcount.scene_config import DEVICES, CyclesConfig, RerenderConfig, SceneConfig

CONFIG_DIR = data_dir("configs")
DEFAULT_CONFIG = CONFIG_DIR / "default.toml"


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {path} is not valid TOML: {exc}") from None


def _check_type(key: str, default: Any, value: Any) -> Any:
    """Return ``value`` coerced to the type of ``default`` or raise ConfigError."""
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
    elif isinstance(default, float):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                return float(value)
            except OverflowError:  # an integer of hundreds of digits
                raise ConfigError(f"config key {key!r}: {str(value)[:20]}... is past the float range") from None
    elif isinstance(default, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif isinstance(default, str):
        if isinstance(value, str):
            return value
    elif isinstance(default, list):
        if isinstance(value, list):
            _check_items(key, default, value)
            return value
    else:
        return value
    raise ConfigError(
        f"config key {key!r} expects {type(default).__name__}, got {type(value).__name__} ({value!r})"
    )


def _item_kind(item: Any) -> str:
    if isinstance(item, bool):
        return "bool"
    if isinstance(item, (int, float)):
        return "number"
    return {"dict": "table", "list": "array"}.get(type(item).__name__, type(item).__name__)


def _check_items(key: str, default: list[Any], value: list[Any]) -> None:
    """Each item of a list value must be of a kind the default's items are (numbers, names, tables).

    Every reader of a list key (set arithmetic on names, ranges of two numbers, palette tables) trusts its
    items; a ``--set scene.floor_patterns=[[1]]`` must stop here as one ConfigError, not as a TypeError deep
    in a validator. A list key whose default is empty (``ingest.extra_roots``,
    ``scene.counted_exclude_categories``) holds names or paths: strings.
    """
    kinds = {_item_kind(item) for item in default} or {"str"}
    kinds = {"string" if k == "str" else k for k in kinds}
    for item in value:
        if {"str": "string"}.get(_item_kind(item), _item_kind(item)) not in kinds:
            want = " or ".join(sorted(kinds))
            raise ConfigError(f"config key {key!r} holds items of kind {want}, got {_item_kind(item)} "
                              f"({str(item)[:40]!r}) in {str(value)[:80]}")


RENAMED_SECTIONS = {"render": "canonical_render"}  # old section name -> new (refused with the new name)


def _merge(base: dict[str, Any], overlay: Mapping[str, Any], prefix: str, source: str) -> None:
    for key, value in overlay.items():
        dotted = f"{prefix}{key}"
        if not prefix and key in RENAMED_SECTIONS and key not in base:
            new = RENAMED_SECTIONS[key]
            keys = sorted(value) if isinstance(value, dict) else []
            example = ", ".join(f"{new}.{k}" for k in keys) or f"{new}.<key>"
            raise ConfigError(f"config section {key!r} in {source} is now {new!r} (canonical white-background "
                              f"renders): rename it, e.g. {example}")
        if key not in base:
            near = difflib.get_close_matches(dotted, [f"{prefix}{k}" for k in base], n=1, cutoff=0.5)
            hint = f"; did you mean {near[0]!r}?" if near else f"; known keys here: {', '.join(sorted(base))}"
            raise ConfigError(f"unknown config key {dotted!r} in {source}{hint}")
        if isinstance(base[key], dict):
            if not isinstance(value, dict):
                raise ConfigError(f"config key {dotted!r} is a section, got {value!r} in {source}")
            _merge(base[key], value, dotted + ".", source)
        else:
            base[key] = _check_type(dotted, base[key], value)


def _parse_override(text: str) -> tuple[list[str], Any]:
    if "=" not in text:
        raise ConfigError(f"override {text!r} must look like section.key=value")
    key, raw = text.split("=", 1)
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw  # bare strings: --set compose.split=test
    except RecursionError:  # arrays nested thousands deep: tomllib recurses per level
        raise ConfigError(f"override {text[:60]!r}...: its value is nested too deep to read") from None
    return key.strip().split("."), value


def _freeze(value: Any) -> Any:
    if isinstance(value, dict):
        return MappingProxyType({k: _freeze(v) for k, v in value.items()})
    if isinstance(value, list):
        return tuple(_freeze(v) for v in value)
    return value


def _thaw(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _thaw(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return [_thaw(v) for v in value]
    return value


@dataclass(frozen=True)
class CatalogConfig:
    """``[catalog]``: where the catalog keeps its files."""

    data_dir: str
    writer_wait_s: float  # seconds a catalog writer waits for another writer before it stops (one line)


@dataclass(frozen=True)
class IngestConfig:
    """``[ingest]``: mesh analysis of ingested objects (docs/ingest.md)."""

    collision_face_budget: int
    workers: int
    max_file_mb: float
    assume_units: str
    assume_up_axis: str
    omniobject3d_units: str
    omniobject3d_up_axis: str
    proxy_max_vertices: int
    facts_face_budget: int  # above it: facts measured whole, hash and collision mesh from a copy
    extra_roots: list[str]  # folders besides the library its references may reach (library_root.py)
    max_image_pixels: int  # an image of more pixels is refused when it enters the catalog

    def validate(self) -> None:
        if self.facts_face_budget < 1000:
            raise ConfigError(f"ingest.facts_face_budget must be >= 1000 faces, got {self.facts_face_budget!r}")


@dataclass(frozen=True)
class DemoConfig:
    """``[demo]``: the generated demo library."""

    seed: int
    n_objects: int


@dataclass(frozen=True)
class ContainersConfig:
    """``[containers]``: which objects may hold the pile (mixcount/catalog/containers.py)."""

    categories: tuple[str, ...]
    keywords: tuple[str, ...]


@dataclass(frozen=True)
class CanonicalRenderConfig:
    """``[canonical_render]``: canonical white-background renders (docs/curation.md)."""

    resolution: int
    samples: int
    denoise: bool
    elevation_deg: float
    azimuth_deg: float
    extra_views: int
    margin: float
    world_strength: float
    sun_strength: float
    workers: int
    threads: int
    timeout_s: float
    heavy_faces: int  # more triangles than this: one render gives RGB and albedo (engine.canonical_render)
    heavy_denoise_prefilter: str  # OIDN prefilter of a heavy model's render (DENOISE_PREFILTERS)

    def validate(self) -> None:
        if not (isinstance(self.heavy_faces, int) and self.heavy_faces >= 0):
            raise ConfigError(f"canonical_render.heavy_faces must be an integer >= 0, got {self.heavy_faces!r}")
        if self.heavy_denoise_prefilter not in DENOISE_PREFILTERS:
            raise ConfigError(f"canonical_render.heavy_denoise_prefilter must be one of {', '.join(DENOISE_PREFILTERS)}, "
                              f"got {self.heavy_denoise_prefilter!r}")


@dataclass(frozen=True)
class FilterConfig:
    """``[filter]``: duplicate and quality flag thresholds (docs/curation.md)."""

    exact_phash: float
    exact_colour: float
    geometry_d2: float
    geometry_proportions: float
    geometry_size: float
    geometry_edge_similarity: float
    appearance_phash: float
    appearance_colour: float
    look_colour: float
    look_layout: float
    look_d2: float
    look_proportions: float
    look_exposure_gain: float
    cross_source_d2: float
    cross_source_proportions: float
    cross_source_min_pattern: float
    cross_source_pattern: float
    cross_source_occupancy: float
    cross_source_min_asymmetry: float
    candidates: int
    copy_gate_d2: float
    copy_max_squash: float
    copy_shape: float
    copy_loose: float
    copy_min_detail: float
    copy_evidence: float
    copy_colour: float
    match_quantile: float
    appearance_min_pattern: float
    exclude_shape: float
    exclude_plain_shape: float
    size_rescale: float
    size_unit_tolerance: float
    min_faces: int
    min_area_ratio: float
    min_volume_ratio: float
    max_aspect_ratio: float
    min_render_coverage: float
    min_size_m: float
    max_size_m: float
    category_min_objects: int
    category_size_factor: float
    exclude_degenerate: bool
    mesh_quality_min_fraction: float
    exclude_mesh_quality: bool
    mesh_quality_exclude_score: float
    workers: int


@dataclass(frozen=True)
class CaptionsConfig:
    """``[captions]``: the stub and http captioners (docs/captions.md)."""

    captioner: str
    stub_prompt_version: str
    colour_source: str
    provider: str
    endpoint: str
    model: str
    api_key_env: str
    allow_plain_http: bool  # an http:// endpoint that is not this machine: refused unless true (the key in clear)
    http_prompt_version: str
    timeout_s: float
    concurrency: int
    max_retries: int
    backoff_base_s: float
    backoff_cap_s: float
    max_retry_after_s: float
    max_image_px: int
    temperature: float

    def validate(self) -> None:
        if self.captioner not in ("stub", "http"):
            raise ConfigError(f"captions.captioner must be stub or http, got {self.captioner!r}")
        if self.colour_source not in ("model", "render"):
            raise ConfigError(f"captions.colour_source must be model or render, got {self.colour_source!r}")
        if self.max_retries < 0 or self.concurrency < 1 or self.timeout_s <= 0:
            raise ConfigError("captions: max_retries >= 0, concurrency >= 1 and timeout_s > 0 are required")


@dataclass(frozen=True)
class SplitConfig:
    """``[split]``: object splits (docs/splits.md)."""

    seed: int
    train_fraction: float
    val_fraction: float
    test_fraction: float
    use_fsc147: bool
    mode: str  # paper | objects | categories (SPLIT_MODES)
    test_objects_fraction: float  # the extra test_objects split: unseen objects of categories kept in train
    test_categories_fraction: float  # the extra test_categories split: whole categories nobody trains on

    @property
    def fractions(self) -> tuple[float, float, float]:
        """(train, val, test), normalised to sum to 1."""
        fr = (self.train_fraction, self.val_fraction, self.test_fraction)
        total = sum(fr)
        return (fr[0] / total, fr[1] / total, fr[2] / total)

    def validate(self) -> None:
        fr = (self.train_fraction, self.val_fraction, self.test_fraction)
        if min(fr) < 0 or sum(fr) <= 0:
            raise ConfigError(f"split fractions must be >= 0 with a positive sum, got {fr}")
        if self.mode not in SPLIT_MODES:
            raise ConfigError(f"split.mode must be one of {', '.join(SPLIT_MODES)}, got {self.mode!r}")
        extra = (self.test_objects_fraction, self.test_categories_fraction)
        if min(extra) < 0 or sum(extra) >= 1:
            raise ConfigError("split.test_objects_fraction and split.test_categories_fraction must be >= 0 "
                              f"with a sum below 1, got {extra}")


HEX_COLOUR = re.compile(r"^#?[0-9a-fA-F]{6}$")


@dataclass(frozen=True)
class PaletteConfig:
    """``[palette]``: looks for model parts with no texture, no vertex colours and no material (CAD
    exports: STL, PLY, OBJ without .mtl), so they render as what they are, not the renderer's default
    near-white grey (docs/captions.md, "Untextured models").

    ``looks``: name, sRGB ``colour`` (``#rrggbb``), ``metallic``, ``roughness`` each. ``categories``:
    ``"word=look"``, a look for objects whose name or category has that word. ``default``: the looks an
    object without a metadata entry or category look is given, one per object by its content hash."""

    looks: tuple[Mapping[str, Any], ...]
    default: tuple[str, ...]
    categories: tuple[str, ...]

    def validate(self) -> None:
        names = set()
        for look in self.looks:
            if not isinstance(look, Mapping) or set(look) != {"name", "colour", "metallic", "roughness"}:
                raise ConfigError(f"palette.looks entries need exactly name, colour, metallic, roughness; got {look!r}")
            if not HEX_COLOUR.match(str(look["colour"])):
                raise ConfigError(f"palette look {look['name']!r}: colour must be #rrggbb, got {look['colour']!r}")
            for key in ("metallic", "roughness"):
                if not isinstance(look[key], (int, float)) or not 0.0 <= float(look[key]) <= 1.0:
                    raise ConfigError(f"palette look {look['name']!r}: {key} must be in [0, 1], got {look[key]!r}")
            names.add(str(look["name"]).lower())
        for name in self.default:
            if name.lower() not in names:
                raise ConfigError(f"palette.default names {name!r}, which is not in palette.looks ({sorted(names)})")
        for entry in self.categories:
            word, _, look_name = str(entry).partition("=")
            if not word.strip() or look_name.strip().lower() not in names:
                raise ConfigError(f"palette.categories entry {entry!r} must be 'word=look' with a look of "
                                  f"palette.looks ({sorted(names)})")

# the splits `catalog split` writes (docs/splits.md): the paper's three, then the two extra test splits
# (unseen objects of trained categories, unseen categories); compose / export / evaluate accept each
SPLIT_NAMES = ("train", "val", "test", "test_objects", "test_categories")
SPLIT_MODES = ("paper", "objects", "categories")  # `catalog split --mode`

# Cycles' OpenImageDenoise prefilter of the albedo / normal guiding passes (docs/performance.md)
DENOISE_PREFILTERS = ("ACCURATE", "FAST", "NONE")
# the one list of passes `compose --passes` chooses from (rgb is always written); mixcount.annotate.passes
# and the worker contract read it from here
PASSES = ("instance", "class", "depth", "normal")
# how the worker keeps imported asset meshes between scenes (mixcount.engine.mesh_cache): a compressed
# or uncompressed .blend beside each converted asset, or no cache (every scene imports from USD)
MESH_CACHE_MODES = ("zstd", "raw", "off")


@dataclass(frozen=True)
class ComposeConfig:
    """``[compose]``: the rendering run (docs/blender.md, docs/ray.md)."""

    split: str
    seed: int
    resolution: int
    samples: int
    denoise: bool
    denoise_prefilter: str
    visibility_threshold: float
    workers: int
    render_threads: int
    recycle_after: int
    settle_ahead: bool
    device: str
    ray_cpus_per_worker: int
    ray_gpus_per_worker: float
    scene_timeout_s: float
    max_attempts_factor: float
    preview_scenes: int
    passes: tuple[str, ...]
    depth_format: str
    normal_format: str
    mesh_cache: str
    merge: bool
    min_object_px: float  # floor of the pixels per counted object (mixcount.run.object_pixels); 0 = none

    def validate(self) -> None:
        if self.split not in SPLIT_NAMES:
            raise ConfigError(f"compose.split must be one of {', '.join(SPLIT_NAMES)}, got {self.split!r}")
        if self.workers < 1 or self.resolution < 1 or self.samples < 1:
            raise ConfigError("compose.workers, compose.resolution and compose.samples must be >= 1")
        if self.denoise_prefilter not in DENOISE_PREFILTERS:
            raise ConfigError(f"compose.denoise_prefilter must be one of {', '.join(DENOISE_PREFILTERS)}, "
                              f"got {self.denoise_prefilter!r}")
        if self.mesh_cache not in MESH_CACHE_MODES:
            raise ConfigError(f"compose.mesh_cache must be one of {', '.join(MESH_CACHE_MODES)}, "
                              f"got {self.mesh_cache!r}")
        unknown = [p for p in self.passes if p not in PASSES]
        if unknown:
            raise ConfigError(f"compose.passes: unknown pass(es) {', '.join(unknown)}; expected some of {', '.join(PASSES)}")
        if self.device not in DEVICES:
            raise ConfigError(f"compose.device must be one of {', '.join(DEVICES)}, got {self.device!r}")
        if not self.ray_gpus_per_worker > 0:
            raise ConfigError(f"compose.ray_gpus_per_worker must be > 0, got {self.ray_gpus_per_worker!r}")
        if not self.min_object_px >= 0:
            raise ConfigError(f"compose.min_object_px must be >= 0 (0: no floor), got {self.min_object_px!r}")


def _tuples(value: Any) -> Any:
    return tuple(_tuples(v) for v in value) if isinstance(value, (list, tuple)) else value


def _build_section(cls: type, name: str, values: Mapping[str, Any]) -> Any:
    """One section dataclass from its merged values: exactly the dataclass's fields, lists as tuples."""
    names = {f.name for f in fields(cls)}
    if set(values) != names:
        missing, extra = sorted(names - set(values)), sorted(set(values) - names)
        raise ConfigError(f"config section [{name}] does not match {cls.__name__}: "
                          f"missing {missing}, unexpected {extra} (default.toml and the dataclass must agree)")
    from_section = getattr(cls, "from_section", None)
    section = from_section(values) if from_section else cls(**{k: _tuples(v) for k, v in values.items()})
    validate = getattr(section, "validate", None)
    if validate is not None:
        validate()
    return section


@dataclass(frozen=True)
class Config:
    """The whole configuration, read-only: one frozen dataclass per section of ``default.toml``."""

    catalog: CatalogConfig
    ingest: IngestConfig
    demo: DemoConfig
    containers: ContainersConfig
    canonical_render: CanonicalRenderConfig
    filter: FilterConfig
    captions: CaptionsConfig
    palette: PaletteConfig
    split: SplitConfig
    scene: SceneConfig
    compose: ComposeConfig
    cycles: CyclesConfig
    rerender: RerenderConfig
    sources: tuple[str, ...]
    data: Mapping[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """Every value as plain TOML-like data (recorded in dataset.json)."""
        thawed: dict[str, Any] = _thaw(self.data)
        return thawed

    @cached_property
    def hash(self) -> str:
        """Stable short hash of every value: recorded in stage metadata and dataset.json."""
        blob = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


SECTIONS: dict[str, type] = {
    "catalog": CatalogConfig, "ingest": IngestConfig, "demo": DemoConfig, "containers": ContainersConfig, "canonical_render": CanonicalRenderConfig,
    "filter": FilterConfig, "captions": CaptionsConfig, "palette": PaletteConfig, "split": SplitConfig, "scene": SceneConfig,
    "compose": ComposeConfig, "cycles": CyclesConfig, "rerender": RerenderConfig,
}


def _nested(dotted: str, value: Any) -> dict[str, Any]:
    parts = dotted.split(".")
    nested: dict[str, Any] = {}
    node = nested
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value
    return nested


def load_config(
    files: Sequence[Path | str] = (),
    overrides: Sequence[str] = (),
    *,
    values: Optional[Mapping[str, Any]] = None,
) -> Config:
    """Load default.toml, then each of ``files`` in order, then ``section.key=value`` ``overrides``, then
    ``values`` (dotted key -> Python value, e.g. a command's ``--samples``), and build the :class:`Config`."""
    data = copy.deepcopy(_read_toml(DEFAULT_CONFIG))
    if set(data) != set(SECTIONS):
        raise ConfigError(f"{DEFAULT_CONFIG} sections {sorted(data)} do not match {sorted(SECTIONS)}")
    sources = [str(DEFAULT_CONFIG)]
    for f in files:
        path = Path(f)
        if not path.exists() and (CONFIG_DIR / path).exists():
            path = CONFIG_DIR / path
        if not path.exists() and (CONFIG_DIR / f"{path}.toml").exists():
            path = CONFIG_DIR / f"{path}.toml"
        if not path.exists() and not path.is_absolute() and (CONFIG_DIR / path.name).is_file():
            path = CONFIG_DIR / path.name  # configs/quick.toml from outside the checkout: the bundled one
        _merge(data, _read_toml(path), "", str(path))
        sources.append(str(path))
    for text in overrides:
        parts, value = _parse_override(text)
        _merge(data, _nested(".".join(parts), value), "", f"override {text!r}")
        sources.append(f"set:{text}")
    for dotted, value in (values or {}).items():
        _merge(data, _nested(dotted, value), "", f"option {dotted}")
        sources.append(f"set:{dotted}={value!r}")
    sections = {name: _build_section(cls, name, data[name]) for name, cls in SECTIONS.items()}
    return Config(**sections, sources=tuple(sources), data=_freeze(data))
