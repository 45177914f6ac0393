"""Migrations from empty to head on a real SQLite file, and the ORM matching the migrated schema."""

from pathlib import Path

from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import inspect

from mixcount.catalog.db import current_revision, head_revision, open_catalog
from mixcount.catalog.models import Base


def test_migrate_empty_file_to_head(tmp_path: Path):
    path = tmp_path / "fresh.db"
    assert not path.exists()
    cat = open_catalog(str(path), data_dir="")
    try:
        assert path.exists()
        assert current_revision(cat.engine) == head_revision()
        tables = set(inspect(cat.engine).get_table_names())
        assert {"objects", "ingest_runs", "flags", "caption_sets", "splits", "renders", "review_decisions"} <= tables
        with cat.engine.connect() as conn:
            assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
            assert conn.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
    finally:
        cat.close()


def test_orm_matches_migrated_schema(tmp_path: Path):
    cat = open_catalog(str(tmp_path / "c.db"), data_dir="")
    try:
        with cat.engine.connect() as conn:
            diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
        assert diff == [], f"models and migrations differ: {diff}"
    finally:
        cat.close()


def test_reopen_is_idempotent(tmp_path: Path):
    path = tmp_path / "c.db"
    open_catalog(str(path), data_dir="").close()
    cat = open_catalog(str(path), data_dir="")
    try:
        assert current_revision(cat.engine) == head_revision()
    finally:
        cat.close()
