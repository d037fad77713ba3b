"""The map's heavy reads: a page of GET /signs (keyset along the index of migration 0005), and the
bounded concurrency every heavy map read runs under, so that a burst of them leaves the rest of the
API (``/health``, uploads, polling) its threads."""

from __future__ import annotations

import asyncio
from contextlib import contextmanager
from datetime import datetime, timezone
from typing import Any, Callable, Iterator, TypeVar

import anyio
import orjson
from fastapi import Request
from sqlalchemy import and_, or_, select, tuple_
from sqlalchemy.engine import Connection

from app.service.db.session import get_engine
from app.service.db.models import MapSignRow
from app.service.db.queries import BBox

T = TypeVar("T")
# What a page carries per sign: the GeoJSON of the wire contract, nothing more (no covariance or
# evidence: those are GET /signs/{id}'s).
PAGE_COLUMNS = (MapSignRow.id, MapSignRow.cls, MapSignRow.lon_deg, MapSignRow.lat_deg, MapSignRow.alt_m,
                MapSignRow.state, MapSignRow.std_m, MapSignRow.n_journeys, MapSignRow.n_observations,
                MapSignRow.first_seen_at, MapSignRow.last_seen_at, MapSignRow.facing_deg)


def live_in_bbox(bbox: BBox):
    """Plain lat/lon ranges on live signs: the partial index of migration 0005 answers them on
    PostgreSQL and SQLite alike, and the planner has real statistics for them (PostgreSQL's
    estimate for a GiST point-in-box is a constant)."""
    return and_(MapSignRow.removed_at.is_(None),
                MapSignRow.lat_deg.between(bbox.min_lat, bbox.max_lat),
                or_(*(MapSignRow.lon_deg.between(lo, hi) for lo, hi in bbox.lon_ranges())))


class BadCursor(ValueError):
    pass


def parse_cursor(text: str) -> tuple[float, float, str]:
    """``lat,lon,id`` of the previous page's last sign, as ``next`` gave it."""
    lat, sep1, rest = text.partition(",")
    lon, sep2, sign_id = rest.partition(",")
    try:
        if not (sep1 and sep2 and sign_id):
            raise ValueError
        return float(lat), float(lon), sign_id
    except ValueError:
        raise BadCursor("cursor is not one this service gave: pass the previous page's `next` "
                        "unchanged") from None


def make_cursor(lat: float, lon: float, sign_id: str) -> str:
    return f"{lat!r},{lon!r},{sign_id}"


def page_query(bbox: BBox, cls: str | None, since: datetime | None, state: str | None,
               cursor: tuple[float, float, str] | None, limit: int):
    """Ordered by (lat, lon, id), the order of the covering index: a page reads its own signs
    and the few of the box's latitude band it skips, however deep it is. (Ordered by id, every page
    sorted the whole box: ~29k signs of a city box at 1 M signs, 25-40 ms a page.)"""
    query = select(*PAGE_COLUMNS).where(live_in_bbox(bbox))
    if cls is not None:
        query = query.where(MapSignRow.cls == cls)
    if since is not None:
        query = query.where(MapSignRow.updated_at >= since)
    if state is not None:
        query = query.where(MapSignRow.state == state)
    if cursor is not None:
        query = query.where(tuple_(MapSignRow.lat_deg, MapSignRow.lon_deg, MapSignRow.id) > tuple_(*cursor))
    return query.order_by(MapSignRow.lat_deg, MapSignRow.lon_deg, MapSignRow.id).limit(limit)


class _UtcText(dict):
    """Datetime -> text as pydantic writes an aware UTC one (the format this route always had);
    one page's signs share few distinct times (their journeys'), each formatted once."""

    def __missing__(self, when: datetime) -> str:
        text = self[when] = when.astimezone(timezone.utc).isoformat().replace("+00:00", "Z")
        return text


def _feature(row, utc: _UtcText) -> dict[str, Any]:
    (sign_id, cls, lon, lat, alt, state, std_m, n_journeys, n_obs, first, last, facing) = row
    return {"type": "Feature", "id": sign_id,
            "geometry": {"type": "Point",
                         "coordinates": [lon, lat] if alt is None else [lon, lat, alt]},
            "properties": {"id": sign_id, "class": cls, "state": state, "std_m": std_m,
                           "n_journeys": n_journeys, "n_observations": n_obs,
                           "first_seen_at": utc[first], "last_seen_at": utc[last],
                           "facing_deg": facing}}


def signs_page_json(conn: Connection, bbox: BBox, cls: str | None, since: datetime | None,
                    state: str | None, cursor: tuple[float, float, str] | None,
                    limit: int) -> bytes:
    """One page of GET /signs as the JSON bytes of its FeatureCollection (plain tuples to dicts to
    one orjson.dumps: no ORM objects, no response-model validation per sign)."""
    rows = conn.execute(
        page_query(bbox, cls, since, state, cursor, limit + 1)).all()
    page = rows[:limit]
    utc = _UtcText()
    body = {"type": "FeatureCollection", "features": [_feature(r, utc) for r in page],
            "next": make_cursor(page[-1][3], page[-1][2], page[-1][0]) if len(rows) > limit
            else None}
    return orjson.dumps(body)


@contextmanager
def read_connection(url: str) -> Iterator[Connection]:
    """A connection without a transaction: a map read is one statement (or two that need not
    agree), and BEGIN and COMMIT were two more round trips to the database per request."""
    with get_engine(url).connect() as conn:
        yield conn.execution_options(isolation_level="AUTOCOMMIT")


def _limiter(request: Request) -> anyio.CapacityLimiter:
    """The app's limiter of heavy map reads, one per event loop (a TestClient runs its own)."""
    loop = asyncio.get_running_loop()
    held = getattr(request.app.state, "map_read_limiter", None)
    if held is None or held[0] is not loop:
        held = (loop, anyio.CapacityLimiter(request.app.state.settings.map_read_concurrency))
        request.app.state.map_read_limiter = held
    return held[1]


async def heavy_read(request: Request, fn: Callable[..., T], *args: Any) -> T:
    """Run ``fn(*args)`` in a worker thread of the map's own limiter: waiting map reads hold no
    thread of the shared pool that every other sync route (``/health`` included) runs in."""
    return await anyio.to_thread.run_sync(fn, *args, limiter=_limiter(request))
