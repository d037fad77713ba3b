"""End to end on the default stack (SQLite, jobs in the API process): a straight journey of a camera
nobody calibrated is uploaded first and waits for its camera (queued, stage waiting_for_camera);
then a rendered journey of the same camera with a turn is uploaded, calibrated and mapped within
1 m of the truth, and the waiting journey resumes by itself and is mapped with that stored
calibration (its first 60 frames: 8 signs, half the cost; what is tested there is that the
stored calibration is found and used)."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import select
from sqlalchemy.orm import undefer

from app.service.db.models import CalibrationRow
from app.service.db.session import session_scope
from app.service.jobs import state
from tests.utils.journeys import first_frames
from tests.utils.results.map_support import map_sign_errors_m
from tests.utils.results.service_support import sign_errors_m, truth_bbox
from tests.utils.stack import auth, poll_journey, sqlite_stack, upload

pytestmark = pytest.mark.slow


def _finished(body: dict) -> bool:
    return body["status"] in ("done", "failed")


def _stopped(body: dict) -> bool:
    return _finished(body) or body["stage"] == "waiting_for_camera"


def test_embedded_stack_maps_synthetic_journeys(tmp_path, turn_journey_bundle,
                                                straight_journey_bundle):
    stack = sqlite_stack(tmp_path / "data", embedded_worker=True)
    fleet, reader = stack.key("fleet"), stack.key("reader")
    turn_zip, turn_truth = turn_journey_bundle
    straight_zip, straight_truth = straight_journey_bundle
    with stack.client() as client:
        straight_60 = first_frames(straight_zip, 60, tmp_path / "straight-60.zip")
        straight_id = upload(client, fleet, straight_60.read_bytes())
        body = poll_journey(client, auth(fleet), straight_id, _stopped)
        assert (body["status"], body["stage"]) == ("queued", "waiting_for_camera"), body["error"]

        turn_id = upload(client, fleet, turn_zip.read_bytes())
        body = poll_journey(client, auth(fleet), turn_id, _finished)
        assert body["status"] == "done", body["error"]
        assert body["calibration_source"] == "self" and body["attempts"] == 1
        for name in ("fx", "fy"):
            assert body["calibration"][name] == pytest.approx(turn_truth["camera"][name],
                                                              rel=0.03)
        features = client.get(f"/api/v1/journeys/{turn_id}/signs",
                              headers=auth(fleet)).json()["features"]
        assert body["n_signs"] == len(features) >= 1  # how many is the pipeline tests' concern
        errors = sign_errors_m(features, turn_truth)
        assert max(errors.values()) < 1.0, errors
        # Its accepted turn window is kept with its calibration, for the camera's joint fit.
        with session_scope(stack.url) as session:
            row = session.scalars(select(CalibrationRow).options(undefer(CalibrationRow.window))
                                  .where(CalibrationRow.journey_id == turn_id)).one()
            window = state.window_of(row.window)
        assert len(window.T_cam_model) == row.n_registered and len(window.xyz_model) >= 500
        assert np.all(np.bincount(window.obs_point) >= 2)

        mapped = client.get("/api/v1/signs", headers=auth(reader),
                            params={"bbox": truth_bbox(turn_truth)}).json()["features"]
        # One journey of this place so far: one fused map sign per journey sign.
        assert [f["properties"]["n_journeys"] for f in mapped] == [1] * len(features)
        assert max(map_sign_errors_m(mapped, turn_truth)) < 1.0

        # Woken by the turn journey's self-calibration: run again, with it.
        body = poll_journey(client, auth(fleet), straight_id, _finished)
        assert body["status"] == "done", body["error"]
        assert (body["calibration_source"], body["attempts"]) == ("supplied", 2)
        features = client.get(f"/api/v1/journeys/{straight_id}/signs",
                              headers=auth(fleet)).json()["features"]
        errors = sign_errors_m(features, straight_truth)
        assert errors and max(errors.values()) < 1.0, errors
