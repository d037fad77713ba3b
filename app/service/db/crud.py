"""Row updates made by the API, the dashboard and the sweeps alike (the job's own writes are in
``app.service.jobs.state``): requeueing a failed (or waiting) journey, taking back an upload,
forgetting expired dashboard sessions. Deleting a journey re-fuses the map: ``app.service.jobs.fusion``."""

from __future__ import annotations

from sqlalchemy import delete, select, update
from sqlalchemy.orm import Session

from app.service.db.models import WAITING_FOR_CAMERA, AdminSessionRow, JourneyRow, utc_now


def owned_upload(session: Session, owner_key_id: int | None, sha256: str) -> JourneyRow | None:
    """The journey this owner uploaded these bytes as, if any."""
    return session.scalars(select(JourneyRow).where(JourneyRow.owner_key_id == owner_key_id,
                                                    JourneyRow.bundle_sha256 == sha256)).first()


def requeue_failed(session: Session, journey_id: str) -> bool:
    """Put a failed journey back to queued, as new (attempts, error and report cleared); False if it
    is not failed. The caller submits it to the queue after the commit."""
    return session.execute(
        update(JourneyRow).where(JourneyRow.id == journey_id, JourneyRow.status == "failed")
        .values(status="queued", stage=None, progress=0.0, error=None, attempts=0, report=None)
    ).rowcount == 1


def retry(session: Session, journey_id: str) -> bool:
    """The dashboard's Retry: a failed journey requeued as new (``requeue_failed``), or one
    waiting for its camera queued to run now (it waits again if its camera still has no
    calibration); False for any other. The caller submits it after the commit."""
    if requeue_failed(session, journey_id):
        return True
    return session.execute(
        update(JourneyRow).where(JourneyRow.id == journey_id, JourneyRow.status == "queued",
                                 JourneyRow.stage == WAITING_FOR_CAMERA)
        .values(stage=None, message=None, progress=0.0, report=None)
    ).rowcount == 1


def delete_upload(session: Session, journey_id: str) -> None:
    """Take back a journey row just inserted by an upload that could not be queued."""
    session.execute(delete(JourneyRow).where(JourneyRow.id == journey_id))


def forget_expired(session: Session) -> int:
    """Delete expired dashboard sessions; returns how many (indexed on expires_at, so cheap when
    none)."""
    return session.execute(delete(AdminSessionRow).where(AdminSessionRow.expires_at <= utc_now())
                           ).rowcount
