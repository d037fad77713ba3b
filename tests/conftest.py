"""Service test fixtures: the embedded stack (SQLite, jobs in the API process) and the real stack
(a throw-away PostgreSQL database migrated by Alembic, Redis, real Celery worker processes).

Without PostgreSQL/Redis the real-stack tests are skipped, except under CI (``CI=true``), where they
fail; the run ends with a "real-service tests skipped" section saying which were skipped and why
(``tests/real_services.py``, which also covers the browser tests). Locations:
SIGNMAP_TEST_POSTGRES_URL (a database to connect to for CREATE DATABASE) and SIGNMAP_TEST_REDIS_URL.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, NoReturn

import pytest
from sqlalchemy import func, make_url, select

from app.service.auth import create_key, key_sha256
from app.service.db.session import session_scope, temporary_database, upgrade
from app.service.db.models import ApiKeyRow, JourneyRow
from app.settings import Settings
from bench.serve import child_env
from tests.real_services import register_real_service_skips, service_unavailable

ADMIN_KEY = "test-admin-" + secrets.token_hex(8)
SESSION_TAG = secrets.token_hex(4)
PG_URL = os.environ.get("SIGNMAP_TEST_POSTGRES_URL",
                        "postgresql+psycopg://postgres@127.0.0.1:5432/postgres")
REDIS_URL = os.environ.get("SIGNMAP_TEST_REDIS_URL", "redis://127.0.0.1:6379/13")
REPO = Path(__file__).resolve().parents[1]


def _unavailable(what: str, where: str, exc: Exception) -> NoReturn:
    detail = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    service_unavailable(f"{what} is not reachable at {where}: {detail}")


def pytest_configure(config) -> None:
    register_real_service_skips(config)


@contextmanager
def _pg_database(name: str) -> Iterator[str]:
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
        _unavailable("PostgreSQL", make_url(PG_URL).render_as_string(hide_password=True), exc)


@pytest.fixture(scope="session")
def pg_url() -> Iterator[str]:
    """A PostgreSQL database shared by the session's tests that do not care what else is in it."""
    with _pg_database(f"signmap_test_{SESSION_TAG}") as url:
        yield url


@pytest.fixture(scope="module")
def own_pg_url(request) -> Iterator[str]:
    """A PostgreSQL database of the test module's own, for tests that assert what the whole map
    holds (the shared one has whatever the session's other tests put at the same place)."""
    module = request.module.__name__.rsplit(".", 1)[-1]
    with _pg_database(f"signmap_test_{SESSION_TAG}_{module}") as url:
        yield url


@pytest.fixture(scope="session")
def redis_url() -> Iterator[str]:
    import redis

    client = redis.Redis.from_url(REDIS_URL)
    try:
        client.ping()
    except Exception as exc:  # noqa: BLE001
        _unavailable("Redis", re.sub(r"//[^/@]*@", "//***@", REDIS_URL), exc)  # no password
    yield REDIS_URL
    _forget_queues(client, f"signmap_test_{SESSION_TAG}")


def _forget_queues(client, prefix: str) -> None:
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


@pytest.fixture(scope="session")
def s3_endpoint() -> Iterator[str]:
    """A real S3-compatible HTTP endpoint for the session: moto's server on a free local port."""
    from moto.server import ThreadedMotoServer

    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    yield f"http://{host}:{port}"
    server.stop()


@pytest.fixture
def s3_storage_url(s3_endpoint, monkeypatch) -> str:
    """A fresh bucket on the session's S3 endpoint, with the standard AWS_* variables set for this
    test and the worker processes it starts; returns the SIGNMAP_STORAGE_URL naming it."""
    import boto3

    for name in [n for n in os.environ if n.startswith("AWS_")]:
        monkeypatch.delenv(name)
    monkeypatch.setenv("AWS_ENDPOINT_URL", s3_endpoint)
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "signmap-test")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "signmap-test-secret")
    bucket = f"signmap-test-{secrets.token_hex(4)}"
    boto3.client("s3").create_bucket(Bucket=bucket)
    return f"s3://{bucket}/bundles"


def s3_objects(storage_url: str) -> dict[str, bytes]:
    """Every object of the bucket that ``storage_url`` names: key -> bytes."""
    import boto3
    from urllib.parse import urlsplit

    client, bucket = boto3.client("s3"), urlsplit(storage_url).netloc
    listed = client.list_objects_v2(Bucket=bucket).get("Contents", [])
    return {o["Key"]: client.get_object(Bucket=bucket, Key=o["Key"])["Body"].read()
            for o in listed}


@dataclass
class Stack:
    """One configured service: its settings, plus helpers to make keys and clients."""

    name: str
    settings: Settings

    @property
    def url(self) -> str:
        return self.settings.effective_database_url

    def key(self, role: str, name: str = "") -> str:
        with session_scope(self.url) as session:
            return create_key(session, role, name or f"{role}-{secrets.token_hex(3)}")

    @contextmanager
    def client(self):
        from fastapi.testclient import TestClient

        from app.commands.service import create_service_app

        with TestClient(create_service_app(self.settings)) as client:
            yield client

    def count_journeys(self, key: str) -> int:
        """Journeys owned by ``key`` (the PostgreSQL database is shared by the whole session)."""
        with session_scope(self.url) as session:
            return session.scalar(select(func.count()).select_from(JourneyRow).join(ApiKeyRow).where(
                ApiKeyRow.key_sha256 == key_sha256(key)))

    def stored_files(self) -> list[str]:
        """Every file under bundles/ and incoming/ (a rejected upload must leave none)."""
        return sorted(str(p.relative_to(self.settings.data_dir))
                      for d in ("bundles", "incoming") if (self.settings.data_dir / d).exists()
                      for p in (self.settings.data_dir / d).rglob("*") if p.is_file())


def make_settings(data_dir: Path, **overrides) -> Settings:
    values = dict(data_dir=data_dir, admin_key=ADMIN_KEY, embedded_worker=False,
                  celery_queue=f"signmap_test_{SESSION_TAG}_{secrets.token_hex(3)}")
    values.update(overrides)
    return Settings(**values)


def sqlite_stack(data_dir: Path, **overrides) -> Stack:
    stack = Stack("sqlite", make_settings(data_dir, **overrides))
    upgrade(stack.url)
    return stack


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def stack(request, tmp_path) -> Stack:
    """The service on SQLite, then on PostgreSQL + Redis; jobs are queued but not run."""
    if request.param == "sqlite":
        return sqlite_stack(tmp_path / "data")
    return Stack("postgres", make_settings(tmp_path / "data",
                                           database_url=request.getfixturevalue("pg_url"),
                                           broker_url=request.getfixturevalue("redis_url")))


def auth(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


def settings_env(settings: Settings) -> dict[str, str]:
    """The environment that makes a child process's Settings() equal ``settings``."""
    return child_env(settings)


class CeleryWorker:
    """A real ``signmap worker`` process (in its own process group, so a kill takes it all)."""

    def __init__(self, settings: Settings, log_path: Path):
        self.log_path = log_path
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "app.cli", "worker", "--hostname",
             f"test-{secrets.token_hex(3)}@%h"],
            cwd=REPO, env=settings_env(settings), stdout=log_path.open("ab"),
            stderr=subprocess.STDOUT, start_new_session=True)

    def kill(self, sig: int = signal.SIGKILL, timeout_s: float = 30) -> int:
        try:
            os.killpg(self.proc.pid, sig)
        except ProcessLookupError:
            pass
        return self.proc.wait(timeout_s)

    def stop(self) -> None:
        if self.proc.poll() is None:
            try:
                self.kill(signal.SIGTERM, timeout_s=20)
            except subprocess.TimeoutExpired:
                self.kill(signal.SIGKILL)


def poll_journey(client, headers: dict, journey_id: str, until, timeout_s: float = 900,
                 worker: CeleryWorker | None = None) -> dict:
    """GET the journey every second until ``until(body)`` holds; fails on timeout."""
    deadline = time.monotonic() + timeout_s
    while True:
        body = client.get(f"/api/v1/journeys/{journey_id}", headers=headers).json()
        if until(body):
            return body
        if worker is not None and worker.proc.poll() is not None:
            pytest.fail(f"the worker exited ({worker.proc.returncode}); log: "
                        f"{worker.log_path.read_text()[-3000:]}")
        if time.monotonic() > deadline:
            pytest.fail(f"journey {journey_id} still {body['status']} at {body['stage']} "
                        f"after {timeout_s} s")
        time.sleep(1.0)


def upload(client, key: str, data: bytes) -> str:
    response = client.post("/api/v1/journeys", headers=auth(key),
                           files={"bundle": ("journey.zip", data, "application/zip")})
    assert response.status_code == 202, response.text
    return response.json()["id"]


def _synthetic(tmp_path_factory, name: str, **config) -> tuple[Path, dict]:
    """Render a synthetic journey once per session (or reuse SIGNMAP_TEST_SYNTH_CACHE/<hash>)."""
    import hashlib

    from app.synth.journey import GENERATOR_VERSION, SynthConfig, write_bundle

    cfg = SynthConfig(**config)
    cache = os.environ.get("SIGNMAP_TEST_SYNTH_CACHE")
    root = Path(cache) if cache else tmp_path_factory.getbasetemp() / "synth"
    digest = hashlib.sha256(repr((GENERATOR_VERSION, cfg)).encode()).hexdigest()[:12]
    out = root / f"{name}-{digest}"
    if not (out / "truth.json").exists():
        write_bundle(cfg, out)
    return out / "bundle.zip", json.loads((out / "truth.json").read_text())


@pytest.fixture(scope="session")
def turn_journey_bundle(tmp_path_factory) -> tuple[Path, dict]:
    """A small rendered journey with one turn: (bundle.zip, truth.json as a dict)."""
    return _synthetic(tmp_path_factory, "turn", turns=1)


@pytest.fixture(scope="session")
def straight_journey_bundle(tmp_path_factory) -> tuple[Path, dict]:
    """A straight journey in another world, filmed by the same camera as the turn journey."""
    return _synthetic(tmp_path_factory, "straight", turns=0, world_seed=1, seed=1)
