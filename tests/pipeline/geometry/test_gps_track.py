"""Frame positions from a smoothing spline through the GPS fixes (``geometry.gps_track``), and the
window scale it gives against straight lines between fixes."""

from __future__ import annotations

import numpy as np

from app.pipeline.geometry import gps_track
from app.pipeline.geometry.similarity import umeyama

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
