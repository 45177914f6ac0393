"""Copies found by their shape, and the look-alikes ranked apart (`catalog filter`, docs/curation.md).

The appearance rules (:mod:`mixcount.curation.finding.look_rules`) find copies whose colours agree; a copy from
another source may carry another print, another plain colour, another resolution, units, pose and a
squash along one axis. Here the shape decides, by the alignment of
:mod:`mixcount.curation.finding.shape_match` (every principal-axis order and sign, ties turned, a bounded
stretch along any axis), on candidate pairs only (:mod:`mixcount.curation.finding.candidates`) whose cheap
shape numbers already agree loosely (``copy_gate_d2``, ``cross_source_proportions``).

* **Shape evidence** needs more than agreement: two boxes, two cans, two balls agree as closely as a
  copy does. Each object's distance to its nearest primitive (box, ellipsoid, cylinder) says how much
  shape it has beyond a plain solid. A pair has *shape evidence* when the aligned distance ``d`` is at
  most ``copy_shape``, both objects are at least ``copy_min_detail`` from any primitive, and ``d`` is at
  most ``copy_evidence`` times the nearer one's primitive distance.
* ``possible_copy`` (*decide*): shape evidence with colours no further apart than ``copy_colour`` (another
  print, a re-bake, other light: the public ducks differ by 0.073), or shape evidence for an appearance
  rule's possible copy (which brings its own: a repeated pattern, the axis-normalised shape of an
  asymmetric object in another plain colour); the same shape in clearly other colours found by the shape
  alone (a navy and a mint mug of one mould) is ranked a look-alike, for a person; or a loose agreement (``d`` at most
  ``copy_loose``, the objects not primitives) with the same surface colours, where both objects have colours
  (:func:`coloured`: the grey that untextured parts are read in agrees for any two). A possible copy from an
  appearance rule without either is not one: it becomes a look-alike.
* ``look_alike`` (*info*): different objects, as far as the evidence goes, whose shapes agree within
  ``copy_loose``: the paper's "too similar to tell apart", the hard pairs a counter must learn; ranked
  by their score on the review page, for a person who decides whether they stay two classes.

Nothing here excludes an object: the duplicates that exclude come from the appearance rules' tight gates
or a person's "same object"."""

from __future__ import annotations

from itertools import combinations
from typing import Iterable

from mixcount.config import FilterConfig
from mixcount.curation.finding import descriptors as D
from mixcount.curation.finding import pair_evidence as E
from mixcount.curation.finding.filter_items import Found, Item, LayoutCache, in_order
from mixcount.curation.finding.look_rules import look_pair, relit_colour_transport
from mixcount.curation.flag_kinds import LOOK_ALIKE, POSSIBLE_COPY
from mixcount.sizes import SizeEvidence


def shape_gate(x: Item, y: Item, th: FilterConfig) -> bool:
    """The cheap gates of :func:`shape_facts` (D2 and principal proportions, both descriptors there): False
    where they already tell the shapes apart and no alignment is made."""
    if x.surface is None or y.surface is None or x.shape is None or y.shape is None:
        return False
    return not (D.d2_distance(x.shape, y.shape) > th.copy_gate_d2
                or D.moment_distance(x.shape, y.shape) > th.cross_source_proportions)


def shape_facts(x: Item, y: Item, th: FilterConfig, layouts: LayoutCache) -> tuple[float, float, float] | None:
    """(aligned shape distance, nearer primitive distance, surface colour distance), or None when the
    cheap gates already tell the shapes apart (or a descriptor is missing)."""
    if not shape_gate(x, y, th):
        return None
    d = E.aligned_distance(x, y, th, layouts)
    prim = min(E.primitive(x, th, layouts), E.primitive(y, th, layouts))
    col = relit_colour_transport(x.surface, y.surface, th)[0]
    return d, prim, col


def coloured(x: Item, y: Item) -> bool:
    """Both objects carry colour information (a texture, vertex colours or a material colour): only then is
    their colour agreement evidence. Untextured parts (an STL, an OBJ without its .mtl) are all read in
    one neutral grey, so two of them agree in colour whatever they are (a drawer and a mug of metaworld's
    untextured parts, aligned 0.064 against 0.067 from a primitive)."""
    return x.appearance != "none" and y.appearance != "none"


def shape_pair(x: Item, y: Item, th: FilterConfig, facts: tuple[float, float, float] | None,
               found: list[Found], *, nearest: bool) -> list[Found]:
    """The flags of one pair: the appearance rules' ``found``, checked for shape evidence where they say
    ``possible_copy``, or the shape rule's ``possible_copy`` / ``look_alike`` where they found nothing.
    ``nearest``: one of the two is the other's nearest shape among its candidates."""
    if found and all(f.kind != POSSIBLE_COPY for f in found):
        return found
    if facts is None:
        return [f for f in found if f.kind != POSSIBLE_COPY]  # no shape agreement at all: not a copy
    d, prim, col = facts
    detailed = prim >= th.copy_min_detail
    shape_evidence = d <= th.copy_shape and detailed and d <= th.copy_evidence * prim
    # an appearance rule's possible copy (a repeated pattern, the axis-normalised shape of an asymmetric
    # object in another plain colour) brings evidence of its own: the shape's is enough; a pair found by
    # the shape alone needs colours within copy_colour too
    evidence = shape_evidence and (bool(found) or col <= th.copy_colour)
    same_colour = col <= th.look_colour
    loose = d <= th.copy_loose
    figures = (f"aligned shape distance {d:.3f} (any axis order, sign and a stretch up to x{th.copy_max_squash:g}), "
               f"nearest primitive {prim:.3f}, surface colours {col:.3f}")
    a, b = x.obj.id, y.obj.id
    score = round(max(0.0, 1.0 - d / th.copy_loose), 4)
    if evidence or (loose and detailed and same_colour and coloured(x, y) and nearest and d <= prim):
        if found:  # an appearance rule's possible copy, now with shape evidence
            return [Found(f.a, f.b, f.kind, f.score, f"{f.reason}; {figures}") for f in found]
        why = ("the shape carries evidence" if evidence else
               "the nearest shape of one of them, a loose agreement of detailed shapes in the same colours")
        return [Found(a, b, POSSIBLE_COPY, score, f"possible copy for review ({why}): {figures}")]
    if loose:
        why = ("a plain solid's shape" if not detailed else
               "the same shape in clearly other colours: variants, or a hard pair" if shape_evidence and col > th.copy_colour
               else "other colours" if not same_colour
               else "loose agreement" if coloured(x, y) else "loose agreement; an untextured surface: colours are no evidence")
        return [Found(a, b, LOOK_ALIKE, score, f"look-alike, not a copy as far as the evidence goes ({why}): {figures}")]
    return []


def pair_flags(items: list[Item], th: FilterConfig, layouts: LayoutCache | None = None,
               pairs: Iterable[tuple[Item, Item]] | None = None) -> list[Found]:
    """Every pair flag of ``pairs`` (default: all pairs of ``items``): appearance rules, weighed by
    :func:`mixcount.curation.finding.pair_evidence.weigh` (size, plain surfaces, aligned geometry), then shape. Two passes: the shape facts of every pair first (each object's nearest shape), then the rules.
    Each pair is taken in :func:`~mixcount.curation.finding.filter_items.in_order`: the catalog's order never
    changes a flag."""
    layouts = layouts or LayoutCache(None)
    looked: list[tuple[Item, Item, list[Found], tuple[float, float, float] | None]] = []
    nearest: dict[int, float] = {}
    against: dict[tuple[int, int], SizeEvidence] = {}
    for x, y in (in_order(*p) for p in (pairs if pairs is not None else combinations(items, 2))):
        found, size = E.weigh(x, y, look_pair(x, y, th, layouts), th, layouts)
        if size is not None:
            against[x.obj.id, y.obj.id] = size
        facts = None
        if not found or any(f.kind == POSSIBLE_COPY for f in found):
            facts = shape_facts(x, y, th, layouts)
        if facts is not None:
            for it in (x, y):
                nearest[it.obj.id] = min(nearest.get(it.obj.id, facts[0]), facts[0])
        looked.append((x, y, found, facts))
    out: list[Found] = []
    for x, y, found, facts in looked:
        nearest_one = facts is not None and facts[0] <= max(nearest[x.obj.id], nearest[y.obj.id])
        flags = shape_pair(x, y, th, facts, found, nearest=nearest_one)
        out.extend(E.cap_to_look_alike(flags, against.get((x.obj.id, y.obj.id))))
    return out
