"""Re-processing (issue 66, item 3): a registered calibration supersedes the one a camera's done
journeys were given, and those journeys are processed again with it through the normal queue,
serving their earlier signs until then; self-calibrated journeys keep their own result, and the
same registration again queues nothing. Over HTTP with a real Celery worker on PostgreSQL, and
the bookkeeping on SQLite (jobs queued, not run)."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

from app.pipeline.bundle import read_bundle
from app.pipeline.types import CameraModel
from app.service.db.models import JourneyRow
from app.service.db.session import session_scope
from app.service.jobs import cameras, fusion, state
from tests.service.cameras.conftest import (BODY, camera_files, new_camera, self_calibrated,
                                            with_camera_id)
from tests.utils.journeys import first_frames
from tests.utils.results.service_support import (bf_zip, made_result, sign_errors_m, signs_enu,
                                                 truth_bbox)
from tests.utils.stack import (ADMIN_KEY, CeleryWorker, Stack, auth, make_settings, poll_journey,
                               upload)

PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2")


def _put(client, camera_id: str, body: dict) -> dict:
    answer = client.put(f"/api/v1/cameras/{camera_id}/calibration", json=body,
                        headers=auth(ADMIN_KEY))
    assert answer.status_code == 200, answer.text
    return answer.json()


def _map_signs(client, key: str, truth: dict) -> list[dict]:
    answer = client.get("/api/v1/signs", params={"bbox": truth_bbox(truth)}, headers=auth(key))
    assert answer.status_code == 200, answer.text
    return answer.json()["features"]


def _nearest_m(features: list[dict], others: list[dict], truth: dict) -> list[float]:
    """For each of ``features``, the distance (m) to the nearest of ``others``."""
    def positions(fs: list[dict]) -> list[np.ndarray]:
        tagged = [{**f, "properties": {"track_id": str(i)}} for i, f in enumerate(fs)]
        return list(signs_enu(tagged, truth).values())

    mine, theirs = positions(features), positions(others)
    return [min(float(np.linalg.norm(p - q)) for q in theirs) for p in mine]


@pytest.mark.slow
@pytest.mark.postgres
def test_a_journey_given_a_wrong_calibration_is_reprocessed_with_the_registered_one(
        own_pg_url, redis_url, tmp_path, straight_journey_bundle, caplog):
    bundle, truth = straight_journey_bundle
    camera_id = new_camera()
    data = with_camera_id(first_frames(bundle, 60, tmp_path / "first-60.zip"), camera_id,
                          tmp_path / "journey.zip").read_bytes()
    settings = make_settings(tmp_path / "data", database_url=own_pg_url, broker_url=redis_url,
                             heartbeat_s=1.0, stale_after_s=6.0)
    stack = Stack("postgres", settings)
    fleet, reader = stack.key("fleet"), stack.key("reader")
    worker = CeleryWorker(settings, tmp_path / "worker.log")
    true = {"width": truth["camera"]["width"], "height": truth["camera"]["height"],
            **{k: truth["camera"][k] for k in PARAMS}}
    wrong = {**true, "fx": true["fx"] * 1.03}  # the seeded calibration: 3 % off in fx
    done = lambda b: b["status"] in ("done", "failed")  # noqa: E731
    try:
        with stack.client() as client, caplog.at_level(logging.INFO, "app.service.jobs.cameras"):
            assert _put(client, camera_id, wrong)["reprocess_queued"] == []
            journey_id = upload(client, fleet, data)
            body = poll_journey(client, auth(fleet), journey_id, done, timeout_s=300,
                                worker=worker)
            assert (body["status"], body["calibration_source"]) == ("done", "supplied"), body
            assert body["calibration"] == {k: wrong[k] for k in PARAMS}
            before = client.get(f"/api/v1/journeys/{journey_id}/signs",
                                headers=auth(fleet)).json()["features"]
            errors_before = sign_errors_m(before, truth)
            map_before = _map_signs(client, reader, truth)
            assert len(map_before) == len(before) >= 1

            answer = _put(client, camera_id, true)
            assert (answer["registered_epoch"], answer["new_epoch"]) == (2, True)
            assert (answer["reprocess_queued"], answer["reprocessing"]) == ([journey_id], 1)
            # Queued again, and meanwhile it serves its earlier signs, in the map too.
            body = client.get(f"/api/v1/journeys/{journey_id}", headers=auth(fleet)).json()
            assert body["status"] in ("queued", "running")
            assert body["message"] == f"reprocessing: camera {camera_id} calibration epoch 2"
            assert len(client.get(f"/api/v1/journeys/{journey_id}/signs",
                                  headers=auth(fleet)).json()["features"]) == len(before)
            assert len(_map_signs(client, reader, truth)) == len(map_before)
            # The same registration again: nothing left to re-process, nothing run twice.
            again = _put(client, camera_id, true)
            assert (again["new_epoch"], again["reprocess_queued"]) == (False, [])
            camera = client.get(f"/api/v1/cameras/{camera_id}", headers=auth(fleet)).json()
            assert camera["reprocessing"] == 1

            body = poll_journey(client, auth(fleet), journey_id, done, timeout_s=300,
                                worker=worker)
            assert body["status"] == "done", body["error"]
            assert body["calibration"] == {k: true[k] for k in PARAMS}  # the registered one
            assert (body["calibration_source"], body["attempts"], body["message"]) == (
                "supplied", 2, None)
            after = client.get(f"/api/v1/journeys/{journey_id}/signs",
                               headers=auth(fleet)).json()["features"]
            errors_after = sign_errors_m(after, truth)
            assert max(errors_after.values()) < 1.0, errors_after
            assert (np.median(list(errors_after.values()))
                    < np.median(list(errors_before.values()))), (errors_before, errors_after)
            # The map was fused again from the new run's signs.
            map_after = _map_signs(client, reader, truth)
            assert len(map_after) == len(after)
            assert max(_nearest_m(map_after, after, truth)) < 0.05
            assert max(_nearest_m(map_before, map_after, truth)) > 0.05  # they moved
            camera = client.get(f"/api/v1/cameras/{camera_id}", headers=auth(fleet)).json()
            assert (camera["reprocessing"], camera["epoch"], camera["source"]) == (
                0, 2, "registered")
    finally:
        worker.stop()
    assert (f"camera {camera_id} epoch 2: 1 journeys queued for re-processing: {journey_id}"
            in caplog.text)


def _row(stack, journey_id: str) -> JourneyRow:
    with session_scope(stack.url) as session:
        return session.get(JourneyRow, journey_id)


def test_only_journeys_given_a_superseded_calibration_are_reprocessed(sqlite):
    """Jobs are queued, not run: the bookkeeping of a re-processing, its failure and its end."""
    camera_id = new_camera()
    fleet = sqlite.key("fleet")
    with sqlite.client() as client:
        own = self_calibrated(sqlite, client, fleet, camera_id, fx=54.0)
        given = self_calibrated(sqlite, client, fleet, camera_id, fx=50.0, n_frames=6,
                                source="supplied")
        other = new_camera()  # another camera's supplied journey is none of this one's business
        self_calibrated(sqlite, client, fleet, other, fx=50.0, source="supplied")

        answer = _put(client, camera_id, BODY)
        assert (answer["registered_epoch"], answer["reprocess_queued"]) == (2, [given])
        assert answer["reprocessing"] == 1
        row = _row(sqlite, given)
        assert (row.status, row.stage, row.reprocess_epoch, row.message) == (
            "queued", "reprocessing", 2, f"reprocessing: camera {camera_id} calibration epoch 2")
        assert (_row(sqlite, own).status, _row(sqlite, own).reprocess_epoch) == ("done", None)
        # It keeps serving its sign, to a fusion of its place too.
        fusion.refuse_around(sqlite.url, given, sqlite.settings)
        bbox = "8.4175,49.0102,8.4195,49.0122"
        signs = client.get("/api/v1/signs", params={"bbox": bbox}, headers=auth(ADMIN_KEY))
        assert len(signs.json()["features"]) == 1
        client.post("/admin/login", data={"key": ADMIN_KEY}, follow_redirects=False)
        listing = client.get("/admin/journeys", params={"camera": camera_id})
        assert f"reprocessing: camera {camera_id} calibration epoch 2" in listing.text
        assert "1 journey is\nbeing re-processed" in client.get("/admin/cameras").text

        again = _put(client, camera_id, BODY)
        assert (again["new_epoch"], again["reprocess_queued"], again["reprocessing"]) == (
            False, [], 1)

        # A re-processing run that fails leaves the earlier result, done, saying why.
        with session_scope(sqlite.url) as session:
            attempt = state.claim(session, given, 60, 3)
            assert state.fail(session, given, attempt, "triangulate", "no signs")
        row = _row(sqlite, given)
        assert (row.status, row.n_signs, row.reprocess_epoch) == ("done", 1, None)
        assert row.message.startswith("re-processing with calibration epoch 2 failed at "
                                      "triangulate: no signs")
        assert client.get(f"/api/v1/cameras/{camera_id}",
                          headers=auth(ADMIN_KEY)).json()["reprocessing"] == 0
        # Registering again queues it again; a run with the registered calibration ends it.
        assert _put(client, camera_id, BODY)["reprocess_queued"] == [given]
        work = sqlite.settings.data_dir / "redo"
        work.mkdir()
        (work / "b.zip").write_bytes(bf_zip(camera_files(camera_id, 6)))
        journey = read_bundle(work / "b.zip", work / "x", decode_images=False)
        result = made_result([("0", "stop", 49.0112, 8.4185, 114.0)], "supplied")
        registered = CameraModel(64, 48, **{k: BODY[k] for k in PARAMS})
        result = dataclasses.replace(result, calibration=dataclasses.replace(
            result.calibration, camera=registered))
        with session_scope(sqlite.url) as session:
            attempt = state.claim(session, given, 60, 3)
        assert fusion.store_and_fuse(sqlite.url, given, attempt, journey, result,
                                     {"total_s": 1.0}, registered, sqlite.settings, "registered")
        row = _row(sqlite, given)
        assert (row.status, row.reprocess_epoch, row.message) == ("done", None, None)
        assert row.calibration == {k: BODY[k] for k in PARAMS}
        assert cameras.reprocess_superseded(sqlite.url, camera_id, None) == []
        assert client.get(f"/api/v1/cameras/{camera_id}",
                          headers=auth(ADMIN_KEY)).json()["reprocessing"] == 0
    assert _row(sqlite, own).calibration_source == "self"
