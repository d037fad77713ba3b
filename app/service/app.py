"""The FastAPI application: ``create_app(settings)``; ``uvicorn --factory app.service.app:create_app``."""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager

from fastapi import FastAPI
from sqlalchemy import text

from app.service.admin import mount_admin
from app.service.api import router
from app.service.map_api import router as map_router
from app.service.db import session_scope
from app.service.queue import make_queue
from app.service.storage import make_store
from app.settings import Settings

log = logging.getLogger(__name__)

DESCRIPTION = """
Signmap maps traffic signs from journeys recorded by cheap car cameras.

**Fleet integrators**: get a `fleet` key (`signmap keys create --role fleet`), upload each journey
as one zip (`POST /api/v1/journeys`, multipart field `bundle`, format in the wire contract), then poll
`GET /api/v1/journeys/{id}` until `status` is `done` or `failed` and fetch the journey's signs with
`GET /api/v1/journeys/{id}/signs`. **Map readers** (`reader` keys) query `GET /api/v1/signs?bbox=`.

Every call takes `Authorization: Bearer <key>`; errors are JSON `{"detail": ...}`.
"""


def create_app(settings: Settings | None = None) -> FastAPI:
    """The API for ``settings`` (default: from the environment). The database must be migrated."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        app.state.queue.start()
        log.info("Signmap API up: database %s, jobs via %s", settings.effective_database_url
                 .split("@")[-1], type(app.state.queue).__name__)
        try:
            yield
        finally:
            app.state.queue.stop()

    app = FastAPI(title="Signmap", version="1", description=DESCRIPTION, lifespan=lifespan)
    app.state.settings = settings
    app.state.queue = make_queue(settings)
    app.state.store = make_store(settings)
    app.include_router(router)
    app.include_router(map_router)
    mount_admin(app)

    @app.get("/api/v1/health", summary="Liveness and database check (no key needed)",
             tags=["ops"])
    def health() -> dict[str, str]:
        with session_scope(settings.effective_database_url) as session:
            session.execute(text("SELECT 1"))
        return {"status": "ok"}

    return app
