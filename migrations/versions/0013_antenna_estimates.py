"""A journey's own estimate of its undeclared GPS antenna offset.

``journeys.antenna_estimate``: {"forward_m", "left_m", "sigma_forward_m", "sigma_left_m",
"n_journeys"} from the journey's turns, NULL when its offset was declared or its windows did not
turn enough; the same vehicle's later journeys combine them (docs/decisions/antenna-offset.md).

Revision ID: 0013
Revises: 0012
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0013"
down_revision: Union[str, Sequence[str], None] = "0012"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    with op.batch_alter_table("journeys") as batch:
        batch.add_column(sa.Column("antenna_estimate", sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("journeys") as batch:
        batch.drop_column("antenna_estimate")
