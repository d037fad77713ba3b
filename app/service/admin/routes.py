"""Dashboard pages and actions. Every route but the sign-in form needs a signed-in admin session."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated
from urllib.parse import quote, urlsplit

import httpx
from fastapi import APIRouter, Depends, Form, HTTPException, Query, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from fastapi.routing import APIRoute
from fastapi.templating import Jinja2Templates

from app.service import storage
from app.service.admin import data, media
from app.service.admin.session import (COOKIE, DashboardSession, as_principal, cookie_args,
                                       current_session, sign_in, sign_out)
from app.service.db.session import session_scope
from app.service.db.models import STATUSES, JourneyRow, CoverageRow, JourneySignRow

log = logging.getLogger(__name__)
templates = Jinja2Templates(directory=str(Path(__file__).parent / "templates"))
router = APIRouter(prefix="/admin", include_in_schema=False)
SignedIn = Annotated[DashboardSession, Depends(current_session)]
DELETE_ROUTE = "/api/v1/journeys/{journey_id}"


def _settings(request: Request):
    return request.app.state.settings


def _url(request: Request) -> str:
    return _settings(request).effective_database_url


def _same_origin(request: Request) -> None:
    """Actions are form posts; SameSite=strict already keeps other sites' posts cookieless, and a
    foreign Origin is refused as well."""
    origin = request.headers.get("origin")
    if origin and urlsplit(origin).netloc != request.url.netloc:
        raise HTTPException(403, "cross-origin request refused")


def _page(request: Request, name: str, status_code: int = 200, **context) -> HTMLResponse:
    return templates.TemplateResponse(request, name, context, status_code=status_code)


@router.get("/login")
def login_form(request: Request) -> HTMLResponse:
    return _page(request, "login.html")


@router.post("/login")
def login(request: Request, key: Annotated[str, Form()] = "") -> Response:
    _same_origin(request)
    cookie = sign_in(_settings(request), key.strip()) if key.strip() else None
    if cookie is None:
        log.info("dashboard sign-in refused from %s", request.client.host if request.client else "?")
        return _page(request, "login.html", 403, error="not an admin key")
    response = RedirectResponse("/admin/journeys", status_code=303)
    response.set_cookie(value=cookie, **cookie_args(request, _settings(request)))
    return response


@router.post("/logout")
def logout(request: Request, signed_in: SignedIn) -> Response:
    _same_origin(request)
    sign_out(_settings(request), signed_in.token_sha256)
    response = RedirectResponse("/admin/login", status_code=303)
    response.delete_cookie(COOKIE, path="/admin")
    return response


@router.get("")
@router.get("/")
def home(_signed_in: SignedIn) -> Response:
    return RedirectResponse("/admin/journeys", status_code=303)


@router.get("/journeys")
def journeys(request: Request, _signed_in: SignedIn, status: str | None = None,
             camera: str | None = None, page: Annotated[int, Query(ge=1)] = 1) -> HTMLResponse:
    with session_scope(_url(request)) as session:
        listing = data.list_journeys(session, status or None, camera or None, page)
        cameras = data.camera_ids(session)
    return _page(request, "journeys.html", listing=listing, statuses=STATUSES, cameras=cameras,
                 status=status or "", camera=camera or "")


@router.get("/journeys/progress.json")
def journeys_progress(request: Request, _signed_in: SignedIn, ids: str = "") -> dict:
    wanted = [i for i in ids.split(",") if i][:500]
    with session_scope(_url(request)) as session:
        return data.progress(session, wanted)


@router.post("/journeys/{journey_id}/retry")
def retry(request: Request, journey_id: str, _signed_in: SignedIn) -> Response:
    _same_origin(request)
    with session_scope(_url(request)) as session:
        requeued = data.requeue_failed(session, journey_id)
    if not requeued:
        raise HTTPException(409, "only a failed journey can be retried")
    request.app.state.queue.submit(journey_id)
    log.info("journey %s: retried from the dashboard", journey_id)
    back = urlsplit(request.headers.get("referer", ""))
    path = back.path if back.path.startswith("/admin/journeys") else "/admin/journeys"
    return RedirectResponse(f"{path}?{back.query}" if back.query else path, status_code=303)


def _has_delete_route(request: Request) -> bool:
    return any(isinstance(r, APIRoute) and r.path == DELETE_ROUTE and "DELETE" in r.methods
               for r in request.app.routes)


@router.post("/journeys/{journey_id}/delete")
async def delete(request: Request, journey_id: str, signed_in: SignedIn) -> Response:
    _same_origin(request)
    if _has_delete_route(request):  # the service's own deletion (re-fuses the map around it)
        async with _api_client(request, signed_in) as client:
            answer = await client.delete(f"/api/v1/journeys/{journey_id}")
        if answer.status_code >= 400:
            raise HTTPException(answer.status_code, answer.json().get("detail", answer.text))
    else:
        with session_scope(_url(request)) as session:
            if not data.delete_journey(session, journey_id):
                raise HTTPException(404, f"journey {journey_id} not found")
    log.info("journey %s: deleted from the dashboard", journey_id)
    return RedirectResponse("/admin/journeys", status_code=303)


def _journey(session, journey_id: str) -> JourneyRow:
    row = session.get(JourneyRow, journey_id)
    if row is None:
        raise HTTPException(404, f"journey {journey_id} not found")
    return row


@router.get("/journeys/{journey_id}")
def journey(request: Request, journey_id: str, _signed_in: SignedIn) -> HTMLResponse:
    settings = _settings(request)
    with session_scope(_url(request)) as session:
        row = _journey(session, journey_id)
        signs = data.journey_signs(session, journey_id)
        history = data.calibrations(session, row.camera_id)
        coverage = session.get(CoverageRow, journey_id)
        estimated = [] if coverage is None else media.estimated_track(
            coverage.poses, coverage.origin_lat_deg, coverage.origin_lon_deg,
            coverage.origin_alt_m)
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
def crop(request: Request, journey_id: str, track: str, frame: str, _signed_in: SignedIn) -> Response:
    settings = _settings(request)
    with session_scope(_url(request)) as session:
        row = _journey(session, journey_id)
        sign = session.get(JourneySignRow, f"{journey_id}:{track}")
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
def map_page(request: Request, _signed_in: SignedIn) -> HTMLResponse:
    return _page(request, "map.html", tile_url=_settings(request).map_tile_url)


def _api_client(request: Request, signed_in: DashboardSession) -> httpx.AsyncClient:
    """A client of this app's public API, in-process, calling as the signed-in operator."""
    transport = httpx.ASGITransport(app=as_principal(request.app, signed_in.principal))
    return httpx.AsyncClient(transport=transport, base_url="http://dashboard")


async def _pass_through(request: Request, signed_in: DashboardSession, path: str) -> Response:
    """A public GET answered unchanged, made as the signed-in operator."""
    async with _api_client(request, signed_in) as client:
        answer = await client.get(path, params=request.query_params.multi_items())
    return Response(answer.content, status_code=answer.status_code,
                    media_type=answer.headers.get("content-type"))


@router.get("/api/signs")
async def map_signs(request: Request, signed_in: SignedIn) -> Response:
    return await _pass_through(request, signed_in, "/api/v1/signs")


@router.get("/api/tiles/{z}/{x}/{y}.mvt")
async def map_tile(request: Request, z: int, x: int, y: int, signed_in: SignedIn) -> Response:
    return await _pass_through(request, signed_in, f"/api/v1/tiles/{z}/{x}/{y}.mvt")


@router.get("/api/signs/{sign_id}")
async def map_sign(request: Request, sign_id: str, signed_in: SignedIn) -> Response:
    return await _pass_through(request, signed_in, f"/api/v1/signs/{quote(sign_id, safe='')}")


@router.get("/cameras")
def cameras(request: Request, _signed_in: SignedIn) -> HTMLResponse:
    with session_scope(_url(request)) as session:
        records = data.calibrations(session)
    by_camera: dict[str, list] = {}
    for record in records:
        by_camera.setdefault(record.camera_id, []).append(record)
    charts = {camera: data.fx_chart(rows) for camera, rows in by_camera.items()}
    return _page(request, "cameras.html", by_camera=by_camera, charts=charts)
