"""The pair rules of `catalog filter` that look at appearance: same content, same mesh, same shape and size
with the same or other colours, the same look from the renders or from every side of the surface, and
the loose cross-source rules (see the module doc of :mod:`mixcount.curation.finding.catalog_filter`). The copy rule
that needs shape evidence only is :mod:`mixcount.curation.finding.copy_rules`."""

from __future__ import annotations

import math

import numpy as np

from mixcount.config import FilterConfig
from mixcount.curation.finding import appearance3d as A
from mixcount.curation.finding import colour_layout as CL
from mixcount.curation.finding import descriptors as D
from mixcount.curation.finding.filter_items import Found, Item, LayoutCache
from mixcount.curation.flag_kinds import (
    COLOUR_VARIANT,
    EXACT,
    NEAR_APPEARANCE,
    NEAR_GEOMETRY,
    POSSIBLE_COPY,
)


def look_pair(x: Item, y: Item, th: FilterConfig, layouts: LayoutCache) -> list[Found]:
    """The appearance rules on one pair, in order (the first that fires ends the search, but a
    ``near_duplicate_geometry`` pair may also get ``near_duplicate_appearance``)."""
    found: list[Found] = []
    for _ in (0,):  # one pass: `continue` ends the rules for this pair
        a, b = x.obj, y.obj
        if a.content_hash and a.content_hash == b.content_hash:
            found.append(Found(a.id, b.id, EXACT, 1.0, "identical model content (content hash {})".format(a.content_hash[:12])))
            continue
        ph = col = edge = None
        if x.look is not None and y.look is not None:
            ph, col = D.phash_distance(x.look, y.look), D.colour_distance(x.look, y.look)
            edge = D.edge_similarity(x.look, y.look)
        if (a.geometry_hash and a.geometry_hash == b.geometry_hash and ph is not None and col is not None
                and ph <= th.exact_phash and col <= th.exact_colour):
            found.append(Found(a.id, b.id, EXACT, 1.0,
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
                    found.append(Found(a.id, b.id, COLOUR_VARIANT, round(max(0.0, score), 4),
                                       f"colour variant: {facts}"))
                    continue
                found.append(Found(a.id, b.id, NEAR_GEOMETRY, round(max(0.0, score), 4), facts))
        if ph is not None and col is not None and ph <= th.appearance_phash and col <= th.appearance_colour:
            score = 1.0 - max(ph / th.appearance_phash, col / th.appearance_colour) / 2
            extra = ""
            if x.shape is not None and y.shape is not None:
                extra = f"; real sizes differ {max(D.size_ratio(x.shape, y.shape), D.size_ratio(y.shape, x.shape)):.2f}x"
            found.append(Found(a.id, b.id, NEAR_APPEARANCE, round(max(0.0, score), 4),
                               f"canonical renders look alike (pHash {ph:.3f}, colour {col:.3f}){extra}"))
            continue
        surface = _surface_match(x, y, th, layouts)
        if surface is not None:
            found.append(Found(a.id, b.id, NEAR_APPEARANCE, *surface))
            continue
        other = _cross_source(x, y, th, layouts)
        if other is not None:
            found.append(Found(a.id, b.id, *other))
    return found


def _surface_colour(x: Item, y: Item, th: FilterConfig) -> float | None:
    """Surface colour transport of two objects, after one bounded brightness factor where it helps."""
    if x.surface is None or y.surface is None:
        return None
    return relit_colour_transport(x.surface, y.surface, th)[0]


def relit_colour_transport(a: A.SurfaceLook, b: A.SurfaceLook, th: FilterConfig) -> tuple[float, float]:
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


def _shape_gate(x: Item, y: Item, max_d2: float, max_proportions: float) -> tuple[float, float] | None:
    """(D2 distance, proportions distance) of two objects that both have a surface and a shape and whose
    shape numbers are within the bounds, else None: the first, cheap test of both look rules."""
    if x.surface is None or y.surface is None or x.shape is None or y.shape is None:
        return None
    d2, mom = D.d2_distance(x.shape, y.shape), D.moment_distance(x.shape, y.shape)
    return None if d2 > max_d2 or mom > max_proportions else (d2, mom)


def _surface_match(x: Item, y: Item, th: FilterConfig, layouts: LayoutCache) -> tuple[float, str] | None:
    """(score, reason) when two objects have the same shape at any scale and look the same from every
    side (the orientation-free rule), else None. Cheap tests first: shape numbers, then colours (after
    one bounded exposure factor), then the colour layout (with a rotation search where axes tie)."""
    gate = _shape_gate(x, y, th.look_d2, th.look_proportions)
    if gate is None:
        return None
    d2, mom = gate
    # colours as stored, or after one bounded exposure factor (a re-bake under other light), whichever
    # is closer (a factor estimated from two means is noisy near 1)
    col, gain = relit_colour_transport(x.surface, y.surface, th)
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


def _cross_source(x: Item, y: Item, th: FilterConfig, layouts: LayoutCache) -> tuple[str, float, str] | None:
    """(kind, score, reason) for a copy another source published, whose shape agrees only loosely (hard
    decimation, a re-export flattening one axis by 10-25 %, other units and up axis), else None.

    The surface colours must pass the duplicate gate (after one brightness factor) and the
    principal-frame layout too, after a local rotation refinement (a flattened copy's principal axes
    tilt a few degrees). On a patterned surface that is a duplicate (``near_duplicate_appearance``); on
    a plain one the layout only repeats the loose shape, so the pair is a ``possible_copy`` for a person.
    Shape alone never pairs: every ball is a sphere, every box a box, every mug of one mould the same."""
    gate = _shape_gate(x, y, th.cross_source_d2, th.cross_source_proportions)
    if gate is None:
        return None
    d2, mom = gate
    col, gain = relit_colour_transport(x.surface, y.surface, th)
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


def _recoloured_copy(x: Item, y: Item, th: FilterConfig, d2: float, mom: float,
                     col: float, layouts: LayoutCache) -> tuple[str, float, str] | None:
    """``possible_copy`` for a loosely agreeing shape in other colours whose colour *pattern* repeats
    (:func:`~mixcount.curation.finding.colour_layout.pattern_correlation` >= ``cross_source_pattern``): maybe a
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
    corr = CL.pattern_correlation(x.surface, y.surface)
    if corr < th.cross_source_pattern:
        return None
    score = round(max(0.0, min(1.0, (corr - th.cross_source_pattern) / (1.0 - th.cross_source_pattern))), 4)
    return (POSSIBLE_COPY, score,
            f"possible copy for review (maybe a colour variant from another source): the colour pattern repeats "
            f"(correlation {corr:.3f}) in other colours ({col:.3f}), pattern {pattern:.3f}; shape agrees loosely "
            f"(D2 {d2:.4f}, proportions {mom:.3f})")


def _plain_recoloured_copy(x: Item, y: Item, th: FilterConfig, d2: float, mom: float,
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

