"""What the dashboard pages show, read from the service's tables (no HTTP here)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.service.db.models import CALIBRATION_PARAMS, CalibrationRow, JourneyRow, JourneySignRow
from app.service.jobs import camera_view
from app.settings import Settings

PAGE_SIZE = 50
LIST_COLUMNS = (JourneyRow.id, JourneyRow.camera_id, JourneyRow.status, JourneyRow.stage, JourneyRow.progress,
                JourneyRow.n_frames, JourneyRow.n_signs, JourneyRow.error, JourneyRow.message,
                JourneyRow.created_at,
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
                                  JourneyRow.error, JourneyRow.message, JourneyRow.n_signs)
                           .where(JourneyRow.id.in_(ids)))
    return {r.id: {"status": r.status, "stage": r.stage, "progress": r.progress,
                   "error": r.error, "message": r.message, "n_signs": r.n_signs} for r in rows}


def journey_signs(session: Session, journey_id: str) -> list[JourneySignRow]:
    return list(session.scalars(select(JourneySignRow).where(JourneySignRow.journey_id == journey_id)
                                .order_by(JourneySignRow.id)))


def calibrations(session: Session, camera_id: str | None = None) -> list[CalibrationRow]:
    """Calibrations (self and registered), per camera, oldest first."""
    query = select(CalibrationRow).order_by(CalibrationRow.camera_id,
                                               CalibrationRow.created_at, CalibrationRow.id)
    if camera_id is not None:
        query = query.where(CalibrationRow.camera_id == camera_id)
    return list(session.scalars(query))


@dataclass(frozen=True)
class CameraSection:
    """One camera on the Cameras page: ``camera_view``'s view, its calibrations oldest first,
    the fx chart's points, the ids of the calibrations its epochs left out (each with the
    reason) and of those its current calibration considered, and the API's answer."""

    view: camera_view.CameraView
    rows: list[CalibrationRow]
    chart: list[tuple[float, float]]
    left_out: dict[int, str]
    considered: frozenset[int]
    answer: dict[str, Any]


def camera_sections(session: Session, settings: Settings) -> list[CameraSection]:
    """Every camera the service knows, by camera_id."""
    sections = []
    for camera_id in camera_view.camera_ids(session):
        view = camera_view.camera_view(session, camera_id, settings)
        if view is None:
            continue
        rows = view.rows
        current = view.current
        sections.append(CameraSection(
            view=view, rows=rows, chart=fx_chart(rows),
            left_out={row.id: reason for e in view.epochs for row, reason in e.left_out},
            considered=frozenset(r.id for r in current.considered) if current else frozenset(),
            answer=camera_view.to_json(view)))
    return sections


REGISTRATION_FIELDS = ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2")


def registration_body(form: dict[str, str]) -> tuple[dict[str, Any], list[str]]:
    """The dashboard form's fields as a PUT /cameras/{id}/calibration body (numbers parsed; empty
    optional fields left out), and what is not a number."""
    body: dict[str, Any] = {}
    errors = []
    for name in (*REGISTRATION_FIELDS, *(f"sigma_{k}" for k in CALIBRATION_PARAMS)):
        value = (form.get(name) or "").strip()
        if not value:
            continue
        try:
            number: float | int = int(value) if name in ("width", "height") else float(value)
        except ValueError:
            errors.append(f"{name}: not a number: {value[:40]!r}")
            continue
        if name.startswith("sigma_"):
            body.setdefault("sigma", {})[name.removeprefix("sigma_")] = number
        else:
            body[name] = number
    return body, errors


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
