"""Catalog faults on real SQLite files: concurrent first use (N processes on a fresh file, on an old
schema, and beside a running ingest) all succeed, and files that are not a usable catalog (not SQLite,
another program's database, a newer schema, a directory) give one line naming the file, change nothing
and show no traceback."""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mixcount.catalog.db import current_revision, head_revision, open_catalog
from mixcount.cli import main

PROJECT_ROOT = Path(__file__).resolve().parent.parent

# One process of the race: wait for the shared start time, open (and migrate) the catalog, print what it saw.
OPENER = """
import json, sys, time
start = float(sys.argv[2])
while time.time() < start:
    time.sleep(0.001)
try:
    from mixcount.catalog.db import current_revision, open_catalog
    cat = open_catalog(sys.argv[1], data_dir="")
    rev = current_revision(cat.engine)
    with cat.session() as s:
        n = s.execute(__import__("sqlalchemy").text("select count(*) from objects")).scalar()
    cat.close()
    print(json.dumps({"ok": True, "revision": rev, "objects": n}))
except Exception as exc:
    print(json.dumps({"ok": False, "error": f"{type(exc).__name__}: {exc}"}))
"""


def race(db: Path, n: int, *, delay: float = 4.0) -> list[dict]:
    """Start ``n`` processes that all open ``db`` at the same moment (after their imports)."""
    start = time.time() + delay
    procs = [subprocess.Popen([sys.executable, "-c", OPENER, str(db), str(start)], cwd=PROJECT_ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(n)]
    results = []
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
        results.append(json.loads(out.strip().splitlines()[-1]))
    return results


def version_rows(db: Path) -> list[tuple]:
    with sqlite3.connect(db) as con:
        return con.execute("select version_num from alembic_version").fetchall()


def _catalog_at_revision(db: Path, revision: str) -> Path:
    """A catalog file migrated by alembic up to ``revision`` only (an older mixcount's catalog)."""
    from alembic import command
    from sqlalchemy import create_engine

    from mixcount.catalog.db import alembic_config

    engine = create_engine(f"sqlite:///{db}")
    cfg = alembic_config(f"sqlite:///{db}")
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, revision)
    engine.dispose()
    return db


def test_concurrent_first_open_of_a_fresh_catalog(tmp_path: Path) -> None:
    db = tmp_path / "fresh.db"
    results = race(db, 6)
    assert [r.get("error") for r in results if not r["ok"]] == []
    assert {r["revision"] for r in results} == {head_revision()}
    assert version_rows(db) == [(head_revision(),)]


def test_concurrent_open_of_an_old_schema_migrates_it_once(tmp_path: Path) -> None:
    db = _catalog_at_revision(tmp_path / "old.db", "0001")
    assert version_rows(db) == [("0001",)] and head_revision() != "0001"
    results = race(db, 5)
    assert [r.get("error") for r in results if not r["ok"]] == []
    assert version_rows(db) == [(head_revision(),)]


def test_concurrent_open_while_an_ingest_writes(tmp_path: Path) -> None:
    """An existing catalog, an ingest writing to it, and N processes opening it meanwhile: every opener
    succeeds, the ingest finishes and records every object once."""
    from mixcount.demo.library import generate_demo_library

    lib = tmp_path / "lib"
    truth = generate_demo_library(lib, seed=3, n_objects=10)
    db = tmp_path / "busy.db"
    open_catalog(str(db), data_dir="").close()  # an existing catalog at head
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    ingest = subprocess.Popen([sys.executable, "-m", "mixcount", "--db", str(db), "catalog", "ingest", str(lib),
                               "--workers", "1", "--json"], cwd=PROJECT_ROOT, env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and ingest.poll() is None:
            with sqlite3.connect(db, timeout=30) as con:
                if con.execute("select count(*) from objects").fetchone()[0] >= 1:
                    break
            time.sleep(0.05)
        assert ingest.poll() is None, "the openers must run while the ingest is still writing"
        results = race(db, 4, delay=0.5)
        during = ingest.poll() is None
    finally:
        out, err = ingest.communicate(timeout=600)
    assert during, "the ingest finished before the openers were done: the test did not overlap"
    assert [r.get("error") for r in results if not r["ok"]] == []
    assert ingest.returncode == 0, err
    summary = json.loads(out)
    assert summary["total"] == truth["expected"]["total"]
    with sqlite3.connect(db) as con:
        rows = con.execute("select source_id from objects").fetchall()
    assert len(rows) == len(set(rows)) == truth["expected"]["total"]


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("kind", ["text", "random", "other_program", "other_alembic", "newer", "directory"])
def test_bad_catalog_is_one_line_and_left_untouched(kind: str, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    db = tmp_path / "x.db"
    expected = {"text": "is not a SQLite database", "random": "is not a SQLite database",
                "other_program": "is a database of another program", "other_alembic": "database of another program",
                "newer": "newer than this mixcount knows", "directory": "is a directory"}[kind]
    if kind == "text":
        db.write_text("name,colour\nmug,red\n")
    elif kind == "random":
        db.write_bytes(os.urandom(4096))
    elif kind == "other_program":
        with sqlite3.connect(db) as con:
            con.execute("create table songs (id integer primary key, title text)")
            con.execute("insert into songs (title) values ('a')")
    elif kind == "other_alembic":
        with sqlite3.connect(db) as con:
            con.execute("create table alembic_version (version_num varchar(32) not null)")
            con.execute("insert into alembic_version values ('9f1c2ab34d')")
            con.execute("create table users (id integer primary key)")
    elif kind == "newer":
        open_catalog(str(db), data_dir="").close()
        with sqlite3.connect(db) as con:
            con.execute("update alembic_version set version_num = '0999'")
        with sqlite3.connect(db) as con:
            con.execute("pragma wal_checkpoint(truncate)")
    else:
        db.mkdir()
    before = None if db.is_dir() else digest(db)
    rc = main(["--db", str(db), "catalog", "list", "--summary"])
    err = capsys.readouterr().err
    assert rc == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and str(db) in lines[0], err
    assert expected in lines[0] and "sqlalche.me" not in err
    if before is not None:
        assert digest(db) == before, "a refused file must not be changed"
        assert not Path(f"{db}-wal").exists() or kind == "newer"


def test_non_sqlite_db_from_the_console_script_has_no_traceback(tmp_path: Path) -> None:
    db = tmp_path / "notes.db"
    db.write_text("not a catalog\n")
    res = subprocess.run([sys.executable, "-m", "mixcount", "--db", str(db), "catalog", "ingest", str(tmp_path)],
                         cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr and "sqlalche.me" not in res.stderr
    assert res.stderr.strip() == (f"error: {db} is not a SQLite database (file is not a database: it lacks the "
                                  "SQLite header): give --db a catalog file or a new path")
    assert db.read_text() == "not a catalog\n"


def columns(db: Path, table: str) -> list[str]:
    with sqlite3.connect(db) as con:
        return [r[1] for r in con.execute(f"pragma table_info({table})")]


def test_a_migration_failing_half_way_leaves_the_old_schema(tmp_path: Path) -> None:
    """The migration runs in one transaction: a step failing half-way (here the last revision's second
    column is already there) rolls every step back, so the catalog stays at its old revision instead of
    half-built (which no later run could migrate), and the error is one line."""
    from mixcount.errors import CatalogError

    db = _catalog_at_revision(tmp_path / "half.db", "0001")
    with sqlite3.connect(db) as con:
        con.execute("alter table objects add column proxy_vertex_count integer")  # what 0003 adds last
    before = columns(db, "objects")
    with pytest.raises(CatalogError, match="duplicate column name: proxy_vertex_count"):
        open_catalog(str(db), data_dir="")
    assert version_rows(db) == [("0001",)]
    assert columns(db, "objects") == before, "0002's columns must be rolled back with the failed 0003"
    with sqlite3.connect(db) as con:
        con.execute("alter table objects drop column proxy_vertex_count")
    cat = open_catalog(str(db), data_dir="")  # the cause removed, the same catalog migrates
    assert current_revision(cat.engine) == head_revision()
    cat.close()
