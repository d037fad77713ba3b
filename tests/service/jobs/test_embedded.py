"""The embedded worker (no broker): jobs run in a child process of the API; journeys left queued or
stale-running by an earlier process are picked up when the API starts."""

from __future__ import annotations

import secrets
from datetime import timedelta

from sqlalchemy import update

from app.service.jobs import state
from app.service.db.session import session_scope
from app.service.db.models import JourneyRow, utc_now
from tests.utils import bundle_factory as bf
from tests.utils.results.service_support import bf_zip
from tests.utils.stack import auth, poll_journey, sqlite_stack, upload

NO_TURN = "the journey has no turn"


def _stopped(body: dict) -> bool:
    """Done, failed, or waiting for its camera (a straight road of an uncalibrated camera)."""
    return body["status"] in ("done", "failed") or body["stage"] == "waiting_for_camera"


def _straight_road(camera_id: str) -> bytes:
    return bf_zip({**bf.valid_files(), "manifest.json": bf.manifest_bytes(camera_id=camera_id)})


def test_queued_and_stale_journeys_are_run_when_the_api_starts(tmp_path):
    held = sqlite_stack(tmp_path / "data")  # embedded worker off: uploads stay queued
    key = held.key("fleet")
    with held.client() as client:
        queued = upload(client, key, _straight_road(secrets.token_hex(4)))
        stale = upload(client, key, bf_zip(bf.valid_files(n_frames=6)))
    # `stale` was being run by a process that died a while ago.
    with session_scope(held.url) as session:
        assert state.claim(session, stale, 60, 3) == 1
        session.execute(update(JourneyRow).where(JourneyRow.id == stale).values(
            heartbeat_at=utc_now() - timedelta(seconds=held.settings.stale_after_s + 1)))

    embedded = held.settings.model_copy(update={"embedded_worker": True})
    held.settings = embedded
    with held.client() as client:
        done = {journey_id: poll_journey(client, auth(key), journey_id, _stopped, timeout_s=120)
                for journey_id in (queued, stale)}
    assert done[queued]["stage"] == "waiting_for_camera" and NO_TURN in done[queued]["message"]
    assert done[queued]["attempts"] == 1
    assert done[stale]["stage"] == "waiting_for_camera" and done[stale]["attempts"] == 2


def test_an_upload_is_run_by_the_embedded_worker(tmp_path):
    stack = sqlite_stack(tmp_path / "data", embedded_worker=True)
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, _straight_road(secrets.token_hex(4)))
        body = poll_journey(client, auth(key), journey_id, _stopped, timeout_s=120)
    assert (body["status"], body["stage"], body["error"]) == ("queued", "waiting_for_camera", None)
    assert NO_TURN in body["message"]
    assert not (stack.settings.data_dir / "work" / f"{journey_id}-1").exists()
