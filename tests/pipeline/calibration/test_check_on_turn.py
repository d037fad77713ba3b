"""A stored calibration checked on the journey's turn (``cameras.check_on_turn``): confirmed, the
journey uses it and keeps its window; another lens, it self-calibrates from the same features.
The verdicts on made-up windows, then the rendered turn journey through real COLMAP."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.pipeline.bundle import read_bundle
from app.pipeline.cameras.check_on_turn import judge
from app.pipeline.colmap.sfm import WindowResult
from app.pipeline.config import PipelineConfig
from app.pipeline.run import process_journey
from app.pipeline.steps.calibrate import CalibrationWindow
from app.pipeline.types import CameraModel

STORED = CameraModel(1242, 375, 959.2, 952.9, 694.4, 241.7, -0.369, 0.158)
WINDOW = CalibrationWindow(np.arange(35, 85, 2), vertex=60)


def _result(camera: CameraModel, *, registered: int = 25, turn_deg: float = 90.0,
            error_px: float = 0.2, error: str | None = None) -> WindowResult:
    T = np.tile(np.eye(4), (registered, 1, 1))
    if registered:
        T[:, :3, :3] = Rotation.from_euler("y", np.linspace(0, turn_deg, registered)[:, None],
                                           degrees=True).as_matrix()
    return WindowResult([f"{i:06d}.png" for i in range(registered)], T, camera,
                        reprojection_error_px=error_px, n_input=25, error=error)


def test_a_turn_that_finds_the_stored_lens_confirms_it():
    check = judge(STORED, WINDOW, _result(STORED.replace(fx=STORED.fx * 1.01)), PipelineConfig())
    assert check.confirmed and check.deviation["fx"] == pytest.approx(0.01)
    calib = check.calibration()
    assert (calib.source, calib.camera, calib.measured.fx) == ("checked", STORED,
                                                               pytest.approx(STORED.fx * 1.01))
    assert calib.turn_estimate == calib.measured and calib.windows == [(35, 84)]
    assert check.summary().startswith("stored calibration confirmed on frames 35-83 (25/25")


@pytest.mark.parametrize("result, why", [
    (_result(STORED.replace(fx=STORED.fx * 1.05)), "differs in fx by 5.0 % (over 3 %)"),
    (_result(STORED.replace(cx=STORED.cx + 50)), "differs in cx by 4.0 % of the width"),
    (_result(STORED, registered=10), "only 10/25 frames registered"),
    (_result(STORED, error_px=1.5), "reprojection error 1.50 px"),
    (_result(STORED, turn_deg=10.0), "only 10 deg of rotation"),
    (_result(STORED, registered=0, error="mapping failed: no pair"), "mapping failed: no pair"),
])
def test_a_turn_that_does_not_find_the_stored_lens_says_why(result, why):
    check = judge(STORED, WINDOW, result, PipelineConfig())
    assert not check.confirmed and why in check.why_not
    assert why in check.summary() and "not c" in check.summary()


@pytest.fixture(scope="module")
def calibrate_only(turn_journey_bundle, tmp_path_factory):
    """The turn journey without its detections: the pipeline stops after calibrating."""
    bundle, truth = turn_journey_bundle
    tmp = tmp_path_factory.mktemp("check")
    journey = dataclasses.replace(read_bundle(bundle, tmp / "bundle"), detections=[])
    true = CameraModel.from_params(journey.image_width, journey.image_height, truth["camera"])
    return journey, true, tmp


def test_a_journey_of_a_calibrated_camera_checks_it_and_keeps_its_window(calibrate_only):
    journey, true, tmp = calibrate_only
    result = process_journey(journey, PipelineConfig(), tmp / "right", known_camera=true)
    calib = result.calibration
    assert (calib.source, calib.camera) == ("checked", true)
    assert abs(calib.measured.fx / true.fx - 1) < 0.01 and calib.observations is not None
    assert calib.n_registered == calib.n_images
    summary = next(r for r in result.report if r.stage == "calibrate").summary
    assert summary.startswith("stored calibration confirmed on frames")
    # One window mapped: the check's, and no self-calibration candidate.
    assert [w.stage for w in result.window_times] == ["calibrate"]


def test_another_lens_is_not_confirmed_and_the_journey_calibrates_itself(calibrate_only):
    journey, true, tmp = calibrate_only
    wrong = true.replace(fx=true.fx * 1.05, fy=true.fy * 1.05)
    result = process_journey(journey, PipelineConfig(), tmp / "wrong", known_camera=wrong)
    calib = result.calibration
    assert calib.source == "self" and abs(calib.camera.fx / true.fx - 1) < 0.01
    details = next(r for r in result.report if r.stage == "calibrate").details
    assert "not confirmed" in details[0] and "differs in fx by 4." in details[0]
    assert details[0].endswith("; self-calibrating")
