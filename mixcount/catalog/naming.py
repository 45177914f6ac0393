"""Names and categories of catalog objects: safe text, odd-name checks, and category words.

Shared by the layout readers (:mod:`mixcount.catalog.layouts`) and ingest. Two category rules:

* technical names of parts (``DIP-8 IC NE555`` -> ic, ``Screw terminal 2 pin`` -> terminal block, KiCad's
  ``CP_Radial_D5.0mm_P2.00mm`` -> capacitor): :func:`technical_category`, a table of head nouns, packages,
  reference designators and count words, consulted first by the two rules below;
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
    FSC-147 classes the way :mod:`mixcount.catalog.splits` matches any text: by its head noun. A technical
    name ('CP_Radial_D5.0mm', 'PinHeader_1x04') gets the noun a person would use (:func:`technical_category`)."""
    technical = technical_category(stem)
    if technical:
        return technical
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
    (singular), notes in brackets and what follows a preposition left out; a technical name ('DIP-8 IC NE555',
    'Screw terminal 2 pin') the noun a person would use (:func:`technical_category`)."""
    head = _NAME_NOTES.sub(" ", name).strip() or name
    technical = technical_category(head)
    if technical:
        return technical
    for word in reversed(words_of(head)):
        if len(word) > 2 and word not in COLOUR_WORDS and word not in GENERIC_STEMS and word not in FORMAT_WORDS:
            return singular(word)
    return fallback


# ------------------------------------------------------------------ technical names (issue 70 item 6)
# Electronic and mechanical parts are named by catalogue conventions ("DIP-8 IC NE555", "Screw terminal 2 pin",
# KiCad's "CP_Radial_D5.0mm_P2.00mm"): the last plain word is often a pin count's unit, a package or a
# mounting note. The noun a person would use comes from a table of technical head nouns instead.

# head noun -> category; found anywhere in a name (the last one wins, as English puts the head last)
TECH_HEADS = {
    "ic": "ic", "chip": "ic", "microcontroller": "ic", "mcu": "ic", "opamp": "ic", "eeprom": "ic",
    "resistor": "resistor", "capacitor": "capacitor", "inductor": "inductor", "choke": "inductor",
    "diode": "diode", "led": "led", "transistor": "transistor", "mosfet": "transistor", "optocoupler": "ic",
    "potentiometer": "potentiometer", "trimpot": "potentiometer", "varistor": "varistor", "thermistor": "thermistor",
    "connector": "connector", "buzzer": "buzzer", "beeper": "buzzer", "regulator": "regulator",
    "dsub": "connector", "sma": "connector", "bnc": "connector",
    "idc": "connector", "rj45": "connector",
}
# head nouns that are everyday words too ("socket wrench", "crystal glass"): counted only in a technical name
TECH_HEADS_IN_CONTEXT = {
    "switch": "switch", "button": "button", "battery": "battery", "terminal": "terminal block",
    "header": "pin header", "socket": "socket", "jack": "jack", "fuse": "fuse", "relay": "relay",
    "crystal": "crystal", "oscillator": "oscillator", "transformer": "transformer", "sensor": "sensor",
    "speaker": "speaker", "microphone": "microphone", "motor": "motor", "holder": "holder", "plug": "plug",
    "usb": "connector", "hdmi": "connector",
}
# two words that name one thing: (word before, head) -> category
TECH_COMPOUNDS = {
    ("screw", "terminal"): "terminal block", ("terminal", "block"): "terminal block",
    ("pin", "header"): "pin header", ("pin", "socket"): "pin socket", ("battery", "holder"): "battery holder",
    ("barrel", "jack"): "barrel jack", ("push", "button"): "button", ("tactile", "switch"): "switch",
    ("dip", "switch"): "switch", ("slide", "switch"): "switch",
}
# IC packages ("DIP-8", "SOIC-14", "TDFN-8"): a designator, the category of a name with no head noun
PACKAGES = {"dip", "pdip", "soic", "sop", "ssop", "tssop", "msop", "qfp", "lqfp", "tqfp", "qfn", "dfn", "tdfn",
            "vqfn", "bga", "plcc", "sot", "sip", "zip"}
# reference designators as the first word of a library name (KiCad's "C_0805", "CP_Radial", "R_Axial")
DESIGNATORS = {"c": "capacitor", "cp": "capacitor", "r": "resistor", "l": "inductor", "d": "diode",
               "q": "transistor", "u": "ic", "sw": "switch", "y": "crystal", "bt": "battery", "f": "fuse",
               "k": "relay", "j": "connector", "led": "led"}
# makers whose name stands for their kind of part ("JST connector", "Phoenix Contact terminal block")
MAKERS = {"jst": "connector", "molex": "connector", "amphenol": "connector", "phoenixcontact": "terminal block"}
# what follows a number as its unit of count ("2 pin", "8-pin", "3 way"): never the noun
COUNT_UNITS = {"pin", "pins", "way", "ways", "pole", "poles", "position", "positions", "contact", "contacts",
               "row", "rows", "p"}
# how a part is mounted, turned or measured: words a technical name carries after its noun
DESCRIPTORS = {"mm", "cm", "mil", "inch", "vertical", "horizontal", "smd", "tht", "smt", "angled", "straight",
               "male", "female", "metric", "imperial", "radial", "axial", "top", "side", "entry", "pitch", "shielded",
               "unshielded", "through", "hole", "mount", "mounting", "pad", "pads", "lead", "leads", "polarized",
               "left", "right", "front", "back", "upper", "lower"}
_PART_NUMBER = re.compile(r"(?=.*[A-Za-z])(?=.*\d)[A-Za-z0-9]{3,}")
_PITCH = re.compile(r"^\d+x\d+$", re.IGNORECASE)
_DIMENSION = re.compile(r"^[A-Za-z]?\d+(?:[.,]\d+)?(?:mm|cm|m|in|mil)$", re.IGNORECASE)  # 10mm, D5.0mm: a size


def _tech_words(name: str) -> tuple[list[str], bool]:
    """(lower-case words, numbers as "#"; whether the name looks technical: a designator prefix, a package,
    a pin count, a grid such as 1x04, or a part number such as NE555)."""
    marker = False
    words: list[str] = []
    for k, token in enumerate(t for t in re.split(r"[_\s/()\[\]]+", name.strip()) if t):
        if (_PART_NUMBER.fullmatch(token.replace("-", "")) and not _DIMENSION.match(token)) or _PITCH.match(token):
            marker = True
        if k == 0 and token.lower() in DESIGNATORS and ("_" in name):
            marker = True
        for piece in re.split(r"-", token):
            for w in re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+(?:[.,]\d+)?", piece):
                lw = "#" if w[0].isdigit() else w.lower()
                if lw in PACKAGES:
                    marker = True
                words.append(lw)
    for a, b in zip(words, words[1:]):
        if a == "#" and b in COUNT_UNITS:
            marker = True
    joined = "".join(words)
    return words, marker or any(m in joined for m in MAKERS)


def _plain_noun_after(words: list[str], i: int) -> bool:
    """Whether a word that may be a plain noun follows ``words[i]`` ("Button Head Screw": the button is not
    the head); descriptors, units, counts, codes of three letters or fewer and known parts words are not."""
    known = DESCRIPTORS | COUNT_UNITS | PACKAGES | set(TECH_HEADS) | set(TECH_HEADS_IN_CONTEXT) | NOT_NOUNS
    return any(w != "#" and len(w) > 3 and w not in known for w in words[i + 1:])


def technical_category(name: str) -> str | None:
    """The category a person would give a technically named part, or None when the name is not one
    (then the plain rules decide). ``DIP-8 IC NE555`` -> ic, ``Screw terminal 2 pin`` -> terminal block,
    ``CP_Radial_D5.0mm_P2.00mm`` -> capacitor, ``PinHeader_1x04_P2.54mm`` -> pin header. The head is the last
    technical head noun (a compound when the word before it makes one); words after a number that count
    (pin, way, pole) are skipped; without a head, a package (DIP -> ic), a leading reference designator
    (C_ -> capacitor) or a maker (JST -> connector) names it."""
    words, technical = _tech_words(name)
    head: str | None = None
    for i, w in enumerate(words):
        if i > 0 and words[i - 1] == "#" and w in COUNT_UNITS:
            continue
        pair = (words[i - 1], w) if i > 0 else None
        if pair in TECH_COMPOUNDS and (technical or w in TECH_HEADS) and not _plain_noun_after(words, i):
            head = TECH_COMPOUNDS[pair]  # type: ignore[index]
        elif w in TECH_HEADS:
            head = TECH_HEADS[w]
        elif technical and w in TECH_HEADS_IN_CONTEXT and not _plain_noun_after(words, i):
            head = TECH_HEADS_IN_CONTEXT[w]
    if head is not None:
        return head
    if not technical:
        return None
    first = re.split(r"[_\s-]+", name.strip().lower(), maxsplit=1)[0]
    if first in DESIGNATORS and "_" in name:
        return DESIGNATORS[first]
    if any(w in PACKAGES for w in words):
        return "ic"
    joined = "".join(words)
    for maker, category in MAKERS.items():
        if maker in joined:
            return category
    return None


_GRID = re.compile(r"(?<![A-Za-z0-9.])(\d{1,2})x(\d{1,2})(?![\d.]*mm)(?!\d)", re.IGNORECASE)  # 1x04, 2x05: rows x pins
_PINS = re.compile(r"(?<![\d.])(\d{1,3})[\s_-]?(?:pins?|pol|poles?|ways?|positions?)\b", re.IGNORECASE)
_PACKAGE_PINS = re.compile(r"\b(?:" + "|".join(sorted(PACKAGES)) + r")-?(\d{1,3})\b", re.IGNORECASE)


def pin_count(name: str) -> int | None:
    """The pin count a technical name states ("1x04" -> 4, "2x05" -> 10, "Screw terminal 2 pin" -> 2,
    "DIP-8" -> 8), or None: what tells two parts of one family apart in an image (a 2- and a 3-pin
    terminal block), where sizes are kept out of captions. Only for a technical name
    (:func:`technical_category`): "Box 10x20" states no pins."""
    if technical_category(name) is None:
        return None
    for pattern in (_GRID, _PINS, _PACKAGE_PINS):
        m = pattern.search(name.replace("_", " "))
        if m:
            return int(m.group(1)) * (int(m.group(2)) if pattern is _GRID else 1)
    return None
