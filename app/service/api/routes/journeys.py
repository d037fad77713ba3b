"""Routes of journeys (base path /api/v1): upload, list, status, a journey's signs, deletion."""

from __future__ import annotations

import logging
import time
import uuid
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Query, Request, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from sqlalchemy import select, update
from sqlalchemy.exc import IntegrityError, SQLAlchemyError
from sqlalchemy.orm import Session

from app.geojson import feature_collection
from app.pipeline.bundle import check_bundle
from app.pipeline.types import BundleError
from app.service import storage
from app.service.api.schemas import (AUTH_ERRORS, NO_NUL, ErrorOut, JourneyAccepted, JourneyOut,
                                     SignCollection, echoed_id)
from app.service.api.upload import FIELD, receive_bundle
from app.service.api.upload_limits import admit_upload, upload_limiter
from app.service.auth import Principal
from app.service.db import crud, queries
from app.service.db.models import JourneyRow
from app.service.deps import Admin, Fleet, SessionDep, SettingsDep
from app.service.jobs import fusion
from app.settings import Settings

log = logging.getLogger(__name__)
router = APIRouter(prefix="/api/v1")

_NOT_YOURS = {404: {"model": ErrorOut, "description": "no such journey among the caller's"}}
JourneyId = Annotated[str, Path(pattern=NO_NUL)]


def _journey_out(row: JourneyRow) -> dict[str, Any]:
    return JourneyOut.model_validate(row, from_attributes=True).model_dump(mode="json")


def _own_journey(session: Session, journey_id: str, who: Principal) -> JourneyRow:
    row = session.get(JourneyRow, journey_id)
    # Another fleet's journey answers 404 like a missing one: ids are not disclosed across fleets.
    if row is None or not who.owns(row.owner_key_id):
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"journey {echoed_id(journey_id)} not found")
    return row


@router.post(
    "/journeys", status_code=status.HTTP_202_ACCEPTED, response_model=JourneyAccepted,
    summary="Upload a journey bundle",
    description=f"Multipart form with the journey zip (wire contract, section 1) in the field "
                f"`{FIELD}`, e.g. `curl -H 'Authorization: Bearer $KEY' -F {FIELD}=@journey.zip "
                f".../api/v1/journeys`. The bundle is validated before it is queued (its frames' "
                f"headers and ends: a frame that does not decode fails the journey's job, naming "
                f"it). Re-uploading the same bytes answers **200** with the existing journey (a "
                f"failed one is queued again and answers 202). Each key may make "
                f"SIGNMAP_UPLOAD_LIMIT_COUNT_PER_MIN uploads of SIGNMAP_UPLOAD_LIMIT_BYTES_PER_MIN "
                f"bytes in a minute; past that, **429** with Retry-After.",
    responses={200: {"model": JourneyAccepted, "description": "these bytes were uploaded before"},
               400: {"model": ErrorOut, "description": "malformed multipart body"},
               413: {"model": ErrorOut, "description": "over SIGNMAP_MAX_UPLOAD_MB"},
               415: {"model": ErrorOut, "description": "not multipart/form-data"},
               422: {"model": ErrorOut, "description": "the bundle breaks the wire contract"},
               503: {"model": ErrorOut, "description": "the database, the job queue or the "
                                                       "bundle store is unavailable"},
               **AUTH_ERRORS,
               429: {**AUTH_ERRORS[429], "description": "this key made too many uploads, or "
                     "uploaded too many bytes, in the last minute (or too many unknown keys came "
                     "from this client address); try again after Retry-After seconds"}},
    # The body is parsed as a stream (not by FastAPI), so its schema is declared here for /docs.
    openapi_extra={"requestBody": {"required": True, "content": {"multipart/form-data": {
        "schema": {"type": "object", "required": [FIELD], "properties": {FIELD: {
            "type": "string", "format": "binary",
            "description": "the journey bundle (.zip, wire contract section 1)"}}}}}}})
async def upload_journey(request: Request, who: Fleet, settings: SettingsDep,
                         session: SessionDep) -> JSONResponse:
    # Counted before the body is read: a flood of broken uploads costs the API as valid ones do.
    admitted = admit_upload(request, "admin" if who.key_id is None else str(who.key_id))
    limiter = upload_limiter(request)
    incoming = storage.incoming_path(settings.data_dir)
    received = await receive_bundle(request, incoming, settings.max_upload_mb * 1024 * 1024,
                                    on_bytes=lambda n: limiter.received(admitted, n))
    try:
        existing = _existing(request, session, who, received.sha256)
        if existing is not None:
            return existing
        t0 = time.perf_counter()
        try:
            # Checks the contract only, writing nothing: headers and ends of the frames, not their
            # pixels (decoding 4096x4096 frames costs seconds of CPU each; the job decodes them and
            # fails, naming the frame, on one that does not decode). The job builds tracks.
            journey = await run_in_threadpool(check_bundle, incoming, settings.bundle,
                                              decode_images=False)
        except BundleError as exc:
            log.info("upload by key %s rejected: %s", who.key_id, exc.reason)
            raise HTTPException(422, exc.reason) from exc
        validate_s = time.perf_counter() - t0
        try:
            new_file = await run_in_threadpool(request.app.state.store.put, received.sha256,
                                               incoming)
        except storage.StorageUnavailable as exc:
            log.error("upload by key %s not stored: %s", who.key_id, exc)
            raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                                "the bundle store is unreachable; try again later") from exc
    finally:
        incoming.unlink(missing_ok=True)

    row = JourneyRow(id=str(uuid.uuid4()), owner_key_id=who.key_id, camera_id=journey.camera_id,
                     vehicle_id=journey.vehicle_id, captured_at=journey.captured_at,
                     bundle_sha256=received.sha256, bundle_bytes=received.n_bytes,
                     status="queued", progress=0.0, n_frames=journey.n_frames, attempts=0)
    # From here on the bundle is stored: every way this request fails must take it back, or a
    # rejected upload leaves a file no journey refers to and no sweep removes.
    row_kept, shared = False, False
    try:
        try:
            session.add(row)
            session.commit()  # before it is queued: the job reads the row
            row_kept = True
        except IntegrityError:  # the same bytes were accepted concurrently
            session.rollback()
            shared = True
            existing = _existing(request, session, who, received.sha256)
            if existing is not None:
                return existing
            raise
        try:
            request.app.state.queue.submit(row.id)
        except Exception as exc:
            log.exception("journey %s: could not be queued; upload undone", row.id)
            crud.delete_upload(session, row.id)
            session.commit()
            row_kept = False
            raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                                "the job queue is unreachable; try again later") from exc
    except BaseException:
        try:
            session.rollback()
        except SQLAlchemyError:  # the database is gone: nothing was written to undo
            log.warning("upload by key %s: rollback failed", who.key_id, exc_info=True)
        if new_file and not row_kept:
            _take_back_bundle(request, settings, received.sha256, shared)
        raise
    log.info("journey %s queued: %d frames, camera %s, %d bytes, key %s, validated in %.1f s",
             row.id, row.n_frames, row.camera_id, row.bundle_bytes, who.key_id, validate_s)
    return JSONResponse({"id": row.id, "status": "queued"}, status.HTTP_202_ACCEPTED)


def _take_back_bundle(request: Request, settings: Settings, sha256: str, shared: bool) -> None:
    """Delete the bundle this upload stored (it was not stored before) unless a journey refers to
    it: bundles are content-addressed, and another owner may have uploaded the same bytes
    meanwhile. Never raises: the request's own error is the answer."""
    store = request.app.state.store
    try:
        storage.release_bundle(settings.effective_database_url, store, sha256)
        return
    except SQLAlchemyError as exc:
        if shared:  # another journey's row holds these bytes: keep them
            log.warning("bundle %s kept: the database cannot be read (%s)", sha256, exc)
            return
        # The database cannot tell; this request created the file, and only an upload of the same
        # bytes by another owner in this very moment could refer to it: a leftover is likelier.
        log.warning("bundle %s deleted without checking for other journeys: the database cannot "
                    "be read (%s)", sha256, exc)
    except Exception:
        log.exception("bundle %s: could not be taken back after a failed upload", sha256)
        return
    try:
        store.delete(sha256)
    except Exception:
        log.exception("bundle %s: could not be taken back after a failed upload", sha256)


def _existing(request: Request, session: Session, who: Principal, sha256: str
              ) -> JSONResponse | None:
    """The answer to a re-upload of bytes this owner uploaded before; a failed journey is requeued.
    Commits either way (the requeue before it is submitted; a plain read holds no connection while
    the bundle is checked)."""
    row = crud.owned_upload(session, who.key_id, sha256)
    requeued = row is not None and crud.requeue_failed(session, row.id)
    session.commit()
    if row is None:
        return None
    if requeued:
        try:
            request.app.state.queue.submit(row.id)
        except Exception as exc:
            # Failed again, not queued: a queued row that no queue holds would never run, and its
            # next re-upload would answer "queued" instead of queueing it.
            log.exception("journey %s: could not be queued again", row.id)
            session.execute(update(JourneyRow).where(JourneyRow.id == row.id,
                                                     JourneyRow.status == "queued")
                            .values(status="failed", error="could not be queued again: the job "
                                    "queue was unreachable; upload the bundle again"))
            session.commit()
            raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                                "the job queue is unreachable; try again later") from exc
        log.info("journey %s: re-uploaded after failing; queued again", row.id)
        return JSONResponse({"id": row.id, "status": "queued"}, status.HTTP_202_ACCEPTED)
    return JSONResponse({"id": row.id, "status": row.status}, status.HTTP_200_OK)


@router.get("/journeys", response_model=list[JourneyOut], summary="The caller's journeys",
            description="Newest first; a fleet key sees its own journeys, an admin key all.",
            responses=AUTH_ERRORS)
def list_journeys(who: Fleet, session: SessionDep,
                  limit: Annotated[int, Query(ge=1, le=500)] = 50) -> list[dict[str, Any]]:
    query = select(JourneyRow).order_by(JourneyRow.created_at.desc()).limit(limit)
    if who.role != "admin":
        query = query.where(JourneyRow.owner_key_id == who.key_id)
    return [_journey_out(row) for row in session.scalars(query)]


@router.get("/journeys/{journey_id}", response_model=JourneyOut, summary="A journey's status",
            responses={**AUTH_ERRORS, **_NOT_YOURS})
def get_journey(journey_id: JourneyId, who: Fleet, session: SessionDep) -> dict[str, Any]:
    return _journey_out(_own_journey(session, journey_id, who))


@router.get("/journeys/{journey_id}/signs", response_model=SignCollection,
            summary="The signs one journey triangulated (GeoJSON)",
            description="Empty until the journey is done. Each feature carries the sign's "
                        "position in every observing frame's camera.",
            responses={**AUTH_ERRORS, **_NOT_YOURS})
def get_journey_signs(journey_id: JourneyId, who: Fleet, session: SessionDep) -> dict[str, Any]:
    _own_journey(session, journey_id, who)
    return feature_collection(queries.journey_signs(session, journey_id))


@router.delete("/journeys/{journey_id}", status_code=status.HTTP_204_NO_CONTENT,
               summary="Delete a journey (admin)",
               description="Removes the journey, its signs and coverage, and re-fuses the map "
                           "around it; its stored bundle goes too unless another journey was "
                           "uploaded with the same bytes. A running journey answers 409.",
               responses={404: {"model": ErrorOut, "description": "no such journey"},
                          409: {"model": ErrorOut, "description": "the journey is running"},
                          **AUTH_ERRORS})
def delete_journey(request: Request, journey_id: JourneyId, who: Admin,
                   settings: SettingsDep) -> None:
    try:
        found = fusion.delete_journey_and_bundle(settings, request.app.state.store, journey_id)
    except fusion.JourneyRunning:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"journey {echoed_id(journey_id)} is running") from None
    if not found:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"journey {echoed_id(journey_id)} not found")
