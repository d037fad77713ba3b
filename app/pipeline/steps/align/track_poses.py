"""The aligned poses a sign is triangulated from (``track_poses``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.pipeline.geometry.similarity import align_trajectory
from app.pipeline.steps.align.window import AlignedWindow, centre_rms_m
from app.pipeline.steps.sign_tracks import SignTrack


@dataclass(frozen=True)
class TrackPoses:
    """Aligned poses of the track's frames that were reconstructed: ``keep`` (M,) bool mask over the
    track's detections, ``T_world_cam`` (keep.sum(), 4, 4)."""

    keep: np.ndarray
    T_world_cam: np.ndarray
    alignment_rms_m: float  # GPS residual rms of the alignment that placed them
    alignment_n: int  # GPS fixes in that alignment
    # GPS residual rms of the window's (or chain's) own alignment: whether the reconstruction
    # broke is judged on it, since a fit over the few frames by a sign can follow a broken one.
    window_rms_m: float


def track_poses(track: SignTrack, windows: list[AlignedWindow], xyz_gps: np.ndarray, *,
                mode: str, margin: int, min_frames: int, local_weight: float = 1.0,
                trusted: np.ndarray | None = None) -> TrackPoses | None:
    """Poses for a sign's frames. ``full``: from the window that reconstructed most of them,
    completed by the windows aligned jointly with it; ``short``: that window alone, aligned again
    to the GPS around the sign (the paper's short trajectories); ``local``: the ``full`` poses,
    their chain aligned again to the GPS around the sign (so a sign spanning two windows keeps
    all its frames), that correction taken ``local_weight`` of the way (``Sim3.partial``): over
    a few seconds the GPS fixes scale about as well as the reconstruction holds it, so the best
    estimate lies between the two. ``trusted`` (N,) bool over the journey's frames:
    those whose GPS position may align the frames around the sign (None: all)."""
    def coverage(w: AlignedWindow) -> int:
        return int(np.isin(track.frame_idx, w.poses.frame_idx).sum())

    best = max(windows, key=coverage, default=None)
    if best is None or coverage(best) < 2:
        return None
    if mode == "full":
        return _chained_poses(track, best, windows)
    # The poses aligned again (``T_from_cam``: the chain's world poses, or the window's model
    # poses), and those already placed, which stand when they cannot be aligned again.
    if mode == "local":
        frame_idx, T_world_cam = _chain_trajectory(best, windows)
        T_from_cam, start_rotation = T_world_cam, np.eye(3)  # in the world: keep the chain's roll
    else:
        frame_idx, T_world_cam = best.poses.frame_idx, best.T_world_cam
        T_from_cam, start_rotation = best.poses.T_model_cam, best.sim.R
    keep = np.isin(track.frame_idx, frame_idx)
    rows = np.searchsorted(frame_idx, track.frame_idx[keep])
    placed = TrackPoses(keep, T_world_cam[rows], *_fit(best.info), best.info["rms_m"])
    a, b = track.span
    near = (frame_idx >= a - margin) & (frame_idx < b + margin)
    # A dropout's interpolated positions cut a bend's corner: over the few seconds by a sign
    # they would pull the poses by metres. Too few frames left: the window's own alignment,
    # which left them out, stands.
    if trusted is not None:
        near &= np.asarray(trusted, bool)[frame_idx]
    if near.sum() < min_frames:
        return placed
    try:
        sim, info = align_trajectory(T_from_cam[near, :3, 3], xyz_gps[frame_idx[near]],
                                     T_from_cam[near, :3, :3], R_fallback=start_rotation)
    except ValueError:  # the car stood still by this sign: the window's alignment must do
        return placed
    if mode == "local" and local_weight != 1.0:
        sim = sim.partial(local_weight, T_from_cam[near, :3, 3].mean(0))
        info = {**info, "rms_m": centre_rms_m(sim.apply_poses(T_from_cam[near]),
                                               xyz_gps[frame_idx[near]])}
    return TrackPoses(keep, sim.apply_poses(T_from_cam[rows]), *_fit(info), best.info["rms_m"])


def _fit(info: dict) -> tuple[float, int]:
    """(rms_m, n) of an alignment's info."""
    return float(info["rms_m"]), int(info.get("n", 0))


def _chain_trajectory(best: AlignedWindow, windows: list[AlignedWindow]
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(frame_idx (F,), T_world_cam (F, 4, 4)) of every frame posed by ``best`` or by the windows
    jointly aligned with it, sorted by frame; a frame two windows pose keeps ``best``'s pose."""
    group = best.info.get("group")
    chain = [best] + [w for w in windows if w is not best and group is not None
                      and w.info.get("group") == group]
    frame_idx, first = np.unique(np.concatenate([w.poses.frame_idx for w in chain]),
                                 return_index=True)
    return frame_idx, np.concatenate([w.T_world_cam for w in chain])[first]


def _chained_poses(track: SignTrack, best: AlignedWindow,
                   windows: list[AlignedWindow]) -> TrackPoses:
    """Poses of the track's frames from ``best`` and, for frames it did not pose, from the other
    windows jointly aligned with it (they agree on shared frames to millimetres, so a sign may
    span two windows of a chain)."""
    frame_idx, T_world_cam = _chain_trajectory(best, windows)
    keep = np.isin(track.frame_idx, frame_idx)
    rows = np.searchsorted(frame_idx, track.frame_idx[keep])
    return TrackPoses(keep, T_world_cam[rows], *_fit(best.info), best.info["rms_m"])
