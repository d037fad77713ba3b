"""The job's life cycle in the database (claim, heartbeat, store, recovery) and ``run_journey`` on
journeys the pipeline refuses; on SQLite and PostgreSQL."""

from __future__ import annotations

import secrets
from datetime import timedelta

import numpy as np
import pytest
from sqlalchemy import func, select, update

from app.service import storage
from app.service.jobs import state
from app.service.db.session import session_scope
from app.service.jobs.run import run_journey
from app.service.db.models import CalibrationRow, JourneyRow, JourneySignRow, utc_now
from tests.utils import bundle_factory as bf
from tests.utils.results.service_support import bf_zip, finish, made_result
from tests.utils.stack import upload

SIGNS = [("0", "stop", 49.0112, 8.4185, 114.0), ("1", "yield", 49.0113, 8.4185, 114.0)]


def _rows(stack, journey_id: str):
    with session_scope(stack.url) as session:
        signs = session.execute(
            select(JourneySignRow.id, JourneySignRow.cls, JourneySignRow.lat_deg, JourneySignRow.lon_deg,
                   JourneySignRow.alt_m, JourneySignRow.observations)
            .where(JourneySignRow.journey_id == journey_id).order_by(JourneySignRow.id)).all()
        calibrations = session.execute(
            select(CalibrationRow.camera_id, CalibrationRow.fx)
            .where(CalibrationRow.journey_id == journey_id)).all()
    return [tuple(r) for r in signs], [tuple(r) for r in calibrations]


def _journey(stack, journey_id: str) -> JourneyRow:
    with session_scope(stack.url) as session:
        return session.get(JourneyRow, journey_id)


def _age_heartbeat(stack, journey_id: str, seconds: float) -> None:
    with session_scope(stack.url) as session:
        session.execute(update(JourneyRow).where(JourneyRow.id == journey_id)
                        .values(heartbeat_at=utc_now() - timedelta(seconds=seconds)))


def test_storing_a_result_twice_gives_the_same_rows(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
    finish(stack, journey_id, made_result(SIGNS))
    first = _rows(stack, journey_id)
    # Put it back as recovery would, and store the same result again.
    with session_scope(stack.url) as session:
        session.execute(update(JourneyRow).where(JourneyRow.id == journey_id).values(status="queued"))
    assert finish(stack, journey_id, made_result(SIGNS)) == 2
    assert _rows(stack, journey_id) == first
    assert [r[0] for r in first[0]] == [f"{journey_id}:0", f"{journey_id}:1"]
    assert first[1] == [("test-cam", 50.0)]
    assert _journey(stack, journey_id).n_signs == 2


def test_claim_heartbeat_and_takeover(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
    with session_scope(stack.url) as session:
        assert state.claim(session, journey_id, 60, 3) == 1
    with session_scope(stack.url) as session:  # a live run is not claimed twice
        assert state.claim(session, journey_id, 60, 3) is None
        assert state.beat(session, journey_id, 1, "calibrate", 0.4)
    row = _journey(stack, journey_id)
    assert (row.status, row.stage, row.progress, row.attempts) == ("running", "calibrate", 0.4, 1)

    _age_heartbeat(stack, journey_id, 61)
    with session_scope(stack.url) as session:
        assert journey_id in state.requeue_stale(session, 60, 3)
    with session_scope(stack.url) as session:
        assert state.claim(session, journey_id, 60, 3) == 2
    # The first run wakes up: it may neither beat, nor fail, nor store over the second.
    with session_scope(stack.url) as session:
        assert not state.beat(session, journey_id, 1, "triangulate", 0.9)
        assert not state.fail(session, journey_id, 1, "x", "late")
    from app.pipeline.bundle import read_bundle

    bundle = stack.settings.data_dir / "b.zip"
    bundle.write_bytes(bf_zip())
    journey = read_bundle(bundle, stack.settings.data_dir / "x", decode_images=False)
    with session_scope(stack.url) as session:
        assert not state.store_result(session, journey_id, 1, journey, made_result(SIGNS), {})
    assert _rows(stack, journey_id) == ([], [])
    row = _journey(stack, journey_id)
    assert (row.status, row.attempts, row.stage) == ("running", 2, "start")


def test_a_journey_whose_worker_keeps_dying_fails_after_max_attempts(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
    for attempt in (1, 2):
        with session_scope(stack.url) as session:
            assert state.claim(session, journey_id, 60, 2) == attempt
        _age_heartbeat(stack, journey_id, 61)
    with session_scope(stack.url) as session:  # a redelivered message finds nothing to claim
        assert state.claim(session, journey_id, 60, 2) is None
    row = _journey(stack, journey_id)
    assert (row.status, row.error) == (
        "failed", "gave up after 2 attempts: the worker died or stalled each time")


def test_the_stored_calibration_of_the_camera_excludes_the_journey_itself(stack):
    key = stack.key("fleet")
    camera_id = f"cam-{key[:8]}"
    files = [{**bf.valid_files(n_frames=n), "manifest.json": bf.manifest_bytes(
        camera_id=camera_id)} for n in (5, 6, 7)]
    with stack.client() as client:
        ids = [upload(client, key, bf_zip(f)) for f in files]
    finish(stack, ids[0], made_result(SIGNS, fx=60.0), files[0])
    finish(stack, ids[1], made_result(SIGNS, fx=70.0), files[1])
    finish(stack, ids[2], made_result(SIGNS, source="supplied", fx=70.0), files[2])
    with session_scope(stack.url) as session:
        # Two that disagree: no majority, the newest.
        assert _stored(session, camera_id, ids[2]).fx == 70.0
        assert _stored(session, camera_id, ids[1]).fx == 60.0
        assert _stored(session, "other-camera", ids[2]) is None
        n_records = session.scalar(select(func.count()).select_from(CalibrationRow)
                                   .where(CalibrationRow.camera_id == camera_id))
    assert n_records == 2  # "supplied" calibrations are not stored again


def _stored(session, camera_id: str, journey_id: str):
    return state.camera_calibration(session, camera_id, journey_id, agree_rel=0.03,
                                    newest=7)


def test_a_wrong_calibration_does_not_outvote_the_cameras_others(stack):
    """Three journeys of a camera calibrate within 1 % of each other, then a fourth 14 % off (as
    a wrong accepted calibration is): later journeys get the three's mean, not the newest."""
    key = stack.key("fleet")
    camera_id = f"cam-{key[:8]}"
    fxs = (50.0, 50.5, 49.8, 57.0)
    files = [{**bf.valid_files(n_frames=5 + k), "manifest.json": bf.manifest_bytes(
        camera_id=camera_id)} for k in range(len(fxs) + 1)]
    with stack.client() as client:
        ids = [upload(client, key, bf_zip(f)) for f in files]
    for journey_id, fx, f in zip(ids, fxs, files):
        finish(stack, journey_id, made_result(SIGNS, fx=fx), f)
    with session_scope(stack.url) as session:
        camera = _stored(session, camera_id, ids[-1])
        assert camera.fx == pytest.approx(np.mean(fxs[:3]))
        assert camera.fy == pytest.approx(np.mean(fxs[:3]) + 1.0)
        # Re-running one of the three leaves two that agree against the wrong one.
        assert _stored(session, camera_id, ids[0]).fx == pytest.approx(np.mean(fxs[1:3]))


def test_a_camera_that_really_changed_takes_over_from_its_third_journey(stack):
    """Three journeys of a camera at fx 50, then journeys of another lens (fx 60) under the same
    id: with two of those the old group is larger; from the third the new one wins the tie as the
    newer, and with more the old calibrations fall out of the newest seven."""
    key = stack.key("fleet")
    camera_id = f"cam-{key[:8]}"
    fxs = (50.0, 50.2, 49.9, 60.0, 60.3, 59.8, 60.1)
    files = [{**bf.valid_files(n_frames=5 + k), "manifest.json": bf.manifest_bytes(
        camera_id=camera_id)} for k in range(len(fxs) + 1)]
    with stack.client() as client:
        ids = [upload(client, key, bf_zip(f)) for f in files]
    seen = []
    for journey_id, fx, f in zip(ids, fxs, files):
        finish(stack, journey_id, made_result(SIGNS, fx=fx), f)
        with session_scope(stack.url) as session:
            seen.append(round(_stored(session, camera_id, ids[-1]).fx))
    assert seen == [50, 50, 50, 50, 50, 60, 60]


def _new_camera_files() -> dict[str, bytes]:
    """The factory bundle with a camera id no other test has calibrated."""
    return {**bf.valid_files(), "manifest.json": bf.manifest_bytes(camera_id=secrets.token_hex(6))}


def test_run_journey_without_a_turn_waits_for_its_camera(stack):
    """The factory bundle is a straight road and the camera is unknown: the pipeline cannot
    calibrate, and the journey waits for its camera's calibration (tests/service/cameras)."""
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip(_new_camera_files()))
    run_journey(journey_id, stack.settings)
    row = _journey(stack, journey_id)
    assert (row.status, row.stage, row.attempts, row.n_signs) == (
        "queued", "waiting_for_camera", 1, None)
    assert row.error is None and "the journey has no turn" in row.message
    assert (row.image_width, row.image_height) == (64, 48)
    assert not storage.work_dir(stack.settings.data_dir, journey_id, 1).exists()
    run_journey(journey_id, stack.settings)  # a waiting journey is not claimed until woken
    assert _journey(stack, journey_id).attempts == 1


def test_run_journey_with_a_lost_bundle_fails_with_a_reason(stack):
    key = stack.key("fleet")
    with stack.client() as client:
        journey_id = upload(client, key, bf_zip())
    for path in (stack.settings.data_dir / "bundles").iterdir():
        path.unlink()
    run_journey(journey_id, stack.settings)
    row = _journey(stack, journey_id)
    assert (row.status, row.stage) == ("failed", "extract")
    bundle = storage.bundle_path(stack.settings.data_dir, row.bundle_sha256)
    assert row.error == f"the stored bundle {bundle} is missing on this host"


def test_run_journey_on_an_unknown_id_does_nothing(stack):
    run_journey("no-such-journey", stack.settings)
