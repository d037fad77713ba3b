"""Ego-motion of the calibrated camera, only where it is needed: in windows around the sign tracks.

Each sign needs camera poses for the frames that see it plus a margin of frames for a well-conditioned
alignment to GPS (the paper's best results came from such short trajectories). Tracks whose windows
overlap share one reconstruction; a window never grows past ``ego_max_frames_per_window`` so mapping
cost stays linear in the journey length. COLMAP maps each window with the intrinsics held fixed at the
self-calibrated values; its camera model applies the calibrated distortion exactly, which is the same
geometry as undistorting the images first without resampling them (no interpolation blur, no time).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.pipeline.colmap_sfm import WindowRequest, WindowResult
from app.pipeline.types import CameraModel, Detection


@dataclass(frozen=True)
class SignTrack:
    """Detections of one physical sign: ``frame_idx`` (M,) indices into the journey's frames (sorted),
    ``px`` (M, 2) box centres in the original distorted image (OpenCV pixels)."""

    track_id: str
    cls: str
    frame_idx: np.ndarray
    px: np.ndarray

    @property
    def span(self) -> tuple[int, int]:
        return int(self.frame_idx[0]), int(self.frame_idx[-1]) + 1


def sign_tracks(detections: list[Detection], frame_ids: list[str]) -> list[SignTrack]:
    """Group detections by track id; one detection per frame (the highest score wins)."""
    index = {f: i for i, f in enumerate(frame_ids)}
    by_track: dict[str, dict[int, Detection]] = {}
    for det in detections:
        frames = by_track.setdefault(det.track_id, {})
        i = index[det.frame_id]
        if i not in frames or (det.score or 0.0) > (frames[i].score or 0.0):
            frames[i] = det
    tracks = []
    for track_id, frames in by_track.items():
        order = sorted(frames)
        classes = [frames[i].cls for i in order]
        cls = max(set(classes), key=classes.count)
        tracks.append(SignTrack(track_id, cls, np.array(order, dtype=int),
                                np.array([frames[i].centre_px for i in order], dtype=float)))
    return sorted(tracks, key=lambda t: (t.span, t.track_id))


def plan_windows(tracks: list[SignTrack], n_frames: int, *, margin: int,
                 max_frames: int) -> list[tuple[int, int]]:
    """Frame ranges [start, end) to reconstruct so that every track lies inside one of them."""
    windows: list[tuple[int, int]] = []
    for track in sorted(tracks, key=lambda t: t.span):
        a, b = track.span
        a, b = max(0, a - margin), min(n_frames, b + margin)
        if windows and a <= windows[-1][1] and max(b, windows[-1][1]) - windows[-1][0] <= max_frames:
            windows[-1] = (windows[-1][0], max(b, windows[-1][1]))
        elif not any(wa <= a and b <= wb for wa, wb in windows):
            windows.append((a, b))
    return windows


def requests(windows: list[tuple[int, int]], frame_names: list[str], camera: CameraModel, *,
             step: int = 1, position_priors: bool = False) -> list[WindowRequest]:
    """One mapping request per window, every ``step``-th frame (at 10 frames/s consecutive frames
    add little geometry but cost extraction, matching and registration time)."""
    return [WindowRequest([frame_names[i] for i in range(a, b, step)], camera,
                          use_position_priors=position_priors) for a, b in windows]


@dataclass(frozen=True)
class WindowPoses:
    """A window's reconstruction: ``frame_idx`` (K,) journey frame indices of the registered frames,
    ``T_model_cam`` (K, 4, 4) in the window's own model frame (arbitrary scale)."""

    window: tuple[int, int]
    frame_idx: np.ndarray
    T_model_cam: np.ndarray


def window_poses(windows: list[tuple[int, int]], results: list[WindowResult],
                 frame_names: list[str]) -> list[WindowPoses]:
    index = {name: i for i, name in enumerate(frame_names)}
    return [WindowPoses(w, np.array([index[n] for n in r.image_names], dtype=int), r.T_model_cam)
            for w, r in zip(windows, results) if len(r.image_names) >= 3]
