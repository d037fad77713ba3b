"""Initial schema: api keys, journeys, their signs, camera calibrations.

Revision ID: 0001
Revises:
Create Date: 2026-11-21
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: Union[str, Sequence[str], None] = None
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def _ts(name: str, nullable: bool = True) -> sa.Column:
    return sa.Column(name, sa.DateTime(timezone=True), nullable=nullable)


def upgrade() -> None:
    op.create_table(
        "api_keys",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("name", sa.String(200), nullable=False),
        sa.Column("role", sa.String(16), nullable=False),
        sa.Column("key_sha256", sa.String(64), nullable=False, unique=True),
        _ts("created_at", nullable=False),
        sa.CheckConstraint("role IN ('fleet', 'reader', 'admin')", name="ck_api_keys_role"),
    )
    op.create_table(
        "journeys",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("owner_key_id", sa.Integer, sa.ForeignKey("api_keys.id"), nullable=True),
        sa.Column("camera_id", sa.String(200), nullable=False),
        sa.Column("vehicle_id", sa.String(200)),
        sa.Column("captured_at", sa.String(64)),
        sa.Column("bundle_sha256", sa.String(64), nullable=False),
        sa.Column("bundle_bytes", sa.Integer, nullable=False),
        sa.Column("status", sa.String(16), nullable=False),
        sa.Column("stage", sa.String(64)),
        sa.Column("progress", sa.Float, nullable=False),
        sa.Column("error", sa.Text),
        sa.Column("n_frames", sa.Integer, nullable=False),
        sa.Column("n_signs", sa.Integer),
        sa.Column("calibration", sa.JSON),
        sa.Column("calibration_source", sa.String(16)),
        sa.Column("timings_s", sa.JSON),
        _ts("created_at", nullable=False),
        _ts("started_at"),
        _ts("finished_at"),
        _ts("heartbeat_at"),
        sa.Column("attempts", sa.Integer, nullable=False),
        sa.UniqueConstraint("owner_key_id", "bundle_sha256", name="uq_journeys_owner_bundle"),
        sa.CheckConstraint("status IN ('queued', 'running', 'done', 'failed')",
                           name="ck_journeys_status"),
    )
    op.create_index("ix_journeys_owner_key_id", "journeys", ["owner_key_id"])
    op.create_index("ix_journeys_camera_id", "journeys", ["camera_id"])
    op.create_index("ix_journeys_status", "journeys", ["status"])

    op.create_table(
        "journey_signs",
        sa.Column("id", sa.String, primary_key=True),
        sa.Column("journey_id", sa.String(36), sa.ForeignKey("journeys.id", ondelete="CASCADE"),
                  nullable=False),
        sa.Column("track_id", sa.String, nullable=False),
        sa.Column("class", sa.String(200), nullable=False),
        sa.Column("lat_deg", sa.Float, nullable=False),
        sa.Column("lon_deg", sa.Float, nullable=False),
        sa.Column("alt_m", sa.Float),
        sa.Column("x_enu_m", sa.Float, nullable=False),
        sa.Column("y_enu_m", sa.Float, nullable=False),
        sa.Column("z_enu_m", sa.Float, nullable=False),
        sa.Column("std_m", sa.Float, nullable=False),
        sa.Column("reprojection_rms_px", sa.Float, nullable=False),
        sa.Column("observations", sa.JSON, nullable=False),
    )
    op.create_index("ix_journey_signs_journey_id", "journey_signs", ["journey_id"])
    op.create_index("ix_journey_signs_class", "journey_signs", ["class"])
    # The bbox index of GET /signs (docs/service.md): a GiST index on the built-in point type on
    # PostgreSQL, matched by `point(lon_deg, lat_deg) <@ box(...)`; a plain btree on SQLite.
    if op.get_bind().dialect.name == "postgresql":
        op.execute("CREATE INDEX ix_journey_signs_lonlat ON journey_signs "
                   "USING gist (point(lon_deg, lat_deg))")
    else:
        op.create_index("ix_journey_signs_lat_lon", "journey_signs", ["lat_deg", "lon_deg"])

    op.create_table(
        "calibrations",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("camera_id", sa.String(200), nullable=False),
        sa.Column("journey_id", sa.String(36), sa.ForeignKey("journeys.id", ondelete="CASCADE"),
                  nullable=False),
        sa.Column("width", sa.Integer, nullable=False),
        sa.Column("height", sa.Integer, nullable=False),
        *(sa.Column(k, sa.Float, nullable=False) for k in ("fx", "fy", "cx", "cy", "k1", "k2")),
        sa.Column("n_images", sa.Integer, nullable=False),
        sa.Column("n_registered", sa.Integer, nullable=False),
        sa.Column("reprojection_error_px", sa.Float),
        sa.Column("rotation_deg", sa.Float, nullable=False),
        _ts("created_at", nullable=False),
    )
    op.create_index("ix_calibrations_camera_id", "calibrations", ["camera_id"])
    op.create_index("ix_calibrations_journey_id", "calibrations", ["journey_id"])


def downgrade() -> None:
    op.drop_table("calibrations")
    op.drop_table("journey_signs")
    op.drop_table("journeys")
    op.drop_table("api_keys")
