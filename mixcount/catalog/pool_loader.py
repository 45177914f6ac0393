"""Catalog -> sampler records: the only SQL behind ``mixcount compose``.

:func:`load_pool` reads active objects that have a split (captions from the active caption set, else a
fallback from name and category; the canonical render, when one exists on disk, as the external exemplar;
its colour variants from the ``colour_variant`` flags of ``catalog filter``);
:func:`load_environments` / :func:`load_materials` read the ingested
HDRIs and PBR sets. Broken and excluded objects never enter the pool.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.grouping import connected_groups
from mixcount.catalog.models import (
    STATUS_ACTIVE,
    CaptionSet,
    CatalogObject,
    Environment,
    Flag,
    Material,
    Render,
    Split,
)
from mixcount.scene.object_records import EnvironmentRecord, MaterialRecord, ObjectRecord, fallback_captions
from mixcount.scene.spec import Captions

COLOUR_VARIANT = "colour_variant"  # mixcount.curation.flag_kinds.COLOUR_VARIANT (no import: scene side stays light)
# mixcount.catalog.tolerated: a texture that did not decode whole at ingest; such an object is never drawn
# (Blender would paint the image black or magenta, the USD conversion stops on it)
DAMAGED_TEXTURE = "damaged_texture"


def colour_variants(session: Session) -> dict[int, set[int]]:
    """Object id -> ids of its colour variants (``colour_variant`` flags, both directions), carried
    through duplicate groups: the kept member of a group is a variant of whatever any member is a variant
    of (a recolour of an excluded copy is a recolour of the object kept in its place)."""
    dup_pairs: list[tuple[int, int]] = []
    var_pairs: list[tuple[int, int]] = []
    for kind, oid, other in session.execute(
        select(Flag.kind, Flag.object_id, Flag.pair_object_id).where(Flag.pair_object_id.is_not(None))
    ):
        if kind == COLOUR_VARIANT:
            var_pairs.append((int(oid), int(other)))
        elif "duplicate" in kind:
            dup_pairs.append((int(oid), int(other)))
    group_of: dict[int, list[int]] = {}
    for group in connected_groups(dup_pairs, members=[i for pair in var_pairs for i in pair]):
        for i in group:
            group_of[i] = group
    out: dict[int, set[int]] = {}
    for a, b in var_pairs:
        for x in group_of[a]:
            out.setdefault(x, set()).update(group_of[b])
        for y in group_of[b]:
            out.setdefault(y, set()).update(group_of[a])
    return {k: v - set(group_of.get(k, [k])) for k, v in out.items()}


def damaged_texture_note(session: Session, split: str) -> Optional[str]:
    """The one line naming the active objects of ``split`` that :func:`load_pool` leaves out because a
    texture of theirs did not decode at ingest (flag ``damaged_texture``), or None: a run says it at its
    start instead of drawing fewer objects than the split table shows without a word."""
    rows = session.execute(
        select(CatalogObject.name, Flag.reason)
        .join(Flag, Flag.object_id == CatalogObject.id)
        .join(Split, Split.object_id == CatalogObject.id)
        .where(Flag.kind == DAMAGED_TEXTURE, CatalogObject.status == STATUS_ACTIVE, Split.split == split)
        .order_by(CatalogObject.id)
    ).all()
    names = list(dict.fromkeys(str(name) for name, _ in rows))
    if not names:
        return None
    more = f" and {len(names) - 5} more" if len(names) > 5 else ""
    return (f"{len(names)} object(s) of split {split!r} are left out of scenes because a texture did not decode "
            f"at ingest ({', '.join(names[:5])}{more}; `mixcount catalog show ID` gives the reason): replace the "
            "file and run catalog ingest again")


def load_pool(session: Session, *, split: Optional[str] = None, palette: Any = None) -> list[ObjectRecord]:
    """Active objects with a split (optionally only ``split``) and no ``damaged_texture`` flag, ordered by id
    (determinism). ``palette`` (``[palette]``): each untextured object's look for its parts without a colour
    (:func:`object_look`)."""
    from mixcount.catalog.materials import object_look

    damaged = select(Flag.object_id).where(Flag.kind == DAMAGED_TEXTURE)  # a texture that did not decode
    stmt = (
        select(CatalogObject, Split.split)
        .join(Split, Split.object_id == CatalogObject.id)
        .where(CatalogObject.status == STATUS_ACTIVE, CatalogObject.id.not_in(damaged))
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
    renders: dict[int, str] = {}  # view "canonical" = mixcount.curation.renders.CANONICAL
    for oid, path in session.execute(
        select(Render.object_id, Render.path).where(Render.view == "canonical", Render.error.is_(None))
    ):
        if path and Path(path).is_file():
            renders[int(oid)] = str(path)
    variants = colour_variants(session)
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
                collision_path=obj.collision_path, status=obj.status, proxy_path=obj.proxy_path,
                source_units=obj.source_units, source_up_axis=obj.source_up_axis,
                render_path=renders.get(int(obj.id)),
                source=obj.source, source_id=obj.source_id, license=obj.license, container=bool(obj.container),
                size_source=obj.size_source,
                variants=tuple(sorted(variants.get(int(obj.id), ()))),
                look=None if palette is None or obj.textured else _look_tuple(object_look(
                    palette, name=obj.name, category=obj.category or "", metadata_json=obj.metadata_json,
                    content_hash=obj.content_hash or "")),
            )
        )
    return pool


def load_environments(session: Session) -> list[EnvironmentRecord]:
    """The ingested environment maps a scene may draw: those that decoded whole (a ``broken`` one never)."""
    return [
        EnvironmentRecord(int(e.id), e.name, e.path, e.content_hash)
        for e in session.execute(select(Environment).where(Environment.broken.is_(None))
                                 .order_by(Environment.id)).scalars()
    ]


def load_materials(session: Session) -> list[MaterialRecord]:
    """The ingested floor materials a scene may draw: those whose maps decoded whole (a ``broken`` one never)."""
    return [
        MaterialRecord(int(m.id), m.name, m.path, dict(sorted(json.loads(m.maps_json or "{}").items())))
        for m in session.execute(select(Material).where(Material.broken.is_(None)).order_by(Material.id)).scalars()
    ]


def _look_tuple(look: Any) -> Optional[tuple[float, ...]]:
    return None if look is None else look.as_tuple()
