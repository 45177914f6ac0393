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
  that is no noun either ("misc") to "object";
* a technical part name (``CP_Radial_D5.0mm_P2.00mm``, ``DIP-8 IC NE555``, ``Screw terminal 2 pin``) is named
  by the noun a person would use (:func:`mixcount.catalog.naming.technical_category`: "capacitor", "IC",
  "terminal block"), not by its package, pin count or mounting words ("blue capacitor", not "blue CP radial").

The broad category is never appended after a noun from the name.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from mixcount.captions.colours import NAMES
from mixcount.catalog.naming import DTC_NAME, GENERIC_STEMS, singular, technical_category

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
    "final", "export", "untitled", "default", "new", "test", "sample", "vhacd", "chs",
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
    text = _PAREN.sub(" ", text).replace("_", " ")  # "_" is a word character: tags between them would hide
    spaced = re.sub(r"(?<=[a-z])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])", " ", text).lower()
    for tag in _TAG_RE.findall(spaced):
        dropped.append(tag)
    spaced = _TAG_RE.sub(" ", spaced)
    kept: list[str] = []
    for word in _split_words(spaced):
        word = _VERSIONED.sub(r"\1", word)
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


ABBREVIATIONS = {"ic": "IC", "led": "LED"}  # technical nouns written in capitals


def technical_words(name: str) -> tuple[str, ...] | None:
    """The noun words of a technical part name ("CP_Radial_D5.0mm" -> ("capacitor",), "DIP-8 IC" -> ("IC",)),
    None for a name that is not one."""
    found = technical_category(name)
    return None if found is None else tuple(ABBREVIATIONS.get(w, w) for w in found.split())


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
    technical = technical_words(name)
    if technical:
        return NounPhrase(tuple(w.lower() for w in technical), "name", tuple(clean_name_words(name)[1]))
    kept, dropped = clean_name_words(name)
    if len(kept) > 1:  # "Ball_B01_Volleyball": a word the head noun contains says it twice
        head = kept[-1]
        kept = [w for w in kept[:-1] if not (w in head or singular(w) == singular(head))] + [head]
    if kept:
        return NounPhrase(tuple(kept[-max_words:]), "name", tuple(dropped + kept[:-max_words]))
    if cat_words:
        return NounPhrase(tuple(cat_words[-max_words:]), "category", tuple(dropped))
    return NounPhrase(("object",), "fallback", tuple(dropped))


# Words that end the noun phrase of a name: what follows describes a part or a use ("Mug with handle").
_PHRASE_BREAK = frozenset({"with", "without", "for", "featuring", "in", "on", "from", "by", "w"})
# Proper adjectives (Siamese, Persian, Italian, Turkish) and well-known test objects of 3D graphics: a name's
# first word is taken for a proper noun only by these (a capital at the start of a name says nothing).
PROPER_WORDS = frozenset({"stanford", "utah", "suzanne", "rubik", "lego", "duplo", "ikea", "nerf", "barbie",
                          "coca-cola", "pepsi", "oreo", "pringles", "starbucks", "nike", "adidas", "xbox",
                          "playstation", "nintendo", "pikachu", "mario", "darth", "vader", "yoda", "christmas",
                          "easter", "halloween", "eiffel", "big", "ben", "statue", "liberty"} - {"big", "statue"})
_PROPER_SUFFIX = re.compile(r"^(?:[A-Z][a-z]{3,}(?:ese|ian|ish)|[A-Z][a-z]+'s)$")  # Siamese, Persian, Rubik's
_VERSIONED = re.compile(r"^([A-Za-z]{3,})\d{1,3}$")  # a word with a version or copy number glued on
_TOKEN_KEEP = re.compile(r"[A-Za-z0-9]+(?:['-][A-Za-z0-9]+)*")


@dataclass(frozen=True)
class NamePhrase:
    """The words a caption names the object with, as the name says them.

    ``words``: the name's own words, in its order and case (proper nouns kept, hyphenated compounds kept
    whole: "Ice-cream dispenser", "Stanford bunny"), bookkeeping, ids and size words dropped, colour
    words KEPT (``colours`` lists them: the name knows the object's colour better than a texture's mean);
    the head noun is the last word. ``detail``: the name's words after a phrase break ("Mug with handle" ->
    "handle"), for the concise and detailed tiers. ``source`` as :class:`NounPhrase`."""

    words: tuple[str, ...]
    colours: tuple[str, ...]
    source: str
    detail: tuple[str, ...] = ()
    dropped: tuple[str, ...] = ()

    @property
    def head(self) -> str:
        return self.words[-1].lower()

    @property
    def noun_words(self) -> tuple[str, ...]:
        """The words without the name's leading colour words ("Red coffee mug" -> coffee mug)."""
        out = list(self.words)
        while len(out) > 1 and out[0].lower() in COLOUR_WORDS:
            out.pop(0)
        return tuple(out)

    def text(self) -> str:
        return " ".join(self.words)


def _is_colour(word: str) -> bool:
    """A name word that names a colour (a family of :mod:`mixcount.captions.colours`): "red", "gray",
    "ivory"; not "dark", "clear", "natural" (they describe, they name no colour)."""
    from mixcount.captions.colours import family

    return family(word) is not None


def _case(word: str, *, first: bool, title_case: bool) -> str:
    """A name word as a caption writes it: ALLCAPS, camelCase and possessive/proper adjectives kept, a
    capital inside a sentence-case name kept, everything else lower case."""
    if len(word) > 1 and (word.isupper() or re.search(r"[a-z][A-Z]", word)):
        return word  # LEGO, iPhone, McDonald
    low = word.lower()
    if low.split("-")[0].removesuffix("'s") in PROPER_WORDS or _PROPER_SUFFIX.match(word):
        return word[:1].upper() + word[1:]
    if word[:1].isupper() and not first and not title_case:
        return word
    return low


def name_phrase(name: str, category: str, *, max_words: int = 4) -> NamePhrase:
    """The name's phrase for the captions (see :class:`NamePhrase`). A DTC folder name, or a name left with
    no word, falls back to :func:`noun_phrase` (category noun), with no colour words from the name."""
    name = (name or "").strip()
    if is_folder_name(name) or not name:
        phrase = noun_phrase(name, category)
        return NamePhrase(phrase.words, (), phrase.source, (), phrase.dropped)
    technical = technical_words(name)
    if technical:  # the part's noun; the name's colour words still count ("LED 5mm red")
        said = tuple(dict.fromkeys(w for w in _split_words(name) if _is_colour(w)))
        return NamePhrase(technical, said, "name", (), tuple(clean_name_words(name)[1]))
    dropped: list[str] = []
    colours: list[str] = []
    text = name
    for inner in _PAREN.findall(text):  # a qualifier in brackets: its colour words count, the rest is a tag
        dropped.append(f"({inner})")
        colours += [w for w in _split_words(inner) if _is_colour(w)]
    text = _PAREN.sub(" ", text)
    text = re.sub(r"(?<=[a-z])(?=[A-Z][a-z])", " ", text) if " " not in text.strip() and "_" not in text else text
    text = text.replace("_", " ")
    low = text.lower()
    for m in list(_TAG_RE.finditer(low))[::-1]:
        dropped.append(m.group(0))
        text = text[:m.start()] + " " + text[m.end():]
        low = text.lower()
    raw = [_VERSIONED.sub(r"\1", t) for t in _TOKEN_KEEP.findall(text)]  # "teddy2" -> "teddy"
    alpha = [t for t in raw if t[:1].isalpha()]
    title_case = len(alpha) > 1 and all(t[:1].isupper() for t in alpha)
    kept: list[str] = []
    detail: list[str] = []
    into = kept
    for tok in raw:
        low_tok = tok.lower()
        if low_tok in _PHRASE_BREAK and kept:
            into = detail
            continue
        if _is_id(low_tok) or len(low_tok) < 2 or low_tok in SIZE_WORDS or low_tok in GENERIC_STEMS:
            dropped.append(low_tok)
            continue
        into.append(_case(tok, first=not kept and into is kept, title_case=title_case))
    kept = [w for w in kept if w.lower() not in ("a", "an", "the")]
    if not kept:
        phrase = noun_phrase(name, category)
        return NamePhrase(phrase.words, tuple(dict.fromkeys(colours)), phrase.source, (), tuple(dropped))
    if len(kept) > 1:  # "Ball B01 Volleyball": a word the head noun contains says it twice
        head = kept[-1].lower()
        kept = [w for w in kept[:-1] if not (w.lower() in head or singular(w.lower()) == singular(head))] + kept[-1:]
    if len(kept) > max_words:
        dropped += kept[:-max_words]
        kept = kept[-max_words:]
    colours = [w.lower() for w in kept if _is_colour(w.lower())] + colours
    return NamePhrase(tuple(kept), tuple(dict.fromkeys(colours)), "name",
                      tuple(w.lower() for w in detail), tuple(dropped))


def name_noun(name: str, category: str) -> str | None:
    """The head noun the caption check expects: from the person-written name, or the category for a folder
    name; None when neither names anything (then there is nothing to miss)."""
    phrase = noun_phrase(name, category)
    return None if phrase.source == "fallback" else phrase.head
