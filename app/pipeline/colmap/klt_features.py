"""KLT feature tracks for ego-motion (image corners followed from frame to frame; not the signs'
tracks of ``steps.sign_tracks``): pyramidal Lucas-Kanade (KLT) over the mapped frames, in place of
SIFT extraction and matching.

Consecutive frames of a car's video differ little, so a corner found once can be followed from frame
to frame instead of being re-detected and matched by descriptor against every neighbour. One
tracking step (OpenCV ``calcOpticalFlowPyrLK``, forward and backward) costs milliseconds where SIFT
extraction plus sequential matching cost ~0.7 s per image here (turn-70;
docs/decisions/klt-ego-motion.md); every pair of frames that share a track gets its
correspondences for free. COLMAP then verifies the pairs
geometrically and maps them with the calibrated camera (``colmap.sfm``), exactly as with SIFT.

Tracking runs on the original (distorted) images: the flow does not care about distortion, and
COLMAP applies the calibrated model to the keypoints. Pixels are OpenCV's (see ``types``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import cv2
import numpy as np

from app.pipeline.colmap.sfm import ImportedFeatures
from app.pipeline.types import CameraModel


@dataclass(frozen=True, kw_only=True)
class KltOptions:
    """How corners are found and followed (OpenCV ``goodFeaturesToTrack`` and
    ``calcOpticalFlowPyrLK``) and which steps of a track are kept."""

    max_corners: int = 1200
    min_distance_px: int = 10
    quality_level: float = 0.005
    win_size_px: int = 21
    pyramid_levels: int = 4
    # A track survives a step only if tracking its new position backwards lands within this of
    # where it started: drops drift on occlusion boundaries and repeated texture.
    max_fb_error_px: float = 0.7
    # Mean absolute grey-level difference between a corner's window and where it was tracked to.
    # Right tracks between mapped frames of turn-70 stay under 15 (99th percentile); a corner that
    # locked onto a similar-looking blob elsewhere scores 25-50 and can still pass the FB check.
    max_patch_error: float = 20.0


@dataclass(frozen=True)
class FrameTracks:
    """KLT tracks over a sequence of frames.

    ``keypoints_px[k]`` (K_k, 2) float32: positions in frame k of the sequence (OpenCV pixels of the
    original image); ``track_ids[k]`` (K_k,) int64: the track each of those keypoints belongs to.
    A track id appears in a run of consecutive frames only.
    """

    keypoints_px: list[np.ndarray]
    track_ids: list[np.ndarray]

    def pair_matches(self, k1: int, k2: int) -> np.ndarray:
        """(M, 2) uint32 keypoint indices (into frame k1, into frame k2) of the tracks both see."""
        _, i1, i2 = np.intersect1d(self.track_ids[k1], self.track_ids[k2], assume_unique=True,
                                   return_indices=True)
        return np.stack([i1, i2], axis=1).astype(np.uint32)


def track_features(images: Iterable[np.ndarray | None], options: KltOptions = KltOptions()
                   ) -> FrameTracks:
    """Track corners through ``images`` (8-bit grayscale, all the same size). ``None`` in the
    sequence marks a break (frames not consecutive): no track crosses it."""
    lk = dict(winSize=(options.win_size_px, options.win_size_px), maxLevel=options.pyramid_levels,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    keypoints, ids = [], []
    prev = None
    pts = np.zeros((0, 2), np.float32)
    vel = np.zeros((0, 2), np.float32)  # last step's motion: the prediction for the next step
    track = np.zeros(0, np.int64)
    next_id = 0
    for image in images:
        if image is None:
            prev = None
            continue
        if prev is not None and len(pts):
            pts, vel, track = _step(prev, image, pts, vel, track, lk, options)
        else:
            pts, vel, track = pts[:0], vel[:0], track[:0]
        new = _new_corners(image, pts, options)
        pts = np.concatenate([pts, new])
        vel = np.concatenate([vel, np.zeros_like(new)])
        track = np.concatenate([track, np.arange(next_id, next_id + len(new))])
        next_id += len(new)
        keypoints.append(pts.copy())
        ids.append(track.copy())
        prev = image
    return FrameTracks(keypoints, ids)


def _step(prev: np.ndarray, image: np.ndarray, pts: np.ndarray, vel: np.ndarray,
          track: np.ndarray, lk: dict, options: KltOptions):
    """Follow ``pts`` from ``prev`` into ``image``; returns the surviving (pts, vel, track)."""
    guess = (pts + vel).astype(np.float32)
    nxt, ok, err = cv2.calcOpticalFlowPyrLK(prev, image, pts, guess.copy(),
                                          flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    back, ok_back, _ = cv2.calcOpticalFlowPyrLK(image, prev, nxt, pts.copy(),
                                                flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    h, w = image.shape[:2]
    fb = np.linalg.norm(back - pts, axis=1)
    keep = ((ok.ravel() == 1) & (ok_back.ravel() == 1) & (fb < options.max_fb_error_px)
            & (err.ravel() < options.max_patch_error)
            & (nxt[:, 0] >= 0) & (nxt[:, 0] <= w - 1) & (nxt[:, 1] >= 0) & (nxt[:, 1] <= h - 1))
    return nxt[keep], (nxt - pts)[keep], track[keep]


def _new_corners(image: np.ndarray, pts: np.ndarray, options: KltOptions) -> np.ndarray:
    """(K, 2) float32 corners away from the tracked ``pts``, up to ``max_corners`` in all."""
    want = options.max_corners - len(pts)
    if want <= options.max_corners // 10:  # topping up a few corners is not worth a detection
        return np.zeros((0, 2), np.float32)
    mask = np.full(image.shape[:2], 255, np.uint8)
    for x, y in np.round(pts).astype(int):
        cv2.circle(mask, (int(x), int(y)), options.min_distance_px, 0, -1)
    corners = cv2.goodFeaturesToTrack(image, maxCorners=want, qualityLevel=options.quality_level,
                                      minDistance=options.min_distance_px, mask=mask)
    if corners is None:
        return np.zeros((0, 2), np.float32)
    return corners.reshape(-1, 2).astype(np.float32)


def klt_correspondences(frame_idx: np.ndarray, images: Iterable[np.ndarray],
                        frame_names: list[str], camera: CameraModel | None, *, step: int,
                        overlap: int, options: KltOptions = KltOptions(), min_matches: int = 15
                        ) -> ImportedFeatures:
    """KLT correspondences for COLMAP over the frames ``frame_idx`` (sorted; ``images`` are those
    frames, 8-bit grayscale, in the same order). Tracks break where two of them are more than
    ``step`` frames apart. Every pair up to ``overlap`` frames of ``frame_idx`` apart, with no
    break between them and at least ``min_matches`` shared tracks, is a tentative pair (COLMAP
    verifies it).

    Tracking every frame instead of every ``step``-th gave the same calibration accuracy on
    turn-70 (0.33 px either way), so only the mapped frames are read and tracked."""
    frame_idx = np.asarray(frame_idx, dtype=int)
    broken = np.concatenate([[False], np.diff(frame_idx) > step])

    def with_breaks():
        for image, brk in zip(images, broken):
            if brk:
                yield None
            yield image

    tracks = track_features(with_breaks(), options)
    segment = np.cumsum(broken)  # no track crosses from one segment into the next
    matches = {}
    for k1 in range(len(frame_idx)):
        for k2 in range(k1 + 1, min(len(frame_idx), k1 + overlap + 1)):
            if segment[k2] != segment[k1]:
                break
            m = tracks.pair_matches(k1, k2)
            if len(m) >= min_matches:
                matches[(k1, k2)] = m
    return ImportedFeatures([frame_names[i] for i in frame_idx], tracks.keypoints_px, matches,
                            camera)
