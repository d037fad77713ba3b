"""The FastAPI application: ``create_app(settings, queue)``. With a broker configured the caller
passes the queue (``app.commands.service.create_service_app`` passes Celery's; it is also the factory
for ``uvicorn --factory app.commands.service:create_service_app``)."""

from __future__ import annotations

import errno
import logging
from contextlib import asynccontextmanager

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy import text
from sqlalchemy.exc import OperationalError, SQLAlchemyError

from app.service import startup
from app.service.admin import mount_admin
from app.service.api.routes import cameras, journeys, tiles, vehicles
from app.service.api.routes import map as map_routes
from app.service.db.session import session_scope, write_refusal
from app.service.jobs.queue import JobQueue, local_queue
from app.service.api.schemas import ErrorOut, echoed_id
from app.service.storage import make_store
from app.service.jobs.sweep import Sweeper
from app.settings import Settings

log = logging.getLogger(__name__)

DESCRIPTION = """
Signmap maps traffic signs from journeys recorded by cheap car cameras.

**Fleet integrators**: get a `fleet` key (`signmap keys create --role fleet`), upload each journey
as one zip (`POST /api/v1/journeys`, multipart field `bundle`, format in the wire contract), then poll
`GET /api/v1/journeys/{id}` until `status` is `done` or `failed` and fetch the journey's signs with
`GET /api/v1/journeys/{id}/signs`. **Map readers** (`reader` keys) query `GET /api/v1/signs?bbox=`.

A journey without a turn whose camera has no calibration yet waits for one (`status` `queued`,
`stage` `waiting_for_camera`, a `message`): it resumes once a journey of the camera with a turn has
self-calibrated, or once an **admin** registers the camera's calibration
(`PUT /api/v1/cameras/{camera_id}/calibration`). `GET /api/v1/cameras/{camera_id}` shows a camera's
calibration, its sigmas, epochs and waiting journeys.

Every call takes `Authorization: Bearer <key>`; errors are JSON `{"detail": ...}`.
"""


def create_app(settings: Settings | None = None, queue: JobQueue | None = None) -> FastAPI:
    """The API for ``settings`` (default: from the environment), handing journeys to ``queue``
    (default, only without a broker: the embedded worker, or none with ``embedded_worker`` off).
    It refuses to start (``startup.StartupError``) unless the database is reachable and migrated and
    data_dir writable."""
    settings = settings or Settings()
    if queue is None:
        if settings.broker_url:
            raise ValueError("a broker is configured: pass its queue (app.commands.service."
                             "create_service_app builds the app with Celery's)")
        queue = local_queue(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        startup.check(settings)  # raises StartupError: no "up" line, no requests answered
        sweeper = Sweeper(settings)
        sweeper.start()
        app.state.queue.start()
        log.info("Signmap API up: database %s, jobs via %s",
                 startup.safe_url(settings.effective_database_url), type(app.state.queue).__name__)
        try:
            yield
        finally:
            sweeper.stop()
            app.state.queue.stop()

    app = FastAPI(title="Signmap", version="1", description=DESCRIPTION, lifespan=lifespan)
    app.state.settings = settings
    app.state.queue = queue
    app.state.store = make_store(settings)
    for routes in (journeys, map_routes, tiles, cameras, vehicles):
        app.include_router(routes.router)
    mount_admin(app)
    app.add_middleware(_JsonErrors)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI's own 422 sends each invalid value back whole ("input"): a 60 KB query parameter
        # came back as 60 KB. Cut what is echoed, as the service's own messages do.
        errors = [{**e, "input": echoed_id(str(e["input"]))} if "input" in e else e
                  for e in exc.errors()]
        return JSONResponse({"detail": jsonable_encoder(errors)}, 422)

    @app.get("/api/v1/health", summary="Liveness and database check (no key needed)",
             description="ok only when the database answers a read and takes a write.",
             tags=["ops"], response_model=dict[str, str],
             responses={503: {"model": ErrorOut,
                              "description": "the database is unreachable or takes no writes"}})
    def health():
        url = settings.effective_database_url
        try:
            with session_scope(url) as session:
                session.execute(text("SELECT 1"))
            # A database that still answers reads can refuse every write (a read-only file or
            # mount, a full disk, a standby): "ok" then would hide an outage of uploads and jobs.
            refusal = write_refusal(url)
        except SQLAlchemyError as exc:
            log.warning("health: database %s unreachable: %s", startup.safe_url(url), exc)
            return JSONResponse({"detail": f"the database is unreachable "
                                           f"({type(exc).__name__})"}, 503)
        if refusal:
            log.warning("health: database %s accepts no writes: %s", startup.safe_url(url),
                        refusal)
            return JSONResponse({"detail": f"the database accepts no writes ({refusal}): uploads "
                                           f"and jobs fail until it does"}, 503)
        return {"status": "ok"}

    return app


class _JsonErrors:
    """Every unhandled exception answers JSON ``{"detail": ...}``, never plain text, and is logged
    once: a full disk 507, the database failing 503 (down, read-only, locked), anything else 500
    with its traceback. A plain ASGI middleware rather than an exception handler for
    ``Exception``: Starlette re-raises after such a handler, and the server would log it twice."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        started = False

        async def send_tracked(message):
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, send_tracked)
        except Exception as exc:
            if started:  # too late for another answer: the server logs it and drops the connection
                raise
            where = f"{scope.get('method')} {scope.get('path')}"
            full = _storage_full(exc)
            if full is not None:  # not a bug: logged in one line, without the traceback
                log.error("%s: storage is full: %s", where, full)
                answer = JSONResponse({"detail": "storage is full on the server; try again later"},
                                      507)
            elif isinstance(exc, OperationalError):  # database down, read-only, connection lost
                log.error("%s: database error", where, exc_info=exc)
                answer = JSONResponse({"detail": "the database is unavailable; try again later"},
                                      503)
            else:
                log.error("%s: internal error", where, exc_info=exc)
                answer = JSONResponse({"detail": f"internal error ({type(exc).__name__}); "
                                                 f"see the server log"}, 500)
            await answer(scope, receive, send)


_SQLITE_FULL = 13  # SQLITE_FULL: "database or disk is full"
_PG_DISK_FULL = "53100"  # SQLSTATE disk_full


def _storage_full(exc: BaseException) -> BaseException | None:
    """The error in ``exc``'s chain (its causes, what it interrupted, a group's members) saying that
    a disk or quota is full: an OSError ENOSPC/EDQUOT from a file write, SQLite's SQLITE_FULL,
    PostgreSQL's disk_full. None when there is none."""
    seen: set[int] = set()
    todo: list[BaseException] = [exc]
    while todo:
        error = todo.pop()
        if error is None or id(error) in seen:
            continue
        seen.add(id(error))
        if isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT):
            return error
        if (getattr(error, "sqlite_errorcode", None) or 0) & 0xFF == _SQLITE_FULL \
                or getattr(error, "sqlstate", None) == _PG_DISK_FULL:
            return error
        todo += [error.__cause__, error.__context__, getattr(error, "orig", None),
                 *(error.exceptions if isinstance(error, BaseExceptionGroup) else ())]
    return None
