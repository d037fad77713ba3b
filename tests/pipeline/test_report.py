"""The per-stage report (``JourneyResult.report``, ``PipelineError.report``): what each stage tried
and how it ended, on rendered journeys through the real pipeline and on made-up candidates."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.commands.process_report import report as json_report
from app.pipeline.bundle import read_bundle
from app.pipeline.colmap.sfm import WindowResult
from app.pipeline.config import PipelineConfig
from app.pipeline.run import process_journey
from app.pipeline.steps.calibrate import CalibrationWindow, self_calibrate
from app.pipeline.types import CameraModel, PipelineError, StageReport

CAMERA = CameraModel(1242, 375, 959.0, 959.0, 621.0, 187.0, -0.37, 0.2)


def _result(error_px: float, registered: int = 30) -> WindowResult:
    angles = np.radians(np.linspace(0.0, 60.0, registered))
    T = np.tile(np.eye(4), (registered, 1, 1))
    T[:, 0, 0] = T[:, 2, 2] = np.cos(angles)
    T[:, 0, 2], T[:, 2, 0] = np.sin(angles), -np.sin(angles)
    return WindowResult([f"{i:06d}.png" for i in range(registered)], T, CAMERA,
                        reprojection_error_px=error_px, n_input=30)


def test_self_calibration_lists_every_candidate_it_tried():
    windows = [CalibrationWindow(np.arange(30) + 10 * k, 40) for k in range(3)]
    results = [_result(0.2, registered=10), _result(0.5), _result(0.2)]
    results[2].focal_std_rel = 0.0012  # stage 2's covariance: fx +- 0.12 %
    trials: list[str] = []

    def map_window(window, start):
        return results[next(k for k, w in enumerate(windows) if w is window)]

    calib = self_calibrate(windows, PipelineConfig(), map_window, width=1242, height=375,
                           trials=trials)
    assert calib.windows == [(20, 50)]
    assert len(trials) == 3
    assert trials[0].startswith("frames 0-29: 10/30 registered") and "refused" in trials[0]
    assert trials[1].startswith("frames 10-39: 30/30 registered, 0.50 px") and "kept" in trials[1]
    assert trials[2] == ("frames 20-49: 30/30 registered, 0.20 px, fx ± 0.12 %: accepted, "
                         "under 0.35 px")


def test_stage_reports_round_trip_through_json():
    r = StageReport("calibrate", "failed: no turn", ("frames 0-21: refused, only 3/22",))
    assert StageReport.from_json(json.loads(json.dumps(r.to_json()))) == r


@pytest.fixture(scope="module")
def turn_result(turn_journey_bundle, tmp_path_factory):
    bundle, _ = turn_journey_bundle
    tmp = tmp_path_factory.mktemp("report")
    journey = read_bundle(bundle, tmp / "bundle")
    return journey, process_journey(journey, PipelineConfig(), tmp / "work")


@pytest.mark.slow
def test_a_processed_journey_reports_every_stage_in_order(turn_result):
    journey, result = turn_result
    assert [r.stage for r in result.report] == ["turns", "calibrate", "ego_motion", "align",
                                                "triangulate"]
    turns, calibrate, ego, align, triangulate = result.report
    assert turns.summary.startswith("1 turn(s)")
    first, end = result.calibration.windows[0]
    assert calibrate.summary.startswith(f"self-calibrated on frames {first}-{end - 1}")
    accepted = [d for d in calibrate.details if "accepted" in d]
    assert len(accepted) == 1 and accepted[0].startswith(f"frames {first}-{end - 1}:")
    assert ego.details and all(" registered" in d for d in ego.details)
    assert "windows aligned to GPS" in align.summary
    assert triangulate.summary.startswith(f"{len(result.signs)} signs placed")
    for r in result.rejected:
        assert any(d.startswith(f"track {r.track_id} ") and r.reason in d
                   for d in triangulate.details)
    written = json_report(result, journey.warnings)["report"]
    assert [StageReport.from_json(r) for r in written] == result.report


@pytest.mark.slow
def test_a_journey_without_turns_fails_with_the_reports_saying_why(straight_journey_bundle,
                                                                    tmp_path):
    bundle, truth = straight_journey_bundle
    journey = read_bundle(bundle, tmp_path / "bundle")
    with pytest.raises(PipelineError) as err:
        process_journey(journey, PipelineConfig(), tmp_path / "work1")
    assert [r.stage for r in err.value.report] == ["turns", "calibrate"]
    turns, calibrate = err.value.report
    assert turns.summary.startswith("no turn of at least 30 deg")
    assert calibrate.summary.startswith("failed: the journey has no turn")

    # With a stored calibration, reusing it is what the calibrate stage reports.
    known = CameraModel.from_params(journey.image_width, journey.image_height, truth["camera"])
    config = PipelineConfig(reuse_known_calibration=True)
    result = process_journey(journey, config, tmp_path / "work2", known_camera=known)
    calibrate = next(r for r in result.report if r.stage == "calibrate")
    assert calibrate.summary.startswith(
        f"stored calibration of camera {journey.camera_id} used")
