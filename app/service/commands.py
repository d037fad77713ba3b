"""Service subcommands of ``signmap``: serve, worker, db upgrade, keys create."""

from __future__ import annotations

import argparse
import logging

from app.service.models import ROLES
from app.settings import Settings


def _logging(settings: Settings) -> None:
    logging.basicConfig(level=settings.log_level,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")


def serve(args: argparse.Namespace) -> int:
    import uvicorn

    from app.service.app import create_app
    from app.service.db import upgrade

    settings = Settings()
    _logging(settings)
    if settings.effective_database_url.startswith("sqlite"):
        # The embedded default must work out of the box; PostgreSQL is migrated by `db upgrade`.
        upgrade(settings.effective_database_url)
    uvicorn.run(create_app(settings), host=args.host, port=args.port, log_config=None)
    return 0


def worker(args: argparse.Namespace) -> int:
    from worker.celery_app import app, settings

    if not settings.broker_url:
        raise SystemExit("signmap worker needs SIGNMAP_BROKER_URL (without it `signmap serve` "
                         "runs jobs itself)")
    argv = ["worker", "--loglevel", settings.log_level, "--queues", settings.celery_queue,
            "--without-gossip", "--without-mingle"]
    if args.hostname:
        argv += ["--hostname", args.hostname]
    app.worker_main(argv)
    return 0


def db_upgrade(args: argparse.Namespace) -> int:
    from app.service.db import upgrade

    settings = Settings()
    _logging(settings)
    upgrade(settings.effective_database_url, args.revision)
    return 0


def keys_create(args: argparse.Namespace) -> int:
    from app.service.auth import create_key
    from app.service.db import session_scope

    settings = Settings()
    with session_scope(settings.effective_database_url) as session:
        key = create_key(session, args.role, args.name)
    print(key)
    return 0


def add_parsers(sub) -> None:
    p = sub.add_parser("serve", help="run the HTTP API (and, without a broker, the jobs)")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.set_defaults(func=serve)

    p = sub.add_parser("worker", help="run a Celery worker (needs SIGNMAP_BROKER_URL)")
    p.add_argument("--hostname", default=None, help="Celery node name, e.g. w1@%%h")
    p.set_defaults(func=worker)

    p = sub.add_parser("db", help="database maintenance")
    db_sub = p.add_subparsers(dest="db_command", required=True)
    q = db_sub.add_parser("upgrade", help="apply the Alembic migrations")
    q.add_argument("revision", nargs="?", default="head")
    q.set_defaults(func=db_upgrade)

    p = sub.add_parser("keys", help="API keys")
    keys_sub = p.add_subparsers(dest="keys_command", required=True)
    q = keys_sub.add_parser("create", help="create a key and print it (shown only this once)")
    q.add_argument("--role", required=True, choices=ROLES)
    q.add_argument("--name", default="", help="who the key is for")
    q.set_defaults(func=keys_create)
