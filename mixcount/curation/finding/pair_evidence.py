"""What a pairing needs before it counts (issue 57): appearance is evidence only where there is some, a size
ratio can be evidence against, and an exclusion needs geometry that agrees after alignment.

The appearance rules (:mod:`mixcount.curation.finding.look_rules`) pair objects whose renders or surface colours
look alike. On an untextured library every object is the same grey: a hex nut's render and a hockey
puck's look alike, a cup's and a mug's, a cone's and a pyramid's, and none of that says they are one
object. :func:`weigh` checks each pairing the appearance rules found, before the shape rule
(:mod:`mixcount.curation.finding.copy_rules`) sees the pair:

* **Size** (:func:`mixcount.sizes.size_ratio_evidence` on the square roots of the real surface areas): a ratio beyond a
  re-export's rescale (``size_rescale``) that no unit factor explains (``size_unit_tolerance``, widened by the
  squash the alignment found: a copy in other units *and* squashed 10-25 % along one axis has 5-13 % less
  surface, issue 69) is evidence against a copy: the pair keeps no duplicate, variant or possible-copy flag (the shape rule makes
  it a ``look_alike`` at most, the size sentence in its reason). An identical file or mesh
  (``exact_duplicate``) stays whatever the size. A largest side no everyday object has
  (:func:`mixcount.sizes.is_plausible`: a unit ingest could not read, a scan 15 m wide) is no evidence.
* **Plain surfaces**: two surfaces with less colour spread than ``appearance_min_pattern`` (untextured,
  one flat colour) carry no evidence in their look. Their ``near_duplicate_*`` flags stand only with
  *shape evidence* after alignment (:mod:`mixcount.curation.finding.shape_match`): the aligned distance at most
  ``exclude_plain_shape`` (tight: a cone and a pyramid agree within 0.048) and ``copy_evidence`` x the nearer primitive distance, both objects at least
  ``copy_min_detail`` from a primitive. Otherwise the flags go and the shape rule decides (a
  ``possible_copy`` for a person with shape evidence, else a ``look_alike`` at most).
* **Patterned surfaces**: an exclusion needs the geometry to agree after alignment too (at most
  ``exclude_shape``); a same-look pair whose shapes do not agree becomes a ``possible_copy``, which the
  shape rule keeps only with shape evidence.

Alignment distances are cached per pair (the same cache entries as the shape rule's)."""

from __future__ import annotations

import math

from mixcount.config import FilterConfig
from mixcount.curation.finding import descriptors as D
from mixcount.curation.finding import shape_match as S
from mixcount.curation.finding.filter_items import Found, Item, LayoutCache, settings_key
from mixcount.curation.finding.look_rules import pattern_strength
from mixcount.curation.flag_kinds import (
    COLOUR_VARIANT,
    LOOK_ALIKE,
    NEAR_APPEARANCE,
    NEAR_GEOMETRY,
    POSSIBLE_COPY,
)
from mixcount.sizes import SizeEvidence, is_plausible, size_ratio_evidence

EXCLUDING = (NEAR_APPEARANCE, NEAR_GEOMETRY)
PAIRING = EXCLUDING + (COLOUR_VARIANT, POSSIBLE_COPY)


def size_evidence(x: Item, y: Item, th: FilterConfig, layouts: LayoutCache | None = None) -> SizeEvidence | None:
    """The real sizes of the two weighed: the square root of the surface area, which no pose changes (a
    bounding box's largest side does: a turned copy's grows up to 1.7x); None when a descriptor is missing or
    a largest side is implausible (its unit is unknown, so its size says nothing).

    A squash changes the area too: squashed by ``f`` along one axis, a surface keeps between ``f`` and all of
    its area. So where a unit factor explains the ratio only with the squash ``copy_max_squash`` allows, and
    the shapes agree loosely (the copy rule's cheap gates), the pair is aligned (``layouts``: the cached
    alignment the shape rule uses too) and the unit tolerance is widened by the square root of the stretch
    the alignment found (largest over smallest stretch of its map): a unit error plus the squash that is
    there, not any squash."""
    if x.shape is None or y.shape is None or not (x.shape.area_m2 and y.shape.area_m2):
        return None
    if not (is_plausible(max(x.shape.extents_m, default=0.0)) and is_plausible(max(y.shape.extents_m, default=0.0))):
        return None
    sizes = math.sqrt(x.shape.area_m2), math.sqrt(y.shape.area_m2)
    got = size_ratio_evidence(*sizes, rescale_limit=th.size_rescale, tolerance=th.size_unit_tolerance)
    if not got.against or layouts is None or x.surface is None or y.surface is None:
        return got
    widest = (1.0 + th.size_unit_tolerance) * math.sqrt(th.copy_max_squash) - 1.0
    if size_ratio_evidence(*sizes, rescale_limit=th.size_rescale, tolerance=widest).against:
        return got
    if D.d2_distance(x.shape, y.shape) > th.copy_gate_d2 or D.moment_distance(x.shape, y.shape) > th.cross_source_proportions:
        return got
    stretch = alignment(x, y, th, layouts)[1]
    squashed = size_ratio_evidence(*sizes, rescale_limit=th.size_rescale,
                                   tolerance=(1.0 + th.size_unit_tolerance) * math.sqrt(max(stretch, 1.0)) - 1.0)
    if squashed.against:
        return got
    return SizeEvidence(got.ratio, False, f"{squashed.explained_by} and a squash x{stretch:.2f}")


def is_plain(it: Item, th: FilterConfig) -> bool:
    """No colour pattern on the surface (untextured, or one flat colour): its look is no evidence."""
    return it.surface is None or pattern_strength(it.surface) < th.appearance_min_pattern


def aligned_distance(x: Item, y: Item, th: FilterConfig, layouts: LayoutCache) -> float:
    """The shape rule's aligned distance of the pair (cached under the same key)."""
    return alignment(x, y, th, layouts)[0]


def alignment(x: Item, y: Item, th: FilterConfig, layouts: LayoutCache) -> tuple[float, float]:
    """(aligned distance, stretch of the map: largest over smallest, 1.0 for none) of the pair, one
    :func:`~mixcount.curation.finding.shape_match.match` for both, each cached (``shape`` / ``stretch``)."""
    done: list[S.Match] = []

    def run() -> S.Match:
        if not done:
            done.append(S.match(x.normalised(), y.normalised(), max_squash=th.copy_max_squash,
                                quantile=th.match_quantile))
        return done[0]

    settings = settings_key(copy_max_squash=th.copy_max_squash, match_quantile=th.match_quantile)
    return (layouts.cached(x, y, "shape", lambda: run().distance, settings),
            layouts.cached(x, y, "stretch", lambda: run().stretch, settings))


def primitive(x: Item, th: FilterConfig, layouts: LayoutCache) -> float:
    """An object's distance to its nearest primitive (cached under the shape rule's key)."""
    return layouts.cached(x, x, "primitive", lambda: S.primitive_distance(x.normalised(), quantile=th.match_quantile),
                          settings_key(match_quantile=th.match_quantile))


def weigh(x: Item, y: Item, found: list[Found], th: FilterConfig,
          layouts: LayoutCache) -> tuple[list[Found], SizeEvidence | None]:
    """The appearance rules' ``found`` flags of one pair that the evidence bears (see the module doc), and
    the size evidence when it is against a copy (the shape rule then ranks the pair a look-alike at most)."""
    size = size_evidence(x, y, th, layouts)
    against = size if size is not None and size.against else None
    if against is not None:
        return [f for f in found if f.kind not in PAIRING], against
    if not any(f.kind in EXCLUDING for f in found) or x.surface is None or y.surface is None:
        return found, None
    d = aligned_distance(x, y, th, layouts)
    plain = is_plain(x, th) and is_plain(y, th)
    if plain:
        prim = min(primitive(x, th, layouts), primitive(y, th, layouts))
        evidence = d <= th.exclude_plain_shape and prim >= th.copy_min_detail and d <= th.copy_evidence * prim
        if not evidence:  # a grey surface says nothing: the shape rule decides
            return [f for f in found if f.kind not in EXCLUDING], None
        figures = f"plain surfaces, the shape carries the evidence: aligned distance {d:.3f}, nearest primitive {prim:.3f}"
    elif d <= th.exclude_shape:
        figures = f"aligned shape distance {d:.3f}"
    else:
        return [Found(f.a, f.b, POSSIBLE_COPY, f.score,
                      f"possible copy for review (the look agrees, the shape does not after alignment: {d:.3f}): {f.reason}")
                if f.kind in EXCLUDING else f for f in found], None
    return [Found(f.a, f.b, f.kind, f.score, f"{f.reason}; {figures}") if f.kind in EXCLUDING else f
            for f in found], None


def cap_to_look_alike(flags: list[Found], against: SizeEvidence | None) -> list[Found]:
    """With size evidence against a copy, every pairing the shape rule made is a look-alike at most."""
    if against is None:
        return flags
    out = []
    for f in flags:
        if f.kind in PAIRING:
            f = Found(f.a, f.b, LOOK_ALIKE, f.score, f"look-alike, not a copy ({against.describe()}): {f.reason}")
        elif f.kind == LOOK_ALIKE:
            f = Found(f.a, f.b, f.kind, f.score, f"{f.reason}; {against.describe()}")
        out.append(f)
    return out

