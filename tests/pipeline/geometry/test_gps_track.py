"""Frame positions from a smoothing spline through the GPS fixes (``geometry.gps_track``), and the
window scale it gives against straight lines between fixes."""

from __future__ import annotations

import numpy as np

from app.pipeline.geometry import gps_track
from app.pipeline.geometry.similarity import umeyama
from app.pipeline.types import AntennaOffset

NOISE_M = 0.3


def _circle(t_s: np.ndarray, speed_mps: float = 16.0, radius_m: float = 14.0) -> np.ndarray:
    """(N, 3) positions on a circle driven at constant speed, 1.5 m up."""
    a = speed_mps * t_s / radius_m
    return np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a), np.full_like(a, 1.5)])


def _linear(t_frame_s, t_fix_s, xyz_fix):
    return np.column_stack([np.interp(t_frame_s, t_fix_s, xyz_fix[:, k]) for k in range(3)])


def test_a_curve_sampled_at_1_hz_keeps_its_scale():
    # Straight lines between 1 Hz fixes cut the corners of a 14 m curve at 10 m/s: the frames
    # between fixes lie inside it, and a window aligned to them comes out ~4 % too small.
    t_fix = np.arange(0.0, 12.01, 1.0)
    t_frame = np.arange(0.0, 12.0, 0.1)
    xyz_fix, truth = _circle(t_fix, 10.0), _circle(t_frame, 10.0)
    lines = _linear(t_frame, t_fix, xyz_fix)
    spline = gps_track.smoothed_positions(t_frame, lines, t_fix, xyz_fix, NOISE_M)
    scale_lines = umeyama(truth, lines).scale
    scale_spline = umeyama(truth, spline).scale
    assert scale_lines < 0.98
    assert abs(scale_spline - 1.0) < 0.01


def test_a_spline_that_flattens_an_undersampled_curve_is_not_believed():
    # Fixes 1.1 rad apart round a 14 m roundabout, three and a half times: cross-validation takes
    # the circle for noise and flattens it (window scale 0.54); the lines are kept.
    t_fix = np.arange(0.0, 20.01, 1.0)
    t_frame = np.arange(0.0, 20.0, 0.1)
    xyz_fix = _circle(t_fix)
    lines = _linear(t_frame, t_fix, xyz_fix)
    out = gps_track.smoothed_positions(t_frame, lines, t_fix, xyz_fix, NOISE_M)
    np.testing.assert_array_equal(out[:, :2], lines[:, :2])  # east, north: both kept
    np.testing.assert_allclose(out[:, 2], 1.5)
    # Unknown noise (too few fixes to tell): judged by a fixed residual, and still not believed.
    out = gps_track.smoothed_positions(t_frame, lines, t_fix, xyz_fix, None)
    np.testing.assert_array_equal(out[:, :2], lines[:, :2])


def test_noisy_fixes_are_smoothed_not_followed():
    rng = np.random.default_rng(0)
    t_fix = np.arange(0.0, 30.0, 0.25)
    t_frame = np.arange(0.0, 30.0, 0.04)
    truth_fix = np.column_stack([10.0 * t_fix, 0.02 * t_fix**2, np.zeros_like(t_fix)])
    truth = np.column_stack([10.0 * t_frame, 0.02 * t_frame**2, np.zeros_like(t_frame)])
    xyz_fix = truth_fix + rng.normal(0.0, 0.3, truth_fix.shape) * [1, 1, 0]
    lines = _linear(t_frame, t_fix, xyz_fix)
    spline = gps_track.smoothed_positions(t_frame, lines, t_fix, xyz_fix, NOISE_M)
    rms = lambda xyz: np.sqrt(np.mean(np.sum((xyz - truth) ** 2, axis=1)))  # noqa: E731
    assert rms(spline) < 0.5 * rms(lines)


def test_frames_outside_the_fixes_continue_from_the_spline_and_few_fixes_keep_the_lines():
    t_fix = np.arange(1.0, 8.01, 1.0)
    t_frame = np.arange(0.0, 9.0, 0.1)
    xyz_fix = _circle(t_fix)
    xyz_fix[:, 0] += np.array([0.3, -0.3] * 4)  # noise the spline smooths away at the end fixes
    lines = _linear(t_frame, t_fix, xyz_fix)
    lines[t_frame < 1.0] = xyz_fix[0]  # the reader's extrapolation, here held at the end fixes
    lines[t_frame > 8.0] = xyz_fix[-1]
    spline = gps_track.smoothed_positions(t_frame, lines, t_fix, xyz_fix, NOISE_M)
    before, first = t_frame < 1.0, np.searchsorted(t_frame, 1.0)
    # Outside the span: the reader's positions, shifted to meet the spline at the end fix.
    np.testing.assert_allclose(spline[before] - lines[before],
                               np.broadcast_to(spline[first] - xyz_fix[0], (before.sum(), 3)),
                               atol=0.02)
    few = gps_track.smoothed_positions(t_frame, lines, t_fix[:4], xyz_fix[:4], NOISE_M)
    np.testing.assert_array_equal(few, lines)


def test_an_axis_with_missing_fixes_keeps_the_lines_and_long_tracks_go_in_pieces():
    rng = np.random.default_rng(1)
    t_fix = np.arange(0.0, 130.0, 0.1)  # 1300 fixes: three pieces
    t_frame = np.arange(0.0, 129.9, 0.05)
    xyz_fix = np.column_stack([5.0 * t_fix, 20.0 * np.sin(t_fix / 10.0), np.full_like(t_fix, np.nan)])
    truth = np.column_stack([5.0 * t_frame, 20.0 * np.sin(t_frame / 10.0)])
    xyz_fix[:, :2] += rng.normal(0.0, 0.3, (len(t_fix), 2))
    lines = _linear(t_frame, t_fix, np.nan_to_num(xyz_fix))
    spline = gps_track.smoothed_positions(t_frame, lines, t_fix, xyz_fix, NOISE_M)
    assert len(gps_track._pieces(t_fix)) == 3
    np.testing.assert_array_equal(spline[:, 2], lines[:, 2])
    err = np.linalg.norm(spline[:, :2] - truth, axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.15
    # No step where one piece hands over to the next: consecutive frames 0.25 m apart.
    assert np.abs(np.diff(np.linalg.norm(np.diff(spline[:, :2], axis=0), axis=1))).max() < 0.05


KITTI_OFFSET = AntennaOffset(forward_m=-1.09, left_m=0.25, up_m=-0.72)


def _in_vehicle_axes(d_enu: np.ndarray, forward_xy: np.ndarray) -> np.ndarray:
    """(N, 3) ENU vectors as (forward, left, up) for horizontal unit directions ``forward_xy``."""
    left_xy = np.column_stack([-forward_xy[:, 1], forward_xy[:, 0]])
    return np.column_stack([(d_enu[:, :2] * forward_xy).sum(axis=1),
                            (d_enu[:, :2] * left_xy).sum(axis=1), d_enu[:, 2]])


def _antenna(camera: np.ndarray, forward_xy: np.ndarray, offset: AntennaOffset) -> np.ndarray:
    left_xy = np.column_stack([-forward_xy[:, 1], forward_xy[:, 0]])
    return camera + np.column_stack([offset.forward_m * forward_xy + offset.left_m * left_xy,
                                     np.full(len(camera), offset.up_m)])


def test_the_antenna_offset_is_taken_off_in_vehicle_axes_round_a_circle():
    # Counter-clockwise round a 14 m circle at 8 m/s, 10 Hz: forward is the camera's tangent,
    # left points to the centre. The camera comes back exactly; within 1.5 s of the journey's ends,
    # where the window is one-sided and a parabola only approximates the circle, within 4 cm.
    t = np.arange(0.0, 12.0, 0.1)
    camera = _circle(t, 8.0)
    a = 8.0 * t / 14.0
    forward = np.column_stack([-np.sin(a), np.cos(a)])
    antenna = _antenna(camera, forward, KITTI_OFFSET)
    out, heading_known = gps_track.camera_positions(t, antenna, KITTI_OFFSET)
    assert heading_known
    inner = slice(15, -15)
    np.testing.assert_allclose(out[inner], camera[inner], atol=1e-3)
    assert np.linalg.norm(out - camera, axis=1).max() < 0.04
    # Left really is towards the centre: the antenna 0.25 m left sits inside the circle.
    assert np.all(np.linalg.norm(antenna[:, :2], axis=1) < 14.0 + 1.09)
    np.testing.assert_allclose(_in_vehicle_axes(antenna - out, forward)[inner],
                               np.tile([-1.09, 0.25, -0.72], (len(t) - 30, 1)), atol=1e-3)
    # The straight line fitted to the antenna's own positions would turn 4.5 degrees too far
    # (its path is another circle, entered earlier): 8.5 cm off; the camera's path is used.
    own = gps_track.travel_direction(t, antenna)[inner]
    assert np.degrees(np.arccos((own * forward[inner]).sum(axis=1))).min() > 4.0


def test_noisy_fixes_give_the_camera_within_centimetres_of_the_offset():
    # 0.3 m of white noise at 10 Hz round the circle: the heading scatters by about a degree, so
    # the offset taken off errs by ~2 cm (the noise itself stays, as it must).
    t = np.arange(0.0, 12.0, 0.1)
    camera = _circle(t, 8.0)
    a = 8.0 * t / 14.0
    forward = np.column_stack([-np.sin(a), np.cos(a)])
    noise = np.random.default_rng(3).normal(0.0, NOISE_M, camera.shape)
    antenna = _antenna(camera, forward, KITTI_OFFSET) + noise
    out, _ = gps_track.camera_positions(t, antenna, KITTI_OFFSET)
    inner = slice(15, -15)
    taken_off = _in_vehicle_axes((antenna - out)[inner], forward[inner])
    assert np.sqrt(np.mean((taken_off - [-1.09, 0.25, -0.72]) ** 2, axis=0)).max() < 0.03


def test_a_stop_holds_the_heading_and_a_vehicle_that_never_moves_gets_only_up():
    # North at 10 m/s for 5 s, stopped 5 s (the fixes wander 0.3 m), east for 5 s.
    t = np.arange(0.0, 15.0, 0.1)
    north = np.minimum(t, 5.0) * 10.0
    east = np.maximum(t - 10.0, 0.0) * 10.0
    camera = np.column_stack([east, north, np.full_like(t, 1.5)])
    forward = np.where((t < 7.5)[:, None], [0.0, 1.0], [1.0, 0.0])
    antenna = _antenna(camera, forward, KITTI_OFFSET)
    stopped = (t > 5.6) & (t < 9.4)
    antenna[stopped, :2] += np.random.default_rng(4).normal(0.0, NOISE_M, (stopped.sum(), 2))
    direction = gps_track.travel_direction(t, antenna)
    # Standing still, each fix holds the heading of the nearest moving one: north, then east
    # (within 3 degrees: the last moving windows take in some of the wandering fixes).
    assert np.all(direction[stopped & (t < 7.4), 1] > np.cos(np.radians(3.0)))
    assert np.all(direction[stopped & (t > 7.6), 0] > np.cos(np.radians(3.0)))
    # Well before and after the stop the camera comes back to the millimetre.
    out, heading_known = gps_track.camera_positions(t, antenna, KITTI_OFFSET)
    assert heading_known
    clean = (t < 3.4) | (t > 11.6)
    np.testing.assert_allclose(out[clean], camera[clean], atol=1e-3)
    # Parked: no heading at all; only the height is corrected.
    parked = np.column_stack([np.random.default_rng(5).normal(0.0, NOISE_M, (len(t), 2)),
                              np.full_like(t, 1.5)])
    out, heading_known = gps_track.camera_positions(t, parked, KITTI_OFFSET)
    assert not heading_known
    np.testing.assert_allclose(out - parked, np.tile([0.0, 0.0, 0.72], (len(t), 1)))
