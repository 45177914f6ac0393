"""One catalog, several writers (issue 68, item 5), with real processes on a real SQLite catalog migrated
by alembic: a command that writes the catalog waits for another writer up to ``catalog.writer_wait_s``,
then stops with one line naming that process (pid, command, since when), never a traceback; a reader
(``catalog list``) does not wait even while the writer holds an open SQLite write transaction; a writer
that finds the lock let go within its wait goes on; a ``database is locked`` from a program without the
writer lock is one line too."""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mixcount.catalog.db import open_catalog, writer_lock_path
from mixcount.cli import main

PROJECT_ROOT = Path(__file__).resolve().parent.parent

# A writer that holds the catalog: takes the writer lock as `mixcount catalog filter` would, opens a SQLite
# write transaction (BEGIN IMMEDIATE: SQLite's own write lock too), says "held", keeps both for argv[2]
# seconds, then closes the catalog.
HOLDER = """
import sys, time
from mixcount.catalog.db import Writer, open_catalog
cat = open_catalog(sys.argv[1], data_dir="", writer=Writer(command="mixcount catalog filter", wait_s=0))
conn = cat.engine.connect()
conn.exec_driver_sql("BEGIN IMMEDIATE")
conn.exec_driver_sql("UPDATE objects SET name = name")
print("held", flush=True)
time.sleep(float(sys.argv[2]))
conn.exec_driver_sql("ROLLBACK")
conn.close()
cat.close()
print("released", flush=True)
"""


@pytest.fixture()
def db(tmp_path: Path) -> Path:
    path = tmp_path / "catalog.db"
    open_catalog(str(path), data_dir="").close()  # created and migrated to head by alembic
    return path


def _holder(db: Path, seconds: float) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(db), str(seconds)], cwd=PROJECT_ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.strip() == "held", proc.stderr.read() if proc.stderr else ""
    return proc


def _mixcount(*args: str) -> tuple[subprocess.CompletedProcess, float]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    t0 = time.monotonic()
    res = subprocess.run([sys.executable, "-m", "mixcount", *args], cwd=PROJECT_ROOT, env=env,
                         capture_output=True, text=True, timeout=300)
    return res, time.monotonic() - t0


def test_second_writer_stops_with_one_line_naming_the_first_and_readers_do_not_wait(db: Path) -> None:
    holder = _holder(db, 60)
    try:
        held = json.loads(writer_lock_path(db).read_text())
        assert held["pid"] == holder.pid and held["command"] == "mixcount catalog filter"
        # a reader, while the writer holds the lock and an open write transaction: no wait at all
        reader, read_s = _mixcount("--db", str(db), "--set", "catalog.writer_wait_s=120", "catalog", "list", "--json")
        assert reader.returncode == 0, reader.stderr
        assert json.loads(reader.stdout) == [] and "waiting" not in reader.stderr
        # the second writer: waits its 2 s, then one line naming the first one
        writer, write_s = _mixcount("--db", str(db), "--set", "catalog.writer_wait_s=2", "catalog", "filter")
        assert holder.poll() is None, "the holder must still hold the catalog"
    finally:
        holder.kill()
        holder.communicate()
    assert read_s < 30  # import time only (the writer waits 120 s with this config before it gives up)
    assert writer.returncode == 2 and "Traceback" not in writer.stderr
    errors = [ln for ln in writer.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1, writer.stderr
    assert f"pid {holder.pid}" in errors[0] and "`mixcount catalog filter`" in errors[0] and "since " in errors[0]
    assert "catalog.writer_wait_s" in errors[0]
    assert f"waiting up to 2 s for the catalog's other writer: pid {holder.pid}" in writer.stderr
    assert 2.0 <= write_s < 2.0 + 30  # the bounded wait, then the stop (plus the interpreter's start)
    print(f"reader {read_s:.1f} s; second writer stopped after {write_s:.1f} s: {errors[0]}")


def test_a_writer_goes_on_when_the_other_lets_go_within_its_wait(db: Path) -> None:
    holder = _holder(db, 4)
    try:
        writer, write_s = _mixcount("--db", str(db), "--set", "catalog.writer_wait_s=120", "catalog", "split")
        out, _ = holder.communicate(timeout=60)
    finally:
        holder.kill()
    assert "released" in out
    assert writer.returncode == 0, writer.stderr
    assert "waiting up to 120 s for the catalog's other writer" in writer.stderr and "no leaks" in writer.stdout
    assert writer_lock_path(db).read_text() == ""  # let go: no stale holder left in the file


def test_locked_by_a_program_without_the_writer_lock_is_one_line(db: Path, monkeypatch, capsys) -> None:
    import mixcount.catalog.db as dbmod

    monkeypatch.setattr(dbmod, "BUSY_TIMEOUT_S", 0.5)
    other = sqlite3.connect(db, isolation_level=None)  # another program holding SQLite's write lock
    other.execute("BEGIN IMMEDIATE")
    other.execute("UPDATE objects SET name = name")
    try:
        from mixcount.catalog.models import IngestRun

        cat = open_catalog(str(db), data_dir="")
        with cat.session() as s:
            s.add(IngestRun(paths="[]", status="running"))
            with pytest.raises(Exception) as caught:
                s.commit()
        cat.close()
    finally:
        other.execute("ROLLBACK")
        other.close()
    from mixcount.errors import CatalogError

    assert isinstance(caught.value, CatalogError), repr(caught.value)
    text = str(caught.value)
    assert "\n" not in text and "stayed locked by another process" in text and str(db) in text
    assert main(["--db", str(db), "catalog", "list"]) == 0  # and usable again once the other let go


def test_one_process_shares_its_lock_and_lets_go_of_it(db: Path) -> None:
    """Two catalogs of one process opened for writing share its lock; the lock goes with the last close, or
    with a catalog dropped unclosed; a process forked by the writer (ingest's analysis pool) does not hold it."""
    import gc

    from mixcount.catalog.db import Writer

    probe = ("import fcntl, os, sys\nfd = os.open(sys.argv[1], os.O_RDWR)\ntry:\n"
             "    fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)\nexcept OSError:\n    sys.exit(1)\n")

    def free() -> bool:  # what another process finds: can it take the lock now?
        return subprocess.run([sys.executable, "-c", probe, str(writer_lock_path(db))]).returncode == 0

    writer = Writer(command="mixcount catalog render", wait_s=0)
    first = open_catalog(str(db), data_dir="", writer=writer)
    t0 = time.monotonic()
    second = open_catalog(str(db), data_dir="", writer=writer)
    assert time.monotonic() - t0 < 5 and not free()
    first.close()
    assert not free() and json.loads(writer_lock_path(db).read_text())["pid"] == os.getpid()
    second.close()
    assert free() and writer_lock_path(db).read_text() == ""
    dropped = open_catalog(str(db), data_dir="", writer=writer)
    assert not free()
    child = os.fork()  # a forked child (a pool worker) outliving its parent's hold
    if child == 0:
        time.sleep(30)
        os._exit(0)
    try:
        del dropped
        gc.collect()
        assert free()  # the child still runs, and does not hold the parent's lock
    finally:
        os.kill(child, 9)
        os.waitpid(child, 0)
