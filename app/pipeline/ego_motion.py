"""Ego-motion of the calibrated camera, only where it is needed: in windows around the sign tracks.

Each sign needs camera poses for the frames that see it plus a margin of frames for a well-conditioned
alignment to GPS (the paper's best results came from such short trajectories). Tracks whose windows
overlap share one reconstruction; a window never grows past ``ego_max_frames_per_window`` so mapping
cost stays linear in the journey length. A sign seen on two passes (a loop) is split into one track
per pass (``split_passes``), each mapped in its own short window.

Each reconstruction starts from two frames a few metres apart (``requests(init_gap_frames=...)``):
left to itself, COLMAP starts from the most-matched pair, i.e. neighbouring frames, and on loop-300
that short forward baseline towards a facade fixed a wrong relative pose which the whole window then
kept (bent trajectories, 2-8 m ATE after a similarity, 25 deg rotation drift in 30 frames, at
0.6 px mean reprojection error while the true poses fit the same feature tracks at 0.12 px). COLMAP maps each window with the intrinsics held fixed at the
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
    part: int = 0  # which pass of the sign, when ``split_passes`` cut its track

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


def split_passes(track: SignTrack, *, max_gap: int, max_frames: int) -> list[SignTrack]:
    """The passes of one track: cut where it goes unseen for more than ``max_gap`` frames (the car
    drove away and came back) and, within a pass, so that no part spans more than ``max_frames``
    frames. Each part keeps the track id; ``part`` numbers them in time order.

    A sign seen again after a loop would otherwise demand one window from the first sighting to the
    last, i.e. the whole journey, whose monocular reconstruction drifts in scale.
    """
    fi = track.frame_idx
    cuts = [0, *(np.flatnonzero(np.diff(fi) > max_gap) + 1).tolist(), len(fi)]
    pieces: list[tuple[int, int]] = []
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        start = lo
        for k in range(lo + 1, hi):
            if fi[k] - fi[start] >= max_frames:
                pieces.append((start, k))
                start = k
        pieces.append((start, hi))
    if len(pieces) == 1:
        return [track]
    return [SignTrack(track.track_id, track.cls, fi[lo:hi], track.px[lo:hi], part)
            for part, (lo, hi) in enumerate(pieces)]


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
             step: int = 1, position_priors: bool = False,
             init_gap_frames: int | None = None) -> list[WindowRequest]:
    """One mapping request per window, every ``step``-th frame (at 10 frames/s consecutive frames
    add little geometry but cost extraction, matching and registration time).

    ``init_gap_frames``: start each reconstruction from two frames about this far apart in the
    window's middle (``init_pair``) instead of COLMAP's most-matched pair. It must not exceed the
    sequential matching overlap, or the two frames may never have been matched.
    """
    out = []
    for a, b in windows:
        idx = list(range(a, b, step))
        out.append(WindowRequest([frame_names[i] for i in idx], camera,
                                 use_position_priors=position_priors,
                                 init_pair=_init_pair(idx, frame_names, step, init_gap_frames)))
    return out


def _init_pair(idx: list[int], frame_names: list[str], step: int,
               gap_frames: int | None) -> tuple[str, str] | None:
    """Names of two mapped frames ``gap_frames`` (rounded down to the step) apart around the middle
    of the window; None when no gap is asked for or the window is too short for it."""
    if gap_frames is None:
        return None
    k = max(1, gap_frames // step)
    if len(idx) <= k:
        return None
    first = max(0, (len(idx) - k) // 2)
    return frame_names[idx[first]], frame_names[idx[first + k]]


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
