"""The journey's plan (``steps.plan``) and what becomes of the tracks it cannot triangulate: no
COLMAP, the turn journey's frames, GPS and detections as read."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from app.pipeline.bundle import read_bundle
from app.pipeline.config import PipelineConfig
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.run import Reconstruction, georeference
from app.pipeline.steps import plan, turns
from app.pipeline.types import Calibration, CameraModel, Detection


def _with_short_tracks(journey):
    """The journey plus a 'flash' track seen in 2 frames and a 'blip' track seen once."""
    ids = [f.frame_id for f in journey.frames]
    extra = [Detection(ids[k], "flash", "stop", 100, 100, 120, 120) for k in (5, 6)]
    extra.append(Detection(ids[9], "blip", "yield", 200, 100, 220, 120))
    return replace(journey, detections=journey.detections + extra)


def test_a_track_too_short_to_triangulate_is_reported_with_the_reason(turn_journey_bundle,
                                                                       tmp_path):
    bundle, _ = turn_journey_bundle
    journey = _with_short_tracks(read_bundle(bundle, tmp_path / "bundle"))
    origin = frame_at(journey.lat_deg[0], journey.lon_deg[0], None)
    xyz_gps = origin.to_local(journey.lat_deg, journey.lon_deg, None)
    config = PipelineConfig()
    the_plan = plan.plan_journey(journey, xyz_gps, config)
    reasons = {r.track_id: r.reason for r in the_plan.too_short}
    assert {"flash", "blip"} <= set(reasons)  # (the rendered journey has a short track too)
    assert "only 2 frame(s)" in reasons["flash"] and "only 1 frame(s)" in reasons["blip"]
    assert {"flash", "blip"}.isdisjoint(t.track_id for t in the_plan.tracks)
    assert {t.track_id for t in the_plan.tracks}  # the journey's own tracks are kept

    # Georeferencing reports them among the rejected signs, even with nothing else to place.
    camera = CameraModel(journey.image_width, journey.image_height, 800.0, 800.0,
                         journey.image_width / 2, journey.image_height / 2, 0.0, 0.0)
    recon = Reconstruction(Calibration(camera=camera, source="supplied"), [], [], xyz_gps,
                           xyz_gps, origin, {}, [], the_plan.too_short)
    result = georeference(journey, recon, config)
    assert {(r.track_id, r.cls, r.reason) for r in result.rejected} == {
        (r.track_id, r.cls, r.reason) for r in the_plan.too_short}
    assert {("flash", "stop"), ("blip", "yield")} <= {(r.track_id, r.cls) for r in result.rejected}


def test_each_calibration_window_knows_how_far_the_gps_turns_over_it(turn_journey_bundle,
                                                                     tmp_path):
    import numpy as np

    from app.pipeline.steps.calibrate import rotation_covered_deg

    bundle, truth = turn_journey_bundle
    journey = read_bundle(bundle, tmp_path / "bundle")
    origin = frame_at(journey.lat_deg[0], journey.lon_deg[0], None)
    xyz_gps = origin.to_local(journey.lat_deg, journey.lon_deg, None)
    the_plan = plan.plan_journey(journey, xyz_gps, PipelineConfig())
    assert the_plan.calib_windows and journey.gps_noise_m is not None
    T_world_cam = np.array([f["T_world_cam"] for f in truth["frames"]])
    for window in the_plan.calib_windows:
        # What the true cameras turn over the window's frames, within the GPS's own 3 sigma.
        true_deg = rotation_covered_deg(T_world_cam[window.frame_idx])
        assert window.gps_rotation_std_deg == pytest.approx(
            np.degrees(2 * journey.gps_noise_m / 10.0))
        assert abs(window.gps_rotation_deg - true_deg) < max(3 * window.gps_rotation_std_deg, 3.0)
    # Without fixes to measure, the accuracy the receiver states stands in (a 68 % radius).
    stated = replace(journey, gps_noise_m=None, gps_accuracy_m=1.5)
    assert plan.gps_sigma_m(stated) == pytest.approx(1.5 / 1.5096, rel=1e-3)
    assert plan.gps_sigma_m(replace(stated, gps_accuracy_m=None)) is None


def test_the_gps_measures_a_window_only_where_its_chords_lie_on_the_track():
    import numpy as np

    from app.pipeline.steps.calibrate import CalibrationWindow

    # 20 m straight, then a quarter circle of 10 m radius, where the journey ends: fixes every
    # 0.5 m, no noise. The chord of a frame within 5 m of either end is cut short and its
    # heading is the track's 2.5 m inside, so such frames are left out of the GPS's measure.
    s = np.arange(0.0, 20.0 + np.pi / 2 * 10.0, 0.5)
    angle = np.clip(s - 20.0, 0.0, None) / 10.0
    xy = np.where((s <= 20.0)[:, None], np.column_stack([s, np.zeros_like(s)]),
                  np.column_stack([20.0 + 10.0 * np.sin(angle), 10.0 - 10.0 * np.cos(angle)]))
    xyz = np.column_stack([xy, np.zeros(len(s))])
    window = CalibrationWindow(np.arange(len(s)), vertex=len(s) // 2)
    out, = plan.gps_rotation([window], xyz, 0.3, PipelineConfig())
    measured = out.gps_frame_idx
    # (The track's length is measured along its simplification, a little short on the arc.)
    assert 10 <= measured[0] <= 11 and len(s) - 14 <= measured[-1] < len(s) - 9
    assert np.array_equal(measured, np.arange(measured[0], measured[-1] + 1))
    # What the car turns over those frames: the heading at the last of them.
    assert out.gps_rotation_deg == pytest.approx(np.degrees(angle[measured[-1]]), abs=1.5)
    # Too short a journey for any whole chord: nothing measured, so nothing is checked.
    short, = plan.gps_rotation([CalibrationWindow(np.arange(18), vertex=9)], xyz[:18], 0.3,
                               PipelineConfig())
    assert short.gps_frame_idx is None and np.isnan(short.gps_rotation_deg)


def test_the_turns_summary_gives_the_turning_that_opposite_turns_cancel_in_the_heading():
    """A left then a right turn 20 m apart merge into one window whose heading change is ~0:
    the stage's one-line summary must still say the car turned (not "+0 deg")."""
    quarter = np.linspace(0.0, np.pi / 2, 20)
    xy_m = np.concatenate([
        np.stack([np.linspace(-60.0, 0.0, 61), np.zeros(61)], 1),
        np.stack([10.0 * np.sin(quarter), 10.0 - 10.0 * np.cos(quarter)], 1),  # left
        np.stack([np.full(11, 10.0), np.linspace(10.0, 20.0, 11)], 1),
        np.stack([20.0 - 10.0 * np.cos(quarter), 20.0 + 10.0 * np.sin(quarter)], 1),  # right
        np.stack([np.linspace(20.0, 80.0, 61), np.full(61, 30.0)], 1)])
    config = PipelineConfig()
    found = turns.find_turns(xy_m, tolerance_m=config.rdp_tolerance_m,
                             min_angle_deg=config.turn_min_angle_deg)
    assert len(found) == 1 and abs(found[0].angle_deg) < 10.0
    empty = np.zeros(0, dtype=int)
    the_plan = plan.JourneyPlan(turns=found, calib_windows=[], tracks=[], ego_windows=[],
                                off_grid=empty, ego_frames=empty)
    summary = plan.report(the_plan, config).summary
    rotation = re.search(r"(\d+) deg of turning", summary)
    assert rotation and abs(int(rotation.group(1)) - 180) <= 20, summary
