"""The offline captioner: deterministic text grounded in what the catalog measured.

Nothing here is canned per object: every word comes from a fact.

* noun phrase: from the person-written name ("Red coffee mug" -> "coffee mug"), bookkeeping, ids, colour
  and size words dropped; the category only when the name has none, e.g. a DTC folder name
  ("Ball_B07X_Volleyball" -> "volleyball"), see :mod:`mixcount.captions.nouns`. Never name + category;
* colours: names of the dominant colours counted over the canonical render's object pixels (or over
  colours sampled on the model's surface when no render exists), see :mod:`mixcount.captions.colours`;
* measured dimensions from the real bounding box (metres, Z-up), in the detailed tier only: scenes rescale
  objects, so absolute size words are noise (a resized pair gets "larger"/"smaller" at scene time);
* shape cues from bounding-box ratios (elongated, flat, compact), the fill ratio volume / box volume of a
  watertight mesh (boxy, cylindrical, round, irregular) and the surface (closed or open, faceted);
* surface finish from the spread of luminance over the object's pixels (plain / patterned);
* separate parts of the model (connected components, 2-12 are said) in the detailed tier.

The same input always gives the same text (no randomness at all).
"""

from __future__ import annotations

import hashlib
import json

from mixcount.captions.base import CaptionInput, CaptionResult
from mixcount.captions.nouns import noun_phrase
from mixcount.catalog.naming import singular

_CONTAINERS = {"plate", "tray", "bowl"}
MAX_PARTS_SAID = 12  # more separate parts than this is a scan's debris or a CAD assembly: not worth a word


def size_class(max_dim_m: float) -> str:
    """Size word from the largest real dimension."""
    if max_dim_m <= 0:
        return "small"
    if max_dim_m < 0.03:
        return "tiny"
    if max_dim_m < 0.08:
        return "small"
    if max_dim_m < 0.2:
        return "hand-sized"
    if max_dim_m < 0.5:
        return "large"
    return "very large"


def _length(value_m: float) -> str:
    """A measured length in words: "2 mm", "3.5 cm", "24 cm" (half-cm steps below 10 cm)."""
    cm = value_m * 100.0
    if cm < 1.0:
        return f"{max(1, round(cm * 10))} mm"
    if cm < 10:
        return f"{round(cm * 2) / 2:.1f}".rstrip("0").rstrip(".") + " cm"
    return f"{round(cm):d} cm"


def shape_cues(item: CaptionInput) -> tuple[str | None, str | None]:
    """(proportion cue, form cue) from the bounding box and, for closed meshes, the fill ratio."""
    x, y, z = item.dims
    a, b, c = sorted((abs(x), abs(y), abs(z)), reverse=True)
    if a <= 0:
        return None, None
    proportion: str | None = None
    if b > 0 and a / b >= 2.2:
        proportion = "slender" if c > 0 and b / c < 1.6 else "long"
    elif b > 0 and c / b <= 0.3:
        proportion = "flat"
    elif c > 0 and a / c < 1.3:
        proportion = "compact"
    form: str | None = None
    if item.watertight and item.volume and a * b * c > 0:
        fill = item.volume / (a * b * c)
        if fill >= 0.9:
            form = "boxy"
        elif fill >= 0.7:
            near = lambda p, q: q > 0 and abs(p - q) / max(p, q) < 0.12  # noqa: E731
            form = "cylindrical" if near(a, b) or near(b, c) else "rounded"
        elif fill >= 0.42:
            form = "round"
        else:
            form = "irregular"
    if form is None and item.face_count is not None and 0 < item.face_count < 300:
        form = "faceted"
    return proportion, form


def _distinct_colours(names: tuple[str, ...]) -> list[str]:
    """Colour names without near-repeats ("light grey" after "grey" reads as one colour)."""
    kept: list[str] = []
    for n in names:
        if not any(set(n.split()) & set(k.split()) for k in kept):
            kept.append(n)
    return kept


def _words(*groups: list[str]) -> list[str]:
    return [w for g in groups for item in g for w in item.split()]


def _colour_phrase(names: tuple[str, ...], style: str) -> str:
    if not names:
        return ""
    names = tuple(_distinct_colours(names))
    if style == "pair":
        return " and ".join(names[:2])
    if len(names) == 1:
        return names[0]
    if len(names) == 2:
        return f"{names[0]} and {names[1]}"
    return f"{names[0]}, {names[1]} and {names[2]}"


def _finish(item: CaptionInput) -> str | None:
    colours = item.colours
    if not colours.names:
        return None
    if len(colours.names) >= 3 or colours.variation >= 0.22:
        return "patterned"
    if len(colours.names) == 1 and colours.variation < 0.08:
        return "plain"
    return None


def _article(word: str) -> str:
    return "an" if word[:1].lower() in "aeiou" else "a"


class StubCaptioner:
    """Deterministic offline captioner (the default). See the module docstring for the rules."""

    name = "stub"
    provider = "offline"
    model = "stub"

    def __init__(self, prompt_version: str) -> None:
        """``prompt_version``: ``captions.stub_prompt_version`` (bump it to re-caption everything)."""
        self.prompt_version = prompt_version

    def caption(self, item: CaptionInput) -> CaptionResult:
        phrase = noun_phrase(item.name, item.category)
        noun_words = list(phrase.words)
        proportion, form = shape_cues(item)
        finish = _finish(item)
        colours = item.colours
        named = _distinct_colours(colours.names)

        # short: 2-5 words = up to two colours + "patterned" + the noun phrase; no size word (scenes rescale
        # objects). Words are dropped least specific first: the pattern word, the second colour, then the
        # compound's first words; the head noun always stays.
        pattern = ["patterned"] if finish == "patterned" else []
        tone = [item.tone] if item.tone else []  # a colour variant's measured shade against its pair
        candidates = [
            _words(tone, named[:2], pattern, noun_words),
            _words(tone, named[:2], noun_words),
            _words(tone, named[:1], pattern, noun_words),
            _words(tone, named[:1], noun_words),
            _words(tone, named[:1], noun_words[-2:]),
            _words(tone, named[:1], noun_words[-1:]),
        ]
        short_words = next((c for c in candidates if 2 <= len(c) <= 5), None)
        if short_words is None:  # no colour measured and a one-word noun: a measured shape cue in front
            cue = [w for w in (form, proportion, "plain") if w][:1]
            short_words = _words(cue, noun_words[-1:])
        short = " ".join(short_words)

        # concise: 5-10 words = colours + noun phrase + "with a <cues> shape" (or finish / surface).
        features = [w for w in (proportion, form) if w]
        tails = []
        if features:
            tails.append(f"with {_article(features[0])} {' '.join(features)} shape")
        if finish:
            tails.append(f"with {_article(finish)} {finish} finish")
        surface = "closed" if item.watertight else "open" if item.watertight is False else None
        if surface:
            tails.append(f"with {_article(surface)} {surface} surface")
        options = []
        for colour_text in (_colour_phrase(colours.names, "concise"), _colour_phrase(colours.names, "pair"),
                            " ".join(named[:1])):
            colour_text = " ".join(tone + [colour_text]).strip()
            for nw in (noun_words, noun_words[-2:], noun_words[-1:]):
                for tail in tails + [""]:
                    options.append([w for w in f"{colour_text} {' '.join(nw)} {tail}".split() if w])
        concise_words = next((c for c in options if 5 <= len(c) <= 10), None)
        if concise_words is None:
            concise_words = max((c for c in options if len(c) <= 10), key=len, default=noun_words[-1:])
            if len(concise_words) < 5:
                concise_words = concise_words + "with no measured colour".split()
        concise = " ".join(concise_words[:10])
        concise = concise[:1].upper() + concise[1:]

        # detailed: the measured facts (finish, colours with their shares, proportions, size, surface).
        x, y, z = item.dims
        length, width = max(x, y), min(x, y)
        colour_text = _colour_phrase(colours.names, "concise")
        lead = " ".join(p for p in (" ".join(tone), finish or "", colour_text, " ".join(noun_words)) if p)
        plural = singular(phrase.head) != phrase.head  # "sneakers", "headphones": no article
        first = lead[:1].upper() + lead[1:] if plural else f"{_article(lead).capitalize()} {lead}"
        if features:
            first += f" with {_article(features[0])} {' and '.join(features)} shape"
        if phrase.head in _CONTAINERS or item.category in _CONTAINERS:
            first += ", used as a container"
        if item.parts is not None and 2 <= item.parts <= MAX_PARTS_SAID:
            first += f" in {item.parts} separate parts"
        if len(colours.names) >= 2 and colours.shares:
            first += f", {round(colours.shares[0] * 100):d} % {colours.names[0]}"
        surface_text = (
            "a closed, watertight surface"
            if item.watertight
            else "an open, non-watertight surface" if item.watertight is False else "a scanned surface"
        )
        second = (
            f"It measures about {_length(length)} by {_length(width)} across and {_length(z)} tall, "
            f"with {surface_text}."
        )
        detailed = f"{first}. {second}"
        raw = json.dumps(
            {
                "short": short,
                "concise": concise,
                "detailed": detailed,
                "facts": item.facts(),
                "noun_phrase": {"words": list(phrase.words), "source": phrase.source,
                                "dropped": list(phrase.dropped)},
                "colours": colours.as_dict(),
            },
            sort_keys=True,
        )
        return CaptionResult(short=short, concise=concise, detailed=detailed, raw=raw, attempts=1)


def response_hash(raw: str) -> str:
    return hashlib.sha256(raw.encode("utf-8")).hexdigest()
