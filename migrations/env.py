"""Alembic environment for the mixcount catalog.

Used through alembic's API (``mixcount.catalog.db.migrate``) or the alembic CLI
(``alembic -c migrations/alembic.ini -x db=sqlite:///catalog/catalog.db upgrade head``).
SQLite needs batch mode to alter tables; constraint names come from the models' naming convention.
"""

from __future__ import annotations

from alembic import context
from sqlalchemy import create_engine

from mixcount.catalog.models import Base

config = context.config
target_metadata = Base.metadata


def _url() -> str:
    xargs = context.get_x_argument(as_dictionary=True)
    return xargs.get("db") or config.get_main_option("sqlalchemy.url")


def run_migrations_offline() -> None:
    context.configure(url=_url(), target_metadata=target_metadata, literal_binds=True, render_as_batch=True)
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        context.configure(connection=connection, target_metadata=target_metadata, render_as_batch=True)
        with context.begin_transaction():
            context.run_migrations()
        return
    engine = create_engine(_url())
    with engine.connect() as conn:
        context.configure(connection=conn, target_metadata=target_metadata, render_as_batch=True)
        with context.begin_transaction():
            context.run_migrations()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
