"""Routes of the fused map (base path /api/v1): the map signs, one map sign with its evidence, the
changes since a time for incremental clients, and deleting a journey (which re-fuses its region)."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request, status
from pydantic import BaseModel, Field
from sqlalchemy import and_, func, or_, select
from sqlalchemy.orm import Session

from app.geojson import feature_collection, sign_feature
from app.service import fusion_job, storage
from app.service.auth import Principal, require
from app.service.db import session_scope
from app.service.models import Journey, JourneySign, MapSign, MapSignMember
from app.service.queries import BBox
from app.service.schemas import NO_NUL, ErrorOut, PointGeometry

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


def _in_bbox(dialect: str, bbox: BBox):
    if dialect == "postgresql":
        # Matches the GiST index on point(lon_deg, lat_deg) (migration 0002).
        point = func.point(MapSign.lon_deg, MapSign.lat_deg)
        return or_(*(point.op("<@")(func.box(func.point(lo, bbox.min_lat),
                                             func.point(hi, bbox.max_lat)))
                     for lo, hi in bbox.lon_ranges()))
    return and_(MapSign.lat_deg.between(bbox.min_lat, bbox.max_lat),
                or_(*(MapSign.lon_deg.between(lo, hi) for lo, hi in bbox.lon_ranges())))


def map_sign_feature(row: MapSign, **extra: Any) -> dict[str, Any]:
    return sign_feature(row.id, row.cls, row.lon_deg, row.lat_deg, row.alt_m, state=row.state,
                        std_m=row.std_m, n_journeys=row.n_journeys,
                        n_observations=row.n_observations,
                        first_seen_at=row.first_seen_at.isoformat(),
                        last_seen_at=row.last_seen_at.isoformat(), **extra)


def map_signs_query(dialect: str, bbox: BBox, cls: str | None, since: datetime | None,
                    state: str | None, cursor: str | None, limit: int):
    query = select(MapSign).where(MapSign.removed_at.is_(None), _in_bbox(dialect, bbox))
    if cls is not None:
        query = query.where(MapSign.cls == cls)
    if since is not None:
        query = query.where(MapSign.updated_at >= _aware(since))
    if state is not None:
        query = query.where(MapSign.state == state)
    if cursor is not None:
        query = query.where(MapSign.id > cursor)
    return query.order_by(MapSign.id).limit(limit)


@router.get("/signs", response_model=MapSignCollection,
            summary="The fused map's signs in a box (GeoJSON), paginated",
            description="`bbox=minlon,minlat,maxlon,maxlat` in WGS84 degrees (minlon > maxlon "
                        "crosses the antimeridian); optional `class`, `state`, `since` (updated at "
                        "or after, ISO 8601). Ordered by id; follow `next` with `cursor`.",
            responses={400: {"model": ErrorOut, "description": "bad bbox or since"}, **_AUTH})
def get_map_signs(request: Request, who: Annotated[Principal, Depends(require("reader"))],
                  bbox: Annotated[str, Query(examples=["8.41,49.00,8.43,49.02"])],
                  cls: Annotated[str | None, Query(alias="class", examples=["stop"],
                                                   pattern=NO_NUL)] = None,
                  since: datetime | None = None, state: State | None = None,
                  limit: Annotated[int, Query(ge=1, le=10000)] = 1000,
                  cursor: Annotated[str | None, Query(pattern=NO_NUL)] = None
                  ) -> dict[str, Any]:
    try:
        box = BBox.parse(bbox)
    except ValueError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc
    since = None if since is None else _since_utc(since)
    with session_scope(_url(request)) as session:
        query = map_signs_query(session.get_bind().dialect.name, box, cls, since, state, cursor,
                                limit + 1)
        rows = list(session.scalars(query))
    page = rows[:limit]
    return feature_collection([map_sign_feature(r) for r in page],
                              next=page[-1].id if len(rows) > limit else None)


@router.get("/signs/changes", response_model=MapChanges,
            summary="Map signs created, updated or removed since a time",
            description="For clients that keep a copy of the map: call with the previous "
                        "answer's `until`. Removed signs come as tombstones.",
            responses={400: {"model": ErrorOut, "description": "since out of range"}, **_AUTH})
def get_map_changes(request: Request, who: Annotated[Principal, Depends(require("reader"))],
                    since: datetime) -> dict[str, Any]:
    since = _since_utc(since)
    with session_scope(_url(request)) as session:
        until = session.scalar(select(func.max(MapSign.updated_at))) or since
        rows = list(session.scalars(select(MapSign).where(MapSign.updated_at >= since)
                                    .order_by(MapSign.id)))
    live = [r for r in rows if r.removed_at is None]
    return {"since": since, "until": max(until, since),
            "created": [map_sign_feature(r) for r in live if r.created_at >= since],
            "updated": [map_sign_feature(r) for r in live if r.created_at < since],
            "removed": [{"id": r.id, "removed_at": r.removed_at.isoformat()}
                        for r in rows if r.removed_at is not None]}


def _members(session: Session, map_sign_id: str) -> list[dict[str, Any]]:
    rows = session.execute(
        select(MapSignMember.weight, JourneySign).join(
            JourneySign, JourneySign.id == MapSignMember.journey_sign_id)
        .where(MapSignMember.map_sign_id == map_sign_id).order_by(JourneySign.id)).all()
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
        row = session.get(MapSign, sign_id)
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
        row = session.get(Journey, journey_id)
        running = row is not None and row.status == "running"
        sha256 = row.bundle_sha256 if row is not None else None
    if running:
        raise HTTPException(status.HTTP_409_CONFLICT, f"journey {journey_id} is running")
    if not fusion_job.delete_journey(_url(request), journey_id, request.app.state.settings):
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"journey {journey_id} not found")
    storage.release_bundle(_url(request), request.app.state.store, sha256)
