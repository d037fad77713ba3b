"""Vehicles: a GPS antenna offset set per vehicle_id by an admin.

``vehicles``: ``gps_antenna_offset_m`` ({"forward", "left", "up"}, metres) applied to the
vehicle's journeys whose manifest gives none (docs/decisions/antenna-offset.md).

Revision ID: 0012
Revises: 0011
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0012"
down_revision: Union[str, Sequence[str], None] = "0011"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    op.create_table(
        "vehicles",
        sa.Column("vehicle_id", sa.String(200), primary_key=True),
        sa.Column("gps_antenna_offset_m", sa.JSON(), nullable=True),
        sa.Column("updated_by", sa.String(200), nullable=True),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
    )


def downgrade() -> None:
    op.drop_table("vehicles")
