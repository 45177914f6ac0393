"""The caption check: what a person reading a caption would object to, said per object.

Every active caption set is checked after ``catalog caption`` (stub and http alike) and again whenever
``catalog list --json`` prints an object (key ``caption_warnings``). A warning is a dict
``{"kind", "tier", "detail"}``; the kinds:

* ``missing_noun``: the short or concise tier lacks the head noun of the object's name (from a person-written
  name; the category for a DTC folder name; see :func:`mixcount.captions.nouns.name_noun`); singular and
  plural count as the same word;
* ``category_appended``: a broad category word that is not in the name follows the noun ("red fire hydrant
  furniture");
* ``repeated_word``: one content word twice in the short or concise tier ("red round red bottle");
* ``id_fragment``: a token with a digit (an id, a version, a catalogue number such as ``B07Z5P84J2``) or a
  source tag (``PartNet``, ``high-res``, ``convex hull``, ``recolour``...); in the detailed tier a number
  followed by a unit ("24 cm", "70 %") is a measurement, not an id;
* ``size_word``: an absolute size word in the short or concise tier, or before the first "with" / comma of
  the detailed tier ("large", "hand-sized", "mini"): scenes rescale every object, so it describes nothing in
  the image (a resized pair gets "larger"/"smaller" at scene time; "a small handle" describes a part);
* ``mesh_fact``: something read off the mesh, not seen in the image: its surface ("open, non-watertight
  surface", "closed surface"), a part count ("in 10 separate parts"), colour percentages ("69 % black"),
  vertices / faces / polygons, or a shape word from the fill ratio ("with an irregular shape");
* ``absolute_size``: a size in units ("24 cm", "about 5 inches", "It measures ..."), in any tier: scenes
  rescale every class, so the caption would contradict its image (sizes stay in the catalog's fields);
* ``name_colour_lost``: the short or concise tier lacks a colour word of the object's name ("Orange juice
  carton" captioned "brown carton"): the name knows the colour better than a texture's mean; a word of the
  same colour family counts ("grey" for "gray");
* ``word_bounds``: a tier outside the word bounds of its captioner (``STUB_WORD_BOUNDS`` for the stub,
  ``LLM_WORD_BOUNDS`` for answers of an LLM);
* ``same_as_variant``: a tier identical (``normalise_caption``) to that of a colour variant of the object
  (a ``colour_variant`` flag): the prompt could not tell the two apart.
"""

from __future__ import annotations

import re
from typing import Any, Iterable, Mapping

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.captions.base import LLM_WORD_BOUNDS, STUB_WORD_BOUNDS, TIERS, display_name
from mixcount.captions.colours import colour_words_in, family
from mixcount.captions.nouns import LEAK_RE, category_noun, is_folder_name, name_noun, name_phrase
from mixcount.catalog.models import STATUS_ACTIVE, CaptionSet, CatalogObject, Flag
from mixcount.catalog.naming import singular
from mixcount.scene.caption_text import normalise_caption

VARIANT_KIND = "colour_variant"
WARNING_KINDS = ("missing_noun", "category_appended", "repeated_word", "id_fragment", "size_word", "mesh_fact",
                 "absolute_size", "name_colour_lost", "word_bounds", "same_as_variant")
# What no caption may carry, from any captioner: an LLM's answer gets one repair request naming them, then
# fails; a stub caption that carries one fails at once (both recorded in caption_failures with the reason).
ANSWER_BLOCKING = frozenset({"category_appended", "repeated_word", "id_fragment", "size_word", "mesh_fact",
                             "absolute_size", "name_colour_lost"})
_MESH_FACT = re.compile(
    r"(?:\b(?:non-?)?watertight\b|\b(?:open|closed|scanned|manifold)(?:,\s*[\w-]+)?\s+surface\b|"
    r"\b\d+\s+(?:separate\s+)?(?:parts|pieces|components)\b|\bseparate\s+parts\b|\d\s*%|\bper\s*cent\b|\bpercent\b|"
    r"\b\d[\d,]*\s+(?:faces|vertices|triangles|polygons)\b|\bvertices\b|\b(?:vertex|polygon|face)\s+count\b|"
    r"\b(?:triangle|polygon)\s+mesh\b|\bnon-manifold\b|\btessellat\w+\b|"
    r"\bwith\s+an?\s+(?:irregular|compact|boxy|rounded|faceted)\s+shape\b|\bfill\s+ratio\b)", re.IGNORECASE)
_ABS_SIZE = re.compile(
    r"(?:\b\d+(?:[.,]\d+)?\s*(?:mm|cm|m|km|in|inch|inches|ft|feet|foot|yd|meters?|metres?|centimet(?:er|re)s?|"
    r"millimet(?:er|re)s?)\b|\b\d+(?:[.,]\d+)?\s*(?:\"|'')|\bmeasures?\b|\bmeasuring\b)", re.IGNORECASE)
_SIZE_WORD = re.compile(
    r"(?<![\w-])(?:tiny|small|large|big|huge|giant|mini|miniature|medium|oversized|jumbo|massive|enormous|little|"
    r"[a-z]+-siz(?:e|ed))(?![\w-])", re.IGNORECASE)
_STOP = frozenset({"a", "an", "the", "and", "with", "of", "in", "on", "to", "its", "it", "is", "by", "at", "for",
                   "as", "from", "about", "across", "tall", "has", "shape", "surface", "finish"})
# words after a number that make it a measurement or a count in the detailed tier ("24 cm", "2 separate parts")
_UNITS = frozenset({"cm", "mm", "m", "%", "kg", "g", "in", "inch", "inches", "degrees", "percent", "x", "separate",
                    "parts", "part"})
_TOKEN = re.compile(r"\d+(?:\.\d+)?%?|[A-Za-z0-9%]+(?:[-'][A-Za-z0-9]+)*")


def _tokens(text: str) -> list[str]:
    return _TOKEN.findall(text)


def _has_colour(text: str, colour: str) -> bool:
    """Whether ``text`` says ``colour`` (a name's colour word) or a word of its colour family."""
    fam = family(colour)
    said = colour_words_in(text)
    return colour in said or (fam is not None and any(family(c) == fam for c in said))


def blocking(tiers: Mapping[str, str], *, name: str, category: str, captioner: str) -> list[dict[str, str]]:
    """The warnings of :func:`check_tiers_text` that no caption may carry (:data:`ANSWER_BLOCKING`)."""
    return [w for w in check_tiers_text(tiers, name=name, category=category, captioner=captioner)
            if w["kind"] in ANSWER_BLOCKING]


def reasons(found: Iterable[Mapping[str, str]]) -> str:
    """One line naming each blocking warning: ``short mesh_fact (mesh fact 'watertight'); ...``."""
    return "; ".join(f"{w['tier']} {w['kind']} ({w['detail']})" for w in found)


def _same(word: str, other: str) -> bool:
    return singular(word.lower()) == singular(other.lower())


def check_tiers_text(
    tiers: Mapping[str, str],
    *,
    name: str,
    category: str,
    captioner: str,
    variant_tiers: Iterable[Mapping[str, str]] = (),
) -> list[dict[str, str]]:
    """Warnings for one object's three tiers (see the module docstring). Deterministic, no I/O."""
    out: list[dict[str, str]] = []
    bounds = STUB_WORD_BOUNDS if captioner == "stub" else LLM_WORD_BOUNDS
    noun = name_noun(name, category)
    name_words = {w.lower() for w in _tokens(name)}
    broad = [w for w in category_noun(category) if w not in name_words and not (noun and _same(w, noun))]
    if is_folder_name(name):
        broad = []  # the category IS the noun of a folder name
    name_colours = name_phrase(name, category).colours
    for tier in TIERS:
        text = tiers.get(tier) or ""
        words = _tokens(text)
        n = len(text.split())
        lo, hi = bounds[tier]
        if not lo <= n <= hi:
            out.append({"kind": "word_bounds", "tier": tier, "detail": f"{n} words, expected {lo}-{hi}"})
        lower = [w.lower() for w in words]
        detailed = tier == "detailed"
        if not detailed:
            if noun and not any(_same(w, noun) for w in lower):
                out.append({"kind": "missing_noun", "tier": tier, "detail": f"no {noun!r} (the name's noun)"})
            if noun:
                at = max((i for i, w in enumerate(lower) if _same(w, noun)), default=-1)
                tacked = [w for w in lower[at + 1:] if any(_same(w, b) for b in broad)] if at >= 0 else []
                if not tacked and at < 0:
                    tacked = [w for w in lower if any(_same(w, b) for b in broad)]
                if tacked:
                    out.append({"kind": "category_appended", "tier": tier,
                                "detail": f"category word {tacked[0]!r} beside the noun"})
        # a size word anywhere in the short tiers; in the detailed one only in its lead (before "with" or a stop)
        sizes = _SIZE_WORD.findall(re.split(r"\bwith\b|[,.;:]", text, maxsplit=1)[0] if detailed else text)
        if sizes:
            out.append({"kind": "size_word", "tier": tier, "detail": f"absolute size {sizes[0].lower()!r}"})
        if not detailed:
            content = [singular(w) for w in lower if w not in _STOP and not w.isdigit()]
            repeats = sorted({w for w in content if content.count(w) > 1})
            if repeats:
                out.append({"kind": "repeated_word", "tier": tier, "detail": f"repeats {', '.join(repeats)}"})
            missing = [c for c in name_colours if not _has_colour(text, c)]
            if missing:
                out.append({"kind": "name_colour_lost", "tier": tier,
                            "detail": f"the name's colour {missing[0]!r} is not said"})
        facts = _MESH_FACT.findall(text)
        if facts:
            out.append({"kind": "mesh_fact", "tier": tier, "detail": f"mesh fact {' '.join(facts[0].split())!r}"})
        measures = _ABS_SIZE.findall(text)
        if measures:
            out.append({"kind": "absolute_size", "tier": tier,
                        "detail": f"size in units {' '.join(measures[0].split())!r}"})
        ids = []
        for i, w in enumerate(words):
            if any(c.isdigit() for c in w):
                nxt = lower[i + 1] if i + 1 < len(lower) else ""
                if tier == "detailed" and re.fullmatch(r"\d+(?:\.\d+)?", w) and nxt in _UNITS:
                    continue
                if tier == "detailed" and re.fullmatch(r"\d+(?:\.\d+)?(?:cm|mm|m|%)", w.lower()):
                    continue
                ids.append(w)
        ids += LEAK_RE.findall(re.sub(r"(?<=[a-z])(?=[A-Z])", " ", text).lower())
        if ids:
            out.append({"kind": "id_fragment", "tier": tier, "detail": f"bookkeeping {sorted(set(ids))}"})
        for other in variant_tiers:
            if normalise_caption(text) and normalise_caption(text) == normalise_caption(other.get(tier) or ""):
                out.append({"kind": "same_as_variant", "tier": tier,
                            "detail": f"same as colour variant {other.get('name', '')}".strip()})
    return out


def _tier_dict(cs: CaptionSet) -> dict[str, str]:
    return {"short": cs.short, "concise": cs.concise, "detailed": cs.detailed}


def object_warnings(session: Session, obj: CatalogObject,
                    captions: Mapping[int, CaptionSet] | None = None) -> list[dict[str, str]] | None:
    """Warnings for one object's active caption set (None when it has none)."""
    if captions is not None:
        cs = captions.get(obj.id)
    else:
        cs = session.scalars(select(CaptionSet).where(CaptionSet.object_id == obj.id, CaptionSet.active.is_(True))
                             .order_by(CaptionSet.id.desc())).first()
    if cs is None:
        return None
    partners = session.scalars(select(Flag.pair_object_id).where(
        Flag.object_id == obj.id, Flag.kind == VARIANT_KIND, Flag.pair_object_id.is_not(None))).all()
    variant_tiers = []
    for pid in sorted({p for p in partners if p is not None}):
        other = captions.get(pid) if captions is not None else session.scalars(
            select(CaptionSet).where(CaptionSet.object_id == pid, CaptionSet.active.is_(True))
            .order_by(CaptionSet.id.desc())).first()
        if other is not None:
            variant_tiers.append({**_tier_dict(other), "name": f"{pid}"})
    return check_tiers_text(_tier_dict(cs), name=display_name(obj), category=obj.category or "",
                            captioner=cs.captioner, variant_tiers=variant_tiers)


def check_catalog(session: Session) -> dict[int, list[dict[str, str]]]:
    """object id -> warnings, for every active object with an active caption set (empty lists kept)."""
    rows = session.scalars(
        select(CaptionSet).join(CatalogObject, CatalogObject.id == CaptionSet.object_id)
        .where(CaptionSet.active.is_(True), CatalogObject.status == STATUS_ACTIVE)
        .order_by(CaptionSet.object_id, CaptionSet.id)
    ).all()
    captions = {cs.object_id: cs for cs in rows}
    out: dict[int, list[dict[str, str]]] = {}
    for oid in sorted(captions):
        obj = session.get(CatalogObject, oid)
        if obj is not None:
            out[oid] = object_warnings(session, obj, captions) or []
    return out


def summarise_warnings(warnings: Mapping[int, list[dict[str, str]]]) -> dict[str, Any]:
    """Counts per kind (objects with at least one warning of that kind) and the warned objects."""
    by_kind = {k: sum(1 for ws in warnings.values() if any(w["kind"] == k for w in ws)) for k in WARNING_KINDS}
    return {"objects_checked": len(warnings), "objects_warned": sum(1 for ws in warnings.values() if ws),
            "by_kind": by_kind}
