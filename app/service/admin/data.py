"""What the dashboard pages show, read from the service's tables (no HTTP here)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.service.db.models import CalibrationRow, JourneyRow, JourneySignRow
from app.service.jobs import state

PAGE_SIZE = 50
LIST_COLUMNS = (JourneyRow.id, JourneyRow.camera_id, JourneyRow.status, JourneyRow.stage, JourneyRow.progress,
                JourneyRow.n_frames, JourneyRow.n_signs, JourneyRow.error, JourneyRow.created_at,
                JourneyRow.started_at, JourneyRow.finished_at, JourneyRow.attempts)


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
        where.append(JourneyRow.status == status)
    if camera_id:
        where.append(JourneyRow.camera_id == camera_id)
    total = session.scalar(select(func.count()).select_from(JourneyRow).where(*where))
    n_pages = max(1, -(-total // PAGE_SIZE))
    page = min(max(1, page), n_pages)
    query = (select(*LIST_COLUMNS).where(*where)
             .order_by(JourneyRow.created_at.desc(), JourneyRow.id)
             .offset((page - 1) * PAGE_SIZE).limit(PAGE_SIZE))
    rows = [dict(r._mapping, wall_s=_wall_s(r)) for r in session.execute(query)]
    return JourneyPage(rows=rows, total=total, page=page, n_pages=n_pages)


def camera_ids(session: Session) -> list[str]:
    return list(session.scalars(select(JourneyRow.camera_id).distinct().order_by(JourneyRow.camera_id)))


def progress(session: Session, ids: list[str]) -> dict[str, dict[str, Any]]:
    rows = session.execute(select(JourneyRow.id, JourneyRow.status, JourneyRow.stage, JourneyRow.progress,
                                  JourneyRow.error, JourneyRow.n_signs).where(JourneyRow.id.in_(ids)))
    return {r.id: {"status": r.status, "stage": r.stage, "progress": r.progress,
                   "error": r.error, "n_signs": r.n_signs} for r in rows}


def journey_signs(session: Session, journey_id: str) -> list[JourneySignRow]:
    return list(session.scalars(select(JourneySignRow).where(JourneySignRow.journey_id == journey_id)
                                .order_by(JourneySignRow.id)))


def calibrations(session: Session, camera_id: str | None = None) -> list[CalibrationRow]:
    """Self-calibrations, per camera, oldest first."""
    query = select(CalibrationRow).order_by(CalibrationRow.camera_id,
                                               CalibrationRow.created_at, CalibrationRow.id)
    if camera_id is not None:
        query = query.where(CalibrationRow.camera_id == camera_id)
    return list(session.scalars(query))


@dataclass(frozen=True)
class CameraConsensus:
    """What the camera's later journeys get as its stored calibration (``state.consensus`` of
    its ``considered`` newest self-calibrations, row ids) and which of those agree on it."""

    camera: Any  # CameraModel | None
    members: frozenset[int]
    considered: frozenset[int]


def camera_consensus(records: list[CalibrationRow], agree_rel: float, newest: int
                     ) -> CameraConsensus:
    """``records``: one camera's self-calibrations, oldest first (as ``calibrations`` gives);
    the ``newest`` of them vote."""
    voters = records[::-1][:newest]
    camera, members = state.consensus([state.stored_camera(r) for r in voters], agree_rel)
    return CameraConsensus(camera, frozenset(voters[i].id for i in members),
                           frozenset(r.id for r in voters))


def fx_chart(records: list[CalibrationRow], width: int = 240, height: int = 60
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
