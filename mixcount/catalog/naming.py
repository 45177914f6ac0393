"""Names and categories of catalog objects: safe text, odd-name checks, and category words.

Shared by the layout readers (:mod:`mixcount.catalog.layouts`) and ingest. Two category rules:

* DTC-style names start with the noun (``Markers_B07Z5P84J2_Peach`` -> marker; ``DTC_NAME``);
* :func:`category_from_stem` for file and folder names a person typed (``red_block.glb`` -> block,
  ``coffee-mug-02.ply`` -> mug) and :func:`category_from_name` for human names from metadata
  (``Red Ceramic Mug`` -> mug, ``Threshold_Porcelain_Teapot_White`` -> teapot): English puts the noun
  last, so the last word that is not a colour, a size, a number, an id or a generic word.
"""

from __future__ import annotations

import re
import unicodedata

from mixcount.scene.words import words_of

# Category_ID_Variant; the id (B07Z5P84J2) has a digit, so "apple_granny_smith" is not taken for one
DTC_NAME = re.compile(r"^(?P<category>[A-Za-z][A-Za-z0-9-]*)_(?P<id>(?=[A-Za-z]*\d)[A-Za-z0-9]{6,})_(?P<variant>.+)$")
GENERIC_STEMS = {"model", "mesh", "scene", "object", "asset", "untitled", "export", "3d", "textured", "scan",
                 "3d-asset", "visual", "geometry", "final", "lod0", "lowpoly", "highpoly", "raw"}
# folder names that sort files rather than name an object: such a folder does not name its one model
GENERIC_FOLDERS = {"sub", "subfolder", "models", "model", "meshes", "mesh", "assets", "asset", "files", "file",
                   "data", "objects", "object", "obj", "stl", "ply", "glb", "gltf", "usd", "export", "exports",
                   "new folder", "untitled folder", "misc", "other", "others", "tmp", "temp", "downloads", "3d",
                   "urdf", "sdf", "visual", "visuals", "collision", "geometry", "source", "src", "output", "out"}
COLOUR_WORDS = {"black", "white", "grey", "gray", "red", "orange", "yellow", "green", "blue", "purple", "pink",
                "brown", "tan", "beige", "gold", "golden", "silver", "navy", "teal", "lime", "olive", "maroon",
                "magenta", "cyan", "violet", "cream", "clear", "multicolor", "multicolour", "dark", "light"}
SIZE_WORDS = {"big", "small", "large", "tiny", "little", "huge", "mini", "medium", "tall", "short", "long", "wide",
              "narrow", "thin", "thick", "xl", "xxl", "xs", "sm", "md", "lg", "giant", "jumbo"}
NOT_NOUNS = COLOUR_WORDS | SIZE_WORDS | GENERIC_STEMS | {"copy", "new", "old", "ver", "version", "rev", "lod"}
# "mug_scaled", "vase_painted": a past participle describes the noun (len > 4 and not -eed: bed, seed, speed)
_PARTICIPLE = re.compile(r"^[a-z]{3,}(?<!e)ed$")


def safe_text(text: str) -> str:
    """A name that SQLite/JSON/one-line messages can carry: undecodable bytes (surrogate escapes)
    become \\xNN and control characters their escape (\\n, \\x07); a stable mapping, so reruns match."""
    text = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    if any(unicodedata.category(c) == "Cc" for c in text):
        text = "".join(c.encode("unicode_escape").decode() if unicodedata.category(c) == "Cc" else c for c in text)
    return text


def odd_name_reason(name: str) -> str | None:
    """Why a file/folder name is unusable (control characters, undecodable bytes), or None."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return f"name is not valid UTF-8: {ascii(name)}"
    bad = [c for c in name if unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co", "Cn")]
    if bad:
        return f"name has control or invisible characters {ascii(''.join(sorted(set(bad))))}: {ascii(name)}"
    if name.strip() != name or not name.strip():
        return f"name has leading/trailing blanks: {ascii(name)}"
    return None


def singular(word: str) -> str:
    """Lower-case singular category word: 'Markers' -> 'marker', 'Berries' -> 'berry'."""
    w = word.strip().lower()
    if len(w) > 4 and w.endswith("ies"):
        return w[:-3] + "y"
    if len(w) > 4 and re.search(r"(ches|shes|xes|sses|oes)$", w):
        return w[:-2]
    if len(w) > 3 and w.endswith("s") and not w.endswith(("ss", "us", "is")):
        return w[:-1]
    return w


def category_text(value: str) -> str:
    """A category from metadata as stored: lower case, words separated by one space, singular."""
    words = [w for w in re.split(r"[_\s]+", value.strip()) if w]
    return singular(" ".join(words)) if words else ""


def category_from_stem(stem: str, parent: str) -> str:
    """Plain files and folders named by a person: the noun of the name, its last word that is no colour,
    size, number, id or generic word ('mug_02.glb' -> mug, 'red_block' -> block, 'coffee-mug-02' -> mug,
    'big ball' -> ball, 'mug_scaled' -> mug); else the parent folder's noun, else "unknown". One word, so that it is matched to
    FSC-147 classes the way :mod:`mixcount.catalog.splits` matches any text: by its head noun."""
    for text in (stem, parent):
        for word in reversed(words_of(text)):
            if word.isalpha() and len(word) > 1 and word not in NOT_NOUNS and not _PARTICIPLE.match(word):
                return singular(word)
    return "unknown"


def category_from_dtc_name(name: str, parent: str) -> str:
    """A DTC folder name without a catalogue id: DTC puts the category first (``Category_ID_Variant``), so the
    category is the noun of the part before the first underscore ('Apple_granny_smith' -> apple, not smith;
    'Teapot-blue' -> teapot); else as :func:`category_from_stem`."""
    return category_from_stem(name.split("_", 1)[0], parent)


# what a person writes after the object's noun: a note in brackets ("Hex nut M6 (STEP)"), and what follows
# a preposition ("Sphere with hole", "Bag of chips"): the noun is the head before it
_NAME_NOTES = re.compile(r"\([^)]*\)|\[[^\]]*\]|\s(?:with|of|for|from|in|on)\s.*$", re.IGNORECASE)
FORMAT_WORDS = {"step", "stp", "stl", "obj", "ply", "glb", "gltf", "usd", "usdz", "fbx", "cad", "mjcf", "urdf", "sdf"}


def category_from_name(name: str, fallback: str = "unknown") -> str:
    """The noun of a human name: its last word that is no colour, generic word, file format or id
    (singular), notes in brackets and what follows a preposition left out."""
    head = _NAME_NOTES.sub(" ", name).strip() or name
    for word in reversed(words_of(head)):
        if len(word) > 2 and word not in COLOUR_WORDS and word not in GENERIC_STEMS and word not in FORMAT_WORDS:
            return singular(word)
    return fallback
