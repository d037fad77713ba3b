"""The real pipeline (pycolmap calibration + ego-motion) on small rendered journeys."""

from __future__ import annotations


import numpy as np
import pytest

from app.pipeline.bundle import read_bundle
from app.pipeline.config import PipelineConfig
from app.pipeline.geometry.facing import angle_between_deg
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.run import process_journey
from app.pipeline.types import CameraModel, PipelineError

pytestmark = pytest.mark.slow


def _truth_errors(result, truth: dict) -> dict[str, float]:
    """Distance (m) from each triangulated sign to its true position, keyed by track id."""
    o = truth["origin"]
    frame = frame_at(o["lat"], o["lon"], o["alt_m"])
    true_by_track = {str(s["track_id"]): s for s in truth["signs"]}
    errors = {}
    for sign in result.signs:
        t = true_by_track[sign.track_id]
        est = frame.to_local([sign.lat_deg], [sign.lon_deg], [sign.alt_m])[0]
        true = frame.to_local([t["lat"]], [t["lon"]], [t["alt_m"]])[0]
        errors[sign.track_id] = float(np.linalg.norm(est - true))
    return errors


def test_turn_journey_calibrates_and_maps_signs(turn_journey_bundle, tmp_path):
    bundle, truth = turn_journey_bundle
    journey = read_bundle(bundle, tmp_path / "bundle")
    stages = []
    result = process_journey(journey, PipelineConfig(), tmp_path / "work",
                             progress=lambda s, f, m="": stages.append((s, f)))
    true_cam = truth["camera"]
    cam = result.calibration.camera
    for key in ("fx", "fy", "cx", "cy"):
        assert getattr(cam, key) == pytest.approx(true_cam[key], rel=0.03), key
    assert result.calibration.source == "self"
    errors = _truth_errors(result, truth)
    assert len(result.signs) >= 0.75 * len(truth["signs"]), result.rejected
    assert max(errors.values()) < 1.0, errors
    for sign in result.signs:  # camera-frame positions are in front of the camera
        assert all(o.p_cam[2] > 0 for o in sign.observations)
    true_facing = {str(s["track_id"]): s["facing_deg"] for s in truth["signs"]}
    facing_err = [angle_between_deg(s.facing_deg, true_facing[s.track_id]) for s in result.signs]
    assert np.median(facing_err) <= 15.0 and max(facing_err) <= 45.0, facing_err
    fractions = [f for _, f in stages]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0


def test_straight_journey_needs_a_known_calibration(straight_journey_bundle, tmp_path):
    bundle, truth = straight_journey_bundle
    journey = read_bundle(bundle, tmp_path / "bundle")
    with pytest.raises(PipelineError) as err:
        process_journey(journey, PipelineConfig(), tmp_path / "work1")
    assert err.value.stage == "calibrate" and "no turn" in err.value.reason

    known = CameraModel.from_params(journey.image_width, journey.image_height, truth["camera"])
    result = process_journey(journey, PipelineConfig(), tmp_path / "work2", known_camera=known)
    assert result.calibration.source == "supplied"
    errors = _truth_errors(result, truth)
    assert errors and max(errors.values()) < 1.0, errors
