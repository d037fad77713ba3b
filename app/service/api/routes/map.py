"""Routes of the fused map (base path /api/v1): the map signs, one map sign with its evidence, the
changes since a time for incremental clients, and deleting a journey (which re-fuses its region)."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request, Response, status
from pydantic import BaseModel, Field
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.geojson import sign_feature
from app.service import storage
from app.service.jobs import fusion
from app.service.auth import Principal, require
from app.service.db.session import session_scope
from app.service.db.models import JourneyRow, JourneySignRow, MapSignRow, MapSignMemberRow
from app.service.db.map_read import heavy_read, parse_cursor, read_connection, signs_page_json
from app.service.db.map_tiles import (MEDIA_TYPE, Tile, TileCache, encode, map_version,
                                   tile_features)
from app.service.db.queries import BBox
from app.service.api.schemas import NO_NUL, ErrorOut, PointGeometry

router = APIRouter(prefix="/api/v1")
_AUTH = {401: {"model": ErrorOut, "description": "no or unknown API key"},
         403: {"model": ErrorOut, "description": "the key's role may not make this call"}}
State = Literal["new", "confirmed", "possibly_removed"]


class MapSignProperties(BaseModel):
    model_config = {"extra": "allow", "populate_by_name": True}

    id: str = Field(examples=["ms-3f2a9c0d1e4b5a69"])
    class_: str = Field(alias="class", examples=["stop"])
    state: State
    std_m: float = Field(description="horizontal 1-sigma of the fused position, metres")
    n_journeys: int
    n_observations: int
    first_seen_at: datetime
    last_seen_at: datetime
    facing_deg: float | None = Field(
        None, description="compass bearing its face points to (degrees clockwise from north), "
                          "the circular mean of the journeys'; null when unknown")


class MapSignFeature(BaseModel):
    type: Literal["Feature"] = "Feature"
    id: str
    geometry: PointGeometry
    properties: MapSignProperties


class MapSignCollection(BaseModel):
    type: Literal["FeatureCollection"] = "FeatureCollection"
    features: list[MapSignFeature]
    next: str | None = Field(description="pass as `cursor` for the next page; null on the last")


class MapChanges(BaseModel):
    since: datetime
    until: datetime = Field(description="pass as the next call's `since`")
    created: list[MapSignFeature]
    updated: list[MapSignFeature]
    removed: list[dict[str, Any]] = Field(description="tombstones: {id, removed_at}")


def _url(request: Request) -> str:
    return request.app.state.settings.effective_database_url


def _aware(when: datetime) -> datetime:
    return when if when.tzinfo else when.replace(tzinfo=timezone.utc)


def _since_utc(since: datetime) -> datetime:
    """``since`` in UTC; 400 for a time the conversion takes out of Python's years 1..9999 (a 500
    from the database driver before, found by schemathesis)."""
    try:
        return _aware(since).astimezone(timezone.utc)
    except OverflowError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            f"since {since.isoformat()} is out of range") from exc


def map_sign_feature(row: MapSignRow, **extra: Any) -> dict[str, Any]:
    return sign_feature(row.id, row.cls, row.lon_deg, row.lat_deg, row.alt_m, state=row.state,
                        std_m=row.std_m, n_journeys=row.n_journeys,
                        n_observations=row.n_observations,
                        first_seen_at=row.first_seen_at.isoformat(),
                        last_seen_at=row.last_seen_at.isoformat(), facing_deg=row.facing_deg,
                        **extra)


@router.get("/signs", response_model=MapSignCollection,
            summary="The fused map's signs in a box (GeoJSON), paginated",
            description="`bbox=minlon,minlat,maxlon,maxlat` in WGS84 degrees (minlon > maxlon "
                        "crosses the antimeridian); optional `class`, `state`, `since` (updated at "
                        "or after, ISO 8601). Ordered by position (latitude, longitude, then id); "
                        "follow `next` with `cursor` (opaque: pass it unchanged). A page holds "
                        "at most `limit` signs and never more than the service's page maximum "
                        "(SIGNMAP_MAP_PAGE_MAX, default 2000).",
            responses={400: {"model": ErrorOut, "description": "bad bbox, cursor or since"}, **_AUTH})
async def get_map_signs(request: Request, who: Annotated[Principal, Depends(require("reader"))],
                        bbox: Annotated[str, Query(examples=["8.41,49.00,8.43,49.02"])],
                        cls: Annotated[str | None, Query(alias="class", examples=["stop"],
                                                         pattern=NO_NUL)] = None,
                        since: datetime | None = None, state: State | None = None,
                        limit: Annotated[int, Query(ge=1, le=10000)] = 1000,
                        cursor: Annotated[str | None, Query(pattern=NO_NUL)] = None) -> Response:
    try:
        box = BBox.parse(bbox)
        after = None if cursor is None else parse_cursor(cursor)
    except ValueError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc
    limit = min(limit, request.app.state.settings.map_page_max)
    since = None if since is None else _since_utc(since)

    def read() -> bytes:
        with read_connection(_url(request)) as conn:
            return signs_page_json(conn, box, cls, since, state, after, limit)

    # Built here rather than through response_model: validating thousands of features one by one
    # was most of the time of a page (issue 13, finding 7); tests check the shape instead.
    return Response(await heavy_read(request, read), media_type="application/json")


@router.get("/tiles/{z}/{x}/{y}.mvt", response_class=Response,
            summary="The map's signs as a vector tile (Mapbox Vector Tile)",
            description="Web Mercator tiles numbered as OpenStreetMap's. One layer `signs` of "
                        "points with `id`, `class`, `state` and `count` (1 for a sign); at low "
                        "zoom, and in a tile with too many signs, a point stands for a cluster: "
                        "`count` signs, `id` the smallest of theirs, `class`/`state` only when "
                        "all members share one. Low-zoom tiles are cached until the map changes.",
            responses={200: {"content": {MEDIA_TYPE: {}}, "description": "the tile"},
                       400: {"model": ErrorOut, "description": "z, x or y out of range"},
                       **_AUTH})
async def get_tile(request: Request, z: int, x: int, y: int,
                   who: Annotated[Principal, Depends(require("reader"))]) -> Response:
    settings = request.app.state.settings
    try:
        tile = Tile.checked(z, x, y, settings.tile_max_zoom)
    except ValueError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc

    cache = _tile_cache(request) if z <= settings.tile_cache_max_zoom else None

    def read() -> bytes:
        with read_connection(_url(request)) as conn:
            version = map_version(conn) if cache is not None else None
            data = cache.get((z, x, y), version) if cache is not None else None
            if data is None:
                data = encode(tile_features(
                    conn, tile, points_min_zoom=settings.tile_points_min_zoom,
                    max_points=settings.tile_max_points, grid=settings.tile_cluster_grid))
                if cache is not None:
                    cache.put((z, x, y), version, data)
        return data

    return Response(await heavy_read(request, read), media_type=MEDIA_TYPE)


def _tile_cache(request: Request) -> TileCache:
    cache = getattr(request.app.state, "tile_cache", None)
    if cache is None:
        settings = request.app.state.settings
        cache = request.app.state.tile_cache = TileCache(settings.tile_cache_size,
                                                         settings.tile_cache_ttl_s)
    return cache


@router.get("/signs/changes", response_model=MapChanges,
            summary="Map signs created, updated or removed since a time",
            description="For clients that keep a copy of the map: call with the previous "
                        "answer's `until`. Removed signs come as tombstones.",
            responses={400: {"model": ErrorOut, "description": "since out of range"}, **_AUTH})
def get_map_changes(request: Request, who: Annotated[Principal, Depends(require("reader"))],
                    since: datetime) -> dict[str, Any]:
    since = _since_utc(since)
    with session_scope(_url(request)) as session:
        until = session.scalar(select(func.max(MapSignRow.updated_at))) or since
        rows = list(session.scalars(select(MapSignRow).where(MapSignRow.updated_at >= since)
                                    .order_by(MapSignRow.id)))
    live = [r for r in rows if r.removed_at is None]
    return {"since": since, "until": max(until, since),
            "created": [map_sign_feature(r) for r in live if r.created_at >= since],
            "updated": [map_sign_feature(r) for r in live if r.created_at < since],
            "removed": [{"id": r.id, "removed_at": r.removed_at.isoformat()}
                        for r in rows if r.removed_at is not None]}


def _members(session: Session, map_sign_id: str) -> list[dict[str, Any]]:
    rows = session.execute(
        select(MapSignMemberRow.weight, JourneySignRow).join(
            JourneySignRow, JourneySignRow.id == MapSignMemberRow.journey_sign_id)
        .where(MapSignMemberRow.map_sign_id == map_sign_id).order_by(JourneySignRow.id)).all()
    return [{"journey_sign_id": s.id, "journey_id": s.journey_id, "track_id": s.track_id,
             "class": s.cls, "lat": s.lat_deg, "lon": s.lon_deg, "alt_m": s.alt_m,
             "std_m": s.std_m, "weight": weight, "observations": s.observations}
            for weight, s in rows]


@router.get("/signs/{sign_id}", summary="One map sign with its evidence (GeoJSON Feature)",
            description="`properties.members`: the journey signs fused into it, with the frames "
                        "and camera-frame positions they were seen at and the detection boxes; "
                        "`properties.evidence`: fusion weights, outliers and the change rule.",
            responses={404: {"model": ErrorOut, "description": "no such map sign"}, **_AUTH})
def get_map_sign(request: Request, sign_id: Annotated[str, Path(pattern=NO_NUL)],
                 who: Annotated[Principal, Depends(require("reader"))]) -> dict[str, Any]:
    with session_scope(_url(request)) as session:
        row = session.get(MapSignRow, sign_id)
        if row is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"map sign {sign_id} not found")
        return map_sign_feature(
            row, evidence=row.evidence, cov_enu=row.cov_enu, members=_members(session, sign_id),
            removed_at=row.removed_at.isoformat() if row.removed_at else None)


@router.delete("/journeys/{journey_id}", status_code=status.HTTP_204_NO_CONTENT,
               summary="Delete a journey (admin)",
               description="Removes the journey, its signs and coverage, and re-fuses the map "
                           "around it; its stored bundle goes too unless another journey was "
                           "uploaded with the same bytes. A running journey answers 409.",
               responses={404: {"model": ErrorOut, "description": "no such journey"},
                          409: {"model": ErrorOut, "description": "the journey is running"},
                          **_AUTH})
def delete_journey(request: Request, journey_id: Annotated[str, Path(pattern=NO_NUL)],
                   who: Annotated[Principal, Depends(require("admin"))]) -> None:
    with session_scope(_url(request)) as session:
        row = session.get(JourneyRow, journey_id)
        running = row is not None and row.status == "running"
        sha256 = row.bundle_sha256 if row is not None else None
    if running:
        raise HTTPException(status.HTTP_409_CONFLICT, f"journey {journey_id} is running")
    if not fusion.delete_journey(_url(request), journey_id, request.app.state.settings):
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"journey {journey_id} not found")
    storage.release_bundle(_url(request), request.app.state.store, sha256)
