"""The stable JSON shape of a catalog object (``catalog list --json`` / ``catalog show --json``).

Documented field by field in docs/catalog-json.md; tests and later issues read it, so keep the shape:
add keys, never rename or remove them.
"""

from __future__ import annotations

import json
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.models import CaptionSet, CatalogObject, Flag, Render, ReviewDecision

RECORD_VERSION = 1


def ingest_appearance(obj: CatalogObject) -> str:
    """How ingest read the model's colours (``image``, ``vertex_color``, ``material`` or ``none``, the
    object's ``metadata.ingest.appearance``); ``none`` where it is not recorded or the metadata is unreadable."""
    try:
        return str((json.loads(obj.metadata_json or "{}").get("ingest") or {}).get("appearance") or "none")
    except (ValueError, AttributeError):
        return "none"

def _iso(value: Any) -> str | None:
    return value.isoformat() + "Z" if value is not None else None


def _metadata(obj: CatalogObject) -> tuple[dict[str, Any], dict[str, Any]]:
    try:
        data = json.loads(obj.metadata_json or "{}")
    except ValueError:
        return {}, {}
    if not isinstance(data, dict):
        return {}, {}
    meta = data.get("metadata") if isinstance(data.get("metadata"), dict) else {}
    ingest = data.get("ingest") if isinstance(data.get("ingest"), dict) else {}
    return meta, ingest


def flag_records(session: Session, obj: CatalogObject) -> list[dict[str, Any]]:
    flags = session.scalars(select(Flag).where(Flag.object_id == obj.id).order_by(Flag.kind, Flag.id)).all()
    out = []
    for f in flags:
        pair_name = None
        if f.pair_object_id is not None:
            pair = session.get(CatalogObject, f.pair_object_id)
            pair_name = pair.name if pair is not None else None
        out.append({"kind": f.kind, "score": float(f.score), "reason": f.reason, "pair": f.pair_object_id,
                    "pair_name": pair_name})
    return out


def active_captions(session: Session, obj: CatalogObject) -> dict[str, str] | None:
    cs = session.scalars(
        select(CaptionSet)
        .where(CaptionSet.object_id == obj.id, CaptionSet.active.is_(True))
        .order_by(CaptionSet.id.desc())
    ).first()
    if cs is None:
        return None
    return {"short": cs.short, "concise": cs.concise, "detailed": cs.detailed}


def object_record(session: Session, obj: CatalogObject, *, caption_warnings: list[dict[str, str]] | None,
                  detail: bool = False) -> dict[str, Any]:
    """One object as a JSON-ready dict. ``detail`` adds renders, reviews and caption history (show).

    ``caption_warnings`` are the caption check's findings on the active captions (None before captioning): the
    caller runs :func:`mixcount.captions.check.object_warnings`, since the catalog room sits below captions."""
    meta, ingest = _metadata(obj)
    record: dict[str, Any] = {
        "id": obj.id,
        "name": obj.name,
        "category": obj.category,
        "status": obj.status,
        "error": obj.error,
        "flags": flag_records(session, obj),
        "captions": active_captions(session, obj),
        "caption_warnings": caption_warnings,
        "split": obj.split.split if obj.split is not None else None,
        "source": obj.source,
        "source_id": obj.source_id,
        "model_path": obj.model_path,
        "content_hash": obj.content_hash,
        "geometry_hash": obj.geometry_hash,
        "source_units": obj.source_units,
        "source_up_axis": obj.source_up_axis,
        "size_source": obj.size_source,
        "dims_m": [obj.dim_x, obj.dim_y, obj.dim_z] if obj.dim_x is not None else None,
        "vertex_count": obj.vertex_count,
        "face_count": obj.face_count,
        "watertight": obj.watertight,
        "volume_m3": obj.volume,
        "area_m2": obj.area,
        "textured": obj.textured,
        "appearance": ingest.get("appearance"),
        "collision_path": obj.collision_path,
        "collision_face_count": obj.collision_face_count,
        "proxy_path": obj.proxy_path,
        "proxy_vertex_count": obj.proxy_vertex_count,
        "license": obj.license,
        "container": bool(obj.container),
        "container_reason": obj.container_reason,
        "layout": ingest.get("layout"),
        "up_axis_reason": ingest.get("up_axis_reason"),
        "units_reason": ingest.get("units_reason"),
        "parts": list(meta.get("parts") or []),
        "parts_rule": ingest.get("parts_rule"),
        "ingest_warnings": list(ingest.get("warnings") or []),
        "collision_source": ingest.get("collision_source"),
        "metadata": meta,
        "ingest_run_id": obj.ingest_run_id,
        "created_at": _iso(obj.created_at),
        "updated_at": _iso(obj.updated_at),
    }
    if detail:
        renders = session.scalars(select(Render).where(Render.object_id == obj.id).order_by(Render.view)).all()
        record["renders"] = [
            {"view": r.view, "path": r.path, "width": r.width, "height": r.height, "error": r.error}
            for r in renders
        ]
        reviews = session.scalars(
            select(ReviewDecision).where(ReviewDecision.object_id == obj.id).order_by(ReviewDecision.id)
        ).all()
        record["reviews"] = [
            {"decision": r.decision, "reviewer": r.reviewer, "note": r.note, "decided_at": _iso(r.decided_at)}
            for r in reviews
        ]
        sets = session.scalars(
            select(CaptionSet).where(CaptionSet.object_id == obj.id).order_by(CaptionSet.id)
        ).all()
        record["caption_sets"] = [
            {"captioner": c.captioner, "provider": c.provider, "model": c.model,
             "prompt_version": c.prompt_version, "active": bool(c.active), "short": c.short,
             "concise": c.concise, "detailed": c.detailed, "created_at": _iso(c.created_at)}
            for c in sets
        ]
        split = obj.split
        record["split_detail"] = (
            {"split": split.split, "method": split.method, "fsc_class": split.fsc_class, "seed": split.seed}
            if split is not None else None
        )
    return record
