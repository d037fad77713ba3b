"""A camera's joint calibration in the service (``jobs.camera_fit``), on SQLite and PostgreSQL:
each self-calibration keeps its turn window, the worker fits the camera's windows together after
storing one, and the camera's later journeys and its API record get the joint camera; a wrong
window is left out and named. The windows are made by projecting points through the factory
bundle's 64x48 camera (``turn_window``); the adjustment is COLMAP's, run for real."""

from __future__ import annotations

from sqlalchemy import func, select

from app.pipeline.types import CameraModel
from app.service.db.models import REPROCESSING, CalibrationRow, CameraFitRow, JourneyRow
from app.service.db.session import session_scope
from app.service.jobs import run, state
from tests.service.cameras.conftest import new_camera, self_calibrated
from tests.utils.results.turn_windows import turn_window
from tests.utils.stack import ADMIN_KEY, auth

TRUE = CameraModel(64, 48, 50.0, 51.0, 31.5, 23.5, -0.1, 0.01)  # made_result's, at fx 50


def _stored(stack, camera_id: str) -> state.StoredCalibration | None:
    with session_scope(stack.url) as session:
        return state.stored_calibration(session, camera_id, "", agree_rel=0.03, newest=7)


def _fits(stack, camera_id: str) -> int:
    with session_scope(stack.url) as session:
        return session.scalar(select(func.count()).select_from(CameraFitRow)
                              .where(CameraFitRow.camera_id == camera_id))


def test_the_camera_is_fitted_jointly_and_a_wrong_window_is_left_out(stack):
    camera_id, fleet = new_camera(), stack.key("fleet")
    url, settings = stack.url, stack.settings
    with stack.client() as client:
        first = self_calibrated(stack, client, fleet, camera_id, fx=50.6, n_frames=5,
                                window=turn_window(TRUE, 0, noise_px=0.05))
        run._refit(url, first, camera_id, settings)
        # One window: nothing to fit; the camera is its one self-calibration.
        assert _fits(stack, camera_id) == 0 and _stored(stack, camera_id).source == "consensus"
        # A straight journey given that calibration (fx 50.6).
        given = self_calibrated(stack, client, fleet, camera_id, fx=50.6, n_frames=9,
                                source="supplied")

        second = self_calibrated(stack, client, fleet, camera_id, fx=49.6, n_frames=6,
                                 window=turn_window(TRUE, 1, noise_px=0.05))
        run._refit(url, second, camera_id, settings)
        stored = _stored(stack, camera_id)
        assert stored.source == "joint"
        assert abs(stored.camera.fx / TRUE.fx - 1) < 0.01  # the windows' camera, not their mean
        assert abs(stored.camera.k1 - TRUE.k1) < 0.01
        # The camera moved by more than its sigma (0.5 px: the two windows' spread over
        # sqrt(2)) from what the straight journey was given: it is processed again.
        run._reprocess_if_superseded(url, camera_id, None, None, settings)
        with session_scope(url) as session:
            row = session.get(JourneyRow, given)
            assert (row.status, row.stage) == ("queued", REPROCESSING)

        wrong_camera = TRUE.replace(fx=44.0, fy=45.0)
        wrong = self_calibrated(stack, client, fleet, camera_id, fx=44.0, n_frames=7,
                                window=turn_window(wrong_camera, 2, noise_px=0.05))
        run._refit(url, wrong, camera_id, settings)
        run._refit(url, wrong, camera_id, settings)  # the same windows: not fitted again
        assert _fits(stack, camera_id) == 2

        body = client.get(f"/api/v1/cameras/{camera_id}", headers=auth(ADMIN_KEY)).json()
        assert body["source"] == "joint" and body["journeys"] == 2
        assert abs(body["calibration"]["fx"] / TRUE.fx - 1) < 0.01
        assert [o["journey_id"] for o in body["left_out"]] == [wrong]
        assert "disagrees" in body["left_out"][0]["reason"]
        assert body["sigma"]["fx"] > 0 and isinstance(body["fy_resolved"], bool)
        assert "joint bundle adjustment of 2" in body["sigma_basis"]
        assert body["epochs"][-1]["calibration_source"] == "joint"
        # The dashboard's Cameras page says the same.
        client.post("/admin/login", data={"key": ADMIN_KEY}, follow_redirects=False)
        page = client.get("/admin/cameras").text
        assert "Joint calibration" in page and f"/admin/journeys/{wrong}" in page
    with session_scope(url) as session:  # windows are kept with self-calibrations only
        kept = dict(session.execute(select(CalibrationRow.journey_id,
                                           CalibrationRow.window.is_not(None))
                                    .where(CalibrationRow.camera_id == camera_id)).all())
    assert kept == {first: True, second: True, wrong: True}  # the supplied one has none
