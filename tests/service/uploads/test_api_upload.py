"""POST /api/v1/journeys: bad input gets an exact status and a useful detail and leaves nothing
behind (no row, no file); a good bundle is stored and queued once; re-uploads are deduplicated."""

from __future__ import annotations

import hashlib
import json
import socket
import threading
import time
from contextlib import contextmanager

import pytest
import uvicorn
from sqlalchemy import update

from app.service.db.session import session_scope
from app.service.db.models import JourneyRow
from tests.utils import bundle_factory as bf
from tests.utils.stack import auth, sqlite_stack


def _post(client, key: str, data: bytes, filename: str = "journey.zip"):
    return client.post("/api/v1/journeys", headers=auth(key),
                       files={"bundle": (filename, data, "application/zip")})


def _assert_nothing_stored(stack, key: str) -> None:
    assert stack.count_journeys(key) == 0
    assert stack.stored_files() == []


@pytest.mark.parametrize("case", bf.BROKEN_CASES)
def test_broken_bundle_is_rejected_with_its_reason(stack, case):
    data, fragment = bf.broken_bundle(case)
    key = stack.key("fleet")
    with stack.client() as client:
        response = _post(client, key, data)
    assert response.status_code == 422, response.text
    assert fragment in response.json()["detail"]
    _assert_nothing_stored(stack, key)


def test_not_multipart_is_415(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        response = client.post("/api/v1/journeys", headers={**auth(key),
                               "Content-Type": "application/zip"},
                               content=bf.zip_bytes(bf.valid_files()))
    assert response.status_code == 415
    assert "multipart/form-data" in response.json()["detail"]
    _assert_nothing_stored(stack, key)


def test_missing_bundle_field_is_422(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        response = client.post("/api/v1/journeys", headers=auth(key),
                               files={"zip": ("journey.zip", bf.zip_bytes(bf.valid_files()))})
    assert response.status_code == 422
    assert response.json()["detail"] == "multipart field 'bundle' (the journey zip) is missing"
    _assert_nothing_stored(stack, key)


def test_truncated_multipart_body_is_400(stack):
    key = stack.key("fleet")
    body = (b"--XyZ\r\nContent-Disposition: form-data; name=\"bundle\"; filename=\"j.zip\"\r\n"
            b"Content-Type: application/zip\r\n\r\n" + bf.zip_bytes(bf.valid_files())[:500])
    with stack.client() as client:
        response = client.post("/api/v1/journeys", content=body, headers={
            **auth(key), "Content-Type": "multipart/form-data; boundary=XyZ"})
    assert response.status_code == 400
    assert response.json()["detail"] == "multipart body ended early"
    _assert_nothing_stored(stack, key)


@contextmanager
def _live_server(app):
    """``app`` served by a real uvicorn on a free local port (TestClient buffers request bodies)."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    try:
        yield sock.getsockname()[1]
    finally:
        server.should_exit = True
        thread.join(30)


def test_over_the_limit_while_streaming_is_413(tmp_path):
    """The body's chunks stop 128 KiB past the limit and the request never ends: a server that
    read the whole body before checking would never answer."""
    from app.commands.service import create_service_app

    stack = sqlite_stack(tmp_path / "data", max_upload_mb=1)
    key = stack.key("fleet")
    head = (b"--XyZ\r\nContent-Disposition: form-data; name=\"bundle\"; filename=\"j.zip\"\r\n"
            b"Content-Type: application/zip\r\n\r\n")
    with _live_server(create_service_app(stack.settings)) as port:
        with socket.create_connection(("127.0.0.1", port), timeout=30) as conn:
            conn.sendall(b"POST /api/v1/journeys HTTP/1.1\r\nHost: test\r\n"
                         b"Authorization: Bearer " + key.encode() + b"\r\n"
                         b"Content-Type: multipart/form-data; boundary=XyZ\r\n"
                         b"Transfer-Encoding: chunked\r\n\r\n")
            for chunk in [head] + [b"\0" * 65536] * 18:
                conn.sendall(b"%x\r\n%s\r\n" % (len(chunk), chunk))
            reply = b""
            while b"\r\n\r\n" not in reply or not reply.rstrip().endswith(b"}"):
                data = conn.recv(65536)
                if not data:
                    break
                reply += data
    assert reply.startswith(b"HTTP/1.1 413 ")
    assert json.loads(reply.split(b"\r\n\r\n", 1)[1]) == {
        "detail": "upload larger than the limit of 1048576 bytes"}
    _assert_nothing_stored(stack, key)


def test_declared_length_over_the_limit_is_413_before_reading(stack):
    stack.settings.max_upload_mb = 1
    key = stack.key("fleet")
    with stack.client() as client:
        response = _post(client, key, bytes(1024 * 1024 + 1))
    assert response.status_code == 413
    _assert_nothing_stored(stack, key)


def test_valid_upload_is_queued_and_stored_once(stack):
    key = stack.key("fleet")
    data = bf.zip_bytes(bf.valid_files(n_frames=6))
    with stack.client() as client:
        response = _post(client, key, data)
        assert response.status_code == 202
        body = response.json()
        assert body["status"] == "queued" and set(body) == {"id", "status"}
        journey = client.get(f"/api/v1/journeys/{body['id']}", headers=auth(key)).json()
    assert (journey["status"], journey["progress"], journey["n_frames"], journey["n_signs"],
            journey["calibration"], journey["camera_id"], journey["vehicle_id"]) == \
        ("queued", 0.0, 6, None, None, "test-cam", "car-7")
    sha = hashlib.sha256(data).hexdigest()
    assert stack.stored_files() == [f"bundles/{sha}.zip"]
    assert (stack.settings.data_dir / "bundles" / f"{sha}.zip").read_bytes() == data
    with session_scope(stack.url) as session:
        row = session.get(JourneyRow, body["id"])
        assert (row.bundle_sha256, row.bundle_bytes, row.attempts) == (sha, len(data), 0)


def test_reupload_of_the_same_bytes_returns_the_same_journey(stack):
    fleet_a, fleet_b = stack.key("fleet"), stack.key("fleet")
    data = bf.zip_bytes(bf.valid_files())
    with stack.client() as client:
        first = _post(client, fleet_a, data)
        again = _post(client, fleet_a, data, filename="other-name.zip")
        other_owner = _post(client, fleet_b, data)
    assert first.status_code == 202
    assert again.status_code == 200 and again.json() == {"id": first.json()["id"],
                                                         "status": "queued"}
    # Dedupe is per owner: another fleet's identical upload is its own journey (one stored file).
    assert other_owner.status_code == 202 and other_owner.json()["id"] != first.json()["id"]
    assert len(stack.stored_files()) == 1


def test_reupload_of_a_failed_journey_queues_it_again(stack):
    key = stack.key("fleet")
    data = bf.zip_bytes(bf.valid_files())
    with stack.client() as client:
        journey_id = _post(client, key, data).json()["id"]
        with session_scope(stack.url) as session:
            session.execute(update(JourneyRow).where(JourneyRow.id == journey_id).values(
                status="failed", error="no turn", attempts=1))
        again = _post(client, key, data)
        body = client.get(f"/api/v1/journeys/{journey_id}", headers=auth(key)).json()
    assert again.status_code == 202 and again.json() == {"id": journey_id, "status": "queued"}
    assert (body["status"], body["error"], body["attempts"]) == ("queued", None, 0)
