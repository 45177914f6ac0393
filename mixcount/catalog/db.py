"""Opening the catalog: resolve the URL, migrate to head with alembic, SQLite in WAL mode.

Every command calls :func:`open_catalog`, which brings the database to the newest migration before
use. The schema exists only through ``migrations/versions``; ``Base.metadata.create_all`` is never used.

Concurrent first use (two terminals, a job array) is safe: a catalog already at head is only read; one
that needs migrating is migrated inside one ``BEGIN IMMEDIATE`` transaction, so SQLite's own write lock
lets one process migrate while the others wait (up to :data:`MIGRATION_WAIT_S`), then find it at head.
The DDL is inside that transaction too, so a migration killed half-way leaves the old schema, never a
half-built one. Every connection waits up to :data:`BUSY_TIMEOUT_S` for a lock another process holds.
A file that is not a mixcount catalog (not SQLite, another program's database, a newer schema) is
refused with one line naming the file and the problem (docs/faults.md).

One catalog, several writers: a command that writes the catalog opens it with a :class:`Writer`, which
takes an exclusive lock (POSIX ``lockf``) on ``<catalog>.writer`` beside the database for as long as the catalog is open
and writes the holder's pid, command and start time into it. A second writer waits for it up to
``catalog.writer_wait_s``, then stops with one line naming the holder (:class:`CatalogBusyError`); SQLite's
own lock is then never fought over for minutes (two ``catalog filter`` runs died after 1 m 52 s with
``database is locked``). Readers take no lock and never wait (WAL). A ``database is locked`` that still
reaches a statement (another program, an old mixcount) becomes one line, a :class:`CatalogError`. The lock
is the kernel's and the process's own: it ends with the process that held it, whatever killed it, and the
processes it forks (ingest's analysis pool) do not hold it (a ``flock`` would be shared with them, and kept
by a pool worker that outlives a killed ingest).
"""

from __future__ import annotations

import ast
import errno
import hashlib
import json
import os
import re
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Optional

from sqlalchemy import create_engine, event, inspect
from sqlalchemy.engine import Engine, make_url
from sqlalchemy.exc import DBAPIError, OperationalError, SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import NullPool

from mixcount.errors import CatalogBusyError, CatalogError
from mixcount.resources import data_dir

MIGRATIONS_DIR = data_dir("migrations")
DEFAULT_DB_PATH = Path("catalog") / "catalog.db"
BUSY_TIMEOUT_S = 30.0  # every connection: how long one statement waits for another process's lock
MIGRATION_WAIT_S = 300.0  # how long a process waits for another one's migration before giving up
OWN_TABLES = ("objects", "ingest_runs")  # tables every mixcount schema revision has


def resolve_db_url(db: str | None = None) -> str:
    """``--db`` beats ``MIXCOUNT_DB`` beats ``catalog/catalog.db``. A plain path becomes a SQLite URL."""
    value = db or os.environ.get("MIXCOUNT_DB") or str(DEFAULT_DB_PATH)
    if "://" in value:
        return value
    return f"sqlite:///{Path(value).expanduser().resolve()}"


WAL_TRY_MS = 200  # one try of the WAL switch waits this long for the lock before it lets go and retries


def _switch_to_wal(cur: Any) -> None:
    """``PRAGMA journal_mode=WAL``, retried for up to :data:`BUSY_TIMEOUT_S`. The switch needs an exclusive
    lock: processes opening a rollback-journal catalog at once (an older mixcount's file) each hold a shared
    lock while they wait for it, so one long wait could only time out (seen as "database is locked" from
    tests/test_faults_catalog.py's race on a loaded machine). A short wait, then letting go and trying again
    after a pause that differs per process, lets one of them win; the others then find WAL already on."""
    deadline = time.monotonic() + BUSY_TIMEOUT_S
    cur.execute(f"PRAGMA busy_timeout={WAL_TRY_MS}")
    while True:
        try:
            cur.execute("PRAGMA journal_mode=WAL")
            return
        except Exception as exc:  # sqlite3.OperationalError: the DB-API connection, not SQLAlchemy's
            if not _is_locked(exc) or time.monotonic() > deadline:
                raise
            time.sleep(0.02 + (os.getpid() % 10) * 0.02)


def _sqlite_pragmas(dbapi_conn, _record) -> None:  # type: ignore[no-untyped-def]
    cur = dbapi_conn.cursor()
    _switch_to_wal(cur)
    cur.execute(f"PRAGMA busy_timeout={int(BUSY_TIMEOUT_S * 1000)}")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA synchronous=NORMAL")
    cur.close()


def sqlite_file(url: str) -> Optional[Path]:
    """The database file of a SQLite URL (None for another backend or an in-memory database)."""
    parsed = make_url(url)
    if parsed.get_backend_name() != "sqlite" or not parsed.database or parsed.database == ":memory:":
        return None
    return Path(parsed.database)


def make_engine(url: str) -> Engine:
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        database = parsed.database
        if database and database != ":memory:":
            path = Path(database)
            if path.is_dir():
                raise CatalogError(f"catalog database {path} is a directory, not a file: give --db a file path")
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise CatalogError(f"cannot create catalog directory {path.parent}: {exc.strerror}") from None
            if path.exists() and not os.access(path, os.W_OK):
                raise CatalogError(f"catalog database {path} is not writable")
            if not os.access(path.parent, os.W_OK):
                raise CatalogError(f"catalog directory {path.parent} is not writable")
        engine = create_engine(url, connect_args={"timeout": BUSY_TIMEOUT_S})
        event.listen(engine, "connect", _sqlite_pragmas)
        event.listen(engine, "handle_error", _damaged_as_catalog_error)
        return engine
    return create_engine(url)


def is_damage(exc: BaseException) -> bool:
    """True for SQLite's own word that the file is damaged (SQLITE_CORRUPT, SQLITE_NOTADB), whenever it is
    found: a damaged page is only read, and only then reported, by the statement that needs it."""
    orig = getattr(exc, "orig", None) or exc
    name = str(getattr(orig, "sqlite_errorname", "") or "")
    if name.startswith(("SQLITE_CORRUPT", "SQLITE_NOTADB")):
        return True
    low = str(orig).lower()
    return "disk image is malformed" in low or "file is not a database" in low


def damaged_line(where: Path | str, text: str) -> str:
    """One line for a damaged catalog: the file, SQLite's words, and how to get a usable catalog back."""
    import shlex

    if isinstance(where, Path):
        fixed = where.with_name(f"{where.stem}-recovered{where.suffix or '.db'}")
        return (f"catalog {where} is damaged ({text}): stop every run that uses it, then copy out what is "
                f"readable with `sqlite3 {shlex.quote(str(where))} .recover | sqlite3 {shlex.quote(str(fixed))}` "
                f"and use --db {shlex.quote(str(fixed))}, or restore {where} from a backup")
    return f"catalog {where} is damaged ({text}): restore it from a backup"


def _damaged_as_catalog_error(context: Any) -> None:
    """SQLAlchemy ``handle_error`` hook: a damaged SQLite file found by any statement, at any time
    (``catalog list`` reading a damaged page), becomes a :class:`CatalogError` of one line; so does a
    ``database is locked`` after :data:`BUSY_TIMEOUT_S` (a writer that does not take the writer lock:
    another program, an older mixcount)."""
    orig = context.original_exception
    url = str(context.engine.url) if context.engine is not None else ""
    text = str(orig).strip().splitlines()[0] if str(orig).strip() else type(orig).__name__
    if is_damage(orig):
        raise CatalogError(damaged_line(sqlite_file(url) or "database", text))
    if _is_locked(orig):
        raise CatalogError(locked_line(sqlite_file(url) or "database", text))


def locked_line(where: Path | str, text: str) -> str:
    """One line for a catalog that SQLite kept locked longer than :data:`BUSY_TIMEOUT_S`."""
    return (f"catalog {where} stayed locked by another process for {BUSY_TIMEOUT_S:.0f} s ({text}): a program "
            "that writes it without mixcount's writer lock; try again when it is done")


def alembic_config(url: str):  # type: ignore[no-untyped-def]
    from alembic.config import Config as AlembicConfig

    cfg = AlembicConfig()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return cfg


def _migration_engine(url: str) -> Engine:
    """A one-connection engine whose transactions start with ``BEGIN IMMEDIATE`` (SQLite takes its
    write lock at the start, so concurrent migrators queue there) and hold the DDL too: pysqlite's own
    transaction handling is switched off on it, as the SQLAlchemy pysqlite documentation describes."""
    engine = create_engine(url, connect_args={"timeout": BUSY_TIMEOUT_S}, poolclass=NullPool)

    def on_connect(dbapi_conn, record) -> None:  # type: ignore[no-untyped-def]
        _sqlite_pragmas(dbapi_conn, record)
        dbapi_conn.isolation_level = None

    event.listen(engine, "connect", on_connect)
    event.listen(engine, "begin", lambda conn: conn.exec_driver_sql("BEGIN IMMEDIATE"))
    return engine


def _is_locked(exc: BaseException) -> bool:
    text = str(getattr(exc, "orig", exc)).lower()
    return "database is locked" in text or "database is busy" in text


def _upgrade(conn: Any) -> None:
    from alembic import command

    cfg = alembic_config(conn.engine.url.render_as_string(hide_password=False))
    cfg.attributes["connection"] = conn
    command.upgrade(cfg, "head")


def migrate(engine: Engine, *, wait_s: float = MIGRATION_WAIT_S) -> None:
    """Upgrade the database behind ``engine`` to the newest migration (no-op when already there).

    A SQLite catalog is migrated in one ``BEGIN IMMEDIATE`` transaction: a process that finds another
    one migrating waits for it (up to ``wait_s`` seconds), then finds the catalog at head."""
    url = engine.url.render_as_string(hide_password=False)
    head = head_revision()
    check_known_catalog(engine, head)
    if head is not None and current_revision(engine) == head:
        return
    if sqlite_file(url) is None:
        try:
            with engine.begin() as conn:
                _upgrade(conn)
        except OperationalError as exc:
            raise CatalogError(f"cannot migrate catalog database {engine.url}: {exc.orig}") from None
        return
    deadline = time.monotonic() + wait_s
    mig = _migration_engine(url)
    try:
        while True:
            try:
                with mig.begin() as conn:  # BEGIN IMMEDIATE: waits for another migrator's commit
                    from alembic.runtime.migration import MigrationContext

                    if MigrationContext.configure(conn).get_current_revision() != head:
                        _upgrade(conn)
                return
            except OperationalError as exc:
                if not _is_locked(exc):
                    raise CatalogError(f"cannot migrate catalog database {sqlite_file(url)}: {exc.orig}") from None
                if time.monotonic() > deadline:
                    raise CatalogError(
                        f"catalog database {sqlite_file(url)} stayed locked by another process for "
                        f"{wait_s:.0f} s while this one waited to migrate it; try again when that one is done"
                    ) from None
                time.sleep(0.2)
    finally:
        mig.dispose()


SQLITE_HEADER = b"SQLite format 3\x00"


def check_known_catalog(engine: Engine, head: Optional[str]) -> None:
    """Refuse, with one line, a database that is not a mixcount catalog this version can use: one of
    another program (tables but no mixcount schema version) or one with a newer schema revision."""
    with engine.connect() as conn:
        tables = set(inspect(conn).get_table_names())
        revisions = _stored_revisions(conn) if "alembic_version" in tables else ()
    _refuse_unknown(str(sqlite_file(str(engine.url)) or engine.url), tables, tuple(revisions), head)


def check_sqlite_file(path: Path, head: Optional[str]) -> None:
    """:func:`check_known_catalog` for an existing SQLite file, read through a read-only connection
    before anything else opens it: a file that is not a catalog is refused without a byte of it changed
    (an ordinary connection would switch it to WAL mode first)."""
    import sqlite3

    try:
        with open(path, "rb") as fh:
            header = fh.read(len(SQLITE_HEADER))
    except OSError as exc:
        raise CatalogError(f"cannot read catalog database {path}: {exc.strerror}") from None
    if not header:
        return  # an empty file is a new catalog
    if header != SQLITE_HEADER:
        raise CatalogError(f"{path} is not a SQLite database (file is not a database: it lacks the SQLite "
                           "header): give --db a catalog file or a new path")
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=BUSY_TIMEOUT_S)
        try:
            tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            revisions: tuple[str, ...] = ()
            if "alembic_version" in tables:
                revisions = tuple(str(r[0]) for r in con.execute("SELECT version_num FROM alembic_version"))
        finally:
            con.close()
    except sqlite3.DatabaseError as exc:
        raise CatalogError(describe_database_error(f"sqlite:///{path}", exc)) from None
    _refuse_unknown(str(path), tables, revisions, head)


def _refuse_unknown(where: str, tables: set[str], revisions: tuple[str, ...], head: Optional[str]) -> None:
    tables = {t for t in tables if not t.startswith("sqlite_")}
    if not tables:
        return  # a new, empty catalog
    if "alembic_version" not in tables:
        shown = ", ".join(sorted(tables)[:6]) + (", ..." if len(tables) > 6 else "")
        raise CatalogError(f"{where} is a database of another program, not a mixcount catalog "
                           f"(tables {shown}; no schema version): give --db a new path or a catalog file")
    known = migration_revisions()[0]
    unknown = [r for r in revisions if r not in known]
    if not unknown:
        return
    if set(OWN_TABLES) <= tables:
        raise CatalogError(f"catalog {where} has schema revision {unknown[0]!r}, newer than this mixcount knows "
                           f"(its newest is {head!r}): it was written by a newer mixcount; upgrade mixcount to use it")
    raise CatalogError(f"{where} is a database of another program, not a mixcount catalog (schema revision "
                       f"{unknown[0]!r} is not mixcount's): give --db a new path or a catalog file")


def _stored_revisions(conn: Any) -> tuple[str, ...]:
    """The revisions in the database's ``alembic_version`` table (which must exist), as alembic's
    ``MigrationContext.get_current_heads`` reads them."""
    return tuple(str(r[0]) for r in conn.exec_driver_sql("SELECT version_num FROM alembic_version"))


def current_revision(engine: Engine) -> str | None:
    """The database's schema revision; None for a database without one (new). Read with plain SQL, as
    alembic's ``MigrationContext.get_current_revision`` reads it (which raises for a branched database with
    several: so does this)."""
    with engine.connect() as conn:
        if "alembic_version" not in set(inspect(conn).get_table_names()):
            return None
        revisions = _stored_revisions(conn)
    if len(revisions) > 1:
        raise CatalogError(f"catalog database {sqlite_file(str(engine.url)) or engine.url} has several schema "
                           f"revisions {list(revisions)}: it is not a catalog this mixcount can use")
    return revisions[0] if revisions else None


@lru_cache(maxsize=1)
def migration_revisions() -> tuple[frozenset[str], Optional[str]]:
    """(every revision, the head revision) of the migration scripts in ``migrations/versions``, from each
    script's ``revision`` and ``down_revision`` assignments, once per process.

    Alembic's own reading (``ScriptDirectory``) imports alembic (0.12 s) and compiles every script on each
    call (30 ms): every command paid both to learn that its catalog is already at head, and an in-process
    test run paid the scripts again on each open (41 CPU-seconds of the suite, docs/testing.md). Alembic
    itself is still what migrates a catalog that is not at head. tests/test_migrations.py holds this equal
    to ``ScriptDirectory``'s revisions and head. Several heads (a branch) give None, as no single head;
    :func:`migrate` then hands the catalog to alembic, which says why."""
    revisions: dict[str, tuple[str, ...]] = {}
    for script in sorted((MIGRATIONS_DIR / "versions").glob("*.py")):
        values: dict[str, Any] = {}
        for node in ast.parse(script.read_text(encoding="utf-8")).body:
            if (isinstance(node, (ast.Assign, ast.AnnAssign)) and len(targets := getattr(node, "targets", None)
                                                                     or [node.target]) == 1
                    and isinstance(targets[0], ast.Name) and targets[0].id in ("revision", "down_revision")
                    and node.value is not None):
                values[targets[0].id] = ast.literal_eval(node.value)
        if "revision" not in values:
            continue  # not a migration script
        down = values.get("down_revision")
        revisions[str(values["revision"])] = tuple(down) if isinstance(down, (tuple, list)) else ((down,) if down else ())
    below = {d for downs in revisions.values() for d in downs}
    heads = [r for r in revisions if r not in below]
    return frozenset(revisions), (heads[0] if len(heads) == 1 else None)


def head_revision() -> str | None:
    """The newest migration's revision (:func:`migration_revisions`)."""
    return migration_revisions()[1]


WRITER_POLL_S = 0.2  # a waiting writer tries the lock this often


@dataclass(frozen=True)
class Writer:
    """A catalog opened for writing: ``command`` (as the user typed it, ``mixcount catalog filter``) is
    written into the lock for whoever waits; ``wait_s`` (``catalog.writer_wait_s``) bounds the wait for
    another writer; ``on_wait`` is told once, with one line, that this process waits and for whom."""

    command: str
    wait_s: float
    on_wait: Optional[Callable[[str], None]] = None


def writer_lock_path(db_path: Path) -> Path:
    """The writer lock of the SQLite catalog ``db_path``: ``catalog.db`` -> ``catalog.db.writer``."""
    return db_path.with_name(db_path.name + ".writer")


def read_holder(lock_path: Path) -> dict[str, Any]:
    """What the writer holding ``lock_path`` wrote into it (pid, command, since, host); {} when unreadable
    or not yet written (the holder writes it right after taking the lock)."""
    try:
        data = json.loads(lock_path.read_text(encoding="utf-8") or "{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def holder_text(holder: dict[str, Any], now: float | None = None) -> str:
    """``pid 1234 (`mixcount catalog filter`, since 03:12:05 UTC, 2 min ago)`` for a holder record."""
    if not holder:
        return "another process (it has not written its name yet)"
    parts = [f"`{holder['command']}`"] if holder.get("command") else []
    started = holder.get("started")
    if isinstance(started, (int, float)):
        ago = max(0.0, (time.time() if now is None else now) - float(started))
        clock = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(float(started)))
        parts.append(f"since {clock}, {ago / 60:.0f} min ago" if ago >= 90 else f"since {clock}, {ago:.0f} s ago")
    host = holder.get("host")
    where = f" on {host}" if host and host != _hostname() else ""
    return f"pid {holder.get('pid', '?')}{where}" + (f" ({', '.join(parts)})" if parts else "")


def _hostname() -> str:
    import socket

    return socket.gethostname()


@dataclass
class _HeldLock:
    """A writer lock this process holds: the open lock file and how many open catalogs share it."""

    fd: int
    users: int = 1


_HELD: dict[Path, _HeldLock] = {}  # lock file -> this process's hold on it (one lock per process and file)


def _let_go(path: Path) -> None:
    """One user fewer of this process's writer lock ``path``; the last one lets the lock go."""
    held = _HELD.get(path)
    if held is None:
        return
    held.users -= 1
    if held.users > 0:
        return
    del _HELD[path]
    import fcntl

    try:
        os.ftruncate(held.fd, 0)  # no stale holder is shown to the next one who reads it
        fcntl.lockf(held.fd, fcntl.LOCK_UN)
    except OSError:
        pass
    finally:
        os.close(held.fd)


@dataclass
class WriterLock:
    """The writer lock held for one open catalog (:meth:`release`, or its garbage collection, lets it go).
    Two catalogs of one process opened for writing on one file share the process's lock (POSIX locks
    belong to the process, and closing any descriptor of the file would let it go)."""

    path: Path
    _finalizer: Any = field(default=None, repr=False)

    def __post_init__(self) -> None:
        import weakref

        self._finalizer = weakref.finalize(self, _let_go, self.path)

    def release(self) -> None:
        self._finalizer()


def take_writer_lock(db_path: Path, writer: Writer) -> WriterLock:
    """Take the writer lock of the catalog ``db_path`` (module docstring), waiting up to ``writer.wait_s``
    for the process that holds it; :class:`CatalogBusyError` (one line naming that process) after that."""
    import fcntl

    path = writer_lock_path(db_path).resolve()
    if path in _HELD:  # this process writes it already (another open catalog): shared
        _HELD[path].users += 1
        return WriterLock(path)
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise CatalogError(f"cannot open the catalog's writer lock {path}: {exc.strerror} (a command that writes "
                           "the catalog needs its folder writable)") from None
    start = time.monotonic()
    told = False
    try:
        while True:
            try:
                fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError as exc:
                if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise CatalogError(f"cannot lock the catalog's writer lock {path}: {exc.strerror}") from None
            waited = time.monotonic() - start
            if waited >= writer.wait_s:
                holder = read_holder(path)
                raise CatalogBusyError(
                    f"catalog {db_path} is being written by {holder_text(holder)}; waited {waited:.0f} s for it "
                    f"(catalog.writer_wait_s = {writer.wait_s:g}): run this again when it is done, or wait longer "
                    f"with --set catalog.writer_wait_s=SECONDS", holder)
            if not told and writer.on_wait is not None:
                writer.on_wait(f"waiting up to {writer.wait_s - waited:.0f} s for the catalog's other writer: "
                               f"{holder_text(read_holder(path))}")
                told = True
            time.sleep(min(WRITER_POLL_S, max(0.0, writer.wait_s - waited)))
    except BaseException:
        os.close(fd)
        raise
    record = {"pid": os.getpid(), "command": writer.command, "started": round(time.time(), 3), "host": _hostname()}
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(record).encode("utf-8"), 0)
    except OSError:
        pass  # the lock itself holds; only its description is missing
    _HELD[path] = _HeldLock(fd)
    return WriterLock(path)


@dataclass
class Catalog:
    """An open, migrated catalog: engine, session factory and the directory for its files.

    Several catalogs may share one ``data_dir`` (two database files in one folder, or one configured
    ``catalog.data_dir``). Files named by a row id or derived from a row's settings (canonical renders,
    USD assets, staged model links) therefore live in a folder of their own per catalog,
    ``<kind>/<files_key>/``; files named by a hash of what they hold (collision meshes, proxies, descriptor
    caches) are shared, since equal names mean equal contents."""

    url: str
    engine: Engine
    sessions: sessionmaker[Session]
    data_dir: Path
    files_key: str
    writer: Optional[WriterLock] = None  # held while open by a catalog opened for writing

    def session(self) -> Session:
        return self.sessions()

    @property
    def collision_dir(self) -> Path:
        return self.data_dir / "collision"

    @property
    def renders_dir(self) -> Path:
        return self.data_dir / "renders" / self.files_key

    @property
    def usd_assets_dir(self) -> Path:
        return self.data_dir / "usd_assets" / self.files_key

    @property
    def staged_dir(self) -> Path:
        return self.data_dir / "staged" / self.files_key

    def close(self) -> None:
        self.engine.dispose()
        if self.writer is not None:
            self.writer.release()


def data_dir_for(url: str, configured: str) -> Path:
    """Files beside the catalog: the SQLite file's directory, else ``catalog.data_dir`` or ./catalog."""
    if configured:
        return Path(configured).expanduser().resolve()
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite" and parsed.database and parsed.database != ":memory:":
        return Path(parsed.database).resolve().parent
    return Path("catalog").resolve()


def files_key_for(url: str, configured: str) -> str:
    """The name of this catalog's own folders under its data folder (see :class:`Catalog`): the SQLite
    file's name without suffix (``catalog.db`` -> ``catalog``), unique among the database files of one
    folder. When the data folder is configured (shared by catalogs of other folders) or the database is
    not a SQLite file, a short hash of the database's resolved location follows, so two catalogs never
    share a key."""
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite" and parsed.database and parsed.database != ":memory:":
        path = Path(parsed.database).resolve()
        stem = re.sub(r"[^A-Za-z0-9._-]+", "_", path.stem) or "catalog"
        if not configured:
            return stem
        where = str(path)
    else:
        stem = re.sub(r"[^A-Za-z0-9._-]+", "_", parsed.database or parsed.get_backend_name()) or "catalog"
        where = parsed.render_as_string(hide_password=True)
    return f"{stem}-{hashlib.sha256(where.encode()).hexdigest()[:8]}"


def describe_database_error(url: str, exc: BaseException) -> str:
    """One line for a database error at open time: the file and what is wrong with it."""
    orig = getattr(exc, "orig", None) or exc
    text = str(orig).strip().splitlines()[0] if str(orig).strip() else type(orig).__name__
    where = sqlite_file(url) or make_url(url).render_as_string(hide_password=True)
    low = text.lower()
    if "file is not a database" in low or "not a database" in low:
        return f"{where} is not a SQLite database ({text}): give --db a catalog file or a new path"
    if "malformed" in low or "corrupt" in low:
        return damaged_line(where, text)
    if _is_locked(exc):
        return locked_line(where, text)
    if "unable to open" in low:
        return f"cannot open catalog {where} ({text}): check that its folder exists and is writable"
    return f"cannot open catalog {where}: {text}"


def open_catalog(db: str | None, *, data_dir: str, migrate_to_head: bool = True,
                 writer: Optional[Writer] = None) -> Catalog:
    """Open (creating if needed) and migrate the catalog at ``db`` (path or SQLAlchemy URL; None = the
    default). ``data_dir``: ``catalog.data_dir`` ("" = beside the SQLite file). A database that is not a
    usable mixcount catalog raises :class:`CatalogError` with one line naming the file and the problem.
    ``writer``: this process will write the catalog: its writer lock is taken first (waiting for another
    writer, module docstring) and held until :meth:`Catalog.close`."""
    url = resolve_db_url(db)
    path = sqlite_file(url)
    if path is not None and path.is_file():
        check_sqlite_file(path, head_revision())
    engine = make_engine(url)
    lock = None
    if writer is not None and path is not None:
        try:
            lock = take_writer_lock(path, writer)
        except BaseException:
            engine.dispose()
            raise
    try:
        return _opened(url, engine, data_dir, migrate_to_head, lock)
    except BaseException:
        if lock is not None:
            lock.release()
        raise


def _opened(url: str, engine: Engine, data_dir: str, migrate_to_head: bool, lock: Optional[WriterLock]) -> Catalog:
    """:func:`open_catalog` after the writer lock: migrate (or only look), then the :class:`Catalog`."""
    try:
        if migrate_to_head:
            migrate(engine)
        else:
            inspect(engine).get_table_names()
    except CatalogError:
        engine.dispose()
        raise
    except (SQLAlchemyError, DBAPIError) as exc:
        engine.dispose()
        raise CatalogError(describe_database_error(url, exc)) from None
    except Exception as exc:  # alembic's CommandError (e.g. an unknown revision) and the like
        engine.dispose()
        if type(exc).__module__.startswith("alembic"):
            raise CatalogError(f"cannot migrate catalog {sqlite_file(url) or url}: {exc}") from None
        raise
    sessions = sessionmaker(bind=engine, expire_on_commit=False)
    return Catalog(url=url, engine=engine, sessions=sessions, data_dir=data_dir_for(url, data_dir),
                   files_key=files_key_for(url, data_dir), writer=lock)
