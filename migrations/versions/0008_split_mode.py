"""splits: the mode that assigned them (paper / objects / categories) and room for the extra test split names

Revision ID: 0008
Revises: 0005
Create Date: 2026-12-05 09:10:00
"""
from alembic import op
import sqlalchemy as sa


revision = '0008'
down_revision = '0005'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('splits', schema=None) as batch_op:
        batch_op.add_column(sa.Column('mode', sa.String(length=16), nullable=True))
        batch_op.alter_column('split', existing_type=sa.String(length=8), type_=sa.String(length=16),
                              existing_nullable=False)


def downgrade() -> None:
    with op.batch_alter_table('splits', schema=None) as batch_op:
        batch_op.alter_column('split', existing_type=sa.String(length=16), type_=sa.String(length=8),
                              existing_nullable=False)
        batch_op.drop_column('mode')
