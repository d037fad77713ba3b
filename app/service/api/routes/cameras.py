"""Routes of cameras (base path /api/v1): what the service knows of each camera, and a calibration
an admin registers (``app.service.jobs.cameras``, ``camera_view``).

A camera id is any printable string of the manifest (``/`` included): the routes take the rest of
the path, so ``GET /api/v1/cameras/van/3`` is camera ``van/3`` (``%2F`` works too). Line breaks
too (Starlette's ``path`` stops at one), so that an id no manifest can have is answered by the
route (404 on GET, 422 on PUT), not by the router."""

from __future__ import annotations

import logging
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Request, status
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session
from starlette.convertors import PathConvertor, register_url_convertor

from app.service.api.schemas import (AUTH_ERRORS, NO_NUL, CameraOut, CameraRegistered, ErrorOut,
                                     echoed_id)
from app.service.auth import Principal
from app.service.db.session import session_scope
from app.service.deps import Admin, Fleet, SessionDep, SettingsDep
from app.service.jobs import camera_view, cameras
from app.settings import Settings

log = logging.getLogger(__name__)
router = APIRouter(prefix="/api/v1")


class _CameraIdConvertor(PathConvertor):
    regex = r"[\s\S]*"


# The convertor of a camera id in a route's path: "{camera_id:" + CAMERA_ID + "}".
CAMERA_ID = "camera_id"
register_url_convertor(CAMERA_ID, _CameraIdConvertor())

CameraId = Annotated[str, Path(pattern=NO_NUL, description="the manifest's camera_id")]
_NOT_YOURS = {404: {"model": ErrorOut, "description": "no such camera among the caller's"}}


def _view(session: Session, camera_id: str, who: Principal, settings: Settings
          ) -> dict[str, Any]:
    admin = who.role == "admin"
    view = (camera_view.camera_view(session, camera_id, settings)
            if admin or camera_view.owns_journey_of(session, camera_id, who.key_id) else None)
    # Another fleet's camera answers 404 like an unknown one, as its journeys do.
    if view is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"camera {echoed_id(camera_id)} not found")
    return camera_view.to_json(view, who.owns, admin)


@router.get("/cameras", response_model=list[CameraOut], summary="The caller's cameras",
            description="Every camera the service knows (of a journey, or with a registered "
                        "calibration), by camera_id; a fleet key sees the cameras of the "
                        "journeys it uploaded. Each as `GET /cameras/{camera_id}` answers.",
            responses=AUTH_ERRORS)
def list_cameras(who: Fleet, session: SessionDep, settings: SettingsDep) -> list[dict[str, Any]]:
    admin = who.role == "admin"
    answer = []
    for camera_id in camera_view.camera_ids(session, who.key_id, everyone=admin):
        view = camera_view.camera_view(session, camera_id, settings)
        if view is not None:
            answer.append(camera_view.to_json(view, who.owns, admin))
    return answer


@router.get("/cameras/{camera_id:camera_id}", response_model=CameraOut,
            summary="A camera: its calibration over all its journeys",
            description="The calibration its journeys without a turn are given (registered, or "
                        "the consensus of its self-calibrations) with sigmas, the journeys in it "
                        "and those left out with the reason, the journeys waiting for it, and its "
                        "epochs (a registered calibration starts one). A fleet key: only cameras "
                        "of journeys it uploaded (404 otherwise); journeys of other owners are "
                        "counted, not named.",
            responses={**AUTH_ERRORS, **_NOT_YOURS})
def get_camera(camera_id: CameraId, who: Fleet, session: SessionDep,
               settings: SettingsDep) -> dict[str, Any]:
    return _view(session, camera_id, who, settings)


@router.put("/cameras/{camera_id:camera_id}/calibration", response_model=CameraRegistered,
            summary="Register a camera's calibration (admin)",
            description="The camera's known calibration, used as given for its later journeys "
                        "(never averaged with self-calibrations): it starts a new epoch, and the "
                        "older epochs' self-calibrations stay there. A later journey's "
                        "self-calibration that disagrees with it is flagged on that journey "
                        "(`calibration_flag`) and listed in `left_out`. The camera's journeys "
                        "waiting for a calibration (stage `waiting_for_camera`) are queued again "
                        "(`resumed`), and its done journeys that were given another calibration "
                        "of it (not self-calibrated, frames of its size) are processed again with "
                        "this one (`reprocess_queued`, `reprocessing`), serving their earlier "
                        "signs until then. The same values again change nothing (`new_epoch` false). "
                        "A camera with no journey yet may be registered too.",
            responses={400: {"model": ErrorOut, "description": "the body is not JSON"},
                       422: {"model": ErrorOut, "description": "a value that is no camera, or "
                             "an image size none of the camera's journeys has; `detail` lists "
                             "each field (`loc`) and what is wrong (`msg`)"},
                       **AUTH_ERRORS})
def put_calibration(request: Request, camera_id: CameraId, body: cameras.Registration,
                    who: Admin, settings: SettingsDep) -> Any:
    url = settings.effective_database_url
    try:
        epoch, new = cameras.register(url, camera_id, body, who.name)
    except cameras.InvalidCalibration as exc:
        return JSONResponse({"detail": exc.errors}, 422)
    try:
        resumed = cameras.wake_waiting(url, camera_id, (body.width, body.height),
                                       request.app.state.queue.submit)
    except Exception:  # the queue is down: they stay waiting, and the workers' sweeps wake them
        log.exception("camera %s: waiting journeys not queued again now", camera_id)
        resumed = []
    try:
        reprocess = cameras.reprocess_superseded(url, camera_id, request.app.state.queue.submit)
    except Exception:  # the queue is down: they stay done, with a message; PUT again to queue
        log.exception("camera %s: journeys not queued for re-processing now", camera_id)
        reprocess = []
    with session_scope(url) as session:
        answer = _view(session, camera_id, who, settings)
    return {**answer, "registered_epoch": epoch, "new_epoch": new, "resumed": resumed,
            "reprocess_queued": reprocess}
