"""collision proxy per object (convex hull with a bounded vertex count)

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-30 13:40:00
"""
from alembic import op
import sqlalchemy as sa


revision = '0003'
down_revision = '0002'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('objects', schema=None) as batch_op:
        batch_op.add_column(sa.Column('proxy_path', sa.Text(), nullable=True))
        batch_op.add_column(sa.Column('proxy_vertex_count', sa.Integer(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('objects', schema=None) as batch_op:
        batch_op.drop_column('proxy_vertex_count')
        batch_op.drop_column('proxy_path')
