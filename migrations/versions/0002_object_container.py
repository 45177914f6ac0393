"""objects.container: whether an object is a container (plate, tray, bowl, ...) and why

Revision ID: 0002
Revises: 0001
Create Date: 2026-12-02 10:00:00.000000
"""
from alembic import op
import sqlalchemy as sa


revision = '0002'
down_revision = '0001'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('objects', schema=None) as batch_op:
        batch_op.add_column(sa.Column('container', sa.Boolean(), nullable=False, server_default=sa.false()))
        batch_op.add_column(sa.Column('container_reason', sa.Text(), nullable=True))
        batch_op.create_index(batch_op.f('ix_objects_container'), ['container'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('objects', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_objects_container'))
        batch_op.drop_column('container_reason')
        batch_op.drop_column('container')
