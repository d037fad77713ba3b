"""Bundles in an S3-compatible object store (issue 15), against a real HTTP endpoint started by the
test session (moto's server, ``s3_endpoint``): uploads land there and nowhere else, an unreachable
store answers 503 and leaves nothing behind, jobs fetch into their own scratch, deleting journeys
deletes objects no journey shares; on SQLite and PostgreSQL."""

from __future__ import annotations

import hashlib
import secrets
import socket
import time
from pathlib import Path

import pytest
from pydantic import ValidationError
from sqlalchemy import update

from app.service import storage
from app.service.admin import media
from app.service.db.session import session_scope
from app.service.jobs.run import run_journey
from app.service.db.models import JourneyRow
from app.settings import Settings
from tests.utils import bundle_factory as bf
from tests.utils.backends import s3_objects
from tests.utils.results.service_support import bf_zip
from tests.utils.stack import ADMIN_KEY, Stack, auth, upload

UNREACHABLE = "the bundle store is unreachable; try again later"


def _with(stack: Stack, **changes) -> Stack:
    return Stack(stack.name, stack.settings.model_copy(update=changes))


@pytest.fixture
def s3_stack(stack, s3_storage_url) -> Stack:
    return _with(stack, storage_url=s3_storage_url)


def _post(client, key: str, data: bytes):
    return client.post("/api/v1/journeys", headers=auth(key),
                       files={"bundle": ("journey.zip", data, "application/zip")})


def _local_files(data_dir: Path) -> list[str]:
    return sorted(str(p.relative_to(data_dir)) for p in data_dir.rglob("*")
                  if p.is_file() and not p.name.startswith("signmap.db"))


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_upload_is_stored_in_the_object_store_only(s3_stack):
    fleet_a, fleet_b = s3_stack.key("fleet"), s3_stack.key("fleet")
    data = bf_zip()
    sha = hashlib.sha256(data).hexdigest()
    with s3_stack.client() as client:
        first = _post(client, fleet_a, data)
        again = _post(client, fleet_a, data)
        other_owner = _post(client, fleet_b, data)
    assert (first.status_code, again.status_code, other_owner.status_code) == (202, 200, 202)
    # Content-addressed: two journeys, one object with exactly the uploaded bytes.
    assert s3_objects(s3_stack.settings.storage_url) == {f"bundles/{sha}.zip": data}
    assert _local_files(s3_stack.settings.data_dir) == []  # nothing kept on the API host


@pytest.mark.parametrize("broken", ["closed port", "no such bucket"])
def test_an_unreachable_object_store_fails_the_upload_with_503(stack, s3_storage_url,
                                                              monkeypatch, broken):
    if broken == "closed port":
        monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{_closed_port()}")
        url = s3_storage_url
    else:
        url = "s3://signmap-no-such-bucket/bundles"
    s3 = _with(stack, storage_url=url)
    key = s3.key("fleet")
    with s3.client() as client:
        t0 = time.monotonic()
        response = _post(client, key, bf_zip())
        elapsed_s = time.monotonic() - t0
    assert response.status_code == 503, response.text
    assert response.json() == {"detail": UNREACHABLE}
    assert elapsed_s < 30  # bounded retries, not the SDK's default minutes
    assert s3.count_journeys(key) == 0
    assert _local_files(s3.settings.data_dir) == []
    if broken == "no such bucket":
        import boto3

        assert "signmap-no-such-bucket" not in [
            b["Name"] for b in boto3.client("s3").list_buckets()["Buckets"]]


def test_a_queue_failure_removes_the_object_it_stored(tmp_path, s3_storage_url):
    from tests.utils.stack import sqlite_stack

    # A broker nobody listens on: the upload is stored, then cannot be queued.
    s3 = sqlite_stack(tmp_path / "data", storage_url=s3_storage_url,
                      broker_url=f"redis://127.0.0.1:{_closed_port()}/0")
    key = s3.key("fleet")
    with s3.client() as client:
        response = _post(client, key, bf_zip())
    assert response.status_code == 503, response.text
    assert response.json() == {"detail": "the job queue is unreachable; try again later"}
    assert s3.count_journeys(key) == 0
    assert s3_objects(s3_storage_url) == {}


def _unique_bundle() -> bytes:
    """Bytes no other test uploads (the PostgreSQL database is shared by the session's tests)."""
    files = bf.valid_files()
    files["manifest.json"] = files["manifest.json"].replace(
        b'"car-7"', f'"car-{secrets.token_hex(4)}"'.encode())
    return bf_zip(files)


def test_deleting_journeys_deletes_their_object_once_no_journey_shares_it(s3_stack):
    fleet_a, fleet_b = s3_stack.key("fleet"), s3_stack.key("fleet")
    data = _unique_bundle()
    url = s3_stack.settings.storage_url
    with s3_stack.client() as client:
        first, second = upload(client, fleet_a, data), upload(client, fleet_b, data)
        assert client.delete(f"/api/v1/journeys/{first}",
                             headers=auth(ADMIN_KEY)).status_code == 204
        assert len(s3_objects(url)) == 1  # the other fleet's journey still needs it
        assert client.delete(f"/api/v1/journeys/{second}",
                             headers=auth(ADMIN_KEY)).status_code == 204
    assert s3_objects(url) == {}


def test_a_job_fetches_the_bundle_into_its_own_scratch(s3_stack, tmp_path):
    key = s3_stack.key("fleet")
    files = bf.valid_files()
    files["manifest.json"] = files["manifest.json"].replace(b"test-cam", b"s3-only-cam")
    with s3_stack.client() as client:
        journey_id = upload(client, key, bf_zip(files))
    # The worker is another host: its own data dir, only the database and the store in common.
    worker = s3_stack.settings.model_copy(update={"data_dir": tmp_path / "worker"})
    run_journey(journey_id, worker)
    with session_scope(s3_stack.url) as session:
        row = session.get(JourneyRow, journey_id)
        # Past extract: the bundle was fetched and read; the pipeline cannot calibrate on a
        # straight road, and the journey waits for its camera.
        assert (row.status, row.stage) == ("queued", "waiting_for_camera"), row.error
        session.execute(update(JourneyRow).where(JourneyRow.id == journey_id)
                        .values(status="queued", stage=None, attempts=0))
        sha = row.bundle_sha256
    assert _local_files(tmp_path / "worker") == []  # its scratch went with the run

    storage.make_store(worker).delete(sha)
    run_journey(journey_id, worker)
    with session_scope(s3_stack.url) as session:
        row = session.get(JourneyRow, journey_id)
    assert (row.status, row.stage) == ("failed", "extract")
    where = f"{s3_stack.settings.storage_url}/{sha}.zip"
    assert row.error == (f"the stored bundle {where} is missing from the object store")


def test_the_dashboard_reads_media_from_a_few_fetched_bundles(tmp_path, s3_storage_url):
    store = storage.S3BundleStore(s3_storage_url)
    shas = []
    for seed in range(media.KEEP_FETCHED + 1):
        data = bf.zip_bytes(bf.valid_files(n_frames=3 + seed))
        shas.append(hashlib.sha256(data).hexdigest())
        (tmp_path / "up.zip").write_bytes(data)
        assert store.put(shas[-1], tmp_path / "up.zip")
    data_dir = tmp_path / "api"
    data_dir.mkdir()
    for n, sha in enumerate(shas):
        assert len(media.gps_track(data_dir, store, sha)) == 3 + n
    png = media.crop_png(data_dir, store, shas[-1], bf.frame_ids()[0], [10, 10, 40, 40])
    assert png is not None and png.startswith(b"\x89PNG")
    fetched = sorted(p.name for p in (data_dir / "cache" / "admin" / "bundles").iterdir())
    assert fetched == sorted(f"{sha}.zip" for sha in shas[1:])  # the oldest one was let go
    with pytest.raises(storage.BundleMissing):
        media.crop_png(data_dir, store, "0" * 64, bf.frame_ids()[0], None)


@pytest.mark.parametrize("url", ["http://bucket/prefix", "s3://", "bucket/prefix"])
def test_a_storage_url_that_is_not_s3_is_refused_at_start(url):
    with pytest.raises(ValidationError, match="storage_url must look like s3://bucket/prefix"):
        Settings(storage_url=url)
