"""Cameras the operator knows, calibration epochs, and journeys that wait for their camera.

``calibrations`` holds every calibration of a camera, self-calibrated or registered:

* ``source``: ``'self'`` (a journey self-calibrated; ``journey_id`` is that journey) or
  ``'registered'`` (an admin gave it: PUT /cameras/{id}/calibration, the dashboard, ``signmap
  cameras set``; ``journey_id`` NULL, ``registered_by`` says who). A CHECK keeps the pair
  consistent.
* ``epoch``: 1, 2, ... per camera. A registered calibration starts a new one; a self-calibration
  joins the camera's newest. Only the newest epoch's calibrations make the camera's stored one.
  At most one registered calibration per epoch (a partial unique index).
* ``sigma_fx`` .. ``sigma_k2``: 1-sigma of each parameter in its own units, NULL when unknown
  (a registered calibration: as given, 0 when not given; a self-calibration: stage 2's, fx..cy).
* ``n_images``, ``n_registered``, ``rotation_deg``: NULL for a registered calibration.

``journeys`` gains ``message`` (what a journey queued with stage ``waiting_for_camera`` waits for)
and ``image_width``/``image_height`` (its frames' size once a run has read them; filled here from
the journeys' self-calibrations).

Every calibration that exists is a self-calibration of epoch 1.

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-04
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0008"
down_revision: Union[str, Sequence[str], None] = "0007"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None

PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2")


def upgrade() -> None:
    with op.batch_alter_table("calibrations") as batch:
        batch.add_column(sa.Column("source", sa.String(16), nullable=False,
                                   server_default="self"))
        batch.add_column(sa.Column("epoch", sa.Integer, nullable=False, server_default="1"))
        batch.add_column(sa.Column("registered_by", sa.String(200), nullable=True))
        for k in PARAMS:
            batch.add_column(sa.Column(f"sigma_{k}", sa.Float, nullable=True))
        batch.alter_column("journey_id", existing_type=sa.String(36), nullable=True)
        for name, kind in (("n_images", sa.Integer), ("n_registered", sa.Integer),
                           ("rotation_deg", sa.Float)):
            batch.alter_column(name, existing_type=kind, nullable=True)
        batch.create_check_constraint(
            "ck_calibrations_source",
            "(source = 'self' AND journey_id IS NOT NULL) "
            "OR (source = 'registered' AND journey_id IS NULL)")
    op.create_index("ix_calibrations_camera_epoch", "calibrations", ["camera_id", "epoch"])
    op.create_index("uq_calibrations_registered_epoch", "calibrations", ["camera_id", "epoch"],
                    unique=True, sqlite_where=sa.text("source = 'registered'"),
                    postgresql_where=sa.text("source = 'registered'"))

    with op.batch_alter_table("journeys") as batch:
        batch.add_column(sa.Column("message", sa.Text, nullable=True))
        batch.add_column(sa.Column("image_width", sa.Integer, nullable=True))
        batch.add_column(sa.Column("image_height", sa.Integer, nullable=True))
    for column in ("width", "height"):
        op.execute(f"UPDATE journeys SET image_{column} = (SELECT c.{column} FROM calibrations c "
                   f"WHERE c.journey_id = journeys.id ORDER BY c.id DESC LIMIT 1)")


def downgrade() -> None:
    with op.batch_alter_table("journeys") as batch:
        batch.drop_column("image_height")
        batch.drop_column("image_width")
        batch.drop_column("message")
    op.drop_index("uq_calibrations_registered_epoch", "calibrations")
    op.drop_index("ix_calibrations_camera_epoch", "calibrations")
    # Registered calibrations have no journey and cannot be kept; journeys waiting for their
    # camera are queued as new.
    op.execute("DELETE FROM calibrations WHERE source = 'registered'")
    op.execute("UPDATE journeys SET stage = NULL WHERE stage = 'waiting_for_camera'")
    with op.batch_alter_table("calibrations") as batch:
        batch.drop_constraint("ck_calibrations_source", type_="check")
        for name, kind in (("n_images", sa.Integer), ("n_registered", sa.Integer),
                           ("rotation_deg", sa.Float)):
            batch.alter_column(name, existing_type=kind, nullable=False)
        batch.alter_column("journey_id", existing_type=sa.String(36), nullable=False)
        for k in reversed(PARAMS):
            batch.drop_column(f"sigma_{k}")
        batch.drop_column("registered_by")
        batch.drop_column("epoch")
        batch.drop_column("source")
