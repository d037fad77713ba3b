"""Ego-motion window planning: passes of a sign seen twice, windows, initial pairs (no COLMAP)."""

from __future__ import annotations

import numpy as np
import pytest

from app.pipeline.steps import ego_motion, sign_tracks
from app.pipeline.steps.place_signs import PlacedPass, TrackOutcome, combine, merge_fragments
from app.pipeline.geometry.uncertainty import GeorefTerms
from app.pipeline.geometry.triangulation import TriangulatedPoint
from app.pipeline.types import CameraModel, Detection

CAMERA = CameraModel(1242, 375, 959.0, 959.0, 621.0, 187.0, 0.0, 0.0)


def _track(frames, track_id="7") -> sign_tracks.SignTrack:
    frames = np.asarray(frames, dtype=int)
    px = np.column_stack([frames * 1.0, frames * 2.0])
    return sign_tracks.SignTrack(track_id, "stop", frames, px)


def test_a_continuous_track_is_one_pass():
    track = _track(range(10, 40))
    assert sign_tracks.split_passes(track, max_gap=30, max_frames=50) == [track]


def test_a_sign_seen_again_after_a_loop_becomes_two_passes():
    track = _track([0, 1, 2, 3, 4, 273, 274, 280, 299])
    parts = sign_tracks.split_passes(track, max_gap=30, max_frames=50)
    assert [p.frame_idx.tolist() for p in parts] == [[0, 1, 2, 3, 4], [273, 274, 280, 299]]
    assert [p.part for p in parts] == [0, 1]
    assert all(p.track_id == "7" and p.cls == "stop" for p in parts)
    # The pixels travel with their frames.
    for p in parts:
        np.testing.assert_array_equal(p.px[:, 0], p.frame_idx)


def test_short_gaps_do_not_split_a_pass():
    track = _track([40, 41, 51, 68, 80])  # missed detections, 17 frames at most
    assert len(sign_tracks.split_passes(track, max_gap=30, max_frames=50)) == 1


def test_a_long_pass_is_cut_into_parts_no_longer_than_max_frames():
    track = _track(range(0, 130))
    parts = sign_tracks.split_passes(track, max_gap=30, max_frames=50)
    assert [p.span for p in parts] == [(0, 50), (50, 100), (100, 130)]
    assert np.array_equal(np.concatenate([p.frame_idx for p in parts]), track.frame_idx)


CHAINED = {"step": 2, "overlap": 16, "bridge_gap": 40}


@pytest.mark.parametrize("chaining", [{}, CHAINED])
def test_windows_of_a_looped_sign_stay_short(chaining):
    """The journey's signs: one seen at the start and again at the end, others in between. Without
    splitting, the looped sign alone would need the whole journey mapped."""
    tracks = [_track([0, 1, 2, 3, 275, 280, 290, 299], "0"), _track(range(30, 60), "1"),
              _track(range(120, 150), "2"), _track(range(200, 240), "3")]
    parts = [p for t in tracks for p in sign_tracks.split_passes(t, max_gap=30, max_frames=50)]
    windows = ego_motion.plan_windows(parts, 300, margin=15, max_frames=80, **chaining)
    _check_windows(windows, parts, 300, margin=15, max_frames=80, step=chaining.get("step", 1))


def _check_windows(windows, tracks, n_frames, *, margin, max_frames, step):
    """The planning guarantees: in time order, inside the journey, on the step grid, no longer than
    max_frames; every frame within ``margin`` of a track inside some window; no frame in more than
    two windows (mapping cost stays about one reconstruction per frame)."""
    assert windows == sorted(windows)
    assert all(0 <= a < b <= n_frames and b - a <= max_frames and a % step == 0
               for a, b in windows), windows
    covered = np.zeros(n_frames, int)
    for a, b in windows:
        covered[a:b] += 1
    for t in tracks:
        a, b = t.span
        assert covered[max(0, a - margin):min(n_frames, b + margin)].all(), (t.span, windows)
    assert covered.max() <= 2, windows


def _shared(w1, w2, step) -> set[int]:
    """Journey frames that both windows map (every step-th frame from their starts)."""
    return set(range(*w1, step)) & set(range(*w2, step))


def test_a_stretch_longer_than_max_frames_becomes_a_chain_of_equal_windows():
    tracks = [_track(range(20, 50), "1"), _track(range(45, 120), "2")]
    windows = ego_motion.plan_windows(tracks, 300, margin=15, max_frames=80, **CHAINED)
    _check_windows(windows, tracks, 300, margin=15, max_frames=80, step=2)
    assert windows[0][0] == 4 and windows[-1][1] == 135  # margins, the start on the step grid
    (a1, b1), (a2, b2) = windows
    assert b1 - a2 >= 16 and len(_shared(*windows, 2)) >= 8  # both map the frames they share
    assert abs((b1 - a1) - (b2 - a2)) <= 2  # no stub window at the end


def test_a_long_pass_becomes_a_chain_of_overlapping_windows():
    parts = sign_tracks.split_passes(_track(range(10, 250)), max_gap=30, max_frames=50)
    windows = ego_motion.plan_windows(parts, 300, margin=15, max_frames=80, **CHAINED)
    _check_windows(windows, parts, 300, margin=15, max_frames=80, step=2)
    assert len(windows) == 4  # 0-265 in windows of at most 80 sharing 16: (265 - 16) / 64
    for w1, w2 in zip(windows, windows[1:]):
        assert len(_shared(w1, w2, 2)) >= 8


def test_tracks_across_a_short_gap_are_bridged_but_not_across_a_long_one():
    tracks = [_track(range(20, 40), "1"), _track(range(94, 140), "2"),
              _track(range(200, 230), "3")]
    windows = ego_motion.plan_windows(tracks, 300, margin=15, max_frames=80, **CHAINED)
    _check_windows(windows, tracks, 300, margin=15, max_frames=80, step=2)
    # 55 -> 79 is a gap of 24 frames: one stretch 4-155, two chained windows; 155 -> 185 is 30
    # frames: bridged too. With a bridge of 20, three separate stretches.
    assert windows[0][0] == 4 and windows[-1][1] == 245
    for w1, w2 in zip(windows, windows[1:]):
        assert w1[1] - w2[0] >= 16
    apart = ego_motion.plan_windows(tracks, 300, margin=15, max_frames=80,
                                    **{**CHAINED, "bridge_gap": 20})
    assert apart == [(4, 55), (78, 155), (184, 245)]


def test_without_chaining_windows_only_cover_the_tracks():
    tracks = [_track(range(20, 30), "1"), _track(range(70, 75), "2")]
    assert ego_motion.plan_windows(tracks, 300, margin=15, max_frames=80) == [(5, 45), (55, 90)]
    joined = ego_motion.plan_windows(tracks, 300, margin=15, max_frames=100, **CHAINED)
    assert joined == [(4, 90)]


def test_sign_tracks_keeps_track_ids_through_splitting():
    frames = [f"{i:06d}" for i in range(300)]
    dets = [Detection(frames[i], "5", "yield", 10.0, 10.0, 20.0, 20.0) for i in (0, 1, 2, 280, 281)]
    (track,) = sign_tracks.group_detections(dets, frames)
    parts = sign_tracks.split_passes(track, max_gap=30, max_frames=50)
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


def _pass(point: TriangulatedPoint, n_frames: int, alignment_rms_m: float) -> PlacedPass:
    return PlacedPass(point, np.zeros((n_frames, 4, 4)), np.arange(n_frames), alignment_rms_m,
                      GeorefTerms(alignment_rms_m**2, 1.0))


def test_passes_combine_into_a_weighted_mean_between_them():
    a = _pass(_point([0.0, 0.0, 0.0], [0.1, 0.1, 0.1]), 4, 0.0)
    b = _pass(_point([1.0, 0.0, 0.0], [0.3, 0.3, 0.3]), 2, 0.0)
    xyz, cov, _, _ = combine([a, b])
    assert abs(xyz[0] - 0.1) < 1e-9  # weights 1/0.1^2 : 1/0.3^2
    assert cov[0, 0] < 0.1**2
    # Alignment errors dominate: the passes count about equally, and their georeferencing
    # errors (independent windows) average.
    xyz, _, _, georef = combine([_pass(a.point, 4, 0.5), _pass(b.point, 2, 0.5)])
    assert 0.4 < xyz[0] < 0.5
    assert 0.5**2 / 2 - 1e-3 < georef.averaged_noise_m2 < 0.5**2 and georef.floor_weight < 1.0
    # Elongated covariances in different directions: still between the passes.
    c = _pass(TriangulatedPoint(np.zeros(3), np.diag([0.01, 4.0, 0.01]), 2.0, 0.5,
                                np.zeros((2, 3))), 3, 0.3)
    d = _pass(TriangulatedPoint(np.array([1.0, 1.0, 0.0]), np.diag([4.0, 0.01, 0.01]), 2.0, 0.5,
                                np.zeros((2, 3))), 3, 0.3)
    xyz, _, _, _ = combine([c, d])
    assert np.all(xyz >= -1e-9) and np.all(xyz <= 1.0 + 1e-9)
    xyz1, _, rms1, _ = combine([a])
    np.testing.assert_array_equal(xyz1, a.point.xyz_world)
    assert rms1 == 0.5


def _frames_pass(xyz, frames) -> PlacedPass:
    return PlacedPass(_point(xyz, [0.05] * 3), np.zeros((len(frames), 4, 4)), np.asarray(frames),
                      0.3, GeorefTerms(0.01, 1.0, 0.09))


def test_pieces_of_one_broken_track_are_merged_and_other_signs_are_not():
    passes = {"auto-1": TrackOutcome([_frames_pass([10.0, 5.0, 2.0], [10, 11, 12])]),
              "auto-0": TrackOutcome([_frames_pass([10.4, 5.3, 2.1], [3, 4, 5])]),   # same, earlier
              "auto-2": TrackOutcome([_frames_pass([10.2, 5.1, 2.0], [11, 12, 13])]),  # shares frames
              "auto-3": TrackOutcome([_frames_pass([10.1, 4.8, 2.0], [20, 21])]),    # another class
              "auto-4": TrackOutcome([_frames_pass([13.0, 5.0, 2.0], [30, 31])]),    # 3 m away
              "auto-5": TrackOutcome([], ["reprojection rms 9.0 px > 4.0"])}
    classes = {"auto-0": "stop", "auto-1": "stop", "auto-2": "stop", "auto-3": "yield",
               "auto-4": "stop", "auto-5": "stop"}
    merged = merge_fragments(passes, classes, within_m=1.0)
    assert sorted(merged) == ["auto-0", "auto-2", "auto-3", "auto-4", "auto-5"]
    assert [p.frame_idx.tolist() for p in merged["auto-0"].placed] == [[3, 4, 5], [10, 11, 12]]
    assert merge_fragments(passes, classes, within_m=0.1) == passes


def test_a_short_track_off_the_step_grid_keeps_all_its_frames():
    """Seen in frames 129-131 only: at step 2 the grid keeps 130 alone, too few to triangulate."""
    short, long_ = _track([129, 130, 131], "11"), _track(range(140, 160), "12")
    extra = ego_motion.off_grid_frames([short, long_], step=2, min_frames=3)
    assert extra.tolist() == [129, 131]
    assert ego_motion.window_frames((120, 150), 2, extra) == [120, 122, 124, 126, 128, 129, 130,
                                                               131, 132, 134, 136, 138, 140, 142,
                                                               144, 146, 148]
    frames = ego_motion.mapped_frames([(120, 150), (140, 170)], 2, extra)
    assert {129, 131} <= set(frames.tolist()) and 133 not in frames
    names = [f"{i:06d}.png" for i in range(300)]
    (request,) = ego_motion.requests([(120, 150)], names, CAMERA, step=2, extra=extra,
                                     init_gap_frames=8)
    assert request.image_names == [names[i] for i in ego_motion.window_frames((120, 150), 2,
                                                                               extra)]
    assert request.init_pair == (names[130], names[138])  # on the grid, in the middle


def test_frame_spacing_is_the_moving_speed_and_a_turn_or_a_stop_does_not_shorten_it():
    from app.pipeline.steps.plan import moving_spacing_m

    rng = np.random.default_rng(0)
    t = np.arange(200) / 10.0  # 10 Hz, 9 m/s round a 20 m radius U-turn and on
    s = 9.0 * t
    arc = s < np.pi * 20.0
    xyz = np.zeros((200, 3))
    xyz[arc, 0], xyz[arc, 1] = 20.0 * np.sin(s[arc] / 20.0), 20.0 - 20.0 * np.cos(s[arc] / 20.0)
    xyz[~arc, 0], xyz[~arc, 1] = -(s[~arc] - np.pi * 20.0), 40.0
    assert moving_spacing_m(xyz, t) == pytest.approx(0.9, rel=0.05)
    noisy = xyz + np.c_[rng.normal(0.0, 0.3, (200, 2)), np.zeros(200)]  # OXTS-like fixes
    assert moving_spacing_m(noisy, t, 0.3) == pytest.approx(0.9, rel=0.05)
    # Phone-like fixes on a straight road, 3 m at 1 Hz, interpolated at the frames: their spread
    # is taken off.
    t_fix = np.arange(0.0, 20.0, 1.0)
    fixes = np.c_[9.0 * t_fix, np.zeros((20, 2))] + rng.normal(0.0, 3.0, (20, 3))
    phone = np.stack([np.interp(t, t_fix, fixes[:, i]) for i in range(3)], 1)
    assert moving_spacing_m(phone, t) > moving_spacing_m(phone, t, 3.0)
    assert moving_spacing_m(phone, t, 3.0) == pytest.approx(0.9, rel=0.12)  # 0.80-0.99 by seed
    stop_and_go = np.concatenate([np.zeros((100, 3)), xyz[:100]])  # half the journey standing
    assert moving_spacing_m(stop_and_go, t) == pytest.approx(0.9, rel=0.05)
    assert moving_spacing_m(np.zeros((50, 3)), t[:50]) is None


def test_frames_mapped_metres_apart_get_sift_and_close_ones_keep_klt():
    from app.pipeline.steps.plan import ego_front_end

    assert ego_front_end(0.8, 2, "klt", 1.7) == "klt"  # the suite: 1.6 m between mapped frames
    assert ego_front_end(3.6, 2, "klt", 1.7) == "sift"  # 5 Hz at 18 m/s
    assert ego_front_end(0.9, 2, "klt", 1.7) == "sift"
    assert ego_front_end(3.6, 2, "klt", 0.0) == "klt"  # 0: never
    assert ego_front_end(0.8, 2, "sift", 1.7) == "sift"  # asked for everywhere
    assert ego_front_end(None, 2, "klt", 1.7) == "klt"


def test_more_initial_pairs_are_tried_with_half_the_gap_and_off_the_middle():
    names = [f"{i:06d}.jpg" for i in range(100)]
    (plain,) = ego_motion.requests([(0, 80)], names, CAMERA, step=2, init_gap_frames=8)
    (more,) = ego_motion.requests([(0, 80)], names, CAMERA, step=2, init_gap_frames=8,
                                  more_init_pairs=3)
    assert plain.more_init_pairs == () and more.init_pair == plain.init_pair
    assert plain.init_pair == (names[36], names[44])  # the middle of 40 mapped frames
    assert more.more_init_pairs == ((names[38], names[42]),  # half the gap, in the middle
                                    (names[18], names[26]),  # a quarter in
                                    (names[54], names[62]))  # three quarters in
