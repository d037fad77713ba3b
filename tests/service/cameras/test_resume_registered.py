"""Over HTTP with a real Celery worker on PostgreSQL: a straight journey of a camera nobody
calibrated waits for it (queued, stage waiting_for_camera), the sweeps leave it waiting, and the
camera's true calibration, registered, makes it resume and finish with its signs, the
calibration used as given. A second trigger (the same registration again) runs nothing twice."""

from __future__ import annotations

import time

import pytest

from tests.service.cameras.conftest import new_camera, with_camera_id
from tests.utils.journeys import first_frames
from tests.utils.results.service_support import sign_errors_m
from tests.utils.stack import CeleryWorker, Stack, auth, make_settings, poll_journey, upload

pytestmark = [pytest.mark.slow, pytest.mark.postgres]

PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2")


def _stopped(body: dict) -> bool:
    return body["status"] in ("done", "failed") or body["stage"] == "waiting_for_camera"


def test_a_waiting_journey_resumes_when_its_camera_is_registered(own_pg_url, redis_url, tmp_path,
                                                                 straight_journey_bundle):
    bundle, truth = straight_journey_bundle
    camera_id = new_camera()
    # Its first 60 frames (8 signs): what is tested is the wait and the resumption.
    data = with_camera_id(first_frames(bundle, 60, tmp_path / "first-60.zip"), camera_id,
                          tmp_path / "journey.zip").read_bytes()
    # Sweeps every 3 s: several pass while the journey waits. A database of its own: the worker
    # would sweep other tests' journeys too.
    settings = make_settings(tmp_path / "data", database_url=own_pg_url, broker_url=redis_url,
                             heartbeat_s=1.0, stale_after_s=6.0)
    stack = Stack("postgres", settings)
    fleet, admin = stack.key("fleet"), stack.key("admin")
    worker = CeleryWorker(settings, tmp_path / "worker.log")
    true = {"width": truth["camera"]["width"], "height": truth["camera"]["height"],
            **{k: truth["camera"][k] for k in PARAMS}}
    try:
        with stack.client() as client:
            journey_id = upload(client, fleet, data)
            body = poll_journey(client, auth(fleet), journey_id, _stopped, timeout_s=300,
                                worker=worker)
            assert (body["status"], body["stage"], body["error"], body["attempts"]) == (
                "queued", "waiting_for_camera", None, 1), body["error"]
            assert body["message"].startswith(f"waiting for a calibration of camera {camera_id}")
            camera = client.get(f"/api/v1/cameras/{camera_id}", headers=auth(fleet)).json()
            assert (camera["waiting"], camera["calibration"]) == (1, None)
            assert (camera["width"], camera["height"]) == (true["width"], true["height"])

            time.sleep(4.0)  # a sweep or two: not taken for stuck, not run again
            body = client.get(f"/api/v1/journeys/{journey_id}", headers=auth(fleet)).json()
            assert (body["stage"], body["attempts"]) == ("waiting_for_camera", 1)

            answer = client.put(f"/api/v1/cameras/{camera_id}/calibration", json=true,
                                headers=auth(admin))
            assert answer.status_code == 200, answer.text
            assert answer.json()["resumed"] == [journey_id]
            again = client.put(f"/api/v1/cameras/{camera_id}/calibration", json=true,
                               headers=auth(admin)).json()
            assert (again["new_epoch"], again["resumed"]) == (False, [])

            body = poll_journey(client, auth(fleet), journey_id,
                                lambda b: b["status"] in ("done", "failed"), timeout_s=300,
                                worker=worker)
            assert body["status"] == "done", body["error"]
            assert body["calibration"] == {k: true[k] for k in PARAMS}  # as given
            assert (body["calibration_source"], body["attempts"], body["message"]) == (
                "supplied", 2, None)
            features = client.get(f"/api/v1/journeys/{journey_id}/signs",
                                  headers=auth(fleet)).json()["features"]
            assert body["n_signs"] == len(features) >= 1
            errors = sign_errors_m(features, truth)
            assert max(errors.values()) < 1.0, errors
            camera = client.get(f"/api/v1/cameras/{camera_id}", headers=auth(fleet)).json()
            assert (camera["waiting"], camera["source"], camera["epoch"]) == (0, "registered", 1)
    finally:
        worker.stop()
    log = (tmp_path / "worker.log").read_text()
    assert "waits for the camera" in log and "stopped beating" not in log
