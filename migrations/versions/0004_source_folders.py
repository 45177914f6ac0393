"""source folders: settings a person stated once for a folder given to ingest (its up axis)

Revision ID: 0004
Revises: 0003
Create Date: 2026-12-04 19:20:00
"""
from alembic import op
import sqlalchemy as sa


revision = '0004'
down_revision = '0003'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        'source_folders',
        sa.Column('id', sa.Integer(), nullable=False),
        sa.Column('path', sa.Text(), nullable=False),
        sa.Column('up_axis', sa.String(length=4), nullable=True),
        sa.Column('updated_at', sa.DateTime(), nullable=True),
        sa.PrimaryKeyConstraint('id', name=op.f('pk_source_folders')),
        sa.UniqueConstraint('path', name=op.f('uq_source_folders_path')),
    )


def downgrade() -> None:
    op.drop_table('source_folders')
