"""The sampler's view of the catalog: plain records, so sampling is testable without a database.

:func:`load_pool` reads active objects that have a split (captions from the active caption set, else a
fallback from name and category); :func:`load_environments` / :func:`load_materials` read the ingested
HDRIs and PBR sets. Broken and excluded objects never enter the pool.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

from mixcount.scene.spec import Captions


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
    source_units: Optional[str] = None
    source_up_axis: Optional[str] = None

    @property
    def max_dim(self) -> float:
        return max(self.dims)


@dataclass(frozen=True)
class EnvironmentRecord:
    environment_id: int
    name: str
    path: str
    content_hash: str


@dataclass(frozen=True)
class MaterialRecord:
    material_id: int
    name: str
    path: str
    maps: Mapping[str, str] = field(default_factory=dict)


_ID_TOKEN = re.compile(r"^(?=.*\d)[A-Za-z0-9]{6,}$")  # catalogue ids such as B0VL4BA90T


def _words(name: str) -> list[str]:
    words = []
    for token in re.split(r"[_\-\s]+", name.strip()):
        if not token or _ID_TOKEN.match(token):
            continue
        words.extend(w.lower() for w in re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+", token))
    return words


def fallback_captions(name: str, category: str) -> Captions:
    """Captions for an object nobody captioned yet, from its name and category: DTC folder names
    ``Donut_B0VL4BA90T_Pink`` give "pink donut" (the id dropped, the category moved last)."""
    words = _words(name)
    cat = category.lower().strip()
    if words and cat and words[0] == cat:
        words = words[1:] + [cat]
    elif cat and cat not in words:
        words.append(cat)
    phrase = " ".join(words) or cat or name
    return Captions(short=cat or phrase, concise=phrase, detailed=f"{phrase} ({cat})" if cat else phrase)


def load_pool(session: Any, *, split: Optional[str] = None) -> list[ObjectRecord]:
    """Active objects with a split (optionally only ``split``), ordered by id (determinism)."""
    from sqlalchemy import select

    from mixcount.catalog.models import STATUS_ACTIVE, CaptionSet, CatalogObject, Split

    stmt = (
        select(CatalogObject, Split.split)
        .join(Split, Split.object_id == CatalogObject.id)
        .where(CatalogObject.status == STATUS_ACTIVE)
        .order_by(CatalogObject.id)
    )
    if split is not None:
        stmt = stmt.where(Split.split == split)
    rows = session.execute(stmt).all()
    caps: dict[int, Captions] = {}
    for cs in session.execute(
        select(CaptionSet).where(CaptionSet.active.is_(True)).order_by(CaptionSet.id)
    ).scalars():
        caps[cs.object_id] = Captions(cs.short, cs.concise, cs.detailed)
    pool = []
    for obj, obj_split in rows:
        dims = (float(obj.dim_x or 0.0), float(obj.dim_y or 0.0), float(obj.dim_z or 0.0))
        if min(dims) <= 0.0:
            continue  # degenerate facts: cannot be normalised to a target size
        pool.append(
            ObjectRecord(
                object_id=int(obj.id), name=obj.name, category=(obj.category or "").lower(), dims=dims,
                captions=caps.get(obj.id) or fallback_captions(obj.name, obj.category or ""),
                split=obj_split, model_path=obj.model_path, content_hash=obj.content_hash or "",
                collision_path=obj.collision_path, status=obj.status,
                source_units=obj.source_units, source_up_axis=obj.source_up_axis,
            )
        )
    return pool


def load_environments(session: Any) -> list[EnvironmentRecord]:
    from sqlalchemy import select

    from mixcount.catalog.models import Environment

    return [
        EnvironmentRecord(int(e.id), e.name, e.path, e.content_hash)
        for e in session.execute(select(Environment).order_by(Environment.id)).scalars()
    ]


def load_materials(session: Any) -> list[MaterialRecord]:
    from sqlalchemy import select

    from mixcount.catalog.models import Material

    return [
        MaterialRecord(int(m.id), m.name, m.path, dict(sorted(json.loads(m.maps_json or "{}").items())))
        for m in session.execute(select(Material).order_by(Material.id)).scalars()
    ]
