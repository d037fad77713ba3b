"""Vector tiles of the map (Mapbox Vector Tile 2.1, Web Mercator z/x/y as OSM's): one layer
``signs`` of points. Up to ``tile_points_min_zoom`` (and in a tile holding more than
``tile_max_points`` signs) the signs are clustered on a grid in SQL: one point per non-empty cell at
its members' mean position, with ``count``, the smallest member ``id`` as its representative, and
``class``/``state`` when all members share one. A single sign always carries its own ``id``,
``class`` and ``state`` with ``count`` 1, and ``facing_deg`` (compass bearing of its face) when
known.

A tile also holds the signs and clusters just outside it whose circle on the dashboard's map
reaches into it (at coordinates beyond 0..EXTENT): each tile is drawn on its own, and a circle
drawn only by the tile holding its centre was cut at that tile's edge."""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import mapbox_vector_tile
import numpy as np
import shapely
from sqlalchemy import Integer, cast, func, select
from sqlalchemy.engine import Connection

from app.service.db.map_read import live_in_bbox
from app.service.db.models import MapSignRow
from app.service.db.queries import BBox

EXTENT = 4096
LAYER = "signs"
MEDIA_TYPE = "application/vnd.mapbox-vector-tile"
MAX_LAT = math.degrees(math.atan(math.sinh(math.pi)))  # 85.0511..., the square world's edge
# The largest circles the dashboard's map draws (admin/static/map.js, ``style``), stroke included,
# in screen pixels of a TILE_PX tile: a sign's, and a cluster's (it grows with its count).
TILE_PX = 256
SIGN_RADIUS_PX = 8
CLUSTER_RADIUS_PX = 23


@dataclass(frozen=True)
class Tile:
    z: int
    x: int
    y: int

    @classmethod
    def checked(cls, z: int, x: int, y: int, max_zoom: int) -> "Tile":
        """ValueError saying what is out of range."""
        if not 0 <= z <= max_zoom:
            raise ValueError(f"zoom must be within [0, {max_zoom}], got {z}")
        n = 2 ** z
        if not (0 <= x < n and 0 <= y < n):
            raise ValueError(f"at zoom {z} x and y must be within [0, {n - 1}], got x={x} y={y}")
        return cls(z, x, y)

    def bbox(self, pad: float = 0.0) -> BBox:
        """The tile's box, grown by ``pad`` tile widths on every side (up to the world's edge)."""
        n = 2 ** self.z
        return BBox(min_lon=max(-180.0, (self.x - pad) / n * 360.0 - 180.0),
                    min_lat=_lat(min(n, self.y + 1 + pad), n),
                    max_lon=min(180.0, (self.x + 1 + pad) / n * 360.0 - 180.0),
                    max_lat=_lat(max(0.0, self.y - pad), n))

    def pixels(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """(N, 2) tile coordinates, y down, 0..EXTENT."""
        n = 2 ** self.z
        merc = np.arcsinh(np.tan(np.radians(np.clip(lat, -MAX_LAT, MAX_LAT))))
        px = ((lon + 180.0) / 360.0 * n - self.x) * EXTENT
        py = ((1.0 - merc / np.pi) / 2.0 * n - self.y) * EXTENT
        return np.rint(np.column_stack([px, py]))


def _lat(y: int, n: int) -> float:
    return math.degrees(math.atan(math.sinh(math.pi * (1.0 - 2.0 * y / n))))


def _points(conn: Connection, box: BBox, cap: int) -> list[tuple] | None:
    """The tile's signs, or None when there are more than ``cap``."""
    rows = conn.execute(
        select(MapSignRow.id, MapSignRow.cls, MapSignRow.state, MapSignRow.lon_deg, MapSignRow.lat_deg,
               MapSignRow.facing_deg)
        .where(live_in_bbox(box)).limit(cap + 1)).all()
    return None if len(rows) > cap else [(1, *r) for r in rows]


def _clusters(conn: Connection, tile: Tile, grid: int) -> list[tuple]:
    """(count, id, class, state, lon, lat, facing None) per non-empty cell of a grid x grid split of
    the tile's box, and of the cells around it as far as a cluster's circle reaches; class and
    state None where the members differ. Everything read is in the covering index."""
    floor = func.floor if conn.dialect.name == "postgresql" else (
        lambda v: cast(v, Integer))  # SQLite: truncation is floor for the non-negative offsets here
    box = tile.bbox()
    around = math.ceil(CLUSTER_RADIUS_PX * grid / TILE_PX)  # cells beyond each edge
    cw = (box.max_lon - box.min_lon) / grid
    ch = (box.max_lat - box.min_lat) / grid
    # Cells counted from the outermost, so that those inside are the tile's own grid's.
    cx = floor((MapSignRow.lon_deg - (box.min_lon - around * cw)) / cw)
    cy = floor((MapSignRow.lat_deg - (box.min_lat - around * ch)) / ch)
    reach = BBox(max(-180.0, box.min_lon - around * cw), max(-90.0, box.min_lat - around * ch),
                 min(180.0, box.max_lon + around * cw), min(90.0, box.max_lat + around * ch))
    rows = conn.execute(
        select(func.count(), func.min(MapSignRow.id), func.min(MapSignRow.cls), func.max(MapSignRow.cls),
               func.min(MapSignRow.state), func.max(MapSignRow.state), func.avg(MapSignRow.lon_deg),
               func.avg(MapSignRow.lat_deg))
        .where(live_in_bbox(reach)).group_by(cx, cy)).all()
    return [(n, first, cls_lo if cls_lo == cls_hi else None,
             st_lo if st_lo == st_hi else None, lon, lat, None)
            for n, first, cls_lo, cls_hi, st_lo, st_hi, lon, lat in rows]


def tile_features(conn: Connection, tile: Tile, *, points_min_zoom: int, max_points: int,
                  grid: int) -> list[dict[str, Any]]:
    found = (_points(conn, tile.bbox(pad=SIGN_RADIUS_PX / TILE_PX), max_points)
             if tile.z >= points_min_zoom else None)
    if found is None:
        found = _clusters(conn, tile, grid)
    lonlat = np.array([(r[4], r[5]) for r in found], dtype=float).reshape(-1, 2)
    points = shapely.points(tile.pixels(lonlat[:, 0], lonlat[:, 1]))
    features = []
    for point, (count, sign_id, cls, state, _lon, _lat, facing) in zip(points, found):
        props: dict[str, Any] = {"id": sign_id, "count": int(count)}
        if cls is not None:
            props["class"] = cls
        if state is not None:
            props["state"] = state
        if facing is not None:
            props["facing_deg"] = round(float(facing), 1)
        features.append({"geometry": point, "properties": props})
    return features


def encode(features: list[dict[str, Any]]) -> bytes:
    return mapbox_vector_tile.encode([{"name": LAYER, "features": features}],
                                     default_options={"y_coord_down": True, "extents": EXTENT})


def decode(data: bytes) -> dict[str, Any]:
    """The tile as the encoder's own decoder reads it (y down, as encoded)."""
    return mapbox_vector_tile.decode(data, default_options={"y_coord_down": True})


class TileCache:
    """Encoded low-zoom tiles (the costly ones: a z6 tile aggregates a country's signs), kept
    while the map is unchanged: every fusion change stamps ``updated_at``, so the newest stamp is
    the map's version. ``ttl_s`` bounds what a host whose clock lags could leave stale."""

    def __init__(self, size: int, ttl_s: float):
        self.size, self.ttl_s = size, ttl_s
        self._tiles: OrderedDict[tuple, tuple[Any, float, bytes]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: tuple, version: Any) -> bytes | None:
        with self._lock:
            held = self._tiles.get(key)
            if held is None or held[0] != version or time.monotonic() - held[1] > self.ttl_s:
                return None
            self._tiles.move_to_end(key)
            return held[2]

    def put(self, key: tuple, version: Any, data: bytes) -> None:
        with self._lock:
            self._tiles[key] = (version, time.monotonic(), data)
            self._tiles.move_to_end(key)
            while len(self._tiles) > self.size:
                self._tiles.popitem(last=False)


def map_version(conn: Connection) -> Any:
    """The newest change of the map (index ix_map_signs_updated_at: one index probe)."""
    return conn.execute(select(func.max(MapSignRow.updated_at))).scalar()
