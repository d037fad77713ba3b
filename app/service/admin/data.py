"""What the dashboard pages show, read from the service's tables (no HTTP here)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import delete, func, select, update
from sqlalchemy.orm import Session

from app.service.models import CalibrationRecord, Journey, JourneySign

PAGE_SIZE = 50
LIST_COLUMNS = (Journey.id, Journey.camera_id, Journey.status, Journey.stage, Journey.progress,
                Journey.n_frames, Journey.n_signs, Journey.error, Journey.created_at,
                Journey.started_at, Journey.finished_at, Journey.attempts)


@dataclass(frozen=True)
class JourneyPage:
    rows: list[dict[str, Any]]
    total: int
    page: int
    n_pages: int


def _wall_s(row) -> float | None:
    if row.started_at is None or row.finished_at is None:
        return None
    return (row.finished_at - row.started_at).total_seconds()


def list_journeys(session: Session, status: str | None, camera_id: str | None, page: int
                  ) -> JourneyPage:
    """One page of journeys, newest first, filtered by status and camera (None = any)."""
    where = []
    if status:
        where.append(Journey.status == status)
    if camera_id:
        where.append(Journey.camera_id == camera_id)
    total = session.scalar(select(func.count()).select_from(Journey).where(*where))
    n_pages = max(1, -(-total // PAGE_SIZE))
    page = min(max(1, page), n_pages)
    query = (select(*LIST_COLUMNS).where(*where)
             .order_by(Journey.created_at.desc(), Journey.id)
             .offset((page - 1) * PAGE_SIZE).limit(PAGE_SIZE))
    rows = [dict(r._mapping, wall_s=_wall_s(r)) for r in session.execute(query)]
    return JourneyPage(rows, total, page, n_pages)


def camera_ids(session: Session) -> list[str]:
    return list(session.scalars(select(Journey.camera_id).distinct().order_by(Journey.camera_id)))


def progress(session: Session, ids: list[str]) -> dict[str, dict[str, Any]]:
    rows = session.execute(select(Journey.id, Journey.status, Journey.stage, Journey.progress,
                                  Journey.error, Journey.n_signs).where(Journey.id.in_(ids)))
    return {r.id: {"status": r.status, "stage": r.stage, "progress": r.progress,
                   "error": r.error, "n_signs": r.n_signs} for r in rows}


def journey_signs(session: Session, journey_id: str) -> list[JourneySign]:
    return list(session.scalars(select(JourneySign).where(JourneySign.journey_id == journey_id)
                                .order_by(JourneySign.id)))


def calibrations(session: Session, camera_id: str | None = None) -> list[CalibrationRecord]:
    """Self-calibrations, per camera, oldest first."""
    query = select(CalibrationRecord).order_by(CalibrationRecord.camera_id,
                                               CalibrationRecord.created_at, CalibrationRecord.id)
    if camera_id is not None:
        query = query.where(CalibrationRecord.camera_id == camera_id)
    return list(session.scalars(query))


def requeue_failed(session: Session, journey_id: str) -> bool:
    """Put a failed journey back to queued exactly as a re-upload does; False if it is not failed."""
    return session.execute(
        update(Journey).where(Journey.id == journey_id, Journey.status == "failed")
        .values(status="queued", stage=None, progress=0.0, error=None, attempts=0)
    ).rowcount == 1


def delete_journey(session: Session, journey_id: str) -> bool:
    """The journey, its signs and its calibration, in the caller's one transaction."""
    session.execute(delete(JourneySign).where(JourneySign.journey_id == journey_id))
    session.execute(delete(CalibrationRecord).where(CalibrationRecord.journey_id == journey_id))
    return session.execute(delete(Journey).where(Journey.id == journey_id)).rowcount == 1


def fx_chart(records: list[CalibrationRecord], width: int = 240, height: int = 60
             ) -> list[tuple[float, float]]:
    """SVG points (x, y) of fx per calibration, oldest first, scaled into ``width`` x ``height``."""
    fxs = [r.fx for r in records]
    if not fxs:
        return []
    lo, hi = min(fxs), max(fxs)
    span = (hi - lo) or 1.0
    step = width / max(1, len(fxs) - 1)
    return [(round(i * step, 1), round(height - 4 - (fx - lo) / span * (height - 8), 1))
            for i, fx in enumerate(fxs)]
