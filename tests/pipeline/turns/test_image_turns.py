"""The plan's image look (``steps.image_turns``): a car's turn read off its frames where the GPS
track shows none. The maths on exact geometry; the look on the rendered turn and straight
journeys' frames (no COLMAP)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from app.pipeline.bundle import read_bundle
from app.pipeline.config import PipelineConfig
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.run import _image_look
from app.pipeline.steps import image_turns, plan


def _views(psi_deg: float, step_m: float, rng: np.random.Generator, n: int = 200):
    """Normalised points of ``n`` corners 4-40 m ahead seen before and after a car's step of
    ``step_m`` along an arc turning ``psi_deg`` (left positive), as the planar model has it."""
    p0 = np.column_stack([rng.uniform(-15, 15, n), rng.uniform(-3, 1.5, n), rng.uniform(4, 40, n)])
    psi = -np.radians(psi_deg)  # about +y (down): a turn to the right is positive
    c, s = np.cos(psi), np.sin(psi)
    R_0_1 = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    centre_0 = step_m * np.array([np.sin(psi / 2), 0.0, np.cos(psi / 2)])
    p1 = (p0 - centre_0) @ R_0_1  # R_0_1^T (p0 - c), row by row
    return p0[:, :2] / p0[:, 2:], p1[:, :2] / p1[:, 2:]


@pytest.mark.parametrize("psi_deg", [-12.0, -3.0, 0.0, 0.7, 5.0, 20.0])
def test_planar_yaw_recovers_the_turn_between_two_views_with_outliers(psi_deg):
    rng = np.random.default_rng(int(psi_deg * 10) % 97)
    x0, x1 = _views(psi_deg, 1.2, rng)
    x1[:30] += rng.normal(0, 0.05, (30, 2))  # 15 % gross mismatches
    noisy = x1 + rng.normal(0, 0.3 / 500, x1.shape)  # 0.3 px at f = 500 px
    assert image_turns.planar_yaw_deg(x0, noisy, 1.0 / 500) == pytest.approx(psi_deg, abs=0.05)


def test_frames_are_sampled_by_time_and_capped():
    t = np.arange(300) / 30.0
    idx = image_turns.sample_frames(t, 0.1, 400)
    assert idx[0] == 0 and idx[-1] == 299 and set(np.diff(idx)[:-1]) == {3}
    assert len(image_turns.sample_frames(t, 0.1, 50)) <= 51
    assert list(image_turns.sample_frames(np.arange(5) / 5.0, 0.1, 400)) == [0, 1, 2, 3, 4]


def test_the_strongest_turn_is_the_largest_heading_change_within_the_window():
    s_m = np.linspace(0.0, 120.0, 121)  # 1 m per frame
    frames = np.arange(0, 121, 4)
    # A 20 deg bend at 20-30 m, then a 70 deg turn at 80-90 m: the turn is the second.
    h = np.interp(frames, [0, 20, 30, 80, 90, 120], [0, 0, 20, 20, -50, -50])
    heads = image_turns.ImageHeadings(frames, h, 0)
    turn = image_turns.strongest_turn(s_m, heads, window_m=40.0, min_angle_deg=30.0)
    assert turn.angle_deg == pytest.approx(-70.0)
    assert 84 <= turn.vertex <= 88 and 80 <= 80 + turn.curve_m <= 90
    assert turn.start == pytest.approx(41, abs=4) and turn.end == len(s_m)
    assert image_turns.rotation_deg(len(s_m), heads)[-1] == pytest.approx(90.0)
    # Spread over 50 m of road, at most 56 deg of it falls within 40 m.
    assert image_turns.strongest_turn(s_m, heads, window_m=40.0, min_angle_deg=60.0) is not None
    assert image_turns.strongest_turn(s_m * 5, heads, window_m=40.0, min_angle_deg=60.0) is None
    assert image_turns.strongest_turn(s_m, heads, window_m=40.0, min_angle_deg=75.0) is None


def _straight_gps(journey):
    """The journey with its GPS positions replaced by a straight line through its first and last
    ones at the same distances: a receiver that saw no turn."""
    origin = frame_at(journey.lat_deg[0], journey.lon_deg[0], None)
    xyz = origin.to_local(journey.lat_deg, journey.lon_deg, None)
    s_m = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xyz[:, :2], axis=0), axis=1))]
    line = np.column_stack([s_m, np.zeros_like(s_m), np.zeros_like(s_m)])
    lat, lon, _ = origin.to_geodetic(line)
    return replace(journey, lat_deg=lat, lon_deg=lon, gps_noise_m=0.5), line


def test_the_image_look_finds_the_turn_the_gps_does_not_show(turn_journey_bundle, tmp_path):
    bundle, truth = turn_journey_bundle
    journey, xyz_gps = _straight_gps(read_bundle(bundle, tmp_path / "bundle"))
    config = PipelineConfig()
    the_plan = plan.plan_journey(journey, xyz_gps, config)
    assert not the_plan.turns and not the_plan.calib_windows

    seen = _image_look(journey, the_plan, xyz_gps, config)
    assert seen.turns_look.startswith("found on the images")
    T = np.array([f["T_world_cam"] for f in truth["frames"]])
    heading = np.degrees(np.unwrap(np.arctan2(T[:, 1, 2], T[:, 0, 2])))
    turning = np.flatnonzero(np.abs(np.gradient(heading)) > 0.5)
    assert turning[0] <= seen.turns[0].vertex <= turning[-1]
    assert abs(seen.turns[0].angle_deg) > config.turn_image_min_angle_deg
    assert seen.calib_windows and seen.image_frames_compared > 0
    # The straight "GPS" turns nothing: the windows carry that for the calibration's check.
    assert all(w.gps_rotation_deg < 5.0 for w in seen.calib_windows)


def test_the_image_look_finds_no_turn_on_a_straight_road(straight_journey_bundle, tmp_path):
    bundle, _ = straight_journey_bundle
    journey = read_bundle(bundle, tmp_path / "bundle")
    origin = frame_at(journey.lat_deg[0], journey.lon_deg[0], None)
    xyz_gps = origin.to_local(journey.lat_deg, journey.lon_deg, None)
    config = PipelineConfig()
    the_plan = plan.plan_journey(journey, xyz_gps, config)
    seen = _image_look(journey, the_plan, xyz_gps, config)
    assert not seen.turns and not seen.calib_windows
    assert seen.image_frames_compared >= 10
    assert "nor of 30 deg on the images" in plan.report(seen, config).summary
