"""Poses of frames the ego-motion skipped, interpolated between the frames it posed.

Ego-motion maps every ``ego_frame_step``-th frame near the signs, but a sign is detected in
every frame: without a pose, half its detections (at step 2) are never used. Between two posed
frames a fraction of a second apart a car's path and heading are smooth, so a skipped frame's
pose is interpolated in the frame index (frames come at a constant rate): centres by a cubic
spline through the run of posed frames around it (a straight chord would cut a 10 m radius turn
by 5 cm between posed frames 2 m apart), rotations by Slerp (exact at a constant turn rate). A
frame is filled only between posed frames at most ``max_gap`` apart; each spline spans one run
of such frames, so it never reaches across a gap the ego-motion left (a window that failed, a
bridge between stretches) or past the ends.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, Slerp


def fill_skipped(frame_idx: np.ndarray, T_world_cam: np.ndarray, wanted: np.ndarray,
                 max_gap: int) -> tuple[np.ndarray, np.ndarray]:
    """(frame_idx (F',), T_world_cam (F', 4, 4)): the posed frames ``frame_idx`` (F,) sorted,
    with poses ``T_world_cam`` (F, 4, 4), plus each frame of ``wanted`` that lies between two
    posed frames at most ``max_gap`` apart, its pose interpolated; sorted by frame. With
    nothing to fill, the inputs themselves."""
    frame_idx = np.asarray(frame_idx)
    wanted = np.setdiff1d(np.asarray(wanted), frame_idx)
    if max_gap < 2 or len(frame_idx) < 2 or len(wanted) == 0:
        return frame_idx, T_world_cam
    # Runs of posed frames with no gap over max_gap between neighbours.
    run_starts = np.flatnonzero(np.diff(frame_idx) > max_gap) + 1
    filled_idx, filled_T = [frame_idx], [T_world_cam]
    for run in np.split(np.arange(len(frame_idx)), run_starts):
        if len(run) < 2:
            continue
        t = frame_idx[run]
        fill = wanted[(wanted > t[0]) & (wanted < t[-1])]
        if len(fill) == 0:
            continue
        T_fill = np.tile(np.eye(4), (len(fill), 1, 1))
        centres = T_world_cam[run, :3, 3]
        T_fill[:, :3, 3] = (CubicSpline(t, centres)(fill) if len(run) >= 3
                            else np.array([np.interp(fill, t, c) for c in centres.T]).T)
        T_fill[:, :3, :3] = Slerp(t, Rotation.from_matrix(T_world_cam[run, :3, :3]))(
            fill).as_matrix()
        filled_idx.append(fill)
        filled_T.append(T_fill)
    if len(filled_idx) == 1:
        return frame_idx, T_world_cam
    all_idx = np.concatenate(filled_idx)
    order = np.argsort(all_idx, kind="stable")
    return all_idx[order], np.concatenate(filled_T)[order]
