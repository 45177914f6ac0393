"""Opening the catalog: resolve the URL, migrate to head with alembic, SQLite in WAL mode.

Every command calls :func:`open_catalog`, which brings the database to the newest migration before
use. The schema exists only through ``migrations/versions``; ``Base.metadata.create_all`` is never used.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from sqlalchemy import create_engine, event, inspect
from sqlalchemy.engine import Engine, make_url
from sqlalchemy.exc import OperationalError, SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from mixcount.errors import CatalogError
from mixcount.resources import data_dir

MIGRATIONS_DIR = data_dir("migrations")
DEFAULT_DB_PATH = Path("catalog") / "catalog.db"


def resolve_db_url(db: str | None = None) -> str:
    """``--db`` beats ``MIXCOUNT_DB`` beats ``catalog/catalog.db``. A plain path becomes a SQLite URL."""
    value = db or os.environ.get("MIXCOUNT_DB") or str(DEFAULT_DB_PATH)
    if "://" in value:
        return value
    return f"sqlite:///{Path(value).expanduser().resolve()}"


def _sqlite_pragmas(dbapi_conn, _record) -> None:  # type: ignore[no-untyped-def]
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA busy_timeout=30000")
    cur.execute("PRAGMA synchronous=NORMAL")
    cur.close()


def make_engine(url: str) -> Engine:
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        database = parsed.database
        if database and database != ":memory:":
            path = Path(database)
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise CatalogError(f"cannot create catalog directory {path.parent}: {exc.strerror}") from None
            if path.exists() and not os.access(path, os.W_OK):
                raise CatalogError(f"catalog database {path} is not writable")
            if not os.access(path.parent, os.W_OK):
                raise CatalogError(f"catalog directory {path.parent} is not writable")
        engine = create_engine(url, connect_args={"timeout": 30})
        event.listen(engine, "connect", _sqlite_pragmas)
        return engine
    return create_engine(url)


def alembic_config(url: str):  # type: ignore[no-untyped-def]
    from alembic.config import Config as AlembicConfig

    cfg = AlembicConfig()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return cfg


def migrate(engine: Engine) -> None:
    """Upgrade the database behind ``engine`` to the newest migration (no-op when already there)."""
    from alembic import command

    cfg = alembic_config(engine.url.render_as_string(hide_password=False))
    try:
        with engine.begin() as conn:
            cfg.attributes["connection"] = conn
            command.upgrade(cfg, "head")
    except OperationalError as exc:
        raise CatalogError(f"cannot migrate catalog database {engine.url}: {exc.orig}") from None


def current_revision(engine: Engine) -> str | None:
    from alembic.runtime.migration import MigrationContext

    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def head_revision() -> str | None:
    from alembic.script import ScriptDirectory

    return ScriptDirectory.from_config(alembic_config("sqlite://")).get_current_head()


@dataclass
class Catalog:
    """An open, migrated catalog: engine, session factory and the directory for its files."""

    url: str
    engine: Engine
    sessions: sessionmaker[Session]
    data_dir: Path

    def session(self) -> Session:
        return self.sessions()

    @property
    def collision_dir(self) -> Path:
        return self.data_dir / "collision"

    @property
    def renders_dir(self) -> Path:
        return self.data_dir / "renders"

    @property
    def usd_assets_dir(self) -> Path:
        return self.data_dir / "usd_assets"

    def close(self) -> None:
        self.engine.dispose()


def data_dir_for(url: str, configured: str) -> Path:
    """Files beside the catalog: the SQLite file's directory, else ``catalog.data_dir`` or ./catalog."""
    if configured:
        return Path(configured).expanduser().resolve()
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite" and parsed.database and parsed.database != ":memory:":
        return Path(parsed.database).resolve().parent
    return Path("catalog").resolve()


def open_catalog(db: str | None, *, data_dir: str, migrate_to_head: bool = True) -> Catalog:
    """Open (creating if needed) and migrate the catalog at ``db`` (path or SQLAlchemy URL; None = the
    default). ``data_dir``: ``catalog.data_dir`` ("" = beside the SQLite file)."""
    url = resolve_db_url(db)
    engine = make_engine(url)
    try:
        if migrate_to_head:
            migrate(engine)
        else:
            inspect(engine).get_table_names()
    except SQLAlchemyError as exc:
        engine.dispose()
        raise CatalogError(f"cannot open catalog {url}: {exc}") from None
    sessions = sessionmaker(bind=engine, expire_on_commit=False)
    return Catalog(url=url, engine=engine, sessions=sessions, data_dir=data_dir_for(url, data_dir))
