"""One configured service under test (``Stack``), its settings, keys and clients, real
``signmap worker`` processes, and the HTTP calls the service tests share (upload, poll)."""

from __future__ import annotations

import os
import secrets
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from sqlalchemy import func, select

from app.service.auth import create_key, key_sha256
from app.service.db.session import session_scope, upgrade
from app.service.db.models import ApiKeyRow, JourneyRow
from app.settings import Settings
from bench.service.serve import child_env
from tests.utils.backends import SESSION_TAG
from tests.utils.paths import REPO

ADMIN_KEY = "test-admin-" + secrets.token_hex(8)


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


def processed_by_celery(data: bytes, camera_id: str, camera, pg_url: str, redis_url: str,
                        tmp_path: Path, before_upload=None, **overrides
                        ) -> tuple[dict, list[dict]]:
    """Upload the bundle ``data`` as a fleet key to PostgreSQL + Redis with a real Celery worker
    and wait until it ends: (the journey's body, its signs' features). The camera's true
    calibration ``camera`` is stored and reused (``reuse_known_calibration``): these tests are
    about the way in, not self-calibration. ``before_upload(client)``: requests made first
    (an admin's settings); ``overrides``: more ``Settings``."""
    from app.pipeline.config import PipelineConfig
    from tests.e2e.test_fusion_rendered import seed_calibration

    seed_calibration(pg_url, camera_id, camera)
    stack = Stack("postgres", make_settings(
        tmp_path / "data", database_url=pg_url, broker_url=redis_url,
        pipeline=PipelineConfig(reuse_known_calibration=True), **overrides))
    fleet = stack.key("fleet")
    worker = CeleryWorker(stack.settings, tmp_path / "worker.log")
    try:
        with stack.client() as client:
            if before_upload is not None:
                before_upload(client)
            journey_id = upload(client, fleet, data)
            body = poll_journey(client, auth(fleet), journey_id,
                                lambda b: b["status"] in ("done", "failed"), worker=worker)
            features = client.get(f"/api/v1/journeys/{journey_id}/signs",
                                  headers=auth(fleet)).json()["features"]
    finally:
        worker.stop()
    return body, features


def cli_on(stack: Stack, *words: str):
    """``signmap WORDS`` on the stack's database through the command line's ``main`` in this
    process (the service's imports take seconds in a new one), with only the stack's SIGNMAP_*
    environment: a ``subprocess.CompletedProcess`` of its exit code, stdout and stderr."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    from app.cli import main

    out, err = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as mp, redirect_stdout(out), redirect_stderr(err):
        for name in [n for n in os.environ if n.startswith("SIGNMAP_")]:
            mp.delenv(name)
        for name, value in stack.settings.as_env().items():
            mp.setenv(name, value)
        try:
            code = main(list(words))
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
            print(exc.code if isinstance(exc.code, str) else "", file=err)
    return subprocess.CompletedProcess(words, code, out.getvalue(), err.getvalue())
