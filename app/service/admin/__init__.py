"""The operators' dashboard under /admin: ``mount_admin(app)`` adds its pages and static files.
Server-rendered pages (``routes``, ``templates/``) over what they show (``data``: table reads;
``media``: a stored bundle's track and sign crops), behind a sign-in session (``session``), with
security headers on every response (``headers``). The map views call the API's route functions
directly: the dashboard is the layer above the API."""

from __future__ import annotations

from pathlib import Path

import xstatic.pkg.leaflet
from fastapi import FastAPI, Request
from fastapi.responses import RedirectResponse
from fastapi.staticfiles import StaticFiles

from app.service.admin.headers import AdminHeaders
from app.service.admin.routes import router
from app.service.admin.session import NotSignedIn

STATIC_DIR = Path(__file__).parent / "static"


def mount_admin(app: FastAPI) -> None:
    app.include_router(router)
    app.mount("/admin/static/leaflet", StaticFiles(directory=xstatic.pkg.leaflet.BASE_DIR),
              name="admin-leaflet")
    app.mount("/admin/static/app", StaticFiles(directory=STATIC_DIR), name="admin-static")
    app.add_middleware(AdminHeaders, tile_url=app.state.settings.map_tile_url)

    @app.exception_handler(NotSignedIn)
    async def _to_sign_in(request: Request, _exc: NotSignedIn) -> RedirectResponse:
        return RedirectResponse("/admin/login", status_code=303)
