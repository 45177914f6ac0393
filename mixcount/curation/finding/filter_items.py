"""The filter's view of one catalog object (descriptors loaded once) and the per-pair layout cache."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from mixcount.atomic import write_text_atomic
from mixcount.catalog.models import CatalogObject
from mixcount.curation.finding import appearance3d as A
from mixcount.curation.finding import colour_layout as CL
from mixcount.curation.finding import descriptors as D
from mixcount.curation.finding import shape_match as S


@dataclass
class Item:
    obj: CatalogObject
    shape: D.ShapeDescriptor | None = None
    look: D.AppearanceDescriptor | None = None
    surface: A.SurfaceLook | None = None
    appearance: str = "none"
    _asymmetry: list[float] | None = None
    _normalised: S.Normalised | None = None
    _primitive: float | None = None
    _shape_look: A.SurfaceLook | None = None

    def shape_look(self) -> A.SurfaceLook:
        """The surface samples without their colours (:func:`~mixcount.curation.finding.colour_layout.shape_only`)."""
        assert self.surface is not None
        if self._shape_look is None:
            self._shape_look = CL.shape_only(self.surface)
        return self._shape_look

    def normalised(self) -> S.Normalised:
        """The surface samples in the principal frame (:func:`~mixcount.curation.finding.shape_match.normalise`)."""
        assert self.surface is not None
        if self._normalised is None:
            self._normalised = S.normalise(self.surface.points)
        return self._normalised

    def primitive(self) -> float:
        """:func:`~mixcount.curation.finding.shape_match.primitive_distance`, computed once."""
        if self._primitive is None:
            self._primitive = S.primitive_distance(self.normalised())
        return self._primitive

    def asymmetry(self) -> list[float]:
        """:func:`~mixcount.curation.finding.colour_layout.mirror_asymmetry`, computed once."""
        if self._asymmetry is None:
            self._asymmetry = CL.mirror_asymmetry(self.shape_look())
        return self._asymmetry


@dataclass
class Found:
    a: int
    b: int | None
    kind: str
    score: float
    reason: str


def in_order(x: Item, y: Item) -> tuple[Item, Item]:
    """The pair in the order every pair rule sees it (issue 69): by content hash, then geometry hash, not by
    the catalog's order, so the same library ingested in another order gets the same flags (several
    rules compare one object *onto* the other: a rotation search of one frame, the layout's first grid).
    The id decides only between two objects of one content (then every rule gives both orders alike)."""
    kx = (x.obj.content_hash or "", x.obj.geometry_hash or "", x.obj.id)
    ky = (y.obj.content_hash or "", y.obj.geometry_hash or "", y.obj.id)
    return (x, y) if kx <= ky else (y, x)


def object_label(obj: CatalogObject) -> str:
    return f"#{obj.id} {obj.name!r}"





def settings_key(**settings: float) -> str:
    """The part of a cache key that names the configured values a figure was computed with, e.g.
    ``/copy_max_squash=1.34/match_quantile=0.5`` (9 significant digits: a value read from TOML twice
    gives the same key)."""
    return "".join(f"/{name}={value:.9g}" for name, value in sorted(settings.items()))


class LayoutCache:
    """Principal-frame layout distances of pairs already compared (the rotation search of a cube or a
    ball costs ~0.1-1 s a pair), kept as JSON beside the descriptors, keyed by both content hashes,
    the brightness factor (the file is named by the sample and layout versions), so a re-run only
    compares new pairs."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.values: dict[str, float] = {}
        self.dirty = False
        if path is not None and path.is_file():
            try:
                self.values = {str(k): float(v) for k, v in json.loads(path.read_text()).items()}
            except (OSError, ValueError, TypeError, AttributeError):
                self.values = {}

    @staticmethod
    def key(x: Item, y: Item, gain: float) -> str | None:
        a, b = (x.obj.content_hash or "")[:32], (y.obj.content_hash or "")[:32]
        return f"{a}:{b}:{gain:.4f}" if a and b else None

    def layout(self, x: Item, y: Item, first: A.SurfaceLook, other: A.SurfaceLook, gain: float, search_above: float) -> float:
        """:func:`~mixcount.curation.finding.colour_layout.layout_distance`, cached under the threshold above
        which it searches rotations too (``[filter] look_layout``): another threshold is another figure."""
        key = self.key(x, y, gain)
        key = f"{key}:above{search_above:.9g}" if key is not None else None
        return self._remember(key, lambda: CL.layout_distance(first, other, search_above=search_above))

    def refined(self, x: Item, y: Item, first: A.SurfaceLook, other: A.SurfaceLook, gain: float) -> float:
        """Layout distance after a local rotation refinement, both ways (cross-source copies), cached."""
        key = self.key(x, y, gain)
        key = f"refined:{key}" if key is not None else None
        return self._remember(key, lambda: min(CL.refined_layout_distance(first, other),
                                               CL.refined_layout_distance(other, first)))

    def occupancy(self, x: Item, y: Item) -> float:
        """Axis-normalised shape distance (:func:`~mixcount.curation.finding.colour_layout.occupancy_distance`), cached."""
        key = self.key(x, y, 1.0)
        key = f"occupancy:{key}" if key is not None else None
        return self._remember(key, lambda: CL.occupancy_distance(x.shape_look(), y.shape_look()))

    def cached(self, x: Item, y: Item, tag: str, compute: Callable[[], float], settings: str) -> float:
        """``compute()`` for the pair (or one object when ``x is y``), cached under ``tag``, the shape-match
        version and ``settings``: every configured value the figure depends on (:func:`settings_key`), so
        a filter re-run with other settings computes its figures anew instead of reading the old ones."""
        key = self.key(x, y, 1.0)
        key = f"{tag}-{S.MATCH_VERSION}{settings}:{key}" if key is not None else None
        return self._remember(key, compute)

    def _remember(self, key: str | None, compute: Callable[[], float]) -> float:
        """The cached figure of ``key``, else ``compute()`` rounded to 6 decimals and kept. The rules always
        read the rounded figure, computed now or read back: a first run, a re-run on the saved cache and a
        run whose figures came from worker processes or Ray tasks then take the same side of every
        threshold (a rule once read the unrounded figure on the first run and the rounded one after)."""
        if key is not None and key in self.values:
            return self.values[key]
        value = round(float(compute()), 6)
        if key is not None:
            self.values[key] = value
            self.dirty = True
        return value

    def save(self) -> None:
        if self.path is None or not self.dirty:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.path, json.dumps(self.values, sort_keys=True))  # a fresh temporary name per writer
        self.dirty = False
