"""Map reads at scale: one partial covering index on the live map signs.

The index is ``(lat_deg, lon_deg, id)`` with every column a page shows, the same on PostgreSQL and
SQLite, replacing the GiST point index (PostgreSQL) and the lat/lon index (SQLite).

GET /signs pages walk it in its order (a keyset on lat, lon, id); a tile's clusters and fusion's
region read it without the table. Measured on 1 M signs (bench/results/2026-11-25-map.md): a city
page through the GiST index, ordered by id, fetched and sorted the box's ~29k rows (~150 ms cold);
along this index a page reads about its own entries and no table page (~1 ms warm). PostgreSQL's
planner has real statistics on lat/lon (its estimate for a GiST point-in-box is a constant).

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-25
"""
from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: Union[str, Sequence[str], None] = "0004"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None

LIVE = sa.text("removed_at IS NULL")
# The rest of what a GET /signs page and a tile read (app/service/db/map_read.py PAGE_COLUMNS).
PAGE = ["class", "state", "alt_m", "std_m", "n_journeys", "n_observations", "first_seen_at",
        "last_seen_at", "facing_deg"]


def upgrade() -> None:
    postgres = op.get_bind().dialect.name == "postgresql"
    op.drop_index("ix_map_signs_lonlat" if postgres else "ix_map_signs_lat_lon",
                  table_name="map_signs")
    # Covering: a page (and a tile) is read from the index alone, not from ~1000 table pages
    # scattered by the order fusion wrote them in. SQLite has no INCLUDE: the same as key columns.
    keys = ["lat_deg", "lon_deg", "id"]
    if postgres:
        op.create_index("ix_map_signs_live_lat_lon", "map_signs", keys, postgresql_where=LIVE,
                        postgresql_include=PAGE)
    else:
        op.create_index("ix_map_signs_live_lat_lon", "map_signs", keys + PAGE, sqlite_where=LIVE)


def downgrade() -> None:
    op.drop_index("ix_map_signs_live_lat_lon", table_name="map_signs")
    if op.get_bind().dialect.name == "postgresql":
        op.execute("CREATE INDEX ix_map_signs_lonlat ON map_signs "
                   "USING gist (point(lon_deg, lat_deg))")
    else:
        op.create_index("ix_map_signs_lat_lon", "map_signs", ["lat_deg", "lon_deg"])
