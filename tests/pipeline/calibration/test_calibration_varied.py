"""Self-calibration with real COLMAP on rendered journeys unlike the ones its knobs were first chosen
on: 20 Hz with a stop at the turn on a small sensor, a wide crop with a strong lens through a U-turn
(issue 11's reported failures). Each must calibrate to the corpus bench's bars: fx and fy
within 1 %, cx and cy within 4 px, k1 within 5 %.

A 5 Hz, 12 m/s journey through a 60 degree bend (blurred JPEG frames, 1 Hz GPS starting late) was a
third case until CI, 2026-11-25, accepted fx 23 % low on it: most of its windows fall into wrong
minima (fx 23-45 % low, k1 +0.3 to +0.65, at 0.75 px) and whether its one right window registers
varies with COLMAP's thread timing. A lone window like those is now refused
(``test_calibration_judge``); how often such journeys calibrate is the corpus bench's figure."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.pipeline.bundle import read_bundle
from app.pipeline.config import PipelineConfig
from app.pipeline.run import process_journey
from app.pipeline.types import CameraModel
from tests.utils.journeys import synthetic_journey

pytestmark = pytest.mark.slow


def _camera(width: int, height: int, hfov_deg: float, k1: float, k2: float,
            offset_px: tuple[float, float] = (0.0, 0.0)) -> CameraModel:
    fx = width / 2 / np.tan(np.radians(hfov_deg) / 2)
    return CameraModel(width, height, fx, fx * 1.003, (width - 1) / 2 + offset_px[0],
                       (height - 1) / 2 + offset_px[1], k1, k2)


VARIED = {
    # 20 Hz at 6 m/s, standing 2 s at the corner: 0.3 m between frames, none while standing.
    "20hz-6mps-stop-small": dict(
        n_frames=320, fps=20.0, speed_mps=6.0, turn_specs=((-90.0, 12.0),), stops=((5.5, 2.0),),
        camera=_camera(640, 360, 75.0, -0.12, 0.03, (-8.0, 5.0)), world_seed=32, seed=32),
    # A wide crop with a strong KITTI-like lens through a U-turn.
    "wide-crop-uturn": dict(
        n_frames=90, fps=10.0, speed_mps=6.0, turn_specs=((180.0, 7.0),),
        camera=CameraModel(1242, 375, 959.2, 952.9, 694.4, 241.7, -0.369, 0.158),
        world_seed=33, seed=33),
}


@pytest.mark.parametrize("name", sorted(VARIED))
def test_varied_journey_self_calibrates_within_the_bars(name, tmp_path_factory, tmp_path):
    bundle, truth = synthetic_journey(tmp_path_factory, name, **VARIED[name])
    journey = read_bundle(bundle, tmp_path / "bundle")
    # Without detections the pipeline stops after calibrating.
    journey = dataclasses.replace(journey, detections=[])
    result = process_journey(journey, PipelineConfig(), tmp_path / "work")
    true, cam = truth["camera"], result.calibration.camera
    assert result.calibration.source == "self"
    assert result.calibration.evidence in {"reprojection", "agreement"}
    assert cam.fx == pytest.approx(true["fx"], rel=0.01)
    assert cam.fy == pytest.approx(true["fy"], rel=0.01)
    assert abs(cam.cx - true["cx"]) <= 4.0 and abs(cam.cy - true["cy"]) <= 4.0
    assert cam.k1 == pytest.approx(true["k1"], rel=0.05)
    # Stage 2's own covariance puts fx within a fraction of a per cent, and the error it made
    # within a few of its standard deviations. COLMAP's covariance is optimistic (on the corpus
    # accepted calibrations were off by a median of 2-2.5 of it; config.calib_max_focal_std), and
    # the 20 Hz journey lands at 4.3-5.1 of it from run to run (fx -0.25 to -0.29 %, sigma
    # 0.057-0.06 %; COLMAP's threads make the runs differ): 8 still catches a covariance that
    # claims a tenth of the error.
    std = result.calibration.focal_std_rel
    assert 0.0 < std < 0.005
    assert abs(cam.fx / true["fx"] - 1.0) < 8.0 * std


def test_a_window_that_registers_little_from_the_first_focal_guess_is_mapped_again(
        tmp_path_factory, tmp_path):
    # A 99 deg lens (focal 0.37 of the width) from the usual guess of 0.8: the initial pair's
    # bundle adjustment ran off (k1 = 263) and 2 of 22 frames registered on every window
    # (corpus c0032, 2026-11-26). Here a guess of 10x the width plays the far-off one, with one
    # COLMAP thread: from 3x, a run with threads sometimes registered every frame at once (CI
    # 2026-11-28), and one thread always did, so the retry went untested.
    bundle, truth = synthetic_journey(tmp_path_factory, "20hz-6mps-stop-small",
                                      **VARIED["20hz-6mps-stop-small"])
    journey = dataclasses.replace(read_bundle(bundle, tmp_path / "bundle"), detections=[])
    config = PipelineConfig(calib_initial_focal_factor=10.0, calib_retry_focal_factors=(0.8,),
                            colmap_reproducible=True)
    result = process_journey(journey, config, tmp_path / "work")
    cam, true = result.calibration.camera, truth["camera"]
    assert cam.fx == pytest.approx(true["fx"], rel=0.01)
    assert cam.k1 == pytest.approx(true["k1"], rel=0.05)
    trials = next(r for r in result.report if r.stage == "calibrate").details
    assert any(" from fx 512: " in line and "accepted" in line for line in trials), trials
