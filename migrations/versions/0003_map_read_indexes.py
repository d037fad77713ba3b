"""Map reads at scale (issues 13 and 15): two covering partial indexes on the live map signs, the
same on PostgreSQL and SQLite, replacing the GiST point index (PostgreSQL) and the lat/lon index
(SQLite).

``(lat_deg, lon_deg, id, class, state)`` answers a box (a page's ids, a tile's clusters, fusion's
region) without reading the table; ``(id, lat_deg, lon_deg)`` walks ids in order for a box holding
a large share of the map. Measured on 1 M signs (bench/results/2026-11-25-map.md): a city page
through the GiST index spent ~150 ms fetching ~29k rows to sort them by id; these answer it
index-only in a few ms, and PostgreSQL's planner, with real statistics on lat/lon (its estimate for
a point-in-box is a constant), picks between them.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-25
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: Union[str, Sequence[str], None] = "0002"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None

LIVE = sa.text("removed_at IS NULL")


def upgrade() -> None:
    postgres = op.get_bind().dialect.name == "postgresql"
    op.drop_index("ix_map_signs_lonlat" if postgres else "ix_map_signs_lat_lon",
                  table_name="map_signs")
    op.create_index("ix_map_signs_live_lat_lon", "map_signs",
                    ["lat_deg", "lon_deg", "id", "class", "state"],
                    postgresql_where=LIVE, sqlite_where=LIVE)
    op.create_index("ix_map_signs_live_id", "map_signs", ["id", "lat_deg", "lon_deg"],
                    postgresql_where=LIVE, sqlite_where=LIVE)


def downgrade() -> None:
    op.drop_index("ix_map_signs_live_id", table_name="map_signs")
    op.drop_index("ix_map_signs_live_lat_lon", table_name="map_signs")
    if op.get_bind().dialect.name == "postgresql":
        op.execute("CREATE INDEX ix_map_signs_lonlat ON map_signs "
                   "USING gist (point(lon_deg, lat_deg))")
    else:
        op.create_index("ix_map_signs_lat_lon", "map_signs", ["lat_deg", "lon_deg"])
