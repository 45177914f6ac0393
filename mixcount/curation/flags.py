"""`catalog filter`: duplicate and quality flags, one kept object per duplicate group, review outranks all.

Flags (each with a score in [0, 1], a reason, and the paired object where it is a pairing; pairs are
flagged in both directions). Thresholds are the ``[filter]`` section; descriptors in
:mod:`mixcount.curation.descriptors`; the rationale is in docs/curation.md.

* ``exact_duplicate``: identical model content (content hash), or the identical mesh (geometry hash) with
  indistinguishable canonical renders.
* ``near_duplicate_geometry``: the same shape (D2 distance and principal-extent proportions under their
  thresholds) at the same size, with the same texture layout (edge structure of the renders) *and* the
  same colours (renders or surface): a copy. Shape alone is not enough: every sphere has the same shape.
* ``colour_variant``: the same test with other colours: one object in two colours (a recolour, another
  print of one mould). Not a duplicate: both stay active, the pair is a hard pair of classes for the
  sampler and the pair shares one split. Flagged in both directions with the figures.
* ``near_duplicate_appearance``: the same look, two ways. (a) Canonical renders that look alike (pHash
  and colour histogram): renders are framed scale-free, so a rescaled copy lands here. (b) Whatever the
  orientation: the same surface colours and the same colour layout in the principal frame
  (:mod:`mixcount.curation.appearance3d`), *and* the same shape at any scale (D2 and second-moment
  proportions): a copy turned over (another up axis), rescaled, re-tessellated or re-exported by another
  source lands here. (c) A copy from another source whose shape agrees only loosely (decimated to a few
  per cent of its faces, flattened by a re-export: ``cross_source_*``) with the same surface colours and
  layout on a *patterned* surface.
* ``possible_copy``: the evidence is not sure: a loosely agreeing shape with the same *plain* colour,
  where the layout has no pattern to confirm it (rule (c) on a plain surface); a loosely agreeing shape
  in other colours whose colour pattern repeats; or, on two plain surfaces in other colours, the same
  shape once each principal axis is scaled to its extent (a re-export's squash taken out), for shapes
  mirror-asymmetric along two principal axes (:func:`_plain_recoloured_copy`; ``colour_variant`` there
  when the shape also agrees tightly). Flagged for a person (``catalog sheet --only flagged``), never
  excluded or merged.
* ``degenerate`` means unusable: unreadable (broken) files, too few faces, (near) zero area, zero volume
  although closed, flat beyond repair (thickness below 1/``max_aspect_ratio`` of the length, along the
  principal axes), a blank render.
* ``mesh_quality`` is a warning with a score: non-manifold edges, holes (open edges), self-intersecting
  faces. Such meshes render, and physics uses convex hulls, so it never excludes unless
  ``filter.exclude_mesh_quality`` is set.
* ``size_outlier``: outside the absolute size bounds, or far from its category's median size.
* ``caption_collision`` belongs to captioning (:mod:`mixcount.captions.captioning`) and is left alone.

Statuses: each connected group of duplicate pairs keeps one object, the first in the *quality order*
(a person accepted it; fewer quality flags, mesh_quality included; image texture > vertex colours > plain material > none; more
faces; lower id), and the other members become ``excluded``; degenerate objects are excluded too when
``filter.exclude_degenerate``. Nothing is deleted. A person's latest review decision outranks all of it
(accept -> active, reject -> excluded) and is re-applied on every run. Re-running is idempotent: the
filter deletes and recomputes only its own flag kinds and first re-activates only the objects it had
excluded itself (their flag reason carries :data:`EXCLUDED_MARK`).
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any, Iterable

import numpy as np
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from mixcount.atomic import write_text_atomic
from mixcount.catalog.containers import refresh_containers
from mixcount.catalog.db import Catalog
from mixcount.catalog.decisions import latest_decisions
from mixcount.catalog.grouping import connected_groups
from mixcount.catalog.models import (
    STATUS_ACTIVE,
    STATUS_BROKEN,
    STATUS_EXCLUDED,
    CatalogObject,
    Flag,
)
from mixcount.config import Config, FilterConfig
from mixcount.curation import appearance3d as A
from mixcount.curation import descriptors as D
from mixcount.curation.renders import canonical_render_path, mask_path_for

EXACT = "exact_duplicate"
NEAR_GEOMETRY = "near_duplicate_geometry"
NEAR_APPEARANCE = "near_duplicate_appearance"
DEGENERATE = "degenerate"
SIZE_OUTLIER = "size_outlier"
MESH_QUALITY = "mesh_quality"
CAPTION_COLLISION = "caption_collision"  # written by captioning, never touched here
COLOUR_VARIANT = "colour_variant"  # same geometry, other appearance: both stay active (a class pair)
POSSIBLE_COPY = "possible_copy"  # maybe the same object from another source: for a person, never excluded
DUPLICATE_KINDS = (EXACT, NEAR_GEOMETRY, NEAR_APPEARANCE)
RELATION_KINDS = (COLOUR_VARIANT, POSSIBLE_COPY)  # pairings that exclude nothing
QUALITY_KINDS = (DEGENERATE, SIZE_OUTLIER, MESH_QUALITY)
FILTER_KINDS = DUPLICATE_KINDS + RELATION_KINDS + QUALITY_KINDS
EXCLUDED_MARK = "[excluded by filter]"
APPEARANCE_RANK = {"image": 0, "vertex_color": 1, "material": 2, "none": 3}


@dataclass
class FilterSummary:
    objects: int = 0
    flags: dict[str, int] = field(default_factory=dict)
    groups: int = 0
    excluded: int = 0
    reactivated: int = 0
    review_applied: int = 0
    missing_renders: int = 0
    containers: int = 0
    descriptor_failures: list[dict[str, Any]] = field(default_factory=list)
    ground_truth: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class _Item:
    obj: CatalogObject
    shape: D.ShapeDescriptor | None = None
    look: D.AppearanceDescriptor | None = None
    surface: A.SurfaceLook | None = None
    appearance: str = "none"
    _asymmetry: list[float] | None = None
    _shape_look: A.SurfaceLook | None = None

    def shape_look(self) -> A.SurfaceLook:
        """The surface samples without their colours (:func:`~mixcount.curation.appearance3d.shape_only`)."""
        assert self.surface is not None
        if self._shape_look is None:
            self._shape_look = A.shape_only(self.surface)
        return self._shape_look

    def asymmetry(self) -> list[float]:
        """:func:`~mixcount.curation.appearance3d.mirror_asymmetry`, computed once."""
        if self._asymmetry is None:
            self._asymmetry = A.mirror_asymmetry(self.shape_look())
        return self._asymmetry


@dataclass
class _Found:
    a: int
    b: int | None
    kind: str
    score: float
    reason: str


def _label(obj: CatalogObject) -> str:
    return f"#{obj.id} {obj.name!r}"


def _appearance_kind(obj: CatalogObject) -> str:
    try:
        data = json.loads(obj.metadata_json or "{}")
        return str((data.get("ingest") or {}).get("appearance") or "none")
    except (ValueError, AttributeError):
        return "none"


def _describe(catalog: Catalog, session: Session, items: list[_Item], summary: FilterSummary) -> None:
    cache = catalog.data_dir / "descriptors"
    for it in items:
        obj = it.obj
        it.appearance = _appearance_kind(obj)
        try:
            it.shape = D.load_shape(obj.model_path, units=obj.source_units, up_axis=obj.source_up_axis,
                                    cache_dir=cache, key=(obj.geometry_hash or "")[:32] or None)
        except Exception as exc:  # a model that ingested but no longer loads: reported, batch goes on
            summary.descriptor_failures.append({"id": obj.id, "name": obj.name, "error": f"{type(exc).__name__}: {exc}"})
        try:
            points, colours = A.load_samples(obj.model_path, cache_dir=cache, key=(obj.content_hash or "")[:32] or None)
            it.surface = A.surface_look(points, colours)
        except Exception as exc:  # noqa: BLE001 - as above
            summary.descriptor_failures.append({"id": obj.id, "name": obj.name,
                                                "error": f"surface appearance: {type(exc).__name__}: {exc}"})
        path = canonical_render_path(session, obj.id)
        if path is None:
            summary.missing_renders += 1
            continue
        try:
            it.look = D.appearance_descriptor(path, mask_path_for(path))
        except OSError as exc:
            summary.descriptor_failures.append({"id": obj.id, "name": obj.name, "error": f"render unreadable: {exc}"})


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
    def key(x: _Item, y: _Item, gain: float) -> str | None:
        a, b = (x.obj.content_hash or "")[:32], (y.obj.content_hash or "")[:32]
        return f"{a}:{b}:{gain:.4f}" if a and b else None

    def layout(self, x: _Item, y: _Item, first: A.SurfaceLook, other: A.SurfaceLook, gain: float, search_above: float) -> float:
        key = self.key(x, y, gain)
        if key is not None and key in self.values:
            return self.values[key]
        value = A.layout_distance(first, other, search_above=search_above)
        if key is not None:
            self.values[key] = round(value, 6)
            self.dirty = True
        return value

    def refined(self, x: _Item, y: _Item, first: A.SurfaceLook, other: A.SurfaceLook, gain: float) -> float:
        """Layout distance after a local rotation refinement, both ways (cross-source copies), cached."""
        key = self.key(x, y, gain)
        key = f"refined:{key}" if key is not None else None
        if key is not None and key in self.values:
            return self.values[key]
        value = min(A.refined_layout_distance(first, other), A.refined_layout_distance(other, first))
        if key is not None:
            self.values[key] = round(value, 6)
            self.dirty = True
        return value

    def occupancy(self, x: _Item, y: _Item) -> float:
        """Axis-normalised shape distance (:func:`~mixcount.curation.appearance3d.occupancy_distance`), cached."""
        key = self.key(x, y, 1.0)
        key = f"occupancy:{key}" if key is not None else None
        if key is not None and key in self.values:
            return self.values[key]
        value = A.occupancy_distance(x.shape_look(), y.shape_look())
        if key is not None:
            self.values[key] = round(value, 6)
            self.dirty = True
        return value

    def save(self) -> None:
        if self.path is None or not self.dirty:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.path, json.dumps(self.values, sort_keys=True))  # a fresh temporary name per writer
        self.dirty = False


def _pair_flags(items: list[_Item], th: FilterConfig, layouts: LayoutCache | None = None) -> list[_Found]:
    layouts = layouts or LayoutCache(None)
    found: list[_Found] = []
    for x, y in combinations(items, 2):
        a, b = x.obj, y.obj
        if a.content_hash and a.content_hash == b.content_hash:
            found.append(_Found(a.id, b.id, EXACT, 1.0, "identical model content (content hash {})".format(a.content_hash[:12])))
            continue
        ph = col = edge = None
        if x.look is not None and y.look is not None:
            ph, col = D.phash_distance(x.look, y.look), D.colour_distance(x.look, y.look)
            edge = D.edge_similarity(x.look, y.look)
        if (a.geometry_hash and a.geometry_hash == b.geometry_hash and ph is not None and col is not None
                and ph <= th.exact_phash and col <= th.exact_colour):
            found.append(_Found(a.id, b.id, EXACT, 1.0,
                                f"identical mesh and indistinguishable renders (pHash {ph:.3f}, colour {col:.3f})"))
            continue
        if x.shape is not None and y.shape is not None:
            d2 = D.d2_distance(x.shape, y.shape)
            prop = D.ratio_distance(x.shape, y.shape)
            size = abs(math.log(D.size_ratio(x.shape, y.shape)))
            same_layout = edge is None or edge >= th.geometry_edge_similarity
            if d2 <= th.geometry_d2 and prop <= th.geometry_proportions and size <= th.geometry_size and same_layout:
                score = 1.0 - max(d2 / th.geometry_d2, prop / th.geometry_proportions, size / th.geometry_size) / 2
                layout = f", edge structure {edge:.2f}" if edge is not None else ""
                colours = f", render colours differ by {col:.2f}" if col is not None else ""
                surface = _surface_colour(x, y, th)
                colours += f", surface colours by {surface:.3f}" if surface is not None else ""
                facts = (f"same shape and size (D2 {d2:.3f}, proportions {prop:.3f}, size ratio "
                         f"{math.exp(size):.3f}{layout}{colours})")
                same_look = ((col is not None and col <= th.appearance_colour)
                             or (surface is not None and surface <= th.look_colour))
                if not same_look:  # one geometry in other colours: a class of its own, not a copy
                    found.append(_Found(a.id, b.id, COLOUR_VARIANT, round(max(0.0, score), 4),
                                        f"colour variant: {facts}"))
                    continue
                found.append(_Found(a.id, b.id, NEAR_GEOMETRY, round(max(0.0, score), 4), facts))
        if ph is not None and col is not None and ph <= th.appearance_phash and col <= th.appearance_colour:
            score = 1.0 - max(ph / th.appearance_phash, col / th.appearance_colour) / 2
            extra = ""
            if x.shape is not None and y.shape is not None:
                extra = f"; real sizes differ {max(D.size_ratio(x.shape, y.shape), D.size_ratio(y.shape, x.shape)):.2f}x"
            found.append(_Found(a.id, b.id, NEAR_APPEARANCE, round(max(0.0, score), 4),
                                f"canonical renders look alike (pHash {ph:.3f}, colour {col:.3f}){extra}"))
            continue
        surface = _surface_match(x, y, th, layouts)
        if surface is not None:
            found.append(_Found(a.id, b.id, NEAR_APPEARANCE, *surface))
            continue
        other = _cross_source(x, y, th, layouts)
        if other is not None:
            found.append(_Found(a.id, b.id, *other))
    return found


def _surface_colour(x: _Item, y: _Item, th: FilterConfig) -> float | None:
    """Surface colour transport of two objects, after one bounded brightness factor where it helps."""
    if x.surface is None or y.surface is None:
        return None
    return _colours(x.surface, y.surface, th)[0]


def _colours(a: A.SurfaceLook, b: A.SurfaceLook, th: FilterConfig) -> tuple[float, float]:
    """(colour transport, brightness factor used): as stored, or after one bounded exposure factor (a
    re-bake under other light), whichever is closer (a factor estimated from two means is noisy near 1)."""
    gain = A.exposure_gain(a, b, th.look_exposure_gain)
    col = A.colour_transport(a, b)
    if gain != 1.0:
        col_relit = A.colour_transport(a, b, gain)
        if col_relit < col:
            return col_relit, gain
    return col, 1.0


def pattern_strength(look: A.SurfaceLook) -> float:
    """Mean distance of the surface colours from their mean (RGB 0..1): 0 for a plain colour. A colour
    layout only confirms a pairing where the surface has a pattern to lay out."""
    colours = np.asarray(look.colours, dtype=np.float64)
    return float(np.abs(colours - colours.mean(axis=0)).sum(axis=1).mean()) if len(colours) else 0.0


def _surface_match(x: _Item, y: _Item, th: FilterConfig, layouts: LayoutCache) -> tuple[float, str] | None:
    """(score, reason) when two objects have the same shape at any scale and look the same from every
    side (the orientation-free rule), else None. Cheap tests first: shape numbers, then colours (after
    one bounded exposure factor), then the colour layout (with a rotation search where axes tie)."""
    if x.surface is None or y.surface is None or x.shape is None or y.shape is None:
        return None
    d2, mom = D.d2_distance(x.shape, y.shape), D.moment_distance(x.shape, y.shape)
    if d2 > th.look_d2 or mom > th.look_proportions:
        return None
    # colours as stored, or after one bounded exposure factor (a re-bake under other light), whichever
    # is closer (a factor estimated from two means is noisy near 1)
    col, gain = _colours(x.surface, y.surface, th)
    if col > th.look_colour:
        return None
    first = A.relit(x.surface, 1.0 / gain) if gain > 1.0 else x.surface  # the brighter side darkened
    other = A.relit(y.surface, gain) if gain < 1.0 else y.surface
    lay = layouts.layout(x, y, first, other, gain, th.look_layout)
    if lay > th.look_layout:
        return None
    score = 1.0 - max(col / th.look_colour, lay / th.look_layout, d2 / th.look_d2,
                      mom / th.look_proportions) / 2
    size = max(D.size_ratio(x.shape, y.shape), D.size_ratio(y.shape, x.shape))
    exposure = f", exposure x{gain:.2f}" if abs(gain - 1.0) >= 0.005 else ""
    return (round(max(0.0, score), 4),
            f"same surface colours and layout from every side (colour {col:.3f}, principal-frame layout {lay:.3f}"
            f"{exposure}) and the same shape at any scale (D2 {d2:.4f}, proportions {mom:.3f}); real sizes differ {size:.2f}x")


def _cross_source(x: _Item, y: _Item, th: FilterConfig, layouts: LayoutCache) -> tuple[str, float, str] | None:
    """(kind, score, reason) for a copy another source published, whose shape agrees only loosely (hard
    decimation, a re-export flattening one axis by 10-25 %, other units and up axis), else None.

    The surface colours must pass the duplicate gate (after one brightness factor) and the
    principal-frame layout too, after a local rotation refinement (a flattened copy's principal axes
    tilt a few degrees). On a patterned surface that is a duplicate (``near_duplicate_appearance``); on
    a plain one the layout only repeats the loose shape, so the pair is a ``possible_copy`` for a person.
    Shape alone never pairs: every ball is a sphere, every box a box, every mug of one mould the same."""
    if x.surface is None or y.surface is None or x.shape is None or y.shape is None:
        return None
    d2, mom = D.d2_distance(x.shape, y.shape), D.moment_distance(x.shape, y.shape)
    if d2 > th.cross_source_d2 or mom > th.cross_source_proportions:
        return None
    col, gain = _colours(x.surface, y.surface, th)
    if col > th.look_colour:
        return _recoloured_copy(x, y, th, d2, mom, col, layouts)
    first = A.relit(x.surface, 1.0 / gain) if gain > 1.0 else x.surface  # the brighter side darkened
    other = A.relit(y.surface, gain) if gain < 1.0 else y.surface
    lay = layouts.refined(x, y, first, other, gain)
    if lay > th.look_layout:
        return None
    pattern = min(pattern_strength(x.surface), pattern_strength(y.surface))
    size = max(D.size_ratio(x.shape, y.shape), D.size_ratio(y.shape, x.shape))
    exposure = f", exposure x{gain:.2f}" if abs(gain - 1.0) >= 0.005 else ""
    facts = (f"surface colours {col:.3f}, principal-frame layout {lay:.3f} (refined){exposure}, pattern {pattern:.3f}; "
             f"shape agrees loosely (D2 {d2:.4f}, proportions {mom:.3f}: decimated or flattened by a re-export?); "
             f"real sizes differ {size:.2f}x")
    score = round(max(0.0, 1.0 - max(col / th.look_colour, lay / th.look_layout, d2 / th.cross_source_d2,
                                      mom / th.cross_source_proportions) / 2), 4)
    if pattern >= th.cross_source_min_pattern:
        return NEAR_APPEARANCE, score, f"copy from another source: {facts}"
    return POSSIBLE_COPY, score, f"possible copy for review (same plain colour, no pattern to confirm it): {facts}"


def _recoloured_copy(x: _Item, y: _Item, th: FilterConfig, d2: float, mom: float,
                     col: float, layouts: LayoutCache) -> tuple[str, float, str] | None:
    """``possible_copy`` for a loosely agreeing shape in other colours whose colour *pattern* repeats
    (:func:`~mixcount.curation.appearance3d.pattern_correlation` >= ``cross_source_pattern``): maybe a
    colour variant republished by another source. Only for patterned surfaces on shapes whose principal
    axes are all distinct: where moments tie (balls, cans, boxes, mugs, cookies) the frame is chosen by
    the colours themselves, and two objects of one mould in other prints correlate by construction.
    Two *plain* surfaces have no pattern: :func:`_plain_recoloured_copy`."""
    assert x.surface is not None and y.surface is not None
    if x.surface.tied or y.surface.tied:
        return None
    strengths = (pattern_strength(x.surface), pattern_strength(y.surface))
    if max(strengths) < th.cross_source_min_pattern:
        return _plain_recoloured_copy(x, y, th, d2, mom, col, layouts)
    pattern = min(strengths)
    if pattern < th.cross_source_min_pattern:
        return None
    corr = A.pattern_correlation(x.surface, y.surface)
    if corr < th.cross_source_pattern:
        return None
    score = round(max(0.0, min(1.0, (corr - th.cross_source_pattern) / (1.0 - th.cross_source_pattern))), 4)
    return (POSSIBLE_COPY, score,
            f"possible copy for review (maybe a colour variant from another source): the colour pattern repeats "
            f"(correlation {corr:.3f}) in other colours ({col:.3f}), pattern {pattern:.3f}; shape agrees loosely "
            f"(D2 {d2:.4f}, proportions {mom:.3f})")


def _plain_recoloured_copy(x: _Item, y: _Item, th: FilterConfig, d2: float, mom: float,
                           col: float, layouts: LayoutCache) -> tuple[str, float, str] | None:
    """A copy from another source in another *plain* colour (the issue's olive duck against the yellow
    one): nothing but the shape to go on, and the loose gates pass whole shape families. A re-export's
    flattening scales one axis, so the shape is compared with each principal axis scaled to its extent
    (``cross_source_occupancy``): unchanged by the squash, units and orientation, and tight. It proves
    nothing for a shape that the scaling makes one of a family (every box a cube, every can one
    cylinder, every egg a ball), so both shapes must be mirror-asymmetric along at least two principal
    axes (``cross_source_min_asymmetry``; a cow, a duck, a bunny are, a box, a can, a bone are not).
    ``colour_variant`` when the shape also passes the tight gates of the look rule (the same shape at any
    scale in other colours: one geometry in two colours); else ``possible_copy`` for a person."""
    asym = [sorted(it.asymmetry(), reverse=True) for it in (x, y)]
    if min(a[1] for a in asym) < th.cross_source_min_asymmetry:
        return None
    occ = layouts.occupancy(x, y)
    if occ > th.cross_source_occupancy:
        return None
    facts = (f"the same shape with each principal axis scaled to its extent (occupancy {occ:.3f}), mirror-asymmetric "
             f"along two principal axes ({asym[0][1]:.2f} / {asym[1][1]:.2f}), in other plain colours ({col:.3f})")
    if d2 <= th.look_d2 and mom <= th.look_proportions:
        score = 1.0 - max(occ / th.cross_source_occupancy, d2 / th.look_d2, mom / th.look_proportions) / 2
        return (COLOUR_VARIANT, round(max(0.0, score), 4),
                f"colour variant (another plain colour, the same shape at any scale): {facts}; D2 {d2:.4f}, "
                f"proportions {mom:.3f}")
    score = 1.0 - max(occ / th.cross_source_occupancy, d2 / th.cross_source_d2, mom / th.cross_source_proportions) / 2
    return (POSSIBLE_COPY, round(max(0.0, score), 4),
            f"possible copy for review (maybe a colour variant from another source): {facts}; shape agrees "
            f"loosely (D2 {d2:.4f}, proportions {mom:.3f}: decimated or flattened by a re-export?)")


def mesh_quality_score(fraction: float) -> float:
    """Severity in [0, 1] of the worst defect fraction: 0.1 at 0.1 %, 0.35 at 1 %, 0.67 at 10 %, 1 at 100 %."""
    return round(min(1.0, math.log10(1.0 + 1000.0 * max(0.0, fraction)) / 3.0), 4)


def _quality_flags(items: list[_Item], broken: list[CatalogObject], th: FilterConfig) -> list[_Found]:
    found = [_Found(o.id, None, DEGENERATE, 1.0, f"unreadable model: {o.error or 'broken'}") for o in broken]
    for it in items:
        o, s = it.obj, it.shape
        reasons: list[str] = []
        faces = s.faces if s is not None else (o.face_count or 0)
        if faces < th.min_faces:
            reasons.append(f"only {faces} faces (< {th.min_faces})")
        if s is not None:
            if s.area_m2 <= th.min_area_ratio * max(s.extents_m[0], 1e-12) ** 2:
                reasons.append(f"(near) zero surface area ({s.area_m2:.3g} m^2 for a {s.extents_m[0] * 100:.1f} cm object)")
            if s.watertight and (s.volume_m3 or 0.0) <= th.min_volume_m3:
                reasons.append(f"closed mesh with zero volume ({s.volume_m3:.3g} m^3)")
            thin = s.ratios[1]  # thickness / length along the principal axes
            if thin <= 0 or 1.0 / thin > th.max_aspect_ratio:
                aspect = "infinitely" if thin <= 0 else f"{1.0 / thin:.0f}:1"
                reasons.append(f"flat beyond repair: {aspect} thin (> {th.max_aspect_ratio:g}:1)")
            worst = max(s.nonmanifold_fraction, s.boundary_fraction, s.self_intersection_fraction)
            if worst > th.mesh_quality_min_fraction:
                found.append(_Found(o.id, None, MESH_QUALITY, mesh_quality_score(worst),
                                    f"{100 * s.nonmanifold_fraction:.2f}% non-manifold edges, {100 * s.boundary_fraction:.2f}% "
                                    f"open edges (holes), {100 * s.self_intersection_fraction:.2f}% self-intersecting faces; "
                                    "usable: it renders and physics uses its convex hull"))
        if it.look is not None and it.look.coverage < th.min_render_coverage:
            reasons.append(f"blank render ({100 * it.look.coverage:.2f}% object pixels)")
        if reasons:
            found.append(_Found(o.id, None, DEGENERATE, 1.0, "; ".join(reasons)))
    # size outliers: absolute bounds, then against the category's median (categories with enough members)
    sizes = {it.obj.id: (it.shape.extents_m[0] if it.shape is not None else max(it.obj.dims)) for it in items}
    by_cat: dict[str, list[float]] = defaultdict(list)
    for it in items:
        if sizes[it.obj.id] > 0:
            by_cat[it.obj.category].append(sizes[it.obj.id])
    for it in items:
        size = sizes[it.obj.id]
        reason, score = None, 1.0
        if size < th.min_size_m:
            reason = f"largest side {size * 100:.2f} cm is below {th.min_size_m * 100:g} cm"
        elif size > th.max_size_m:
            reason = f"largest side {size:.2f} m is above {th.max_size_m:g} m"
        else:
            peers = by_cat[it.obj.category]
            if len(peers) >= th.category_min_objects:
                median = float(np.median(peers))
                factor = max(size / median, median / size)
                if factor > th.category_size_factor:
                    reason = (f"{size * 100:.1f} cm is {factor:.1f}x {'larger' if size > median else 'smaller'} than "
                              f"the {it.obj.category} median {median * 100:.1f} cm")
                    score = min(1.0, math.log(factor) / math.log(th.category_size_factor) / 2)
        if reason:
            found.append(_Found(it.obj.id, None, SIZE_OUTLIER, round(score, 4), reason))
    return found


def quality_key(obj: CatalogObject, *, accepted: set[int], quality_flags: dict[int, int], appearance: str) -> tuple:
    """Sort key of the documented quality order: smaller is better."""
    return (
        0 if obj.id in accepted else 1,
        quality_flags.get(obj.id, 0),
        APPEARANCE_RANK.get(appearance, 3),
        -(obj.face_count or 0),
        obj.id,
    )


def _groups(pairs: Iterable[tuple[int, int]]) -> list[list[int]]:
    return connected_groups(pairs)


def run_filter(catalog: Catalog, config: Config, *, ground_truth: bool = True) -> FilterSummary:
    """Recompute every filter flag, re-pick duplicate keepers, re-apply review decisions (idempotent).

    ``config.filter`` holds the thresholds; ``config.containers`` the container rules recomputed at the end."""
    th = config.filter
    summary = FilterSummary()
    with catalog.session() as session:
        objects = session.scalars(select(CatalogObject).order_by(CatalogObject.id)).all()
        summary.objects = len(objects)
        by_id = {o.id: o for o in objects}
        # 1. undo our own exclusions, then forget our flags (captioning's flags stay)
        ours = session.scalars(select(Flag).where(Flag.kind.in_(FILTER_KINDS))).all()
        marked = {f.object_id for f in ours if EXCLUDED_MARK in (f.reason or "")}
        for oid in marked:
            obj = by_id.get(oid)
            if obj is not None and obj.status == STATUS_EXCLUDED:
                obj.status = STATUS_ACTIVE
                summary.reactivated += 1
        session.execute(delete(Flag).where(Flag.kind.in_(FILTER_KINDS)))
        session.flush()

        live = [o for o in objects if o.status in (STATUS_ACTIVE, STATUS_EXCLUDED)]
        broken = [o for o in objects if o.status == STATUS_BROKEN]
        items = [_Item(o) for o in live]
        _describe(catalog, session, items, summary)
        item_of = {it.obj.id: it for it in items}
        layouts = LayoutCache(catalog.data_dir / "descriptors" / f"layouts_{A.APPEARANCE_VERSION}_{A.LAYOUT_VERSION}.json")
        found = _pair_flags(items, th, layouts) + _quality_flags(items, broken, th)
        layouts.save()

        decisions = latest_decisions(session)
        accepted = {oid for oid, rd in decisions.items() if rd.decision == "accept"}
        rejected = {oid for oid, rd in decisions.items() if rd.decision == "reject"}
        qflags: dict[int, int] = defaultdict(int)
        for f in found:
            if f.kind in QUALITY_KINDS:
                qflags[f.a] += 1

        # 2. duplicate groups: keep the best active member, exclude the other active ones
        exclude: dict[int, str] = {}
        pairs = [(f.a, f.b) for f in found if f.kind in DUPLICATE_KINDS and f.b is not None]
        for group in _groups(pairs):
            summary.groups += 1
            members = [by_id[i] for i in group]
            candidates = [o for o in members if o.status == STATUS_ACTIVE and o.id not in rejected]
            if not candidates:
                continue
            keep = min(candidates, key=lambda o: quality_key(o, accepted=accepted, quality_flags=qflags,
                                                             appearance=item_of[o.id].appearance))
            for o in candidates:
                if o is not keep and o.id not in accepted:
                    exclude[o.id] = f"{EXCLUDED_MARK} duplicate group keeps {_label(keep)}"
        for f in found:
            if f.a not in item_of or f.a in accepted or by_id[f.a].status != STATUS_ACTIVE:
                continue
            if f.kind == DEGENERATE and th.exclude_degenerate:
                exclude.setdefault(f.a, f"{EXCLUDED_MARK} degenerate")
            if f.kind == MESH_QUALITY and th.exclude_mesh_quality and f.score >= th.mesh_quality_exclude_score:
                exclude.setdefault(f.a, f"{EXCLUDED_MARK} mesh quality {f.score:.2f}")

        # 3. write flags (both directions for pairs); the excluded side's reasons carry the mark
        counts: dict[str, int] = defaultdict(int)
        for f in found:
            ends = [(f.a, f.b), (f.b, f.a)] if f.b is not None else [(f.a, None)]
            for oid, other in ends:
                reason = f.reason
                if other is not None:
                    reason = f"{reason}; pair {_label(by_id[other])}"
                if oid in exclude and (f.kind in DUPLICATE_KINDS or f.kind in (DEGENERATE, MESH_QUALITY)):
                    reason = f"{reason} {exclude[oid]}"
                session.add(Flag(object_id=oid, kind=f.kind, score=float(f.score), reason=reason, pair_object_id=other))
                counts[f.kind] += 1
        for oid in exclude:
            by_id[oid].status = STATUS_EXCLUDED
        summary.excluded = len(exclude)

        # 4. a person's decision outranks everything
        for oid, rd in decisions.items():
            obj = by_id.get(oid)
            if obj is None or obj.status == STATUS_BROKEN:
                continue
            want = STATUS_ACTIVE if rd.decision == "accept" else STATUS_EXCLUDED
            if obj.status != want:
                obj.status = want
            summary.review_applied += 1
        session.commit()
        summary.flags = {k: counts.get(k, 0) for k in FILTER_KINDS}
        summary.containers = refresh_containers(session, config).containers
    if ground_truth:
        summary.ground_truth = evaluate_against_ground_truth(catalog)
    return summary


# --------------------------------------------------------------------------- ground truth (demo library)


def find_ground_truth(objects: Iterable[CatalogObject]) -> Path | None:
    """``ground_truth.json`` of the demo library the objects were ingested from (next to their folders)."""
    roots: dict[Path, int] = defaultdict(int)
    for o in objects:
        if o.model_path:
            roots[Path(o.model_path).parent.parent] += 1
    for root, _ in sorted(roots.items(), key=lambda kv: -kv[1]):
        gt = root / "ground_truth.json"
        if gt.is_file():
            return gt
    return None


VARIANT_TRAPS = ("recolour",)  # trap kinds that are colour variants (a class pair), not duplicates
TRAP_KINDS = (  # ground_truth.json key -> trap kind
    ("exact_copies", "exact"), ("recolours", "recolour"), ("rescales", "rescale"),
    ("turned_rescales", "turned_rescale"), ("retessellated", "retessellated"), ("other_source", "other_source"),
    ("remeshed", "remeshed"), ("unit_changes", "units"), ("rebaked", "rebaked"), ("split_parts", "split"),
)


def evaluate_against_ground_truth(catalog: Catalog, path: Path | None = None) -> dict[str, Any] | None:
    """Precision/recall of duplicate pairs, per trap kind, against a demo library's ground truth.

    Objects are matched by their folder name. A predicted pair (any duplicate kind, ``colour_variant`` or
    ``possible_copy``) is correct when both objects belong to one planted group (two copies of one
    original are duplicates of each other too). Per trap kind: recall = planted pairs found with the
    expected kind (``colour_variant`` for the recolours of :data:`VARIANT_TRAPS`, a duplicate kind for the
    others); precision = of the predicted pairs that involve the kind's copies, the share that is correct.
    ``clean`` objects are those in no planted group and not broken; the share of them carrying any
    duplicate flag is the false-flag rate (at most 5 % by the issue's bound), ``clean_paired`` counts
    those with any pairing (variants and possible copies too).
    Also: broken files flagged degenerate, and each planted ``mesh_quality`` object's flags and status.
    """
    with catalog.session() as session:
        objects = session.scalars(select(CatalogObject)).all()
        gt_path = path or find_ground_truth(objects)
        if gt_path is None:
            return None
        try:
            truth = json.loads(Path(gt_path).read_text())
        except (OSError, ValueError):
            return None
        root = Path(gt_path).parent.resolve()
        folder_of: dict[int, str] = {}
        status_of: dict[str, str] = {}
        for o in objects:
            p = Path(o.model_path).parent
            if p.parent.resolve() == root:
                folder_of[o.id] = p.name
                status_of[p.name] = o.status
        id_of = {v: k for k, v in folder_of.items()}
        flags = session.scalars(select(Flag).where(Flag.object_id.in_(list(folder_of)))).all()
    true_pairs: dict[frozenset[str], str] = {}
    copy_kind: dict[str, str] = {}
    for key, kind in TRAP_KINDS:
        for entry in truth.get(key, []):
            if entry[0] in id_of and entry[1] in id_of:
                true_pairs[frozenset(entry[:2])] = kind
                copy_kind[entry[1]] = kind
    group_of: dict[str, int] = {}
    for k, group in enumerate(connected_groups(tuple(p) for p in true_pairs)):
        for name in group:
            group_of[name] = k
    predicted: dict[frozenset[str], set[str]] = defaultdict(set)
    flagged_dup: set[str] = set()
    flagged_any: set[str] = set()
    quality: dict[str, dict[str, float]] = defaultdict(dict)
    for f in flags:
        name = folder_of.get(f.object_id)
        if f.kind in DUPLICATE_KINDS + RELATION_KINDS and f.pair_object_id in folder_of:
            predicted[frozenset((name, folder_of[f.pair_object_id]))].add(f.kind)
            flagged_any.add(name)  # type: ignore[arg-type]
            if f.kind in DUPLICATE_KINDS:
                flagged_dup.add(name)  # type: ignore[arg-type]
        if f.kind in QUALITY_KINDS:
            quality[name][f.kind] = float(f.score)  # type: ignore[index]

    def correct(pair: frozenset[str]) -> bool:
        a, b = tuple(pair)
        return a in group_of and group_of.get(a) == group_of.get(b)

    def expected(pair: frozenset[str], kind: str) -> bool:
        wanted = (COLOUR_VARIANT,) if kind in VARIANT_TRAPS else DUPLICATE_KINDS
        return bool(predicted.get(pair, set()) & set(wanted))

    hits = [p for p in predicted if correct(p)]
    broken = [b["folder"] for b in truth.get("broken", []) if b["folder"] in id_of]
    clean = [n for n in id_of if n not in group_of and n not in set(broken)]
    clean_flagged = sorted(n for n in clean if n in flagged_dup)
    per_kind = {}
    for _, kind in TRAP_KINDS:
        pairs = [p for p, k in true_pairs.items() if k == kind]
        copies = {n for n, k in copy_kind.items() if k == kind}
        touching = [p for p in predicted if p & copies]
        found = sum(expected(p, kind) for p in pairs)
        per_kind[kind] = {
            "expected": "colour_variant" if kind in VARIANT_TRAPS else "duplicate",
            "planted": len(pairs), "found": found,
            "recall": round(found / len(pairs), 4) if pairs else None,
            "precision": round(sum(correct(p) for p in touching) / len(touching), 4) if touching else None,
            "flags": sorted({k for p in pairs for k in predicted.get(p, ())}),
        }
    planted_quality = [n for n in truth.get("mesh_quality", []) if n in id_of]
    return {
        "ground_truth": str(gt_path),
        "pairs_planted": len(true_pairs),
        "pairs_predicted": len(predicted),
        "pairs_correct": len(hits),
        "precision": round(len(hits) / len(predicted), 4) if predicted else 1.0,
        "recall": round(sum(expected(p, k) for p, k in true_pairs.items()) / len(true_pairs), 4) if true_pairs else 1.0,
        "by_trap": per_kind,
        "missed_pairs": sorted(sorted(p) for p, k in true_pairs.items() if not expected(p, k)),
        "false_pairs": sorted(sorted(p) for p in predicted if not correct(p)),
        "broken_planted": len(broken),
        "broken_flagged": sum(DEGENERATE in quality.get(b, {}) for b in broken),
        "clean_objects": len(clean),
        "clean_with_duplicate_flag": len(clean_flagged),
        "clean_flag_rate": round(len(clean_flagged) / len(clean), 4) if clean else 0.0,
        "clean_flagged": clean_flagged,
        "clean_paired": sorted(n for n in clean if n in flagged_any),
        "variant_pairs": sum(COLOUR_VARIANT in k for k in predicted.values()),
        "possible_copies": sum(POSSIBLE_COPY in k for k in predicted.values()),
        "mesh_quality_planted": [
            {"folder": n, "status": status_of[n], "mesh_quality": quality.get(n, {}).get(MESH_QUALITY),
             "degenerate": DEGENERATE in quality.get(n, {})} for n in planted_quality
        ],
    }
