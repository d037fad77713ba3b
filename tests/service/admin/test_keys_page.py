"""The dashboard's keys page (TestClient, SQLite): it lists every stored key with its role, name,
times and never the key, and its Revoke button revokes (the key answers 401 at once and its own
dashboard sessions end), only for a signed-in admin and only from the dashboard's own origin."""

from __future__ import annotations

import re

import pytest

from app.service.admin.session import COOKIE
from app.service.auth import key_sha256
from app.service.db.models import ApiKeyRow
from app.service.db.session import session_scope
from tests.utils.stack import ADMIN_KEY, auth, sqlite_stack


@pytest.fixture
def stack(tmp_path):
    return sqlite_stack(tmp_path / "data")


def _id(stack, key: str) -> int:
    with session_scope(stack.url) as session:
        return session.query(ApiKeyRow).filter_by(key_sha256=key_sha256(key)).one().id


def _revoked(stack, key_id: int) -> bool:
    with session_scope(stack.url) as session:
        return session.get(ApiKeyRow, key_id).revoked_at is not None


def _sign_in(client, key: str = ADMIN_KEY) -> None:
    answer = client.post("/admin/login", data={"key": key}, follow_redirects=False)
    assert answer.status_code == 303, answer.text


def _row(page: str, key_id: int) -> str:
    match = re.search(rf'<tr data-key-id="{key_id}".*?</tr>', page, flags=re.S)
    assert match, page
    return match.group(0)


def test_the_keys_page_lists_and_revokes(stack):
    fleet, reader = stack.key("fleet", "van-3"), stack.key("reader", "<b>map</b>")
    fleet_id, reader_id = _id(stack, fleet), _id(stack, reader)
    with stack.client() as client:
        assert client.get("/api/v1/journeys", headers=auth(fleet)).status_code == 200
        _sign_in(client)
        page = client.get("/admin/keys")
        assert page.status_code == 200
        assert '<a href="/admin/keys">Keys</a>' in page.text
        row = _row(page.text, fleet_id)
        assert "<td>fleet</td>" in row and "<td>van-3</td>" in row
        assert 'class="last-used">never<' not in row  # used just above
        assert f'action="/admin/keys/{fleet_id}/revoke"' in row
        reader_row = _row(page.text, reader_id)
        assert "&lt;b&gt;map&lt;/b&gt;" in reader_row and 'class="last-used">never<' in reader_row
        for key in (fleet, reader, ADMIN_KEY):
            assert key not in page.text and key_sha256(key) not in page.text

        answer = client.post(f"/admin/keys/{fleet_id}/revoke", follow_redirects=False)
        assert answer.status_code == 303 and answer.headers["location"] == "/admin/keys"
        assert _revoked(stack, fleet_id) and not _revoked(stack, reader_id)
        refused = client.get("/api/v1/journeys", headers=auth(fleet))
        assert refused.status_code == 401
        assert refused.json()["detail"] == "this API key was revoked"
        row = _row(client.get("/admin/keys").text, fleet_id)
        assert 'class="revoked"' in row and "/revoke" not in row
        # Again (a second tab): nothing changes; an unknown id is 404.
        assert client.post(f"/admin/keys/{fleet_id}/revoke",
                           follow_redirects=False).status_code == 303
        assert client.post("/admin/keys/999999/revoke", follow_redirects=False).status_code == 404


def test_revoking_needs_a_session_and_the_dashboards_origin(stack):
    key_id = _id(stack, stack.key("fleet"))
    with stack.client() as client:
        answer = client.post(f"/admin/keys/{key_id}/revoke", follow_redirects=False)
        assert answer.status_code == 303 and answer.headers["location"] == "/admin/login"
        assert client.get("/admin/keys", follow_redirects=False).status_code == 303
        _sign_in(client, stack.key("admin"))
        answer = client.post(f"/admin/keys/{key_id}/revoke",
                             headers={"Origin": "https://evil.example"}, follow_redirects=False)
        assert answer.status_code == 403
        assert not _revoked(stack, key_id)


def test_a_revoked_admin_key_loses_its_dashboard_sessions_and_cannot_sign_in(stack):
    admin = stack.key("admin", "ops")
    admin_id = _id(stack, admin)
    with stack.client() as client:
        _sign_in(client, admin)
        answer = client.post(f"/admin/keys/{admin_id}/revoke", follow_redirects=False)
        assert answer.status_code == 303
        # Its own session ended with it: the next page sends to the sign-in.
        answer = client.get("/admin/keys", follow_redirects=False)
        assert answer.status_code == 303 and answer.headers["location"] == "/admin/login"
        answer = client.post("/admin/login", data={"key": admin}, follow_redirects=False)
        assert answer.status_code == 403 and "this key was revoked" in answer.text
        assert COOKIE not in answer.cookies
