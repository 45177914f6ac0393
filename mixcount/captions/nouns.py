"""The noun phrase of a caption: what a person calls the object, from its name or its category.

Real libraries carry a person-written name ("Red coffee mug", "Bottle (PartNet-Mobility 3763)", "Teddy bear
convex-hull approximation") and a broad category ("kitchenware", "toy"). The name says what the object is;
the category is a shelf label. So:

* a person-written name gives the noun phrase: its last word is the head noun (English puts it last) and
  up to two words before it form the compound ("coffee mug", "fire hydrant", "table tennis paddle");
  bookkeeping is dropped first: parenthesised source tags, ids and digits, source-tag phrases
  (:data:`SOURCE_TAGS`), colour words (colours are measured from the surface, never read from a name,
  which is how a "(blue recolour)" tag gets its colour from the albedo) and size words (scenes rescale);
* a DTC-style folder name (``Markers_B07Z5P84J2_Peach``: no person wrote it) gives the category as head
  noun, refined by a variant word that contains it ("Ball_..._Volleyball" -> "volleyball"); other variant
  words that are neither colours nor ids are modifiers ("Toy_..._TruckRed" -> "truck toy");
* a name left with no word (``Random object 17 (procedural)``) falls back to the category, and a category
  that is no noun either ("misc") to "object".

The broad category is never appended after a noun from the name.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from mixcount.captions.colours import NAMES
from mixcount.catalog.naming import DTC_NAME, GENERIC_STEMS, singular

# Colour words a name may carry; captions take colours from measurement only. Beyond the 24 measured names:
# words shops and DTC variants use for colours.
COLOUR_WORDS = frozenset(
    {w for n in NAMES for w in n.split()}
    | {"gray", "golden", "silver", "cyan", "violet", "cream", "ivory", "peach", "coral", "crimson", "scarlet",
       "turquoise", "lavender", "mint", "charcoal", "khaki", "burgundy", "aqua", "indigo", "rose", "salmon",
       "amber", "bronze", "copper", "multicolor", "multicolour", "multicolored", "multicoloured", "colorful",
       "colourful", "clear", "transparent", "dark", "light", "pale", "bright", "natural"}
)
SIZE_WORDS = frozenset({"tiny", "small", "mini", "miniature", "medium", "large", "big", "huge", "giant", "xl",
                        "xxl", "xs", "oversized", "little", "sized"})
# Source tags and bookkeeping phrases of asset libraries (lower case, matched as whole words; a hyphen or a
# blank between words both match). Longest first so "convex hull approximation" goes before "hull".
SOURCE_TAGS = (
    "partnet mobility", "convex hull approximation", "convex hull", "hull approximation", "approximation",
    "high res", "hi res", "low res", "lo res", "high resolution", "low resolution", "high poly", "low poly",
    "highpoly", "lowpoly", "random object", "procedural", "primitive", "recolour", "recolor", "recoloured",
    "recolored", "copy", "duplicate", "variant", "version", "decimated", "simplified", "remeshed", "remesh",
    "scanned", "scan", "photogrammetry", "textured", "untextured", "watertight", "model", "mesh", "asset",
    "object", "shapenet", "objaverse", "sketchfab", "google scanned objects", "gso", "abo", "ycb", "lod",
    "final", "export", "untitled", "default", "new", "test", "sample",
)
GENERIC_CATEGORIES = frozenset({"misc", "miscellaneous", "other", "others", "unknown", "uncategorized",
                                "uncategorised", "general", "none", "object", "objects", "item", "items", ""})
# The subset the caption check reports when it finds them in a caption (words that never describe an object).
LEAK_TAGS = (
    "partnet mobility", "partnet", "mobility", "convex hull", "hull approximation", "approximation", "high res", "hi res",
    "low res", "lo res", "high poly", "low poly", "highpoly", "lowpoly", "random object", "procedural",
    "primitive", "recolour", "recolor", "recoloured", "recolored", "copy", "duplicate", "decimated", "remeshed",
    "shapenet", "objaverse", "sketchfab",
)
LEAK_RE = re.compile(r"\b(?:" + "|".join(t.replace(" ", r"[\s_-]+") for t in LEAK_TAGS) + r")\b")
_TAG_RE = re.compile(r"\b(?:" + "|".join(t.replace(" ", r"[\s_-]+") for t in SOURCE_TAGS) + r")\b")
_PAREN = re.compile(r"[(\[{]([^)\]}]*)[)\]}]")


@dataclass(frozen=True)
class NounPhrase:
    """``words`` end with the head noun; ``source`` says where the head came from ("name" | "category" |
    "fallback"); ``dropped`` lists what was taken out of the name (for docs/tests: nothing silent)."""

    words: tuple[str, ...]
    source: str
    dropped: tuple[str, ...] = ()

    @property
    def head(self) -> str:
        return self.words[-1]

    def text(self, max_words: int = 3) -> str:
        return " ".join(self.words[-max_words:])


def _split_words(text: str) -> list[str]:
    """Words of a text: camelCase and snake_case split, lower case, no punctuation."""
    spaced = re.sub(r"(?<=[a-z])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])", " ", text)
    return [w for w in re.split(r"[^A-Za-z0-9']+", spaced.lower()) if w]


def _is_id(word: str) -> bool:
    return any(c.isdigit() for c in word) or (len(word) >= 6 and not re.search(r"[aeiouy]", word))


def is_folder_name(name: str) -> bool:
    """A DTC-style ``Category_ID_Variant`` name: written by a pipeline, not by a person."""
    return bool(DTC_NAME.match(name.strip()))


def clean_name_words(name: str) -> tuple[list[str], list[str]]:
    """(kept words, dropped words) of a person-written name, after removing bookkeeping, ids, colours and
    sizes. Order kept: the head noun is the last kept word."""
    dropped: list[str] = []
    text = name
    for inner in _PAREN.findall(text):  # parenthesised parts are qualifiers or tags: keep only real words
        dropped.append(f"({inner})")
    text = _PAREN.sub(" ", text)
    spaced = re.sub(r"(?<=[a-z])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])", " ", text).lower()
    for tag in _TAG_RE.findall(spaced):
        dropped.append(tag)
    spaced = _TAG_RE.sub(" ", spaced)
    kept: list[str] = []
    for word in _split_words(spaced):
        if _is_id(word) or len(word) < 2 or word in COLOUR_WORDS or word in SIZE_WORDS or word in GENERIC_STEMS:
            dropped.append(word)
            continue
        kept.append(word.strip("'"))
    return [w for w in kept if w], dropped


def category_noun(category: str) -> list[str]:
    """The category as noun words ("toy truck" -> ["toy", "truck"]); [] for a category that names nothing."""
    words = [w for w in _split_words(category) if not _is_id(w)]
    if not words or " ".join(words) in GENERIC_CATEGORIES:
        return []
    return words[:-1] + [singular(words[-1])]


def noun_phrase(name: str, category: str, *, max_words: int = 3) -> NounPhrase:
    """The noun phrase a caption names the object with (see the module docstring)."""
    name = (name or "").strip()
    cat_words = category_noun(category)
    if is_folder_name(name):
        match = DTC_NAME.match(name)
        assert match is not None
        variant, dropped = clean_name_words(match.group("variant"))
        head_words = cat_words or [singular(w) for w in _split_words(match.group("category"))][-1:] or ["object"]
        head = head_words[-1]
        refined = [w for w in variant if head in w and singular(w) != head]
        if refined:
            head_words = head_words[:-1] + [refined[-1]]
        modifiers = [w for w in variant if w not in refined and singular(w) not in head_words]
        words = (modifiers + head_words)[-max_words:]
        return NounPhrase(tuple(words), "category", tuple(dropped + [match.group("id")]))
    kept, dropped = clean_name_words(name)
    if len(kept) > 1:  # "Ball_B01_Volleyball": a word the head noun contains says it twice
        head = kept[-1]
        kept = [w for w in kept[:-1] if not (w in head or singular(w) == singular(head))] + [head]
    if kept:
        return NounPhrase(tuple(kept[-max_words:]), "name", tuple(dropped + kept[:-max_words]))
    if cat_words:
        return NounPhrase(tuple(cat_words[-max_words:]), "category", tuple(dropped))
    return NounPhrase(("object",), "fallback", tuple(dropped))


def name_noun(name: str, category: str) -> str | None:
    """The head noun the caption check expects: from the person-written name, or the category for a folder
    name; None when neither names anything (then there is nothing to miss)."""
    phrase = noun_phrase(name, category)
    return None if phrase.source == "fallback" else phrase.head
