"""The lowest piece of `catalog split`: the split names, the word normalisation (plurals, synonyms) and the
FSC-147 class table each object is matched against (docs/splits.md). :mod:`mixcount.catalog.split_units`,
:mod:`~mixcount.catalog.split_assign`, :mod:`~mixcount.catalog.split_report` and
:mod:`~mixcount.catalog.splits` all read these; this module imports none of them (no import circle)."""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Mapping

from mixcount.errors import CatalogError

SPLITS = ("train", "val", "test")  # the paper's three; SPLIT_NAMES adds the two extra test splits
# how held out each split is: an object of an FSC-147 test class must never reach a lower rank
HELD_OUT_RANK = {"train": 0, "val": 1, "test": 2, "test_objects": 2, "test_categories": 2}

# Irregular plurals (and words that look plural but are not) for :func:`singular`.
IRREGULAR = {
    "geese": "goose", "people": "person", "sheep": "sheep", "mice": "mouse", "teeth": "tooth",
    "feet": "foot", "children": "child", "knives": "knife", "leaves": "leaf", "loaves": "loaf",
    "glasses": "glass", "sunglasses": "sunglass", "series": "series", "species": "species",
    "cactus": "cactus", "octopus": "octopus", "bus": "bus", "lens": "lens", "chess": "chess",
    "dice": "die", "matches": "match", "peaches": "peach", "boxes": "box", "shoes": "shoe",
    "canoes": "canoe", "toes": "toe", "oases": "oasis", "cookies": "cookie", "movies": "movie",
}

# Object words -> the FSC-147 word(s) they mean. Keys and values are singular. Kept short and documented
# in docs/splits.md; each entry is a word a DTC-style catalog uses for an object FSC-147 names differently.
SYNONYMS: dict[str, str] = {
    # balls: FSC-147 "balls" (train) covers every kind
    "football": "ball", "soccerball": "ball", "basketball": "ball", "volleyball": "ball",
    "baseball": "ball", "softball": "ball", "tennisball": "ball", "golfball": "ball",
    "beachball": "ball", "dodgeball": "ball", "handball": "ball", "rugbyball": "ball",
    # drinkware / tableware
    "mug": "cup", "teacup": "cup", "tumbler": "cup", "dish": "plate", "saucer": "plate", "platter": "plate",
    "flowerpot": "flower pot", "planter": "flower pot",
    # writing tools
    "highlighter": "marker", "sharpie": "marker", "biro": "pen", "ballpoint": "pen",
    # food
    "doughnut": "donut", "cookie": "biscuit", "tangerine": "orange", "mandarin": "orange",
    "clementine": "orange", "capsicum": "pepper", "chili": "pepper", "chilli": "pepper",
    "seashell": "sea shell", "cashew": "cashew nut", "walnut": "nut", "almond": "nut",
    "hazelnut": "nut", "peanut": "nut",
    # other
    "sneaker": "shoe", "boot": "shoe", "sandal": "shoe", "slipper": "shoe",
    "tin": "can", "wristwatch": "watch", "duplo": "lego", "tshirt": "shirt", "t-shirt": "shirt",
    "gem": "gemstone", "candlestick": "candle", "skewer": "meat skewer",
}

TOKEN = re.compile(r"[a-z0-9&]+(?:-[a-z0-9]+)*")


def singular(word: str) -> str:
    """A plural-insensitive key for one lower-case word (same rules on both sides is what matters)."""
    if word in IRREGULAR:
        return IRREGULAR[word]
    if len(word) <= 3 or word.endswith(("ss", "us", "ous", "sis", "xis")):
        return word
    if word.endswith("ies") and len(word) > 4:
        return word[:-3] + "y"
    if word.endswith(("ches", "shes", "xes", "zes", "sses")):
        return word[:-2]
    if word.endswith("oes") and len(word) > 4:
        return word[:-2]
    if word.endswith("s"):
        return word[:-1]
    return word


def normalise(text: str, *, synonyms: bool = True) -> list[str]:
    """Lower-case singular words, synonyms applied to object text (a synonym may expand to several words).

    FSC-147 class names are normalised without synonyms: they are the targets synonyms point at.
    """
    spaced = re.sub(r"(?<=[a-z])(?=[A-Z])", " ", text or "").lower().replace("_", " ")
    out: list[str] = []
    for raw in TOKEN.findall(spaced):
        if any(ch.isdigit() for ch in raw):
            continue  # ids and version numbers
        word = singular(raw)
        for w in (SYNONYMS.get(word, SYNONYMS.get(raw, word)) if synonyms else word).split():
            if not out or out[-1] != w:  # "cashew nuts" -> "cashew nut nut" -> "cashew nut"
                out.append(w)
    return out


@dataclass(frozen=True)
class FscTable:
    """FSC-147 class name -> split, with each class's normalised words."""

    classes: Mapping[str, str]
    keys: Mapping[tuple[str, ...], str]  # normalised words -> class name

    @classmethod
    def load(cls, path: Path | None = None) -> "FscTable":
        if path is None:
            text = resources.files("mixcount.data").joinpath("fsc147_class_splits.csv").read_text("utf-8")
        else:
            text = Path(path).read_text("utf-8")
        classes: dict[str, str] = {}
        keys: dict[tuple[str, ...], str] = {}
        for row in csv.DictReader(text.splitlines()):
            name, split = row["class_name"].strip(), row["split"].strip()
            if split not in SPLITS:
                raise CatalogError(f"FSC-147 table: class {name!r} has unknown split {split!r}")
            classes[name] = split
            key = tuple(normalise(name, synonyms=False))
            if key in keys and classes[keys[key]] != split:
                raise CatalogError(f"FSC-147 table: {name!r} and {keys[key]!r} normalise alike but differ in split")
            keys.setdefault(key, name)
        return cls(classes, keys)

    def match_words(self, words: list[str]) -> str | None:
        """The longest class whose words end ``words`` (the head noun decides)."""
        for n in range(min(len(words), 4), 0, -1):
            name = self.keys.get(tuple(words[-n:]))
            if name is not None:
                return name
        return None

    def match(self, *, category: str, name: str, short: str | None) -> tuple[str | None, str | None]:
        """(class, source) from category, then name, then short caption; (None, None) when nothing fits."""
        for source, text in (("category", category), ("name", name), ("short", short or "")):
            found = self.match_words(normalise(text))
            if found is not None:
                return found, source
        return None, None
