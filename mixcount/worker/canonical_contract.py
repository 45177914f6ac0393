"""The ``canonical`` worker operation's contract: :class:`CanonicalRequest` -> :class:`CanonicalResult`, one
catalog object's white-background renders, one :class:`CanonicalView` per view (:func:`canonical_views`
names them, for both sides of the process boundary). The look of every render is ``[canonical_render]``
carried as one :class:`CanonicalSettings`. Imports neither bpy nor pxr; the JSON round-trip checks fields
as the scene op's does (:func:`mixcount.worker.contract.known_fields`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar, Mapping, Optional

from mixcount.config import CanonicalRenderConfig
from mixcount.worker.contract import known_fields

CANONICAL = "canonical"  # the first canonical render's view name (the external exemplar)


def canonical_views(extra_views: int, azimuth_deg: float) -> tuple[tuple[str, float], ...]:
    """(view name, camera azimuth in degrees) of each canonical render: ``canonical`` at the configured
    azimuth, then ``view_<k>`` spread evenly around the object."""
    return ((CANONICAL, float(azimuth_deg)),) + tuple(
        (f"view_{k}", float(azimuth_deg) + 360.0 * k / (extra_views + 1)) for k in range(1, extra_views + 1))


@dataclass(frozen=True)
class CanonicalSettings:
    """How every canonical render looks: ``[canonical_render]``'s image settings, carried as one object
    (:meth:`from_config` is the one place the config section becomes them; workers and threads stay the
    runner's)."""

    resolution: int
    samples: int
    denoise: bool
    elevation_deg: float
    azimuth_deg: float
    extra_views: int
    margin: float
    world_strength: float
    sun_strength: float
    heavy_faces: int  # a model of more triangles than this takes the heavy path (engine.canonical_render)
    heavy_denoise_prefilter: str  # ... and its render's OIDN prefilter

    @classmethod
    def from_config(cls, config: CanonicalRenderConfig) -> "CanonicalSettings":
        return cls(**{f.name: getattr(config, f.name) for f in fields(cls)})

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CanonicalSettings":
        return cls(**known_fields(cls, d))


@dataclass(frozen=True)
class CanonicalRequest:
    """One ``canonical`` request: render the model at ``model_path`` into ``out_dir`` as ``<stem>.png``
    (+ ``<stem>_<view>.png`` for extra views), each with a ``_mask.png``, with ``settings``."""

    OP: ClassVar[str] = "canonical"

    model_path: str
    out_dir: str
    stem: str
    threads: int  # Cycles threads (0 = Blender's automatic choice)
    settings: CanonicalSettings
    # the up axis the catalog reads the model with (objects.source_up_axis); the render turns the import
    # into that frame. "" = as Blender's importer reads it (glTF/OBJ Y-up, PLY/STL Z-up, USD its own)
    up_axis: str
    # (sRGB r, g, b, metallic, roughness) for the model's parts without texture, vertex colours or material
    # ([palette], mixcount.catalog.materials.object_look); None: they keep the importer's default
    look: Optional[tuple[float, ...]] = None
    # True where the catalog read no colour in any part of the model (appearance "none"): a material its
    # importer makes anyway (Blender's OBJ importer names one after a ``usemtl`` whose .mtl is missing) is a
    # stand-in, and ``look`` replaces it as it would a part without any material
    stand_in_materials: bool = False
    # which render path: True heavy, False light, None the worker's own triangle count against
    # settings.heavy_faces. The catalog always says (curation.renders.is_heavy, from the face count its
    # render rows are hashed with), so one rule picks both the path and the hash that records it.
    heavy: Optional[bool] = None

    def views(self) -> tuple[tuple[str, float], ...]:
        return canonical_views(self.settings.extra_views, self.settings.azimuth_deg)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CanonicalRequest":
        v = known_fields(cls, d)
        look = None if v["look"] is None else tuple(float(x) for x in v["look"])
        return cls(**{**v, "settings": CanonicalSettings.from_dict(v["settings"]), "look": look})


@dataclass(frozen=True)
class CanonicalView:
    """One written canonical render: RGB on white at ``path``, its coverage mask at ``mask_path``."""

    view: str
    path: str
    mask_path: str
    coverage: float  # share of pixels the object covers (alpha > 127)
    width: int
    height: int


@dataclass(frozen=True)
class CanonicalResult:
    views: tuple[CanonicalView, ...]
    faces: int = -1  # triangles of the imported meshes (-1: not counted)
    heavy: bool = False  # whether it took the heavy path (faces > settings.heavy_faces)

    def to_dict(self) -> dict[str, Any]:
        return {"views": [asdict(v) for v in self.views], "faces": self.faces, "heavy": self.heavy}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CanonicalResult":
        v = known_fields(cls, d)
        return cls(views=tuple(CanonicalView(**known_fields(CanonicalView, x)) for x in v["views"]),
                   faces=int(v["faces"]), heavy=bool(v["heavy"]))
