"""Catalog -> sampler records: the only SQL behind ``mixcount compose``.

:func:`load_pool` reads active objects that have a split (captions from the active caption set, else a
fallback from name and category; the canonical render, when one exists on disk, as the external exemplar);
:func:`load_environments` / :func:`load_materials` read the ingested
HDRIs and PBR sets. Broken and excluded objects never enter the pool.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.models import STATUS_ACTIVE, CaptionSet, CatalogObject, Environment, Material, Render, Split
from mixcount.scene.pool import EnvironmentRecord, MaterialRecord, ObjectRecord, fallback_captions
from mixcount.scene.spec import Captions


def load_pool(session: Session, *, split: Optional[str] = None) -> list[ObjectRecord]:
    """Active objects with a split (optionally only ``split``), ordered by id (determinism)."""

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
    renders: dict[int, str] = {}  # view "canonical" = mixcount.curation.renders.CANONICAL
    for oid, path in session.execute(
        select(Render.object_id, Render.path).where(Render.view == "canonical", Render.error.is_(None))
    ):
        if path and Path(path).is_file():
            renders[int(oid)] = str(path)
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
            )
        )
    return pool


def load_environments(session: Session) -> list[EnvironmentRecord]:

    return [
        EnvironmentRecord(int(e.id), e.name, e.path, e.content_hash)
        for e in session.execute(select(Environment).order_by(Environment.id)).scalars()
    ]


def load_materials(session: Session) -> list[MaterialRecord]:

    return [
        MaterialRecord(int(m.id), m.name, m.path, dict(sorted(json.loads(m.maps_json or "{}").items())))
        for m in session.execute(select(Material).order_by(Material.id)).scalars()
    ]
