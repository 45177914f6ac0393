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


def test_migration_revisions_read_as_alembic_reads_them():
    """The catalog learns the head and the known revisions from the scripts themselves (no alembic import
    on the way to a catalog already at head); alembic's ScriptDirectory must agree, revision for revision."""
    from alembic.script import ScriptDirectory

    from mixcount.catalog.db import alembic_config, migration_revisions

    script = ScriptDirectory.from_config(alembic_config("sqlite://"))
    known, head = migration_revisions()
    assert known == {rev.revision for rev in script.walk_revisions()} and len(known) >= 6
    assert head == script.get_current_head() == head_revision()


def test_branched_scripts_have_no_single_head(tmp_path: Path, monkeypatch):
    """Two scripts revising one parent: no head (alembic's own refusal then speaks), the chain's
    revisions all known; a tuple down_revision (a merge) joins them into one head again."""
    import mixcount.catalog.db as db

    versions = tmp_path / "versions"
    versions.mkdir()
    for rev, down in (("a1", None), ("b1", "'a1'"), ("c1", "'a1'")):
        (versions / f"{rev}.py").write_text(f'"""{rev}"""\nrevision = "{rev}"\ndown_revision = {down}\n')
    monkeypatch.setattr(db, "MIGRATIONS_DIR", tmp_path)
    db.migration_revisions.cache_clear()
    try:
        assert db.migration_revisions() == (frozenset({"a1", "b1", "c1"}), None)
        (versions / "m1.py").write_text('revision: str = "m1"\ndown_revision = ("b1", "c1")\n')
        db.migration_revisions.cache_clear()
        assert db.migration_revisions() == (frozenset({"a1", "b1", "c1", "m1"}), "m1")
    finally:
        db.migration_revisions.cache_clear()


def test_opening_a_catalog_at_head_does_not_import_alembic(tmp_path: Path):
    """A command on a catalog already at head reads its revision with plain SQL: alembic (0.12 s of
    import, every script compiled) is loaded only to migrate. A new catalog still migrates through it."""
    import subprocess
    import sys

    path = tmp_path / "c.db"
    code = ("import sys; from mixcount.catalog.db import open_catalog; "
            f"c = open_catalog({str(path)!r}, data_dir=''); c.close(); print('alembic' in sys.modules)")
    first = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    again = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert first.stdout.split() == ["True"] and again.stdout.split() == ["False"]
