"""One window aligned on its own: the similarity that maps its reconstruction onto its frames'
GPS positions, and which of those positions may take part (``fit_rows``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.pipeline.geometry.similarity import Sim3, align_trajectory
from app.pipeline.steps.ego_motion import WindowPoses


@dataclass(frozen=True)
class AlignedWindow:
    poses: WindowPoses
    sim: Sim3
    info: dict
    T_world_cam: np.ndarray  # (K, 4, 4) aligned poses of poses.frame_idx


def align_window(poses: WindowPoses, xyz_gps: np.ndarray,
                 trusted: np.ndarray | None = None) -> AlignedWindow:
    """Full alignment of one window; ``xyz_gps`` (N, 3) is the whole journey's metric GPS,
    ``trusted`` (N,) bool the frames whose GPS position may be used (``fit_rows``)."""
    use = fit_rows(poses.frame_idx, trusted)
    centres = poses.T_model_cam[use, :3, 3]
    sim, info = align_trajectory(centres, xyz_gps[poses.frame_idx[use]],
                                 poses.T_model_cam[use, :3, :3])
    return AlignedWindow(poses, sim, info, sim.apply_poses(poses.T_model_cam))


# A window needs this many frames, and this share of its own, with trusted GPS positions to be
# aligned by those alone; else by all its frames, as before the dropout mask.
MIN_TRUSTED_FRAMES = 6
MIN_TRUSTED_SHARE = 1 / 3


def fit_rows(frame_idx: np.ndarray, trusted: np.ndarray | None) -> np.ndarray:
    """(K,) bool over a window's frames ``frame_idx``: those whose GPS position aligns and judges
    it. ``trusted`` (N,) bool over the journey's frames (None: all; ``gps_track.in_dropout``
    marks the rest)."""
    if trusted is None:
        return np.ones(len(frame_idx), bool)
    use = np.asarray(trusted, bool)[frame_idx]
    if use.sum() < max(MIN_TRUSTED_FRAMES, MIN_TRUSTED_SHARE * len(frame_idx)):
        return np.ones(len(frame_idx), bool)
    return use


def centre_rms_m(T_world_cam: np.ndarray, xyz: np.ndarray) -> float:
    """Rms distance (m) of the camera centres of ``T_world_cam`` (K, 4, 4) from ``xyz`` (K, 3)."""
    return float(np.sqrt(np.mean(np.sum((T_world_cam[:, :3, 3] - xyz) ** 2, axis=1))))


def shared_rows(a: WindowPoses, b: WindowPoses) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``a`` and of ``b`` that pose the same journey frames, (S,) each, in frame order."""
    _, rows_a, rows_b = np.intersect1d(a.frame_idx, b.frame_idx, assume_unique=True,
                                       return_indices=True)
    return rows_a, rows_b
