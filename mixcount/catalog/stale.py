"""Nothing stale after a change: what ingest removes when an object it updates has changed.

An object is derived from in later steps: canonical renders (``catalog render``), shape and surface
descriptors cached under ``<data_dir>/descriptors`` (``catalog filter``), flags (``filter``, captions'
collision check) and caption sets (``catalog caption``). Each step skips work it finds done, so when
ingest updates an object whose geometry, units, up axis, textures (its content), name or category
changed, it removes what was derived from the old one at that point: the render rows and their files,
the descriptor cache files of the old geometry and content, the object's flags and the pair flags others
carry about it (ingest writes its own warning flags again) and its caption sets and caption failures. The next ``catalog render``, ``filter``
and ``caption`` then do them again for this object without ``--force``. A person's review decisions are
kept: they are about the object, not about one measurement of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from mixcount.catalog.models import CaptionFailure, CaptionSet, CatalogObject, Flag, Render

# what a change is made of: the columns whose old value derived data was computed from
WATCHED = ("content_hash", "geometry_hash", "source_units", "source_up_axis", "name", "category")


@dataclass
class StoreContext:
    """Where ingest's store step reports changes (``summary``: its ``IngestSummary``, whose ``invalidated``
    and ``reoriented`` lists it appends to) and finds the files derived from an object."""

    summary: Any
    renders_dir: Path
    descriptors_dir: Path


@dataclass(frozen=True)
class Before:
    """The watched columns of a row before ingest updates it."""

    values: tuple[object, ...]

    @classmethod
    def of(cls, obj: CatalogObject) -> "Before":
        return cls(tuple(getattr(obj, k) for k in WATCHED))

    def changed(self, obj: CatalogObject) -> list[str]:
        """The watched columns whose value differs on the updated row."""
        return [k for k, old in zip(WATCHED, self.values) if getattr(obj, k) != old]

    def get(self, key: str) -> object:
        return self.values[WATCHED.index(key)]


def _unlink(path: Path) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        pass
    except OSError:
        pass  # unreadable folder: the row is gone, so the step redoes it anyway


def invalidate(session: Session, obj: CatalogObject, before: Before, *, renders_dir: Path,
               descriptors_dir: Path) -> None:
    """Remove what later steps derived from the object as it was (see the module docstring); no commit."""
    for row in session.scalars(select(Render).where(Render.object_id == obj.id)).all():
        if row.path:
            p = Path(row.path)
            _unlink(p)
            _unlink(p.with_name(f"{p.stem}_mask.png"))
        session.delete(row)
    stem = f"obj_{obj.id:06d}"
    if renders_dir.is_dir():
        for p in [*renders_dir.glob(f"{stem}.png"), *renders_dir.glob(f"{stem}_*.png")]:
            _unlink(p)
    for key in (before.get("geometry_hash"), before.get("content_hash")):
        if isinstance(key, str) and key and descriptors_dir.is_dir():
            for p in descriptors_dir.glob(f"{key[:32]}_*"):
                _unlink(p)
    # its flags, and the pair flags other objects carry about it (a duplicate of the old shape, a caption
    # collision with the old name): filter and caption find the pairs again
    session.execute(delete(Flag).where((Flag.object_id == obj.id) | (Flag.pair_object_id == obj.id)))
    session.execute(delete(CaptionSet).where(CaptionSet.object_id == obj.id))
    session.execute(delete(CaptionFailure).where(CaptionFailure.object_id == obj.id))
