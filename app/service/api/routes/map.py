"""Routes of the fused map (base path /api/v1): the map signs in a box, the changes since a time
for incremental clients, and one map sign with its evidence. Each is admitted by a reader key (route
``dependencies``), so the dashboard serves the same functions behind its own sign-in."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request, Response, status
from sqlalchemy import func, select

from app.service.api.schemas import (AUTH_ERRORS, NO_NUL, ErrorOut, MapChanges,
                                     MapSignCollection, MapSignState, echoed_id)
from app.service.db.map_read import heavy_read, parse_cursor, read_connection, signs_page_json
from app.service.db.models import MapSignRow
from app.service.db.queries import BBox, map_sign_feature, map_sign_members
from app.service.deps import SessionDep, SettingsDep, require

router = APIRouter(prefix="/api/v1")
READER = [Depends(require("reader"))]


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


@router.get("/signs", response_model=MapSignCollection, dependencies=READER,
            summary="The fused map's signs in a box (GeoJSON), paginated",
            description="`bbox=minlon,minlat,maxlon,maxlat` in WGS84 degrees (minlon > maxlon "
                        "crosses the antimeridian); optional `class`, `state`, `since` (updated at "
                        "or after, ISO 8601). Ordered by position (latitude, longitude, then id); "
                        "follow `next` with `cursor` (opaque: pass it unchanged). A page holds "
                        "at most `limit` signs and never more than the service's page maximum "
                        "(SIGNMAP_MAP_PAGE_MAX, default 2000).",
            responses={400: {"model": ErrorOut, "description": "bad bbox, cursor or since"},
                       **AUTH_ERRORS})
async def get_map_signs(request: Request, settings: SettingsDep,
                        bbox: Annotated[str, Query(examples=["8.41,49.00,8.43,49.02"])],
                        cls: Annotated[str | None, Query(alias="class", examples=["stop"],
                                                         pattern=NO_NUL)] = None,
                        since: datetime | None = None, state: MapSignState | None = None,
                        limit: Annotated[int, Query(ge=1, le=10000)] = 1000,
                        cursor: Annotated[str | None, Query(pattern=NO_NUL)] = None) -> Response:
    try:
        box = BBox.parse(bbox)
        after = None if cursor is None else parse_cursor(cursor)
    except ValueError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc
    limit = min(limit, settings.map_page_max)
    since = None if since is None else _since_utc(since)

    def read() -> bytes:
        with read_connection(settings.effective_database_url) as conn:
            return signs_page_json(conn, box, cls, since, state, after, limit)

    # Built here rather than through response_model: validating thousands of features one by one
    # was most of the time of a page (issue 13, finding 7); tests check the shape instead.
    return Response(await heavy_read(request, read), media_type="application/json")


@router.get("/signs/changes", response_model=MapChanges, dependencies=READER,
            summary="Map signs created, updated or removed since a time",
            description="For clients that keep a copy of the map: call with the previous "
                        "answer's `until`. Removed signs come as tombstones.",
            responses={400: {"model": ErrorOut, "description": "since out of range"},
                       **AUTH_ERRORS})
def get_map_changes(session: SessionDep, since: datetime) -> dict[str, Any]:
    since = _since_utc(since)
    until = session.scalar(select(func.max(MapSignRow.updated_at))) or since
    rows = list(session.scalars(select(MapSignRow).where(MapSignRow.updated_at >= since)
                                .order_by(MapSignRow.id)))
    live = [r for r in rows if r.removed_at is None]
    return {"since": since, "until": max(until, since),
            "created": [map_sign_feature(r) for r in live if r.created_at >= since],
            "updated": [map_sign_feature(r) for r in live if r.created_at < since],
            "removed": [{"id": r.id, "removed_at": r.removed_at.isoformat()}
                        for r in rows if r.removed_at is not None]}


@router.get("/signs/{sign_id}", dependencies=READER,
            summary="One map sign with its evidence (GeoJSON Feature)",
            description="`properties.members`: the journey signs fused into it, with the frames "
                        "and camera-frame positions they were seen at and the detection boxes; "
                        "`properties.evidence`: fusion weights, outliers and the change rule.",
            responses={404: {"model": ErrorOut, "description": "no such map sign"},
                       **AUTH_ERRORS})
def get_map_sign(session: SessionDep, sign_id: Annotated[str, Path(pattern=NO_NUL)]
                 ) -> dict[str, Any]:
    row = session.get(MapSignRow, sign_id)
    if row is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"map sign {echoed_id(sign_id)} not found")
    return map_sign_feature(
        row, evidence=row.evidence, cov_enu=row.cov_enu, members=map_sign_members(session, sign_id),
        removed_at=row.removed_at.isoformat() if row.removed_at else None)
