"""Ego-motion window planning: passes of a sign seen twice, windows, initial pairs (no COLMAP)."""

from __future__ import annotations

import numpy as np

from app.pipeline import ego_motion
from app.pipeline.run import _combine
from app.pipeline.triangulation import TriangulatedPoint
from app.pipeline.types import CameraModel, Detection

CAMERA = CameraModel(1242, 375, 959.0, 959.0, 621.0, 187.0, 0.0, 0.0)


def _track(frames, track_id="7") -> ego_motion.SignTrack:
    frames = np.asarray(frames, dtype=int)
    px = np.column_stack([frames * 1.0, frames * 2.0])
    return ego_motion.SignTrack(track_id, "stop", frames, px)


def test_a_continuous_track_is_one_pass():
    track = _track(range(10, 40))
    assert ego_motion.split_passes(track, max_gap=30, max_frames=50) == [track]


def test_a_sign_seen_again_after_a_loop_becomes_two_passes():
    track = _track([0, 1, 2, 3, 4, 273, 274, 280, 299])
    parts = ego_motion.split_passes(track, max_gap=30, max_frames=50)
    assert [p.frame_idx.tolist() for p in parts] == [[0, 1, 2, 3, 4], [273, 274, 280, 299]]
    assert [p.part for p in parts] == [0, 1]
    assert all(p.track_id == "7" and p.cls == "stop" for p in parts)
    # The pixels travel with their frames.
    for p in parts:
        np.testing.assert_array_equal(p.px[:, 0], p.frame_idx)


def test_short_gaps_do_not_split_a_pass():
    track = _track([40, 41, 51, 68, 80])  # missed detections, 17 frames at most
    assert len(ego_motion.split_passes(track, max_gap=30, max_frames=50)) == 1


def test_a_long_pass_is_cut_into_parts_no_longer_than_max_frames():
    track = _track(range(0, 130))
    parts = ego_motion.split_passes(track, max_gap=30, max_frames=50)
    assert [p.span for p in parts] == [(0, 50), (50, 100), (100, 130)]
    assert np.array_equal(np.concatenate([p.frame_idx for p in parts]), track.frame_idx)


def test_windows_of_a_looped_sign_stay_short():
    """The journey's signs: one seen at the start and again at the end, others in between. Without
    splitting, one window would cover the whole journey."""
    tracks = [_track([0, 1, 2, 3, 275, 280, 290, 299], "0"), _track(range(30, 60), "1"),
              _track(range(120, 150), "2"), _track(range(200, 240), "3")]
    unsplit = ego_motion.plan_windows(tracks, 300, margin=15, max_frames=80)
    assert unsplit == [(0, 300)]
    parts = [p for t in tracks for p in ego_motion.split_passes(t, max_gap=30, max_frames=50)]
    windows = ego_motion.plan_windows(parts, 300, margin=15, max_frames=80)
    assert max(b - a for a, b in windows) <= 80
    for p in parts:  # every pass lies inside one window
        a, b = p.span
        assert any(wa <= a and b <= wb for wa, wb in windows), (p.span, windows)


def test_sign_tracks_keeps_track_ids_through_splitting():
    frames = [f"{i:06d}" for i in range(300)]
    dets = [Detection(frames[i], "5", "yield", 10.0, 10.0, 20.0, 20.0) for i in (0, 1, 2, 280, 281)]
    (track,) = ego_motion.sign_tracks(dets, frames)
    parts = ego_motion.split_passes(track, max_gap=30, max_frames=50)
    assert [p.span for p in parts] == [(0, 3), (280, 282)]


def test_requests_start_from_a_pair_in_the_window_middle():
    names = [f"{i:06d}.png" for i in range(100)]
    (req,) = ego_motion.requests([(10, 70)], names, CAMERA, step=2, init_gap_frames=8)
    assert req.image_names == names[10:70:2]
    a, b = req.init_pair
    assert a in req.image_names and b in req.image_names
    ia, ib = names.index(a), names.index(b)
    assert ib - ia == 8  # within the sequential matching overlap: the pair was matched
    assert abs((ia + ib) / 2 - 40) <= 2
    (plain,) = ego_motion.requests([(10, 70)], names, CAMERA, step=2)
    assert plain.init_pair is None
    (tiny,) = ego_motion.requests([(10, 16)], names, CAMERA, step=2, init_gap_frames=8)
    assert tiny.init_pair is None  # too short for the gap: COLMAP chooses


def _point(xyz, sigma, rms=0.5) -> TriangulatedPoint:
    return TriangulatedPoint(np.asarray(xyz, float), np.diag(np.square(sigma)),
                             float(max(sigma)), rms, np.zeros((2, 3)))


def test_passes_combine_into_a_weighted_mean_between_them():
    a = (_point([0.0, 0.0, 0.0], [0.1, 0.1, 0.1]), np.zeros((4, 4, 4)), np.arange(4), 0.0)
    b = (_point([1.0, 0.0, 0.0], [0.3, 0.3, 0.3]), np.zeros((2, 4, 4)), np.arange(2), 0.0)
    xyz, cov, _ = _combine([a, b])
    assert abs(xyz[0] - 0.1) < 1e-9  # weights 1/0.1^2 : 1/0.3^2
    assert cov[0, 0] < 0.1**2
    # Alignment errors dominate: the passes count about equally.
    xyz, _, _ = _combine([a[:3] + (0.5,), b[:3] + (0.5,)])
    assert 0.4 < xyz[0] < 0.5
    # Elongated covariances in different directions: still between the passes.
    c = (TriangulatedPoint(np.zeros(3), np.diag([0.01, 4.0, 0.01]), 2.0, 0.5, np.zeros((2, 3))),
         None, np.arange(3), 0.3)
    d = (TriangulatedPoint(np.array([1.0, 1.0, 0.0]), np.diag([4.0, 0.01, 0.01]), 2.0, 0.5,
                           np.zeros((2, 3))), None, np.arange(3), 0.3)
    xyz, _, _ = _combine([c, d])
    assert np.all(xyz >= -1e-9) and np.all(xyz <= 1.0 + 1e-9)
    xyz1, _, rms1 = _combine([a])
    np.testing.assert_array_equal(xyz1, a[0].xyz_world)
    assert rms1 == 0.5
