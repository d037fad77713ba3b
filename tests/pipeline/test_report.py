"""The per-stage report (``JourneyResult.report``, ``PipelineError.report``) on made-up candidates.
What the real pipeline reports on rendered journeys is asserted beside their other outcomes in
``test_run`` (the turn journey is processed once for both)."""

from __future__ import annotations

import json

import numpy as np

from app.pipeline.colmap.sfm import WindowResult
from app.pipeline.config import PipelineConfig
from app.pipeline.steps.calibrate import CalibrationWindow, initial_camera, self_calibrate
from app.pipeline.types import CameraModel, StageReport

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

    calib = self_calibrate(windows, PipelineConfig(), map_window,
                           start=initial_camera(1242, 375, PipelineConfig()), trials=trials)
    assert calib.windows == [(20, 50)]
    assert len(trials) == 3
    assert trials[0].startswith("frames 0-29: 10/30 registered") and "refused" in trials[0]
    assert trials[1].startswith("frames 10-39: 30/30 registered, 0.50 px") and "kept" in trials[1]
    assert trials[2] == ("frames 20-49: 30/30 registered, 0.20 px, fx 959.0, fx ± 0.12 %, "
                         "turns 60.0 deg: accepted, under 0.35 px")


def test_stage_reports_round_trip_through_json():
    r = StageReport("calibrate", "failed: no turn", ("frames 0-21: refused, only 3/22",))
    assert StageReport.from_json(json.loads(json.dumps(r.to_json()))) == r
