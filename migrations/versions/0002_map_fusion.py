"""Map fusion: fused map signs, their member journey signs, journey coverage, calibration flag.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: Union[str, Sequence[str], None] = "0001"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def _ts(name: str, nullable: bool = True) -> sa.Column:
    return sa.Column(name, sa.DateTime(timezone=True), nullable=nullable)


def upgrade() -> None:
    with op.batch_alter_table("journeys") as batch:
        batch.add_column(sa.Column("calibration_flag", sa.JSON))

    op.create_table(
        "map_signs",
        sa.Column("id", sa.String(64), primary_key=True),
        sa.Column("class", sa.String(200), nullable=False),
        sa.Column("lat_deg", sa.Float, nullable=False),
        sa.Column("lon_deg", sa.Float, nullable=False),
        sa.Column("alt_m", sa.Float),
        sa.Column("cov_enu", sa.JSON, nullable=False),
        sa.Column("std_m", sa.Float, nullable=False),
        sa.Column("n_journeys", sa.Integer, nullable=False),
        sa.Column("n_observations", sa.Integer, nullable=False),
        _ts("first_seen_at", nullable=False),
        _ts("last_seen_at", nullable=False),
        sa.Column("state", sa.String(32), nullable=False),
        sa.Column("evidence", sa.JSON, nullable=False),
        _ts("created_at", nullable=False),
        _ts("updated_at", nullable=False),
        _ts("removed_at"),
        sa.CheckConstraint("state IN ('new', 'confirmed', 'possibly_removed')",
                           name="ck_map_signs_state"),
    )
    op.create_index("ix_map_signs_class", "map_signs", ["class"])
    op.create_index("ix_map_signs_updated_at", "map_signs", ["updated_at"])
    # Same bbox index scheme as journey_signs (migration 0001).
    if op.get_bind().dialect.name == "postgresql":
        op.execute("CREATE INDEX ix_map_signs_lonlat ON map_signs "
                   "USING gist (point(lon_deg, lat_deg))")
    else:
        op.create_index("ix_map_signs_lat_lon", "map_signs", ["lat_deg", "lon_deg"])

    op.create_table(
        "map_sign_members",
        sa.Column("map_sign_id", sa.String(64),
                  sa.ForeignKey("map_signs.id", ondelete="CASCADE"), primary_key=True),
        sa.Column("journey_sign_id", sa.String,
                  sa.ForeignKey("journey_signs.id", ondelete="CASCADE"), primary_key=True),
        sa.Column("weight", sa.Float, nullable=False),
    )
    op.create_index("ix_map_sign_members_journey_sign_id", "map_sign_members",
                    ["journey_sign_id"])

    op.create_table(
        "journey_coverage",
        sa.Column("journey_id", sa.String(36), sa.ForeignKey("journeys.id", ondelete="CASCADE"),
                  primary_key=True),
        sa.Column("journey_key", sa.String(120), nullable=False),
        sa.Column("captured_at_s", sa.Float, nullable=False),
        sa.Column("origin_lat_deg", sa.Float, nullable=False),
        sa.Column("origin_lon_deg", sa.Float, nullable=False),
        sa.Column("origin_alt_m", sa.Float, nullable=False),
        sa.Column("camera", sa.JSON, nullable=False),
        sa.Column("frame_ids", sa.JSON, nullable=False),
        sa.Column("poses", sa.JSON, nullable=False),
        *(sa.Column(k, sa.Float) for k in ("min_lat_deg", "min_lon_deg", "max_lat_deg",
                                           "max_lon_deg")),
    )
    op.create_index("ix_journey_coverage_bbox", "journey_coverage",
                    ["min_lat_deg", "max_lat_deg", "min_lon_deg", "max_lon_deg"])


def downgrade() -> None:
    op.drop_table("journey_coverage")
    op.drop_table("map_sign_members")
    op.drop_table("map_signs")
    with op.batch_alter_table("journeys") as batch:
        batch.drop_column("calibration_flag")
