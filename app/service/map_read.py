"""The map's heavy reads: a page of GET /signs (keyset on id, two-step through covering indexes) and
the bounded concurrency every heavy map read runs under, so that a burst of them leaves the rest of
the API (``/health``, uploads, polling) its threads."""

from __future__ import annotations

import asyncio
import json
from datetime import datetime, timezone
from typing import Any, Callable, TypeVar

import anyio
from fastapi import Request
from sqlalchemy import and_, or_, select
from sqlalchemy.orm import Session

from app.service.models import MapSign
from app.service.queries import BBox

T = TypeVar("T")
# What a page carries per sign: the GeoJSON of the wire contract, nothing more (no covariance or
# evidence: those are GET /signs/{id}'s).
PAGE_COLUMNS = (MapSign.id, MapSign.cls, MapSign.lon_deg, MapSign.lat_deg, MapSign.alt_m,
                MapSign.state, MapSign.std_m, MapSign.n_journeys, MapSign.n_observations,
                MapSign.first_seen_at, MapSign.last_seen_at)


def live_in_bbox(bbox: BBox):
    """Plain lat/lon ranges on live signs: the partial indexes of migration 0003 answer them
    index-only, on PostgreSQL and SQLite alike, and the planner has real statistics for them
    (PostgreSQL's estimate for a GiST point-in-box is a constant)."""
    return and_(MapSign.removed_at.is_(None),
                MapSign.lat_deg.between(bbox.min_lat, bbox.max_lat),
                or_(*(MapSign.lon_deg.between(lo, hi) for lo, hi in bbox.lon_ranges())))


def page_query(bbox: BBox, cls: str | None, since: datetime | None, state: str | None,
               cursor: str | None, limit: int):
    """The ids of one page first (index-only: id, lat and lon are in the indexes), then only those
    rows: sorting a city's worth of ids is cheap, fetching a city's worth of rows is not."""
    ids = select(MapSign.id).where(live_in_bbox(bbox))
    if cls is not None:
        ids = ids.where(MapSign.cls == cls)
    if since is not None:
        ids = ids.where(MapSign.updated_at >= since)
    if state is not None:
        ids = ids.where(MapSign.state == state)
    if cursor is not None:
        ids = ids.where(MapSign.id > cursor)
    page = ids.order_by(MapSign.id).limit(limit).subquery()
    return select(*PAGE_COLUMNS).join(page, MapSign.id == page.c.id).order_by(MapSign.id)


def _utc_text(when: datetime) -> str:
    # As pydantic writes an aware UTC datetime (the format this route always had).
    return when.astimezone(timezone.utc).isoformat().replace("+00:00", "Z")


def _feature(row) -> dict[str, Any]:
    (sign_id, cls, lon, lat, alt, state, std_m, n_journeys, n_obs, first, last) = row
    return {"type": "Feature", "id": sign_id,
            "geometry": {"type": "Point",
                         "coordinates": [lon, lat] if alt is None else [lon, lat, alt]},
            "properties": {"id": sign_id, "class": cls, "state": state, "std_m": std_m,
                           "n_journeys": n_journeys, "n_observations": n_obs,
                           "first_seen_at": _utc_text(first), "last_seen_at": _utc_text(last)}}


def signs_page_json(session: Session, bbox: BBox, cls: str | None, since: datetime | None,
                    state: str | None, cursor: str | None, limit: int) -> bytes:
    """One page of GET /signs as the JSON bytes of its FeatureCollection (plain tuples to dicts to
    one json.dumps: no ORM objects, no response-model validation per sign)."""
    rows = session.execute(page_query(bbox, cls, since, state, cursor, limit + 1)).all()
    page = rows[:limit]
    body = {"type": "FeatureCollection", "features": [_feature(r) for r in page],
            "next": page[-1][0] if len(rows) > limit else None}
    return json.dumps(body, separators=(",", ":"), allow_nan=False).encode()


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
