"""environments / materials: the decode check made when they enter the catalog (issue 68, "Decode before use")

``checked_at`` is when ingest decoded the files (NULL: ingested before the check, decoded at the next
ingest of the same files); ``broken`` is why they did not decode (NULL: whole), and a broken row is never
drawn for a scene.

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-07 03:20:00
"""
from alembic import op
import sqlalchemy as sa


revision = '0009'
down_revision = '0008'
branch_labels = None
depends_on = None


def upgrade() -> None:
    for table in ('environments', 'materials'):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.add_column(sa.Column('broken', sa.Text(), nullable=True))
            batch_op.add_column(sa.Column('checked_at', sa.DateTime(), nullable=True))


def downgrade() -> None:
    for table in ('environments', 'materials'):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_column('checked_at')
            batch_op.drop_column('broken')
