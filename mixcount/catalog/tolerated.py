"""What ingest tolerated in a model's files, as flags on the object.

A missing ``.mtl`` or texture, a texture found by name rather than where its material points, a URDF
scale that is not applied: the object stays active (as with ``mesh_quality``) and carries one flag per
problem, kind ``missing_material``, ``missing_texture``, ``damaged_texture`` (a texture that does not
decode whole: truncated, lying about its size, over ``[ingest] max_image_pixels``) or ``ingest_note``,
with the warning as reason. ``catalog filter`` leaves these kinds alone; each ingest that writes the object writes them again.
"""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.models import CatalogObject, Flag

# flags ingest writes itself: what it tolerated in a model's files (filter keeps them; a change rewrites them)
INGEST_FLAG_KINDS = ("missing_material", "missing_texture", "damaged_texture", "ingest_note")


def _warning_kind(warning: str) -> str:
    if warning.startswith("missing material file"):
        return "missing_material"
    if warning.startswith("missing texture file"):
        return "missing_texture"
    if warning.startswith("texture ") and " does not decode: " in warning:  # media_check.texture_warnings
        return "damaged_texture"
    return "ingest_note"


def write_warning_flags(session: Session, obj: CatalogObject, warnings: list[str]) -> None:
    """The object's ingest flags, one per tolerated problem (a mesh_quality-like warning: it stays active)."""
    for flag in session.scalars(select(Flag).where(Flag.object_id == obj.id, Flag.kind.in_(INGEST_FLAG_KINDS))):
        session.delete(flag)
    for warning in warnings:
        kind = _warning_kind(warning)
        session.add(Flag(object_id=obj.id, kind=kind, score=0.5 if kind == "ingest_note" else 1.0, reason=warning))
