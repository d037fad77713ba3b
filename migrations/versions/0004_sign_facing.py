"""Signs get the compass direction they face and a 95 % horizontal radius.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: Union[str, Sequence[str], None] = "0003"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    with op.batch_alter_table("journey_signs") as batch:
        batch.add_column(sa.Column("facing_deg", sa.Float, nullable=True))
        batch.add_column(sa.Column("r95_h_m", sa.Float, nullable=True))
    with op.batch_alter_table("map_signs") as batch:
        batch.add_column(sa.Column("facing_deg", sa.Float, nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("map_signs") as batch:
        batch.drop_column("facing_deg")
    with op.batch_alter_table("journey_signs") as batch:
        batch.drop_column("r95_h_m")
        batch.drop_column("facing_deg")
