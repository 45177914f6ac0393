"""SQLAlchemy 2 ORM models of the catalog.

The schema is created and changed only by alembic migrations in ``migrations/versions``; these models
must match the migrated schema (a test compares them). A schema change is a new migration file.
Object status is one of ``active``, ``excluded`` (kept, but never drawn into scenes) or ``broken``.
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Optional

from sqlalchemy import (
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Text,
    UniqueConstraint,
    false,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

STATUS_ACTIVE = "active"
STATUS_EXCLUDED = "excluded"
STATUS_BROKEN = "broken"
STATUSES = (STATUS_ACTIVE, STATUS_EXCLUDED, STATUS_BROKEN)


def utcnow() -> datetime:
    return datetime.now(timezone.utc).replace(tzinfo=None)


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)


class IngestRun(Base):
    """One `catalog ingest` invocation; `status` stays `running` if it was interrupted."""

    __tablename__ = "ingest_runs"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    started_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    finished_at: Mapped[Optional[datetime]] = mapped_column(DateTime)
    paths: Mapped[str] = mapped_column(Text, default="[]")  # JSON list
    status: Mapped[str] = mapped_column(String(16), default="running")
    n_new: Mapped[int] = mapped_column(Integer, default=0)
    n_unchanged: Mapped[int] = mapped_column(Integer, default=0)
    n_updated: Mapped[int] = mapped_column(Integer, default=0)
    n_broken: Mapped[int] = mapped_column(Integer, default=0)


class SourceFolder(Base):
    """A folder given to ``catalog ingest`` with a setting a person stated for it once (``--up-axis``):
    a later ingest of the folder, or of a folder inside it, without the option keeps it."""

    __tablename__ = "source_folders"
    __table_args__ = (UniqueConstraint("path"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    path: Mapped[str] = mapped_column(Text)  # absolute, resolved
    up_axis: Mapped[Optional[str]] = mapped_column(String(4))
    updated_at: Mapped[Optional[datetime]] = mapped_column(DateTime, default=utcnow)


class CatalogObject(Base):
    """One 3D object capture and the facts measured from its mesh (metres, Z-up)."""

    __tablename__ = "objects"
    __table_args__ = (UniqueConstraint("source", "source_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    source: Mapped[str] = mapped_column(String(32))  # dtc | folder
    source_id: Mapped[str] = mapped_column(String(512))  # stable key within the source (folder/file path)
    name: Mapped[str] = mapped_column(String(256))
    category: Mapped[str] = mapped_column(String(128), index=True)
    model_path: Mapped[str] = mapped_column(Text)
    content_hash: Mapped[Optional[str]] = mapped_column(String(64), index=True)
    geometry_hash: Mapped[Optional[str]] = mapped_column(String(64), index=True)
    license: Mapped[Optional[str]] = mapped_column(Text)
    metadata_json: Mapped[Optional[str]] = mapped_column(Text)
    source_units: Mapped[Optional[str]] = mapped_column(String(16))
    source_up_axis: Mapped[Optional[str]] = mapped_column(String(4))
    # where the real size comes from (mixcount.sizes.SIZE_SOURCES): stated | model | kind | none (issue 70)
    size_source: Mapped[Optional[str]] = mapped_column(String(16))
    dim_x: Mapped[Optional[float]] = mapped_column(Float)
    dim_y: Mapped[Optional[float]] = mapped_column(Float)
    dim_z: Mapped[Optional[float]] = mapped_column(Float)
    vertex_count: Mapped[Optional[int]] = mapped_column(Integer)
    face_count: Mapped[Optional[int]] = mapped_column(Integer)
    watertight: Mapped[Optional[bool]] = mapped_column(Boolean)
    volume: Mapped[Optional[float]] = mapped_column(Float)
    area: Mapped[Optional[float]] = mapped_column(Float)
    textured: Mapped[Optional[bool]] = mapped_column(Boolean)
    collision_path: Mapped[Optional[str]] = mapped_column(Text)
    collision_face_count: Mapped[Optional[int]] = mapped_column(Integer)
    proxy_path: Mapped[Optional[str]] = mapped_column(Text)  # convex collision proxy (mixcount.catalog.proxies)
    proxy_vertex_count: Mapped[Optional[int]] = mapped_column(Integer)
    status: Mapped[str] = mapped_column(String(16), default=STATUS_ACTIVE, index=True)
    error: Mapped[Optional[str]] = mapped_column(Text)
    # a container (plate, tray, bowl, ...) scenes drop the counted objects into: set from the
    # [containers] rules or a person's review (mixcount.catalog.containers), with the reason
    container: Mapped[bool] = mapped_column(Boolean, default=False, server_default=false(), index=True)
    container_reason: Mapped[Optional[str]] = mapped_column(Text)
    ingest_run_id: Mapped[Optional[int]] = mapped_column(ForeignKey("ingest_runs.id"))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow, onupdate=utcnow)

    flags: Mapped[list["Flag"]] = relationship(
        back_populates="obj", foreign_keys="Flag.object_id", cascade="all, delete-orphan"
    )
    caption_sets: Mapped[list["CaptionSet"]] = relationship(back_populates="obj", cascade="all, delete-orphan")
    split: Mapped[Optional["Split"]] = relationship(back_populates="obj", cascade="all, delete-orphan")
    renders: Mapped[list["Render"]] = relationship(back_populates="obj", cascade="all, delete-orphan")
    reviews: Mapped[list["ReviewDecision"]] = relationship(back_populates="obj", cascade="all, delete-orphan")

    @property
    def dims(self) -> tuple[float, float, float]:
        return (self.dim_x or 0.0, self.dim_y or 0.0, self.dim_z or 0.0)


class Flag(Base):
    """An automatic curation finding: kind, score, human-readable reason, and the paired object."""

    __tablename__ = "flags"
    __table_args__ = (UniqueConstraint("object_id", "kind", "pair_object_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id", ondelete="CASCADE"), index=True)
    kind: Mapped[str] = mapped_column(String(64))  # exact_duplicate, near_duplicate_geometry, ...
    score: Mapped[float] = mapped_column(Float, default=1.0)
    reason: Mapped[str] = mapped_column(Text, default="")
    pair_object_id: Mapped[Optional[int]] = mapped_column(ForeignKey("objects.id", ondelete="SET NULL"))
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)

    obj: Mapped[CatalogObject] = relationship(back_populates="flags", foreign_keys=[object_id])


class CaptionSet(Base):
    """Three-tier captions from one captioner/model/prompt version; one set per object is active."""

    __tablename__ = "caption_sets"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id", ondelete="CASCADE"), index=True)
    captioner: Mapped[str] = mapped_column(String(32))  # stub | http
    provider: Mapped[str] = mapped_column(String(64))
    model: Mapped[str] = mapped_column(String(128))
    prompt_version: Mapped[str] = mapped_column(String(32))
    short: Mapped[str] = mapped_column(Text)
    concise: Mapped[str] = mapped_column(Text)
    detailed: Mapped[str] = mapped_column(Text)
    response_hash: Mapped[str] = mapped_column(String(64))
    active: Mapped[bool] = mapped_column(Boolean, default=True)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)

    obj: Mapped[CatalogObject] = relationship(back_populates="caption_sets")


class CaptionFailure(Base):
    """A recorded captioning failure for one object (the batch went on)."""

    __tablename__ = "caption_failures"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id", ondelete="CASCADE"), index=True)
    captioner: Mapped[str] = mapped_column(String(32))
    provider: Mapped[str] = mapped_column(String(64))
    model: Mapped[str] = mapped_column(String(128))
    prompt_version: Mapped[str] = mapped_column(String(32))
    attempts: Mapped[int] = mapped_column(Integer, default=1)
    error: Mapped[str] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)


class Split(Base):
    """The object's split (train / val / test / test_objects / test_categories) and how it was decided."""

    __tablename__ = "splits"

    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id", ondelete="CASCADE"), primary_key=True)
    split: Mapped[str] = mapped_column(String(16), index=True)
    method: Mapped[str] = mapped_column(String(16))  # fsc147 | random | group | category | kept
    mode: Mapped[Optional[str]] = mapped_column(String(16))  # paper | objects | categories (None: before 0008)
    fsc_class: Mapped[Optional[str]] = mapped_column(String(128))
    seed: Mapped[Optional[int]] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)

    obj: Mapped[CatalogObject] = relationship(back_populates="split")


class Render(Base):
    """A canonical render of an object (view `canonical` or `view_<k>`); `error` set if it failed."""

    __tablename__ = "renders"
    __table_args__ = (UniqueConstraint("object_id", "view"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id", ondelete="CASCADE"), index=True)
    view: Mapped[str] = mapped_column(String(32), default="canonical")
    path: Mapped[Optional[str]] = mapped_column(Text)
    model_hash: Mapped[Optional[str]] = mapped_column(String(64))
    settings_hash: Mapped[Optional[str]] = mapped_column(String(64))
    width: Mapped[Optional[int]] = mapped_column(Integer)
    height: Mapped[Optional[int]] = mapped_column(Integer)
    error: Mapped[Optional[str]] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)

    obj: Mapped[CatalogObject] = relationship(back_populates="renders")


class ReviewDecision(Base):
    """A person's decision on an object: accept/reject (the latest outranks automatic flags) or
    container/not_container (the latest outranks the container rules)."""

    __tablename__ = "review_decisions"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id", ondelete="CASCADE"), index=True)
    decision: Mapped[str] = mapped_column(String(16))  # accept | reject | container | not_container | same | variants | different
    # the other object of a pair decision (same / variants / different), else None
    pair_object_id: Mapped[Optional[int]] = mapped_column(Integer, nullable=True)
    reviewer: Mapped[str] = mapped_column(String(128), default="")
    note: Mapped[str] = mapped_column(Text, default="")
    decided_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)

    obj: Mapped[CatalogObject] = relationship(back_populates="reviews")


class Environment(Base):
    """An HDR/EXR environment map ingested with `catalog ingest-env`."""

    __tablename__ = "environments"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(256))
    path: Mapped[str] = mapped_column(Text)
    content_hash: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    broken: Mapped[Optional[str]] = mapped_column(Text, nullable=True)  # why it did not decode; never drawn
    checked_at: Mapped[Optional[datetime]] = mapped_column(DateTime, nullable=True)  # None: before 0009


class Material(Base):
    """A PBR texture set ingested with `catalog ingest-materials`; `maps_json` names map -> file."""

    __tablename__ = "materials"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(256))
    path: Mapped[str] = mapped_column(Text)
    maps_json: Mapped[str] = mapped_column(Text, default="{}")
    content_hash: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[datetime] = mapped_column(DateTime, default=utcnow)
    broken: Mapped[Optional[str]] = mapped_column(Text, nullable=True)  # why a map did not decode; never drawn
    checked_at: Mapped[Optional[datetime]] = mapped_column(DateTime, nullable=True)  # None: before 0009
