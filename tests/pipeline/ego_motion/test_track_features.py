"""KLT tracks for ego-motion (``track_features``) and the COLMAP pairs made from them
(``klt_features.klt_correspondences``): known image motions, no COLMAP."""

from __future__ import annotations

import time

import cv2
import numpy as np

from app.pipeline.steps import ego_motion
from app.pipeline.colmap import klt_features
from app.pipeline.colmap.klt_features import KltOptions, track_features
from app.pipeline.types import CameraModel

CAMERA = CameraModel(480, 240, 400.0, 400.0, 240.0, 120.0, -0.1, 0.0)


def _texture(seed: int = 0, h: int = 240, w: int = 480) -> np.ndarray:
    """Blurred random blobs: corners everywhere, no repeated pattern."""
    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.uniform(0, 255, (h // 6, w // 6)).astype(np.float32), (w, h),
                     interpolation=cv2.INTER_CUBIC)
    return np.clip(cv2.GaussianBlur(img, (0, 0), 1.2), 0, 255).astype(np.uint8)


def _shifted(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``img`` moved by (dx, dy) pixels: content at p appears at p + (dx, dy)."""
    M = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(img, M, (img.shape[1], img.shape[0]), flags=cv2.INTER_CUBIC,
                          borderMode=cv2.BORDER_REFLECT)


def test_tracks_follow_a_known_subpixel_motion():
    base = _texture()
    steps = [(3.25, -1.5), (6.5, -3.0), (9.75, -4.5), (13.0, -6.0)]  # constant velocity
    frames = [base] + [_shifted(base, dx, dy) for dx, dy in steps]
    tracks = track_features(frames, KltOptions(max_corners=300))
    first = dict(zip(tracks.track_ids[0].tolist(), tracks.keypoints_px[0]))
    assert len(first) > 150
    for k, (dx, dy) in enumerate(steps, start=1):
        ids, pts = tracks.track_ids[k], tracks.keypoints_px[k]
        old = np.array([i in first for i in ids.tolist()])
        assert old.sum() > 0.7 * len(first)  # most corners survive (a few leave the image)
        moved = pts[old] - np.array([first[i] for i in ids[old].tolist()])
        # Interior points only: the reflected border is not a translated copy.
        inside = ((pts[old][:, 0] > 30) & (pts[old][:, 0] < 450) & (pts[old][:, 1] > 30)
                  & (pts[old][:, 1] < 210))
        err = np.linalg.norm(moved[inside] - [dx, dy], axis=1)
        assert np.median(err) < 0.05 and np.percentile(err, 95) < 0.2


def test_a_break_starts_every_track_anew():
    base = _texture()
    tracks = track_features([base, _shifted(base, 2, 0), None, _shifted(base, 4, 0)])
    assert len(tracks.keypoints_px) == 3
    assert len(tracks.pair_matches(0, 1)) > 100
    assert len(tracks.pair_matches(1, 2)) == 0  # nothing crosses the break


def test_an_unrelated_frame_loses_the_tracks():
    """A cut to another scene: the forward-backward and patch checks drop the tracks."""
    tracks = track_features([_texture(0), _texture(1)], KltOptions(max_corners=300))
    assert len(tracks.pair_matches(0, 1)) < 0.05 * len(tracks.keypoints_px[0])


def test_pairs_reach_overlap_frames_and_never_cross_a_gap():
    base = _texture()
    frame_idx = np.array([0, 2, 4, 6, 20, 22, 24])  # the gap 6 -> 20 is more than the step
    images = [_shifted(base, 1.5 * i, 0.0) for i in frame_idx]
    names = [f"{i:06d}.png" for i in range(30)]
    feats = klt_features.klt_correspondences(frame_idx, images, names, CAMERA, step=2, overlap=2)
    assert feats.image_names == [names[i] for i in frame_idx]
    assert sorted(feats.matches) == [(0, 1), (0, 2), (1, 2), (1, 3), (2, 3), (4, 5), (4, 6),
                                     (5, 6)]
    for (k1, k2), m in feats.matches.items():
        assert m.dtype == np.uint32 and m.shape[1] == 2
        moved = feats.keypoints_px[k2][m[:, 1]] - feats.keypoints_px[k1][m[:, 0]]
        expected = 1.5 * (frame_idx[k2] - frame_idx[k1])
        inside = feats.keypoints_px[k1][m[:, 0], 0] < 400
        assert np.median(np.abs(moved[inside, 0] - expected)) < 0.05
    assert feats.camera == CAMERA


def test_mapped_frames_are_the_union_of_the_windows_steps():
    frames = ego_motion.mapped_frames([(0, 9), (6, 15), (30, 33)], step=3)
    assert frames.tolist() == [0, 3, 6, 9, 12, 30]


def test_frames_are_read_ahead_in_order_and_only_a_few_at_a_time():
    from app.pipeline.colmap.stage import read_ahead

    reads = []
    frames = read_ahead(list(range(100)), lambda i: reads.append(i) or i, ahead=4)
    assert next(frames) == 0
    time.sleep(0.05)
    assert len(reads) == 5  # the one handed out and four ahead, not the journey
    assert list(frames) == list(range(1, 100))
