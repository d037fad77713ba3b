"""A camera's joint calibration over its journeys' turn windows.

``calibrations.window``: a self-calibration's accepted window (the reconstruction the joint fit
adjusts again), NULL for registered calibrations and those stored before. ``camera_fits``: each
joint calibration of a camera's epoch, the newest of which its later journeys are given
(``jobs.camera_fit``, docs/decisions/camera-joint-calibration.md).

Revision ID: 0011
Revises: 0010
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0011"
down_revision: Union[str, Sequence[str], None] = "0010"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None

_PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2")


def upgrade() -> None:
    with op.batch_alter_table("calibrations") as batch:
        batch.add_column(sa.Column("window", sa.LargeBinary(), nullable=True))
    op.create_table(
        "camera_fits",
        sa.Column("id", sa.Integer(), primary_key=True, autoincrement=True),
        sa.Column("camera_id", sa.String(200), nullable=False),
        sa.Column("epoch", sa.Integer(), nullable=False),
        sa.Column("width", sa.Integer(), nullable=False),
        sa.Column("height", sa.Integer(), nullable=False),
        *[sa.Column(k, sa.Float(), nullable=False) for k in _PARAMS],
        *[sa.Column(f"sigma_{k}", sa.Float(), nullable=True) for k in _PARAMS],
        sa.Column("fy_resolved", sa.Boolean(), nullable=False),
        sa.Column("inputs", sa.JSON(), nullable=False),
        sa.Column("used", sa.JSON(), nullable=False),
        sa.Column("left_out", sa.JSON(), nullable=False),
        sa.Column("rms_px", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
    )
    op.create_index("ix_camera_fits_camera_epoch", "camera_fits", ["camera_id", "epoch"])


def downgrade() -> None:
    op.drop_index("ix_camera_fits_camera_epoch", table_name="camera_fits")
    op.drop_table("camera_fits")
    with op.batch_alter_table("calibrations") as batch:
        batch.drop_column("window")
