"""The sampler's view of the catalog: plain records, so sampling is testable without a database.

The records are filled from the database by :mod:`mixcount.catalog.pool_loader` (the scene room runs no SQL).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Optional

from mixcount.scene.spec import Captions
from mixcount.scene.words import words_of


@dataclass(frozen=True)
class ObjectRecord:
    """One drawable catalog object: real dimensions in metres (Z-up) and its three-tier captions."""

    object_id: int
    name: str
    category: str
    dims: tuple[float, float, float]
    captions: Captions
    split: Optional[str]
    model_path: str
    content_hash: str
    collision_path: Optional[str] = None
    status: str = "active"
    proxy_path: Optional[str] = None
    source_units: Optional[str] = None
    source_up_axis: Optional[str] = None
    render_path: Optional[str] = None  # canonical white-background render (the external exemplar), if any
    source: Optional[str] = None  # provenance for attribution: ingest source (dtc | folder) ...
    source_id: Optional[str] = None  # ... its stable key there ...
    license: Optional[str] = None  # ... and the licence text found at ingest
    container: bool = False  # catalog objects.container: may be drawn as the scene's container
    variants: tuple[int, ...] = ()  # object ids of its colour variants (catalog flag colour_variant)
    # (sRGB r, g, b, metallic, roughness) for its parts without a colour of their own ([palette]); None: none
    look: Optional[tuple[float, ...]] = None
    # where its real size comes from (objects.size_source: stated | model | kind | none; None: not recorded)
    size_source: Optional[str] = None

    @property
    def max_dim(self) -> float:
        return max(self.dims)


@dataclass(frozen=True)
class EnvironmentRecord:
    """An HDRI the sampler may draw: an ingested one (catalog id), or one of bpy's bundled maps
    (``environment_id`` None, ``source`` "bpy_bundled", see :mod:`mixcount.scene.bundled_environments`)."""

    environment_id: Optional[int]
    name: str
    path: str
    content_hash: str
    source: Optional[str] = None  # None: ingested into the catalog


@dataclass(frozen=True)
class MaterialRecord:
    material_id: int
    name: str
    path: str
    maps: Mapping[str, str] = field(default_factory=dict)


def fallback_captions(name: str, category: str) -> Captions:
    """Captions for an object nobody captioned yet, from its name and category: DTC folder names
    ``Donut_B0VL4BA90T_Pink`` give "pink donut" (the id dropped, the category moved last).

    The short tier is that phrase too when it has at most five words, else the category: objects of one
    category then keep distinct prompts when their names differ (the sampler never puts two objects
    with an identical caption into one scene)."""
    words = words_of(name, keep_numbers=True)
    cat = category.lower().strip()
    if words and cat and words[0] == cat:
        words = words[1:] + [cat]
    elif cat and cat not in words:
        words.append(cat)
    phrase = " ".join(words) or cat or name
    short = phrase if len(phrase.split()) <= 5 else (cat or phrase)
    return Captions(short=short, concise=phrase, detailed=f"{phrase} ({cat})" if cat else phrase)
