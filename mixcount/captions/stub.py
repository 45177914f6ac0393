"""The offline captioner: deterministic text grounded in what the catalog measured.

Nothing here is canned per object: every word comes from a fact.

* noun: the catalog category, refined by the object's name tokens ("Ball_B07X_Volleyball" -> "volleyball");
* colours: names of the dominant colours counted over the canonical render's object pixels (or over
  colours sampled on the model's surface when no render exists), see :mod:`mixcount.captions.colours`;
* size class and measured dimensions from the real bounding box (metres, Z-up);
* shape cues from bounding-box ratios (elongated, flat, compact), the fill ratio volume / box volume of a
  watertight mesh (boxy, cylindrical, round, irregular) and the surface (closed or open, faceted);
* surface finish from the spread of luminance over the object's pixels (plain / patterned).

The same input always gives the same text (no randomness at all).
"""

from __future__ import annotations

import hashlib
import json

from mixcount.captions.base import CaptionInput, CaptionResult, name_tokens
from mixcount.captions.colours import NAMES

_COLOUR_WORDS = {w for n in NAMES for w in n.split()}
_CONTAINERS = {"plate", "tray", "bowl"}


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


def _noun(item: CaptionInput) -> tuple[list[str], str]:
    """(modifiers, head noun): the name token containing the category wins as head noun."""
    category = item.category.replace("_", " ").strip() or "object"
    cat_words = category.split()
    head = cat_words[-1]
    tokens = [t for t in name_tokens(item.name) if t not in cat_words]
    refined = [t for t in tokens if head in t and t != head]
    if refined:
        head = refined[-1]
        tokens = [t for t in tokens if t != head]
    modifiers = cat_words[:-1] + [t for t in tokens if t not in _COLOUR_WORDS and t not in cat_words]
    seen: list[str] = []
    for t in modifiers:
        if t not in seen and t != head:
            seen.append(t)
    return seen[-2:], head


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
        modifiers, head = _noun(item)
        size = size_class(max(item.dims))
        proportion, form = shape_cues(item)
        finish = _finish(item)
        colours = item.colours
        noun_phrase = " ".join(modifiers + [head])

        # short: 2-5 words = colour(s) + one cue + noun phrase, dropping the least specific words first.
        named = _distinct_colours(colours.names)
        two = named[:2]
        one = named[:1]
        cue = [finish] if finish == "patterned" else ([form] if form else ([proportion] if proportion else []))
        noun_words = noun_phrase.split()
        candidates = [
            _words(two, cue, noun_words),
            _words(two, noun_words),
            _words(two, noun_words[-1:]),
            _words(one, cue, noun_words),
            _words(one, noun_words[-2:]),
            _words(one, noun_words[-1:]),
            _words([size], noun_words[-1:]),
        ]
        short_words = next(c for c in candidates if 2 <= len(c) <= 5 or c is candidates[-1])
        short = " ".join(short_words)

        # concise: 5-10 words = size + colours + noun + "with a <cue> <cue> shape/finish".
        colour_text = _colour_phrase(colours.names, "concise")
        features = [w for w in (proportion, form) if w]
        tail = (
            f"with {_article(features[0])} {' '.join(features)} shape"
            if features
            else (f"with {_article(finish)} {finish} finish" if finish else "")
        )
        first_colour = one[0] if one else ""
        options = [
            (size, colour_text, noun_phrase, tail),
            (size, colour_text, noun_words[-1], tail),
            (size, _colour_phrase(colours.names, "pair"), noun_phrase, tail),
            (size, _colour_phrase(colours.names, "pair"), noun_words[-1], tail),
            (size, first_colour, noun_words[-1], tail),
            (size, first_colour, noun_words[-1]),
        ]
        candidates_c = [" ".join(p for p in opt if p).split() for opt in options]
        concise_words = next((c for c in candidates_c if 5 <= len(c) <= 10), None)
        if concise_words is None:
            concise_words = min(candidates_c, key=len)
        if len(concise_words) < 5:
            surface = "closed" if item.watertight else "open" if item.watertight is False else "solid"
            concise_words += f"with {_article(surface)} {surface} surface".split()
        concise = " ".join(concise_words[:10])
        concise = concise[:1].upper() + concise[1:]

        # detailed: two sentences with the measured facts.
        x, y, z = item.dims
        length, width = max(x, y), min(x, y)
        first = " ".join(
            p
            for p in (
                _article(size).capitalize(),
                size,
                finish if finish else "",
                colour_text,
                noun_phrase,
            )
            if p
        )
        if features:
            first += f" with {_article(features[0])} {' and '.join(features)} shape"
        if item.category in _CONTAINERS:
            first += ", used as a container"
        surface = (
            "a closed, watertight surface"
            if item.watertight
            else "an open, non-watertight surface" if item.watertight is False else "a scanned surface"
        )
        second = (
            f"It measures about {_length(length)} by {_length(width)} across and {_length(z)} tall, with {surface}."
        )
        detailed = f"{first}. {second}"
        raw = json.dumps(
            {
                "short": short,
                "concise": concise,
                "detailed": detailed,
                "facts": item.facts(),
                "colours": colours.as_dict(),
            },
            sort_keys=True,
        )
        return CaptionResult(short=short, concise=concise, detailed=detailed, raw=raw, attempts=1)


def response_hash(raw: str) -> str:
    return hashlib.sha256(raw.encode("utf-8")).hexdigest()
