"""Per-object flags of `catalog filter`: degenerate (unusable), mesh_quality (a usable warning), size_outlier."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from mixcount.catalog.models import CatalogObject
from mixcount.config import FilterConfig
from mixcount.curation.finding.filter_items import Found, Item
from mixcount.curation.flag_kinds import DEGENERATE, MESH_QUALITY, SIZE_OUTLIER


def mesh_quality_score(fraction: float) -> float:
    """Severity in [0, 1] of the worst defect fraction: 0.1 at 0.1 %, 0.35 at 1 %, 0.67 at 10 %, 1 at 100 %."""
    return round(min(1.0, math.log10(1.0 + 1000.0 * max(0.0, fraction)) / 3.0), 4)


def _broken_kind(error: str | None) -> str:
    """A broken object's flag head: a file read whole whose geometry cannot be an object (inf / nan or absurd
    coordinates, zero area: mesh_bounds) is a degenerate model, anything else an unreadable one."""
    text = error or ""
    return "degenerate model" if text.startswith(("mesh is degenerate", "mesh has non-finite")) else "unreadable model"


def quality_flags(items: list[Item], broken: list[CatalogObject], th: FilterConfig) -> list[Found]:
    found = [Found(o.id, None, DEGENERATE, 1.0, f"{_broken_kind(o.error)}: {o.error or 'broken'}") for o in broken]
    for it in items:
        o, s = it.obj, it.shape
        reasons: list[str] = []
        faces = s.faces if s is not None else (o.face_count or 0)
        if faces < th.min_faces:
            reasons.append(f"only {faces} faces (< {th.min_faces})")
        if s is not None:
            if s.area_m2 <= th.min_area_ratio * max(s.extents_m[0], 1e-12) ** 2:
                reasons.append(f"(near) zero surface area ({s.area_m2:.3g} m^2 for a {s.extents_m[0] * 100:.1f} cm object)")
            # relative to the object's size, as the area test: an absolute floor in m^3 called every real
            # part under a millimetre cube degenerate (FreeCAD's SOD-523 diode, 1.8 mm long)
            if s.watertight and (s.volume_m3 or 0.0) <= th.min_volume_ratio * max(s.extents_m[0], 1e-12) ** 3:
                reasons.append(f"closed mesh with zero volume ({s.volume_m3:.3g} m^3 for a "
                               f"{s.extents_m[0] * 1000:.3g} mm object)")
            thin = s.ratios[1]  # thickness / length along the principal axes
            if thin <= 0 or 1.0 / thin > th.max_aspect_ratio:
                aspect = "infinitely" if thin <= 0 else f"{1.0 / thin:.0f}:1"
                reasons.append(f"flat beyond repair: {aspect} thin (> {th.max_aspect_ratio:g}:1)")
            worst = max(s.nonmanifold_fraction, s.boundary_fraction, s.self_intersection_fraction)
            if worst > th.mesh_quality_min_fraction:
                found.append(Found(o.id, None, MESH_QUALITY, mesh_quality_score(worst),
                                   f"{100 * s.nonmanifold_fraction:.2f}% non-manifold edges, {100 * s.boundary_fraction:.2f}% "
                                   f"open edges (holes), {100 * s.self_intersection_fraction:.2f}% self-intersecting faces; "
                                   "usable: it renders and physics uses its convex hull"))
        if it.look is not None and it.look.coverage < th.min_render_coverage:
            reasons.append(f"blank render ({100 * it.look.coverage:.2f}% object pixels)")
        if reasons:
            found.append(Found(o.id, None, DEGENERATE, 1.0, "; ".join(reasons)))
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
            found.append(Found(it.obj.id, None, SIZE_OUTLIER, round(score, 4), reason))
    return found

