"""The asset catalog: SQLAlchemy 2 models, alembic-migrated engine, ingest, curation, splits."""
