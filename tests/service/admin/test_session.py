"""Dashboard sessions hold an opaque token, not an API key (issue 13, finding 4), on SQLite and
PostgreSQL: nothing in the cookie works on /api/v1, expiry and sign-out end it at once, expired
rows are swept, and deleting the key that signed in ends its sessions."""

from __future__ import annotations

import base64
import json
import time
from datetime import timedelta

from sqlalchemy import delete, select, text, update

from app.service.auth import key_sha256
from app.service.admin.session import COOKIE
from app.service.db.session import get_engine, session_scope, upgrade
from app.service.db.models import AdminSessionRow, ApiKeyRow, JourneyRow, utc_now
from tests.utils.stack import ADMIN_KEY, Stack, auth, make_settings


def _sign_in(client, key: str = ADMIN_KEY) -> str:
    answer = client.post("/admin/login", data={"key": key}, follow_redirects=False)
    assert answer.status_code == 303, answer.text
    return answer.cookies[COOKIE]


def _derived(value: str) -> list[str]:
    """The cookie and everything readable in it: its dot-separated parts, base64-decoded, and
    JSON-decoded (the old signed cookie carried a key as base64 JSON in its first part)."""
    found = {value, *value.split(".")}
    for part in list(found):
        try:
            raw = base64.urlsafe_b64decode(part + "=" * (-len(part) % 4)).decode()
        except ValueError:
            continue
        found.add(raw)
        try:
            found.add(str(json.loads(raw)))
        except ValueError:
            pass
    return sorted(s for s in found if s)


def _refused_everywhere(client, value: str) -> None:
    for candidate in _derived(value):
        answer = client.get("/api/v1/journeys", headers=auth(candidate))
        assert answer.status_code == 401, (candidate, answer.status_code)
        assert answer.json()["detail"] == "unknown API key"


def _rows(stack: Stack, value: str) -> int:
    with session_scope(stack.url) as session:
        return len(session.scalars(select(AdminSessionRow).where(
            AdminSessionRow.token_sha256 == key_sha256(value))).all())


def test_the_cookie_is_not_an_api_key(stack):
    with stack.client() as client:
        value = _sign_in(client)
        assert client.get("/admin/journeys").status_code == 200
        _refused_everywhere(client, value)
        # The dashboard still calls the API for the operator, in-process and without a key.
        assert client.get("/admin/api/signs?bbox=0,0,1,1").status_code == 200
    assert _rows(stack, value) == 1
    with session_scope(stack.url) as session:
        assert session.scalars(select(ApiKeyRow).where(ApiKeyRow.name.like("dashboard%"))).all() == []


def test_an_expired_session_ends_at_once_and_is_swept(stack, tmp_path):
    stack.settings.admin_session_max_age_s = 1
    with stack.client() as client:
        value = _sign_in(client)
        assert client.get("/admin/journeys").status_code == 200
        time.sleep(1.5)
        client.cookies.set(COOKIE, value, path="/admin")  # replayed although the browser dropped it
        answer = client.get("/admin/journeys", follow_redirects=False)
        assert answer.status_code == 303 and answer.headers["location"] == "/admin/login"
        _refused_everywhere(client, value)
        assert _rows(stack, value) == 1  # refused before any sweep ran
        _sign_in(client)  # anyone's sign-in sweeps the expired rows
        assert _rows(stack, value) == 0


def test_expired_sessions_are_swept_at_start_and_periodically(stack):
    stack.settings.sweep_interval_s = 1
    with stack.client() as client:
        old, fresh = _sign_in(client), _sign_in(client)
    with session_scope(stack.url) as session:
        session.execute(update(AdminSessionRow).where(AdminSessionRow.token_sha256 == key_sha256(old))
                        .values(expires_at=utc_now() - timedelta(seconds=1)))
    with stack.client():  # start
        assert (_rows(stack, old), _rows(stack, fresh)) == (0, 1)
        with session_scope(stack.url) as session:
            session.execute(update(AdminSessionRow).where(
                AdminSessionRow.token_sha256 == key_sha256(fresh))
                .values(expires_at=utc_now() - timedelta(seconds=1)))
        deadline = time.monotonic() + 10
        while _rows(stack, fresh) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert _rows(stack, fresh) == 0  # the running API's periodic sweep


def test_sign_out_deletes_the_session(stack):
    with stack.client() as client:
        value = _sign_in(client)
        assert client.post("/admin/logout", follow_redirects=False).status_code == 303
        assert _rows(stack, value) == 0
        client.cookies.set(COOKIE, value, path="/admin")
        assert client.get("/admin/journeys", follow_redirects=False).status_code == 303


def test_deleting_the_key_ends_its_sessions(stack):
    key = stack.key("admin")
    with stack.client() as client:
        value = _sign_in(client, key)
        assert client.get("/admin/cameras").status_code == 200
        with session_scope(stack.url) as session:
            session.execute(delete(ApiKeyRow).where(ApiKeyRow.key_sha256 == key_sha256(key)))
        assert client.get("/admin/cameras", follow_redirects=False).status_code == 303
    assert _rows(stack, value) == 0  # gone with the key (ON DELETE CASCADE)


def test_the_migration_revokes_the_old_session_keys(tmp_path):
    stack = Stack("sqlite", make_settings(tmp_path / "data"))
    upgrade(stack.url, "0002")
    with get_engine(stack.url).begin() as conn:
        conn.execute(text("DELETE FROM api_keys"))
        conn.execute(text("INSERT INTO api_keys (id, name, role, key_sha256, created_at) VALUES "
                          "(7, 'dashboard-session of SIGNMAP_ADMIN_KEY', 'admin', :h, :t), "
                          "(8, 'van-3', 'fleet', :h2, :t)"),
                     {"h": key_sha256("leaked"), "h2": key_sha256("fleet"), "t": utc_now()})
        conn.execute(text(
            "INSERT INTO journeys (id, owner_key_id, camera_id, bundle_sha256, bundle_bytes, status, "
            "progress, n_frames, created_at, attempts) VALUES ('j1', 7, 'c', 'x', 1, 'done', 1.0, "
            "3, :t, 1)"), {"t": utc_now()})
    upgrade(stack.url)
    with session_scope(stack.url) as session:
        assert [k.name for k in session.scalars(select(ApiKeyRow))] == ["van-3"]
        assert session.get(JourneyRow, "j1").owner_key_id is None
    with stack.client() as client:
        assert client.get("/api/v1/journeys", headers=auth("leaked")).status_code == 401
