"""Scale and place monocular reconstructions in the metric GPS frame (the paper's eq. 5-6).

``full`` aligns each reconstructed window with one Umeyama similarity over all its frames; ``short``
(the paper's best) aligns again over only the frames around one sign, which follows local scale
drift. A short stretch of straight road leaves the roll about the road undetermined by positions;
``alignment.align_trajectory`` then borrows the rotation from the window's full alignment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.pipeline.alignment import Sim3, align_trajectory
from app.pipeline.ego_motion import SignTrack, WindowPoses


@dataclass(frozen=True)
class AlignedWindow:
    poses: WindowPoses
    sim: Sim3
    info: dict
    T_world_cam: np.ndarray  # (K, 4, 4) aligned poses of poses.frame_idx


def align_window(poses: WindowPoses, xyz_gps: np.ndarray) -> AlignedWindow:
    """Full alignment of one window; ``xyz_gps`` (N, 3) is the whole journey's metric GPS."""
    centres = poses.T_model_cam[:, :3, 3]
    sim, info = align_trajectory(centres, xyz_gps[poses.frame_idx], poses.T_model_cam[:, :3, :3])
    return AlignedWindow(poses, sim, info, sim.apply_poses(poses.T_model_cam))


@dataclass(frozen=True)
class TrackPoses:
    """Aligned poses of the track's frames that were reconstructed: ``keep`` (M,) bool mask over the
    track's detections, ``T_world_cam`` (keep.sum(), 4, 4)."""

    keep: np.ndarray
    T_world_cam: np.ndarray
    alignment_rms_m: float


def track_poses(track: SignTrack, windows: list[AlignedWindow], xyz_gps: np.ndarray, *,
                mode: str, margin: int, min_frames: int) -> TrackPoses | None:
    """Poses for a sign's frames from the window that reconstructed most of them."""
    def coverage(w: AlignedWindow) -> int:
        return int(np.isin(track.frame_idx, w.poses.frame_idx).sum())

    best = max(windows, key=coverage, default=None)
    if best is None or coverage(best) < 2:
        return None
    frame_idx = best.poses.frame_idx
    keep = np.isin(track.frame_idx, frame_idx)
    rows = np.searchsorted(frame_idx, track.frame_idx[keep])
    if mode == "full":
        return TrackPoses(keep, best.T_world_cam[rows], float(best.info["rms_m"]))
    a, b = track.span
    near = (frame_idx >= a - margin) & (frame_idx < b + margin)
    if near.sum() < min_frames:
        return TrackPoses(keep, best.T_world_cam[rows], float(best.info["rms_m"]))
    T_model_cam = best.poses.T_model_cam[near]
    try:
        sim, info = align_trajectory(T_model_cam[:, :3, 3], xyz_gps[frame_idx[near]],
                                     T_model_cam[:, :3, :3], R_fallback=best.sim.R)
    except ValueError:  # the car stood still by this sign: the window's alignment must do
        return TrackPoses(keep, best.T_world_cam[rows], float(best.info["rms_m"]))
    return TrackPoses(keep, sim.apply_poses(best.poses.T_model_cam[rows]), float(info["rms_m"]))
