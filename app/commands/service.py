"""Service subcommands of ``signmap``: serve, worker, db upgrade, keys create/list/revoke; and the
composition of the API with its job queue (``create_service_app``), the one place that knows both
the service (``app.service``) and the Celery worker (``worker``)."""

from __future__ import annotations

import argparse
import logging
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fastapi import FastAPI

    from app.settings import Settings

COMMANDS = {"serve": "run the HTTP API (and, without a broker, the jobs too)",
            "worker": "run a job worker (needs SIGNMAP_BROKER_URL)",
            "db": "database maintenance: `signmap db upgrade`",
            "keys": "API keys: `signmap keys create`, `list`, `revoke`"}


def create_service_app(settings: Settings | None = None) -> FastAPI:
    """The API for ``settings`` (default: from the environment) with its job queue: Celery when a
    broker is configured, else the embedded worker (``app.service.app.create_app``'s own choice).
    ``signmap serve`` runs it; ``uvicorn --factory app.commands.service:create_service_app`` too."""
    from app.service.app import create_app
    from app.settings import Settings

    settings = settings or Settings()
    if not settings.broker_url:
        return create_app(settings)
    from worker.queue import CeleryQueue

    return create_app(settings, queue=CeleryQueue(settings))


def _logging(settings: Settings) -> None:
    from app import logs

    logs.configure(settings.log_level)  # one line per record: control characters escaped
    # Alembic's INFO lines (the SQL dialect on every start, each migration's notes) are for whoever
    # writes migrations; `signmap db upgrade` says in one line what it did.
    logging.getLogger("alembic").setLevel(logging.WARNING)


def serve(args: argparse.Namespace) -> int:
    import uvicorn

    from app.service import startup
    from app.service.db.session import upgrade
    from app.settings import Settings

    settings = Settings()
    _logging(settings)
    try:
        startup.check_data_dir(settings.data_dir)
        if settings.effective_database_url.startswith("sqlite"):
            # The embedded default must work out of the box; PostgreSQL is migrated by `db upgrade`.
            upgrade(settings.effective_database_url)
        startup.check_database(settings.effective_database_url)
        startup.check_detector(settings)  # before uvicorn: one line, not a lifespan traceback
    except startup.StartupError as exc:
        raise SystemExit(f"signmap serve: {exc}") from None
    uvicorn.run(create_service_app(settings), host=args.host, port=args.port, log_config=None)
    return 0


def worker(args: argparse.Namespace) -> int:
    from app.service import startup
    from worker.celery_app import app, settings

    if not settings.broker_url:
        raise SystemExit("signmap worker needs SIGNMAP_BROKER_URL (without it `signmap serve` "
                         "runs jobs itself)")
    try:
        startup.check(settings)
    except startup.StartupError as exc:
        raise SystemExit(f"signmap worker: {exc}") from None
    argv = ["worker", "--loglevel", settings.log_level, "--queues", settings.celery_queue,
            "--without-gossip", "--without-mingle"]
    if args.hostname:
        argv += ["--hostname", args.hostname]
    app.worker_main(argv)
    return 0


def db_upgrade(args: argparse.Namespace) -> int:
    from app.service import startup
    from app.service.db.session import upgrade
    from app.settings import Settings

    settings = Settings()
    _logging(settings)
    url = settings.effective_database_url
    try:
        if url.startswith("sqlite"):
            startup.check_data_dir(settings.data_dir)
        before = startup.current_revision(url)
    except startup.StartupError as exc:
        raise SystemExit(f"signmap db upgrade: {exc}") from None
    upgrade(url, args.revision)
    after = startup.current_revision(url)
    print(f"database {startup.safe_url(url)}: "
          + (f"already at schema revision {after}" if after == before else
             f"schema revision {before or 'none'} -> {after}"))
    return 0


def usable_database(command: str) -> Settings:
    """The settings of `signmap COMMAND` (e.g. "keys create"), once their database is found
    usable (reachable and migrated; SQLite's data_dir writable)."""
    from app.service import startup
    from app.settings import Settings

    settings = Settings()
    try:
        if settings.effective_database_url.startswith("sqlite"):
            startup.check_data_dir(settings.data_dir)
        startup.check_database(settings.effective_database_url)
    except startup.StartupError as exc:
        raise SystemExit(f"signmap {command}: {exc}") from None
    return settings


def _keys_database(command: str) -> str:
    """The URL of the database `signmap keys COMMAND` works on, once it is found usable."""
    return usable_database(f"keys {command}").effective_database_url


def keys_create(args: argparse.Namespace) -> int:
    from app.service.auth import create_key
    from app.service.db.session import session_scope

    with session_scope(_keys_database("create")) as session:
        key = create_key(session, args.role, args.name)
    print(key)
    return 0


def _when(moment) -> str:
    return moment.strftime("%Y-%m-%d %H:%M:%SZ") if moment is not None else "-"


def keys_list(args: argparse.Namespace) -> int:
    from app.service.auth import list_keys
    from app.service.db.session import session_scope

    with session_scope(_keys_database("list")) as session:
        rows = [(str(k.id), k.role, k.name or "-", _when(k.created_at),
                 _when(k.last_used_at) if k.last_used_at else "never", _when(k.revoked_at))
                for k in list_keys(session)]
    table = [("ID", "ROLE", "NAME", "CREATED", "LAST USED", "REVOKED"), *rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    for row in table:
        print("  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip())
    return 0


def keys_revoke(args: argparse.Namespace) -> int:
    from app.service.auth import UnknownKey, revoke_key
    from app.service.db.session import session_scope

    try:
        with session_scope(_keys_database("revoke")) as session:
            row, revoked = revoke_key(session, args.id)
            what = f"key {row.id} ({row.role}, {row.name or 'no name'})"
            when = _when(row.revoked_at)
    except UnknownKey as exc:
        raise SystemExit(f"signmap keys revoke: {exc} (`signmap keys list` shows them)") from None
    print(f"{what} revoked" if revoked else f"{what} was already revoked at {when}")
    return 0


def _key_id(text: str) -> int:
    if not (text.isascii() and text.isdigit()) or not 1 <= int(text) < 2**31:
        raise argparse.ArgumentTypeError(f"not a key id: {text!r}")
    return int(text)


def add_parsers(sub) -> None:
    from app.commands.usage import show_help
    from app.service.db.models import ROLES

    p = sub.add_parser("serve", help=COMMANDS["serve"],
                       description="Runs the HTTP API. With nothing configured it keeps its data "
                       "in SQLite under SIGNMAP_DATA_DIR (default ./signmap-data) and runs the "
                       "jobs itself; with SIGNMAP_BROKER_URL set, `signmap worker` runs them. "
                       "Settings: SIGNMAP_* environment variables (docs/service.md).")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default: %(default)s, this machine only; "
                   "0.0.0.0 for every interface)")
    p.add_argument("--port", type=int, default=8000,
                   help="TCP port to listen on (default: %(default)s)")
    p.set_defaults(func=serve)

    p = sub.add_parser("worker", help=COMMANDS["worker"],
                       description="Runs a Celery worker that processes uploaded journeys from "
                       "the queue at SIGNMAP_BROKER_URL (e.g. redis://127.0.0.1:6379/0); start "
                       "as many as there are cores to spare.")
    p.add_argument("--hostname", default=None,
                   help="this worker's node name, e.g. w1@%%h (default: Celery's, celery@HOST)")
    p.set_defaults(func=worker)

    p = sub.add_parser("db", help=COMMANDS["db"],
                       description="Database maintenance (the database at SIGNMAP_DATABASE_URL, "
                       "default SQLite under SIGNMAP_DATA_DIR).")
    p.set_defaults(func=show_help(p))
    db_sub = p.add_subparsers(dest="db_command", metavar="COMMAND")
    q = db_sub.add_parser("upgrade", help="create the database tables or bring them up to date",
                          description="Creates the database tables or migrates them to REVISION "
                          "(Alembic). Run it after installing a new version; `signmap serve` "
                          "does it itself on SQLite.")
    q.add_argument("revision", nargs="?", default="head",
                   help="schema revision to migrate to (default: %(default)s, the newest)")
    q.set_defaults(func=db_upgrade)

    p = sub.add_parser("keys", help=COMMANDS["keys"],
                       description="API keys for the HTTP API and the dashboard.")
    p.set_defaults(func=show_help(p))
    keys_sub = p.add_subparsers(dest="keys_command", metavar="COMMAND")
    q = keys_sub.add_parser("create", help="create a key and print it (shown only this once)",
                            description="Creates an API key and prints it; only its hash is "
                            "stored, so it is shown this once. Roles: fleet uploads journeys and "
                            "reads its own; reader reads the map; admin may do everything, "
                            "including signing in to the dashboard.")
    q.add_argument("--role", required=True, choices=ROLES, help="what the key may do")
    q.add_argument("--name", default="", help="who the key is for, e.g. van-3")
    q.set_defaults(func=keys_create)
    q = keys_sub.add_parser("list", help="list the keys (never the keys themselves)",
                            description="Lists every stored key: id, role, name, when it was "
                            "created, last used (to within a minute) and revoked, in UTC. The "
                            "keys themselves are not stored, so they cannot be shown; "
                            "SIGNMAP_ADMIN_KEY is not listed.")
    q.set_defaults(func=keys_list)
    q = keys_sub.add_parser("revoke", help="revoke a key: refused from its next request on",
                            description="Revokes the key with this id (from `signmap keys "
                            "list`): the API refuses it from its next request on (401) and its "
                            "dashboard sign-ins end. Its row stays, with the journeys it "
                            "uploaded. Revoking a revoked key changes nothing.")
    q.add_argument("id", type=_key_id, help="the key's id, as `signmap keys list` shows it")
    q.set_defaults(func=keys_revoke)
