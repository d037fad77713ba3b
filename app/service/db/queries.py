"""Reading signs out of the database as GeoJSON features: a journey's signs, a map sign with its
members (a page of the map is ``map_read``'s)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import Select, and_, func, or_, select
from sqlalchemy.orm import Session

from app.geojson import sign_feature
from app.service.db.models import (JourneyRow, JourneySignRow, MapSignMemberRow, MapSignRow,
                                   serves_result)


@dataclass(frozen=True)
class BBox:
    """WGS84 degrees; ``min_lon > max_lon`` means the box crosses the antimeridian (RFC 7946 5.2)."""

    min_lon: float
    min_lat: float
    max_lon: float
    max_lat: float

    @classmethod
    def parse(cls, text: str) -> "BBox":
        """From ``minlon,minlat,maxlon,maxlat``; ValueError says what is wrong."""
        parts = text.split(",")
        if len(parts) != 4:
            raise ValueError("bbox must be minlon,minlat,maxlon,maxlat")
        try:
            box = cls(*(float(p) for p in parts))
        except ValueError:
            raise ValueError("bbox values must be numbers") from None
        if not all(-180 <= v <= 180 for v in (box.min_lon, box.max_lon)):
            raise ValueError("bbox longitudes must be within [-180, 180]")
        if not all(-90 <= v <= 90 for v in (box.min_lat, box.max_lat)):
            raise ValueError("bbox latitudes must be within [-90, 90]")
        if box.min_lat > box.max_lat:
            raise ValueError("bbox minlat must not exceed maxlat")
        return box

    def lon_ranges(self) -> list[tuple[float, float]]:
        if self.min_lon <= self.max_lon:
            return [(self.min_lon, self.max_lon)]
        return [(self.min_lon, 180.0), (-180.0, self.max_lon)]


def _in_bbox(dialect: str, bbox: BBox):
    if dialect == "postgresql":
        # Matches the GiST index on point(lon_deg, lat_deg) (migration 0001).
        point = func.point(JourneySignRow.lon_deg, JourneySignRow.lat_deg)
        return or_(*(point.op("<@")(func.box(func.point(lo, bbox.min_lat),
                                             func.point(hi, bbox.max_lat)))
                     for lo, hi in bbox.lon_ranges()))
    return and_(JourneySignRow.lat_deg.between(bbox.min_lat, bbox.max_lat),
                or_(*(JourneySignRow.lon_deg.between(lo, hi) for lo, hi in bbox.lon_ranges())))


def map_signs_query(dialect: str, bbox: BBox, cls: str | None = None, limit: int = 1000) -> Select:
    query = (select(JourneySignRow).join(JourneyRow, JourneyRow.id == JourneySignRow.journey_id)
             .where(serves_result(), _in_bbox(dialect, bbox))
             .order_by(JourneySignRow.id).limit(limit))
    return query if cls is None else query.where(JourneySignRow.cls == cls)


def journey_signs(session: Session, journey_id: str) -> list[dict[str, Any]]:
    rows = session.scalars(select(JourneySignRow).where(JourneySignRow.journey_id == journey_id)
                           .order_by(JourneySignRow.id))
    return [_feature(row, with_observations=True) for row in rows]


def _feature(row: JourneySignRow, with_observations: bool) -> dict[str, Any]:
    extra: dict[str, Any] = {"observations": row.observations} if with_observations else {}
    return sign_feature(row.id, row.cls, row.lon_deg, row.lat_deg, row.alt_m,
                        track_id=row.track_id, journey_id=row.journey_id, std_m=row.std_m,
                        r95_h_m=row.r95_h_m, facing_deg=row.facing_deg,
                        reprojection_rms_px=row.reprojection_rms_px, **extra)


def map_sign_feature(row: MapSignRow, **extra: Any) -> dict[str, Any]:
    """A map sign as GeoJSON (times as ``isoformat``); ``extra`` properties after its own."""
    return sign_feature(row.id, row.cls, row.lon_deg, row.lat_deg, row.alt_m, state=row.state,
                        std_m=row.std_m, n_journeys=row.n_journeys,
                        n_observations=row.n_observations,
                        first_seen_at=row.first_seen_at.isoformat(),
                        last_seen_at=row.last_seen_at.isoformat(), facing_deg=row.facing_deg,
                        **extra)


def map_sign_members(session: Session, map_sign_id: str) -> list[dict[str, Any]]:
    """The journey signs fused into a map sign, with their weights and observations."""
    rows = session.execute(
        select(MapSignMemberRow.weight, JourneySignRow).join(
            JourneySignRow, JourneySignRow.id == MapSignMemberRow.journey_sign_id)
        .where(MapSignMemberRow.map_sign_id == map_sign_id).order_by(JourneySignRow.id)).all()
    return [{"journey_sign_id": s.id, "journey_id": s.journey_id, "track_id": s.track_id,
             "class": s.cls, "lat": s.lat_deg, "lon": s.lon_deg, "alt_m": s.alt_m,
             "std_m": s.std_m, "weight": weight, "observations": s.observations}
            for weight, s in rows]
