"""The real services the tests run against: PostgreSQL (SIGNMAP_TEST_POSTGRES_URL, a database to
connect to for CREATE DATABASE), Redis (SIGNMAP_TEST_REDIS_URL) and an S3-compatible store. Each
test session names its databases and queues with its own ``SESSION_TAG``."""

from __future__ import annotations

import json
import os
import secrets
from contextlib import contextmanager
from typing import Iterator, NoReturn

from sqlalchemy import make_url

from app.service.db.session import temporary_database, upgrade
from tests.utils.real_services import service_unavailable

SESSION_TAG = secrets.token_hex(4)
PG_URL = os.environ.get("SIGNMAP_TEST_POSTGRES_URL",
                        "postgresql+psycopg://postgres@127.0.0.1:5432/postgres")
REDIS_URL = os.environ.get("SIGNMAP_TEST_REDIS_URL", "redis://127.0.0.1:6379/13")


def backend_unavailable(what: str, where: str, exc: Exception) -> NoReturn:
    detail = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    service_unavailable(f"{what} is not reachable at {where}: {detail}")


@contextmanager
def pg_database(name: str) -> Iterator[str]:
    """A new PostgreSQL database ``name``, migrated with Alembic, dropped at the end."""
    created = False
    try:
        with temporary_database(PG_URL, name) as url:
            created = True
            upgrade(url)
            yield url
    except Exception as exc:  # noqa: BLE001 - failing to create it means "no PostgreSQL here"
        if created:
            raise
        backend_unavailable("PostgreSQL", make_url(PG_URL).render_as_string(hide_password=True),
                            exc)


def forget_queues(client, prefix: str) -> None:
    """Delete this session's queues and its unacknowledged messages (Kombu's shared hash)."""
    for key in client.scan_iter(f"*{prefix}*"):
        client.delete(key)
    for tag, payload in client.hscan_iter("unacked"):
        try:
            routing_key = json.loads(payload)[2]
        except (ValueError, IndexError):
            continue
        if str(routing_key).startswith(prefix):
            client.hdel("unacked", tag)
            client.zrem("unacked_index", tag)


def s3_objects(storage_url: str) -> dict[str, bytes]:
    """Every object of the bucket that ``storage_url`` names: key -> bytes."""
    import boto3
    from urllib.parse import urlsplit

    client, bucket = boto3.client("s3"), urlsplit(storage_url).netloc
    listed = client.list_objects_v2(Bucket=bucket).get("Contents", [])
    return {o["Key"]: client.get_object(Bucket=bucket, Key=o["Key"])["Body"].read()
            for o in listed}
