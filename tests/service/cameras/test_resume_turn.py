"""A journey waiting for its camera resumes once a journey of the same camera has self-calibrated:
through the job itself (``run_journey``, in this process, SQLite). The waiting journey is a
rendered straight road run by the real pipeline, before and after; the other journey's
pipeline is replaced by one that self-calibrates at once (a real self-calibration costs a minute:
tests/e2e/test_default_stack.py runs one, the waiting journey resuming after it, on the default
stack)."""

from __future__ import annotations

import numpy as np

from app.pipeline.types import Calibration, CameraModel, JourneyResult
from app.service.jobs import run
from tests.service.cameras.conftest import journey, new_camera, with_camera_id
from tests.utils.journeys import first_frames
from tests.utils.results.service_support import sign_errors_m
from tests.utils.stack import auth, sqlite_stack, upload


def test_a_waiting_journey_resumes_when_a_journey_of_its_camera_self_calibrates(
        tmp_path, monkeypatch, straight_journey_bundle):
    stack = sqlite_stack(tmp_path / "data")  # jobs run here, by run_journey
    fleet = stack.key("fleet")
    bundle, truth = straight_journey_bundle
    camera_id = new_camera()
    straight = with_camera_id(first_frames(bundle, 60, tmp_path / "first-60.zip"), camera_id,
                              tmp_path / "straight.zip")
    other = with_camera_id(first_frames(bundle, 12, tmp_path / "first-12.zip"), camera_id,
                           tmp_path / "other.zip")
    true = CameraModel(**{k: truth["camera"][k] for k in
                          ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2")})
    submitted: list[str] = []
    with stack.client() as client:
        straight_id = upload(client, fleet, straight.read_bytes())
        run.run_journey(straight_id, stack.settings, submitted.append)
        row = journey(stack, straight_id)
        assert (row.status, row.stage, row.attempts) == ("queued", "waiting_for_camera", 1)

        other_id = upload(client, fleet, other.read_bytes())
        real = run.process_journey

        def self_calibrates(journey_data, config, workdir, *, known_camera=None, progress):
            assert known_camera is None  # the camera has no calibration yet
            return JourneyResult(Calibration(true, "self", n_images=12, n_registered=12,
                                             reprojection_error_px=0.3, rotation_deg=90.0),
                                 signs=[], rejected=[], timings_s={"calibrate": 0.0},
                                 trajectory_T_world_cam=np.zeros((0, 4, 4)))

        monkeypatch.setattr(run, "process_journey", self_calibrates)
        run.run_journey(other_id, stack.settings, submitted.append)
        monkeypatch.setattr(run, "process_journey", real)
        assert journey(stack, other_id).status == "done"
        assert submitted == [straight_id]  # woken by the self-calibration, and queued
        row = journey(stack, straight_id)
        assert (row.status, row.stage, row.message) == ("queued", "requeued", None)

        run.run_journey(straight_id, stack.settings, submitted.append)
        body = client.get(f"/api/v1/journeys/{straight_id}", headers=auth(fleet)).json()
        assert body["status"] == "done", body["error"]
        assert (body["calibration_source"], body["attempts"]) == ("supplied", 2)
        assert body["calibration"] == true.params()
        features = client.get(f"/api/v1/journeys/{straight_id}/signs",
                              headers=auth(fleet)).json()["features"]
        errors = sign_errors_m(features, truth)
        assert errors and max(errors.values()) < 1.0, errors
        camera = client.get(f"/api/v1/cameras/{camera_id}", headers=auth(fleet)).json()
    assert (camera["source"], camera["journeys"], camera["waiting"]) == ("consensus", 1, 0)
    assert submitted == [straight_id]
