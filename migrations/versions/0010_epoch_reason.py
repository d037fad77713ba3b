"""Lens changes: why a calibration epoch started.

``calibrations.epoch_reason``: set on the first self-calibration of an epoch that a lens change
started (frames of another size, or ``calibration_epoch_confirm`` journeys agreeing with each
other and differing from the epoch's calibration); NULL otherwise
(``jobs.state.lens_change``, docs/decisions/registered-calibration.md).

Revision ID: 0010
Revises: 0009
Create Date: 2026-12-06
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0010"
down_revision: Union[str, Sequence[str], None] = "0009"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    with op.batch_alter_table("calibrations") as batch:
        batch.add_column(sa.Column("epoch_reason", sa.String(500), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("calibrations") as batch:
        batch.drop_column("epoch_reason")
