"""Re-processing a camera's done journeys when an admin registers its calibration.

``journeys.reprocess_epoch``: set while a done journey, which was given a calibration of its
camera that a registered one has since superseded, is queued or running again with that epoch's
calibration; NULL otherwise. Such a journey keeps serving its earlier signs (the map and GET
/signs count it as done) until the new run replaces them (``jobs.cameras.reprocess_superseded``).

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-05
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0009"
down_revision: Union[str, Sequence[str], None] = "0008"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    with op.batch_alter_table("journeys") as batch:
        batch.add_column(sa.Column("reprocess_epoch", sa.Integer, nullable=True))


def downgrade() -> None:
    # A journey queued for re-processing keeps its earlier result: done again.
    op.execute("UPDATE journeys SET status = 'done', stage = 'done', progress = 1.0, "
               "message = NULL WHERE reprocess_epoch IS NOT NULL AND status = 'queued'")
    with op.batch_alter_table("journeys") as batch:
        batch.drop_column("reprocess_epoch")
