"""Dashboard pages and actions. Every route but the sign-in form needs a signed-in admin session.
The map's data routes under /admin/api are the public API's own functions (``api.routes.map`` and
``tiles``), served here behind the sign-in instead of an API key."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated
from urllib.parse import quote, urlsplit

from fastapi import APIRouter, Depends, Form, HTTPException, Query, Request
from fastapi import Path as PathParam
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from fastapi.templating import Jinja2Templates
from pydantic import BaseModel, ConfigDict, ValidationError

from app.service import storage
from app.service.admin import data, media
from app.service.admin.session import (DashboardSession, cookie_args, current_session,
                                       deletion_args, sign_in, sign_out)
from app.service.api.routes import cameras as camera_routes
from app.service.api.routes import journeys as journey_routes
from app.service.api.routes import map as map_routes
from app.service.api.routes import tiles as tile_routes
from app.service.api.schemas import echoed_id
from app.service.auth import RevokedKey, UnknownKey, list_keys, revoke_key
from app.service.db import crud
from app.service.db.models import STATUSES, CoverageRow, JourneyRow, JourneySignRow
from app.service.deps import SessionDep, SettingsDep, count_failure, refuse_if_throttled
from app.service.jobs import cameras as camera_jobs

log = logging.getLogger(__name__)
templates = Jinja2Templates(directory=str(Path(__file__).parent / "templates"))
router = APIRouter(prefix="/admin", include_in_schema=False)
SignedIn = Annotated[DashboardSession, Depends(current_session)]


def _same_origin(request: Request) -> None:
    """Actions are form posts; SameSite=strict already keeps other sites' posts cookieless, and a
    post from another origin is refused as well: by its Origin, or by its Referer when it has no
    Origin (browsers that send none). ``Origin: null`` (a sandboxed or privacy-stripped context)
    is refused too.

    A post with neither header is let through: browsers send Origin on every POST, so such a
    post comes from a script or tool, not from a page a signed-in operator visits, which is what
    forging needs; refusing it would stop nothing forged and break scripted use."""
    for header in ("origin", "referer"):
        value = request.headers.get(header)
        if value is not None:
            if urlsplit(value).netloc != request.url.netloc:
                raise HTTPException(403, f"refused: this form was posted from another site "
                                         f"({header.title()} is not {request.url.netloc}); "
                                         f"post it from the dashboard's own page")
            return


def _page(request: Request, name: str, status_code: int = 200, **context) -> HTMLResponse:
    return templates.TemplateResponse(request, name, context, status_code=status_code)


@router.get("/login")
def login_form(request: Request) -> HTMLResponse:
    return _page(request, "login.html")


@router.post("/login")
def login(request: Request, settings: SettingsDep, session: SessionDep,
          key: Annotated[str, Form()] = "") -> Response:
    _same_origin(request)
    try:
        refuse_if_throttled(request)  # before the key is looked at: the right one is refused too
    except HTTPException as exc:
        page = _page(request, "login.html", exc.status_code, error=exc.detail)
        page.headers.update(exc.headers or {})
        return page
    try:
        cookie = sign_in(session, settings, key.strip()) if key.strip() else None
    except RevokedKey:
        return _page(request, "login.html", 403, error="this key was revoked")
    if cookie is None:
        log.info("dashboard sign-in refused from %s", request.client.host if request.client else "?")
        count_failure(request, "dashboard sign-in refused")
        return _page(request, "login.html", 403, error="not an admin key")
    response = RedirectResponse("/admin/journeys", status_code=303)
    response.set_cookie(value=cookie, **cookie_args(request, settings))
    return response


@router.post("/logout")
def logout(request: Request, signed_in: SignedIn, session: SessionDep) -> Response:
    _same_origin(request)
    sign_out(session, signed_in.token_sha256)
    response = RedirectResponse("/admin/login", status_code=303)
    response.delete_cookie(**deletion_args(request))
    return response


@router.get("")
@router.get("/")
def home(_signed_in: SignedIn) -> Response:
    return RedirectResponse("/admin/journeys", status_code=303)


@router.get("/journeys")
def journeys(request: Request, _signed_in: SignedIn, session: SessionDep,
             status: str | None = None, camera: str | None = None,
             page: Annotated[int, Query(ge=1)] = 1) -> HTMLResponse:
    listing = data.list_journeys(session, status or None, camera or None, page)
    cameras = data.camera_ids(session)
    return _page(request, "journeys.html", listing=listing, statuses=STATUSES, cameras=cameras,
                 status=status or "", camera=camera or "")


@router.get("/journeys/progress.json")
def journeys_progress(_signed_in: SignedIn, session: SessionDep, ids: str = "") -> dict:
    wanted = [i for i in ids.split(",") if i][:500]
    return data.progress(session, wanted)


@router.post("/journeys/{journey_id}/retry")
def retry(request: Request, journey_id: str, _signed_in: SignedIn, session: SessionDep
          ) -> Response:
    _same_origin(request)
    if not crud.retry(session, journey_id):
        raise HTTPException(409, "only a failed journey, or one waiting for its camera, can be "
                                 "retried")
    session.commit()  # before it is queued: the job reads the row
    request.app.state.queue.submit(journey_id)
    log.info("journey %s: retried from the dashboard", journey_id)
    back = urlsplit(request.headers.get("referer", ""))
    path = back.path if back.path.startswith("/admin/journeys") else "/admin/journeys"
    return RedirectResponse(f"{path}?{back.query}" if back.query else path, status_code=303)


@router.post("/journeys/{journey_id}/delete")
def delete(request: Request, journey_id: journey_routes.JourneyId, signed_in: SignedIn,
           settings: SettingsDep) -> Response:
    _same_origin(request)
    # The API's own deletion (re-fuses the map around it; 404 or 409 as there), as this admin.
    journey_routes.delete_journey(request, journey_id, signed_in.principal, settings)
    log.info("journey %s: deleted from the dashboard", journey_id)
    return RedirectResponse("/admin/journeys", status_code=303)


def _journey(session, journey_id: str) -> JourneyRow:
    row = session.get(JourneyRow, journey_id)
    if row is None:
        raise HTTPException(404, f"journey {echoed_id(journey_id)} not found")
    return row


@router.get("/journeys/{journey_id}")
def journey(request: Request, journey_id: str, _signed_in: SignedIn, settings: SettingsDep,
            session: SessionDep) -> HTMLResponse:
    row = _journey(session, journey_id)
    signs = data.journey_signs(session, journey_id)
    history = data.calibrations(session, row.camera_id)
    coverage = session.get(CoverageRow, journey_id)
    estimated = [] if coverage is None else media.estimated_track(
        coverage.poses, coverage.origin_lat_deg, coverage.origin_lon_deg, coverage.origin_alt_m)
    session.commit()  # the rest reads the bundle, not the database
    try:
        track = media.gps_track(settings.data_dir, request.app.state.store, row.bundle_sha256)
    except Exception as exc:  # noqa: BLE001 - a missing/unreadable bundle must not hide the page
        log.warning("journey %s: no GPS track for the dashboard: %s", journey_id, exc)
        track = []
    sign_points = [{"id": s.id, "track": s.track_id, "cls": s.cls, "lat": s.lat_deg,
                    "lon": s.lon_deg, "std_m": s.std_m} for s in signs]
    return _page(request, "journey.html", j=row, signs=signs, history=history, track=track,
                 estimated=estimated, sign_points=sign_points, tile_url=settings.map_tile_url)


@router.get("/journeys/{journey_id}/crop.png")
def crop(request: Request, journey_id: str, track: str, frame: str, _signed_in: SignedIn,
         settings: SettingsDep, session: SessionDep) -> Response:
    row = _journey(session, journey_id)
    sign = session.get(JourneySignRow, f"{journey_id}:{track}")
    session.commit()  # the rest reads the bundle, not the database
    obs = next((o for o in (sign.observations if sign else []) if o.get("frame") == frame), None)
    if obs is None:
        raise HTTPException(404, "no such observation")
    try:
        png = media.crop_png(settings.data_dir, request.app.state.store, row.bundle_sha256, frame,
                             obs.get("box"))
    except storage.BundleMissing as exc:
        raise HTTPException(404, str(exc)) from exc
    except storage.StorageUnavailable as exc:
        raise HTTPException(503, str(exc)) from exc
    if png is None:
        raise HTTPException(404, "frame not in the bundle")
    return Response(png, media_type="image/png",
                    headers={"Cache-Control": "private, max-age=86400"})


@router.get("/map")
def map_page(request: Request, _signed_in: SignedIn, settings: SettingsDep) -> HTMLResponse:
    return _page(request, "map.html", tile_url=settings.map_tile_url)


# The map page's data: the public routes' functions, same parameters and answers, behind the sign-in.
for _path, _endpoint in (("/api/signs", map_routes.get_map_signs),
                         ("/api/tiles/{z}/{x}/{y}.mvt", tile_routes.get_tile),
                         ("/api/signs/{sign_id}", map_routes.get_map_sign)):
    router.add_api_route(_path, _endpoint, methods=["GET"],
                         dependencies=[Depends(current_session)])


def _cameras_page(request: Request, session, settings, status_code: int = 200,
                  form_camera: str | None = None, form: dict | None = None,
                  form_errors: list[str] | None = None) -> HTMLResponse:
    return _page(request, "cameras.html", status_code, sections=data.camera_sections(
        session, settings), agree_pct=100 * settings.calibration_flag_rel,
        newest=settings.calibration_consensus_newest, form_camera=form_camera,
        form=form or {}, form_errors=form_errors or [])


@router.get("/cameras")
def cameras(request: Request, _signed_in: SignedIn, settings: SettingsDep,
            session: SessionDep) -> HTMLResponse:
    return _cameras_page(request, session, settings)


class CalibrationForm(BaseModel):
    """The Cameras page's registration form, as typed (``data.registration_body`` parses it)."""

    model_config = ConfigDict(extra="ignore")

    width: str = ""
    height: str = ""
    fx: str = ""
    fy: str = ""
    cx: str = ""
    cy: str = ""
    k1: str = ""
    k2: str = ""
    sigma_fx: str = ""
    sigma_fy: str = ""
    sigma_cx: str = ""
    sigma_cy: str = ""
    sigma_k1: str = ""
    sigma_k2: str = ""


@router.post(f"/cameras/{{camera_id:{camera_routes.CAMERA_ID}}}/calibration")
def register_calibration(request: Request, camera_id: str,
                         form: Annotated[CalibrationForm, Form()], signed_in: SignedIn,
                         settings: SettingsDep, session: SessionDep) -> Response:
    """The API's PUT /cameras/{camera_id}/calibration from the Cameras page's form: the page
    again with what is wrong (422), or back to the camera's section."""
    _same_origin(request)
    typed = form.model_dump()
    body, errors = data.registration_body(typed)
    registration = None
    if not errors:
        try:
            registration = camera_jobs.Registration.model_validate(body)
        except ValidationError as exc:
            errors = [f"{'.'.join(str(p) for p in e['loc'])}: "
                      f"{e['msg'].removeprefix('Value error, ')}" for e in exc.errors()]
    url = settings.effective_database_url
    if registration is not None:
        try:
            epoch, new = camera_jobs.register(url, camera_id, registration,
                                              signed_in.principal.name)
        except camera_jobs.InvalidCalibration as exc:
            errors = [f"{e['loc'][-1]}: {e['msg']}" for e in exc.errors]
    if errors:
        return _cameras_page(request, session, settings, 422, form_camera=camera_id,
                             form=typed, form_errors=errors)
    session.commit()  # the page's reads are done; the wake commits on its own
    try:
        resumed = camera_jobs.wake_waiting(url, camera_id,
                                           (registration.width, registration.height),
                                           request.app.state.queue.submit)
    except Exception:  # the queue is down: they stay waiting, and the workers' sweeps wake them
        log.exception("camera %s: waiting journeys not queued again now", camera_id)
        resumed = []
    try:
        camera_jobs.reprocess_superseded(url, camera_id, request.app.state.queue.submit)
    except Exception:  # the queue is down: they stay done, with a message; register again
        log.exception("camera %s: journeys not queued for re-processing now", camera_id)
    log.info("camera %s: calibration registered from the dashboard by %r (epoch %d%s); %d "
             "waiting journeys queued again", camera_id, signed_in.principal.name, epoch,
             "" if new else ", unchanged", len(resumed))
    return RedirectResponse(f"/admin/cameras#camera-{quote(camera_id, safe='')}",
                            status_code=303)


@router.get("/keys")
def keys(request: Request, _signed_in: SignedIn, session: SessionDep) -> HTMLResponse:
    return _page(request, "keys.html", keys=list_keys(session))


@router.post("/keys/{key_id}/revoke")
def revoke(request: Request, key_id: Annotated[int, PathParam(ge=1, le=2**31 - 1)],
           signed_in: SignedIn, session: SessionDep) -> Response:
    _same_origin(request)
    try:
        row, revoked = revoke_key(session, key_id)
    except UnknownKey as exc:
        raise HTTPException(404, str(exc)) from exc
    if revoked:
        log.info("key %d (%s, %r) revoked from the dashboard by %r", row.id, row.role,
                 row.name, signed_in.principal.name)
    # Revoking the key this session signed in with ended the session: the page sends to sign-in.
    return RedirectResponse("/admin/keys", status_code=303)
