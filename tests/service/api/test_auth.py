"""Every route under every kind of caller: 401 without a valid key, 403 for the wrong role, and a
fleet key sees only its own journeys (another fleet's answer 404, like a missing one)."""

from __future__ import annotations

import subprocess
import sys

from sqlalchemy import select

from app.service.db.session import session_scope
from app.service.db.models import ApiKeyRow
from tests.utils import bundle_factory as bf
from tests.utils.paths import REPO
from tests.utils.stack import ADMIN_KEY, auth, settings_env, sqlite_stack

CALLERS = ("none", "unknown", "fleet_owner", "fleet_other", "reader", "admin_key", "env_admin")

# route -> expected status per caller
EXPECTED = {
    "POST /journeys": dict(none=401, unknown=401, fleet_owner=202, fleet_other=202, reader=403,
                           admin_key=202, env_admin=202),
    "GET /journeys": dict(none=401, unknown=401, fleet_owner=200, fleet_other=200, reader=403,
                          admin_key=200, env_admin=200),
    "GET /journeys/{id}": dict(none=401, unknown=401, fleet_owner=200, fleet_other=404,
                               reader=403, admin_key=200, env_admin=200),
    "GET /journeys/{id}/signs": dict(none=401, unknown=401, fleet_owner=200, fleet_other=404,
                                     reader=403, admin_key=200, env_admin=200),
    "GET /signs": dict(none=401, unknown=401, fleet_owner=403, fleet_other=403, reader=200,
                       admin_key=200, env_admin=200),
}


def _headers(keys: dict[str, str], caller: str) -> dict[str, str]:
    if caller == "none":
        return {}
    if caller == "unknown":
        return auth("not-a-key")
    return auth(keys[caller])


def test_every_route_and_role(stack):
    keys = {"fleet_owner": stack.key("fleet"), "fleet_other": stack.key("fleet"),
            "reader": stack.key("reader"), "admin_key": stack.key("admin"),
            "env_admin": ADMIN_KEY}
    with stack.client() as client:
        journey_id = client.post("/api/v1/journeys", headers=auth(keys["fleet_owner"]),
                                 files={"bundle": ("j.zip", bf.zip_bytes(bf.valid_files()))}
                                 ).json()["id"]
        seen = {}
        for route in EXPECTED:
            method, path = route.split(" ")
            for n, caller in enumerate(CALLERS):
                url = "/api/v1" + path.replace("{id}", journey_id)
                if method == "POST":  # distinct bytes per caller: no dedupe
                    files = {"bundle": ("j.zip", bf.zip_bytes(bf.valid_files(n_frames=5 + n)))}
                    response = client.post(url, headers=_headers(keys, caller), files=files)
                else:
                    params = {"bbox": "-180,-90,180,90"} if path == "/signs" else None
                    response = client.get(url, headers=_headers(keys, caller), params=params)
                seen[(route, caller)] = response.status_code
                if response.status_code >= 400:
                    assert isinstance(response.json()["detail"], str)
                if response.status_code == 401:
                    assert response.headers["www-authenticate"] == "Bearer"
    assert seen == {(route, caller): code for route, codes in EXPECTED.items()
                    for caller, code in codes.items()}


def test_fleet_lists_only_its_own_journeys(stack):
    mine, theirs = stack.key("fleet"), stack.key("fleet")
    with stack.client() as client:
        ids = [client.post("/api/v1/journeys", headers=auth(key),
                           files={"bundle": ("j.zip", bf.zip_bytes(bf.valid_files(n_frames=n)))}
                           ).json()["id"] for key, n in ((mine, 5), (theirs, 6), (mine, 7))]
        listed = client.get("/api/v1/journeys", headers=auth(mine)).json()
        everything = client.get("/api/v1/journeys", headers=auth(ADMIN_KEY),
                                params={"limit": 500}).json()
    assert [j["id"] for j in listed] == [ids[2], ids[0]]  # newest first
    assert set(ids) <= {j["id"] for j in everything}


def test_wrong_scheme_is_401(stack):
    with stack.client() as client:
        response = client.get("/api/v1/journeys", headers={"Authorization": f"Basic {ADMIN_KEY}"})
    assert response.status_code == 401


def test_keys_create_prints_a_working_key_stored_hashed(tmp_path):
    stack = sqlite_stack(tmp_path / "data")
    out = subprocess.run([sys.executable, "-m", "app.cli", "keys", "create", "--role", "fleet",
                          "--name", "van-3"], cwd=REPO, env=settings_env(stack.settings),
                         capture_output=True, text=True, check=True)
    key = out.stdout.strip()
    assert len(key) >= 40 and "\n" not in key
    with session_scope(stack.url) as session:
        rows = session.scalars(select(ApiKeyRow)).all()
        assert [(r.name, r.role) for r in rows] == [("van-3", "fleet")]
        assert key not in (rows[0].key_sha256, rows[0].name)
    with stack.client() as client:
        assert client.get("/api/v1/journeys", headers=auth(key)).status_code == 200
        assert client.get("/api/v1/signs", headers=auth(key),
                          params={"bbox": "0,0,1,1"}).status_code == 403


def test_keys_create_refuses_an_unknown_role(tmp_path):
    stack = sqlite_stack(tmp_path / "data")
    out = subprocess.run([sys.executable, "-m", "app.cli", "keys", "create", "--role", "root"],
                         cwd=REPO, env=settings_env(stack.settings), capture_output=True,
                         text=True)
    assert out.returncode == 2 and "invalid choice: 'root'" in out.stderr
