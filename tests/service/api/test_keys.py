"""API keys over their life: `signmap keys list` and `signmap keys revoke` (the command itself, in a
subprocess on the stack's database), a revoked key refused by a running API at its very next
request, the last-used time written at most once a minute, and migration 0007 on a database made
at 0006 (SQLite and PostgreSQL)."""

from __future__ import annotations

import re
import secrets
import subprocess
import sys
from datetime import timedelta

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import text, update

from app.commands.service import create_service_app
from app.service.auth import key_sha256
from app.service.db.models import ApiKeyRow, utc_now
from app.service.db.session import get_engine, session_scope, temporary_database, upgrade
from tests.utils.backends import PG_URL
from tests.utils.paths import REPO
from tests.utils.stack import Stack, auth, cli_on, make_settings, settings_env


def _keys(stack: Stack, *words: str, own_process: bool = False) -> subprocess.CompletedProcess:
    """`signmap keys WORDS` on the stack's database: through the command line's ``main`` in this
    process (the service's imports take seconds in a new one), or in a process of its own."""
    if own_process:
        return subprocess.run([sys.executable, "-m", "app.cli", "keys", *words], cwd=REPO,
                              env=settings_env(stack.settings), capture_output=True, text=True,
                              timeout=120)
    return cli_on(stack, "keys", *words)


def _row(stack: Stack, key: str) -> ApiKeyRow:
    with session_scope(stack.url) as session:
        return session.query(ApiKeyRow).filter_by(key_sha256=key_sha256(key)).one()


def _listed(stack: Stack) -> dict[str, list[str]]:
    """`signmap keys list` as {id: its row's cells}, checked to have the announced header."""
    done = _keys(stack, "list")
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert re.split(r"\s{2,}", lines[0]) == ["ID", "ROLE", "NAME", "CREATED", "LAST USED",
                                             "REVOKED"]
    return {cells[0]: cells for cells in (re.split(r"\s{2,}", line) for line in lines[1:])}


def test_keys_list_shows_each_key_but_never_the_key(stack):
    name = f"van-{secrets.token_hex(3)}"
    fleet, reader = stack.key("fleet", name), stack.key("reader", name + "-map")
    listed = _listed(stack)
    fleet_id, reader_id = str(_row(stack, fleet).id), str(_row(stack, reader).id)
    assert listed[fleet_id][1:3] == ["fleet", name]
    assert listed[reader_id][1:3] == ["reader", name + "-map"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\dZ", listed[fleet_id][3])
    assert listed[fleet_id][4:] == ["never", "-"]
    out = _keys(stack, "list").stdout
    for key in (fleet, reader):
        assert key not in out and key_sha256(key) not in out


def test_a_revoked_key_is_refused_at_its_next_request(stack):
    key, other = stack.key("fleet"), stack.key("fleet")
    key_id = _row(stack, key).id
    with stack.client() as client:
        assert client.get("/api/v1/journeys", headers=auth(key)).status_code == 200
        done = _keys(stack, "revoke", str(key_id), own_process=True)  # as an operator would
        assert done.returncode == 0, done.stderr[-2000:]
        assert re.fullmatch(rf"key {key_id} \(fleet, fleet-\w+\) revoked\n", done.stdout)
        answer = client.get("/api/v1/journeys", headers=auth(key))
        assert answer.status_code == 401
        assert answer.json()["detail"] == "this API key was revoked"
        assert answer.headers["www-authenticate"] == "Bearer"
        assert client.get("/api/v1/journeys", headers=auth(other)).status_code == 200
    revoked_at = _row(stack, key).revoked_at
    assert revoked_at is not None and abs(utc_now() - revoked_at) < timedelta(minutes=2)
    assert _listed(stack)[str(key_id)][5] == revoked_at.strftime("%Y-%m-%d %H:%M:%SZ")

    again = _keys(stack, "revoke", str(key_id))
    assert again.returncode == 0 and "was already revoked at" in again.stdout
    assert _row(stack, key).revoked_at == revoked_at
    missing = _keys(stack, "revoke", str(2**31 - 1))
    assert missing.returncode == 1 and missing.stdout == ""
    assert missing.stderr.strip().endswith(f"signmap keys revoke: no key {2**31 - 1} "
                                           "(`signmap keys list` shows them)")
    assert _keys(stack, "revoke", "van-3").returncode == 2


def test_last_used_is_set_by_a_request_and_written_once_a_minute(stack):
    key = stack.key("fleet")
    assert _row(stack, key).last_used_at is None
    with stack.client() as client:
        assert client.get("/api/v1/journeys", headers=auth(key)).status_code == 200
        first = _row(stack, key).last_used_at
        assert first is not None and abs(utc_now() - first) < timedelta(minutes=1)
        assert client.get("/api/v1/journeys", headers=auth(key)).status_code == 200
        assert _row(stack, key).last_used_at == first  # within the minute: no write
        with session_scope(stack.url) as session:
            session.execute(update(ApiKeyRow).where(ApiKeyRow.key_sha256 == key_sha256(key))
                            .values(last_used_at=first - timedelta(minutes=2)))
        assert client.get("/api/v1/journeys", headers=auth(key)).status_code == 200
        assert _row(stack, key).last_used_at > first
    listed = _listed(stack)[str(_row(stack, key).id)]
    assert listed[4] != "never"


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def url_at_0006(request, tmp_path):
    """A database migrated to 0006, the revision before keys could be revoked."""
    if request.param == "sqlite":
        url = make_settings(tmp_path / "data").effective_database_url
        upgrade(url, "0006")
        yield url
        return
    request.getfixturevalue("pg_url")  # skips (or fails under CI) without PostgreSQL
    with temporary_database(PG_URL, f"signmap_test_0007_{secrets.token_hex(3)}") as url:
        upgrade(url, "0006")
        yield url


def test_migration_0007_keeps_the_keys_and_adds_revocation(url_at_0006, tmp_path):
    with get_engine(url_at_0006).begin() as conn:
        conn.execute(text("INSERT INTO api_keys (name, role, key_sha256, created_at) VALUES "
                          "('van-3', 'fleet', :h, :t)"), {"h": key_sha256("old-key"),
                                                          "t": utc_now()})
    upgrade(url_at_0006)
    stack = Stack("migrated", make_settings(tmp_path / "data", database_url=url_at_0006))
    row = _row(stack, "old-key")
    assert (row.name, row.role, row.revoked_at, row.last_used_at) == ("van-3", "fleet", None, None)
    with TestClient(create_service_app(stack.settings)) as client:
        assert client.get("/api/v1/journeys", headers=auth("old-key")).status_code == 200
        assert _row(stack, "old-key").last_used_at is not None
        assert _keys(stack, "revoke", str(row.id)).returncode == 0
        assert client.get("/api/v1/journeys", headers=auth("old-key")).status_code == 401
