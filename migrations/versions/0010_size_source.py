"""objects.size_source: where an object's real size comes from (issue 70, "A size for every object")

``stated`` (a ``size`` in metadata.json or ``catalog ingest --size-of``), ``model`` (the model in its unit),
``kind`` (the typical size of its kind, mixcount/data/typical_sizes.csv: a model normalised into a unit
cube or implausible for its kind), ``none`` (no trustworthy size: the real-size scene rule refuses it);
NULL: ingested before the rule (measured again at the next ingest: the analysis version changed).

Revision ID: 0010
Revises: 0009
Create Date: 2026-12-07 03:40:00
"""
from alembic import op
import sqlalchemy as sa


revision = '0010'
down_revision = '0009'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('objects', schema=None) as batch_op:
        batch_op.add_column(sa.Column('size_source', sa.String(length=16), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('objects', schema=None) as batch_op:
        batch_op.drop_column('size_source')
