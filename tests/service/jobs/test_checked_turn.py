"""A calibrated camera's next journey checks the camera on its turn instead of self-calibrating
(``cameras.check_on_turn``), uses the stored calibration it confirmed, and adds its turn window to
the camera's joint calibration. Over HTTP with a real Celery worker on PostgreSQL, real COLMAP."""

from __future__ import annotations

import time

import numpy as np
import pytest

from tests.service.cameras.conftest import new_camera, with_camera_id
from tests.utils.results.service_support import sign_errors_m
from tests.utils.stack import (ADMIN_KEY, CeleryWorker, Stack, auth, make_settings, poll_journey,
                               upload)

PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2")


@pytest.mark.slow
@pytest.mark.postgres
def test_a_calibrated_cameras_next_journey_checks_it_on_its_turn_and_joins_its_joint_fit(
        own_pg_url, redis_url, tmp_path, turn_journey_bundle, offset_journey_bundle):
    (first_bundle, truth), (second_bundle, second_truth) = (turn_journey_bundle,
                                                            offset_journey_bundle)
    camera_id = new_camera()
    first = with_camera_id(first_bundle, camera_id, tmp_path / "first.zip").read_bytes()
    second = with_camera_id(second_bundle, camera_id, tmp_path / "second.zip").read_bytes()
    settings = make_settings(tmp_path / "data", database_url=own_pg_url, broker_url=redis_url,
                             heartbeat_s=1.0, stale_after_s=30.0)
    stack = Stack("postgres", settings)
    fleet = stack.key("fleet")
    worker = CeleryWorker(settings, tmp_path / "worker.log")
    done = lambda b: b["status"] in ("done", "failed")  # noqa: E731
    try:
        with stack.client() as client:
            one = poll_journey(client, auth(fleet), upload(client, fleet, first), done,
                               timeout_s=300, worker=worker)
            assert (one["status"], one["calibration_source"]) == ("done", "self"), one
            two_id = upload(client, fleet, second)
            two = poll_journey(client, auth(fleet), two_id, done, timeout_s=300, worker=worker)
            assert (two["status"], two["calibration_source"]) == ("done", "checked"), two
            # It used the camera's stored calibration (the first journey's own), not its own.
            assert two["calibration"] == one["calibration"]
            calibrate = next(r for r in two["report"] if r["stage"] == "calibrate")
            assert calibrate["summary"].startswith("stored calibration confirmed on frames")
            errors = sign_errors_m(client.get(f"/api/v1/journeys/{two_id}/signs",
                                              headers=auth(fleet)).json()["features"],
                                   second_truth)
            assert len(errors) >= 4 and np.median(list(errors.values())) < 0.5, errors

            # Both turns in one joint fit (the worker fits after storing the journey), within
            # 1 % of the lens in fx and fy.
            deadline = time.monotonic() + 120
            while True:
                camera = client.get(f"/api/v1/cameras/{camera_id}",
                                    headers=auth(ADMIN_KEY)).json()
                if camera["source"] == "joint" or time.monotonic() > deadline:
                    break
                time.sleep(1.0)
            assert (camera["source"], camera["journeys"], camera["left_out"]) == ("joint", 2, [])
            for k in ("fx", "fy"):
                assert abs(camera["calibration"][k] / truth["camera"][k] - 1) < 0.01, camera
            assert camera["epochs"][0]["self_calibrations"] == 2
    finally:
        worker.stop()
