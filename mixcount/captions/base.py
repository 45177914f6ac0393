"""The Captioner protocol and what it is given.

A captioner turns one :class:`CaptionInput` (the facts the catalog knows about an object, plus the path
of its canonical render when there is one) into a :class:`CaptionResult` with three tiers of text:
``short`` (2-5 words), ``concise`` (the phrase that picks it out) and ``detailed`` (1-2 sentences), and the raw answer it
was built from (hashed into the caption set, never stored whole).

``name`` is the captioner kind stored in ``caption_sets.captioner`` (``stub`` | ``http``); together with
``provider``, ``model`` and ``prompt_version`` it is the resume key of ``catalog caption``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from mixcount.captions.colours import EMPTY, ColourSummary, colours_from_model, colours_from_render
from mixcount.scene.spec import TIERS
from mixcount.scene.words import words_of

COLOUR_SOURCES = ("model", "render")

# Word bounds every captioner's answer is checked against (inclusive). The stub aims inside the
# issue's bounds (2-5, 5-10, 1-2 sentences); answers from an LLM get a little slack before they count as
# schema violations.
STUB_WORD_BOUNDS = {"short": (2, 5), "concise": (2, 12), "detailed": (2, 60)}
LLM_WORD_BOUNDS = {"short": (1, 8), "concise": (3, 16), "detailed": (5, 80)}

def words(text: str) -> list[str]:
    return text.split()


def name_tokens(name: str) -> list[str]:
    """Lower-case words of an object name by the one tokenizer (:func:`mixcount.scene.words.words_of`:
    separators and camelCase split, catalogue ids and numbers dropped), less single letters (what a
    version such as ``v2`` leaves)."""
    return [w for w in words_of(name) if len(w) > 1]


def display_name(obj: Any) -> str:
    """The object's own name from its metadata (DTC ``metadata.json`` "name") when ingest kept one, else
    the catalog name (folder or file stem). Metadata names describe the object ("Rubber ball"); folder
    names may carry ids and bookkeeping suffixes."""
    raw = getattr(obj, "metadata_json", None)
    if raw:
        try:
            meta = json.loads(raw)
        except (TypeError, ValueError):
            meta = None
        if isinstance(meta, dict):
            for node in (meta.get("metadata"), meta):
                if isinstance(node, dict) and isinstance(node.get("name"), str) and node["name"].strip():
                    return node["name"].strip()
    return obj.name or ""


def _name_hint(name: str, category: str) -> str:
    """The name as the captions should say it: its own words, colours and case; bookkeeping dropped."""
    from mixcount.captions.nouns import name_phrase

    return name_phrase(name, category).text()


@dataclass(frozen=True)
class CaptionInput:
    """Everything a captioner may use about one object (metres, Z-up)."""

    object_id: int
    name: str
    category: str
    dims: tuple[float, float, float]
    vertex_count: int | None = None
    face_count: int | None = None
    watertight: bool | None = None
    volume: float | None = None
    area: float | None = None
    textured: bool | None = None
    model_path: str | None = None
    render_path: Path | None = None
    colours: ColourSummary = field(default=EMPTY)
    parts: int | None = None  # unused since stub-v3 (a part count is a mesh fact, not what a person sees)
    # "darker" / "lighter": set only for a colour variant whose captions came out the same as its pair's
    # (same colour names): the measured mean luminance of the two tells them apart
    tone: str | None = None
    # the model file's content hash: seeds the surface-colour sampling, so the same asset gets the same
    # colour shares whatever row id an ingest gave it ("" = seed by object_id)
    content_hash: str = ""
    # how many telling words to add (0 = the plain prompt): set only when two different objects got equal
    # captions (:func:`mixcount.captions.captioning.separate_collisions`); 1 = every measured colour and the
    # pattern also beside the name's colours, 2 = also the proportion word ("long", "flat")
    tell: int = 0
    # (sRGB r, g, b, metallic, roughness): the [palette] look its parts without a colour render with
    look: tuple[float, ...] | None = None

    @classmethod
    def from_object(cls, obj: Any, *, render_path: Path | None = None, palette: Any = None) -> "CaptionInput":
        """Build from a ``CatalogObject`` (a plain snapshot: safe to hand to worker threads); ``palette``
        (``[palette]``) gives an untextured object the look its renders give it.

        Colours are not measured here (that reads files): see :meth:`with_measured_colours`.
        """
        look = None
        if palette is not None and not obj.textured:
            from mixcount.catalog.materials import object_look

            found = object_look(palette, name=obj.name or "", category=obj.category or "",
                                metadata_json=getattr(obj, "metadata_json", None),
                                content_hash=str(getattr(obj, "content_hash", "") or ""))
            look = None if found is None else found.as_tuple()
        item = cls(
            object_id=int(obj.id),
            content_hash=str(getattr(obj, "content_hash", "") or ""),
            name=display_name(obj),
            category=(obj.category or "object").strip().lower(),
            dims=(float(obj.dim_x or 0.0), float(obj.dim_y or 0.0), float(obj.dim_z or 0.0)),
            vertex_count=obj.vertex_count,
            face_count=obj.face_count,
            watertight=obj.watertight,
            volume=obj.volume,
            area=obj.area,
            textured=obj.textured,
            model_path=obj.model_path,
            render_path=Path(render_path) if render_path is not None and Path(render_path).is_file() else None,
            look=look,
        )
        return item

    def colour_seed(self) -> int:
        """The surface-colour sampling's seed: from the content hash (the same asset, the same shares in
        every catalog; ingest order sets row ids), else the object id."""
        try:
            return int(self.content_hash[:16], 16) if self.content_hash else self.object_id
        except ValueError:  # not hex: a stable integer of its bytes instead
            return int.from_bytes(self.content_hash.encode()[:8], "big")

    def with_measured_colours(self, source: str) -> "CaptionInput":
        """A copy with dominant colours measured from ``source`` first ("model": the surface albedo
        sampled from the model file; "render": the canonical render's pixels), the other one as fallback.

        The model's albedo (``captions.colour_source = "model"``) does not depend on the render's lighting, which in a
        white-world render washes saturated colours out to "light grey"/"beige" (see docs/captions.md).
        """
        if source not in COLOUR_SOURCES:
            raise ValueError(f"colour source must be one of {COLOUR_SOURCES}, got {source!r}")
        order = ("model", "render") if source == "model" else ("render", "model")
        colours = EMPTY
        for kind in order:
            if kind == "render" and self.render_path is not None and self.render_path.is_file():
                try:
                    colours = colours_from_render(self.render_path)
                except (OSError, ValueError):  # unreadable/corrupt PNG: use the other source
                    colours = EMPTY
            elif kind == "model" and self.model_path and Path(self.model_path).is_file():
                colours = colours_from_model(Path(self.model_path), seed=self.colour_seed(), look=self.look)
            if colours.names:
                break
        return replace(self, colours=colours)

    def facts(self, *, with_image: bool = True) -> dict[str, Any]:
        """JSON-able facts (no paths, no mesh facts, no sizes): what an LLM prompt is told besides the image.

        The name as the captions should say it (its colour words and proper nouns kept, ids, source tags
        and size words dropped) and the category (a shelf label). Without an image, also the colours
        measured the way the renderer shows the material (the only look there is to go by)."""
        out: dict[str, Any] = {"name": _name_hint(self.name, self.category), "category": self.category}
        if not with_image:
            out["colours_seen"] = list(self.colours.names)
        return out


@dataclass(frozen=True)
class CaptionResult:
    """Three tiers of text plus the raw answer they came from and the number of requests it took."""

    short: str
    concise: str
    detailed: str
    raw: str
    attempts: int = 1

    def tiers(self) -> dict[str, str]:
        return {"short": self.short, "concise": self.concise, "detailed": self.detailed}


@runtime_checkable
class Captioner(Protocol):
    name: str
    provider: str
    model: str
    prompt_version: str

    def caption(self, item: CaptionInput) -> CaptionResult:
        """Caption one object or raise :class:`mixcount.errors.CaptionError` (with ``attempts``)."""
        ...


def check_tiers(data: Any, bounds: dict[str, tuple[int, int]]) -> dict[str, str]:
    """Validate a parsed answer: exactly the three tiers, non-empty strings within word bounds.

    Returns the cleaned tiers (whitespace collapsed); raises ValueError saying what is wrong.
    """
    if not isinstance(data, dict):
        raise ValueError(f"answer is a {type(data).__name__}, expected an object with {list(TIERS)}")
    missing = [t for t in TIERS if t not in data]
    if missing:
        raise ValueError(f"answer lacks {missing}")
    extra = sorted(set(data) - set(TIERS))
    if extra:
        raise ValueError(f"answer has unexpected keys {extra}")
    out: dict[str, str] = {}
    for tier in TIERS:
        value = data[tier]
        if not isinstance(value, str):
            raise ValueError(f"{tier!r} is a {type(value).__name__}, expected a string")
        text = " ".join(value.split())
        lo, hi = bounds[tier]
        n = len(words(text))
        if not lo <= n <= hi:
            raise ValueError(f"{tier!r} has {n} words, expected {lo}-{hi}")
        out[tier] = text
    return out
