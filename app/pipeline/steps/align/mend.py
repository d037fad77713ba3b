"""A broken window mended: one whose own alignment leaves more GPS residual than the limit
(``place_signs.alignment_limit_m``: 5x the GPS's noise, at least 1 m), whose signs would
otherwise all be rejected.

What it mends is the GPS: a run of fixes metres off (multipath by a building, a receiver's jump)
while one similarity follows the rest, at least two thirds of the window's fixes, as closely as a
good window follows its own (``GOOD_SHARE_OF_LIMIT``). Over those the reconstruction holds, so
the window is aligned on them and the run left out. Frames of the run that lie between followed
fixes keep their poses (the reconstruction holds across them); a run at the window's end looks
the same as a reconstruction whose end bent, so those frames keep their poses only out to the
farthest one a good neighbouring window poses within the limit of the same place, and are left
unposed otherwise.

A reconstruction that broke is not mended: cut into parts each aligned on its own, a window
whose reconstruction had broken with its self-calibration (corpus c0114, seed 100) placed its
signs 2.7-8.2 m off, five of them counted false (docs/decisions/broken-window-mend.md). Its
signs are refused with the reason, as before. Frames: model (a window's reconstruction) and
world (the journey's ENU, metres), as in ``window``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from app.pipeline.geometry.similarity import Sim3, align_trajectory
from app.pipeline.steps.align.window import AlignedWindow, fit_rows
from app.pipeline.steps.ego_motion import WindowPoses

# The fixes a whole reconstruction follows must be most of the window's, and follow it as a good
# window does (<= 3.1x the GPS noise, docs/decisions/broken-window-limit.md: 0.6 of the limit).
GPS_RUN_MIN_SHARE = 2 / 3
GOOD_SHARE_OF_LIMIT = 0.6


@dataclass(frozen=True)
class Mend:
    """What became of a broken window: ``window`` replaces it in the alignment (still broken
    when ``info["broken"]``); ``how`` says it in one line."""

    window: AlignedWindow
    how: str

    @property
    def mended(self) -> bool:
        return not self.window.info.get("broken")


def mend_window(window: AlignedWindow, xyz_gps: np.ndarray, limit_m: float, *,
                xyz_check: np.ndarray | None = None, trusted: np.ndarray | None = None,
                min_frames: int = 10, neighbours: Sequence[AlignedWindow] = ()) -> Mend:
    """``window`` (its ``info["rms_m"]`` over ``limit_m``) mended where a run of bad fixes
    explains it. ``xyz_gps`` (N, 3): the positions windows are fitted to; ``xyz_check`` (N, 3):
    those they are judged against (the fixes as read, where ``xyz_gps`` is smoothed; default
    ``xyz_gps``); ``trusted`` (N,) bool as in ``fit_rows``; ``min_frames``: the fewest fixes it
    is aligned on; ``neighbours``: the windows that are not broken, which may vouch for it."""
    xyz_check = xyz_gps if xyz_check is None else xyz_check
    frame_idx, T_model_cam = window.poses.frame_idx, window.poses.T_model_cam
    rows = fit_rows(frame_idx, trusted)
    followed = _followed(window, xyz_gps, xyz_check, limit_m, rows, min_frames)
    if followed is None:
        return Mend(replace(window, info={**window.info, "broken": True}),
                    "not mended: no similarity follows two thirds of its fixes as a good window "
                    "does (its reconstruction broke, or the GPS over most of it)")
    sim, info, use, off_m = followed
    T_world_cam = sim.apply_poses(T_model_cam)
    inside = np.flatnonzero(use)
    keep = _kept(frame_idx, T_world_cam, inside, list(neighbours), limit_m)
    left_out = rows & ~use
    rms_m = float(np.sqrt(np.mean(off_m[use] ** 2)))
    run = frame_idx[left_out]
    how = (f"mended: the GPS was off by up to {off_m[left_out].max():.1f} m at {left_out.sum()} "
           f"frames within {run.min()}-{run.max()}; aligned without them ({rms_m:.2f} m)")
    if inside.min() > 0 or inside.max() < len(frame_idx) - 1:
        how += ("; a neighbouring window agrees" if keep.all() else
                f"; frames {_unkept(frame_idx, keep)} past the fixes it follows left unposed "
                "(bad fixes or a bent end: the window alone cannot tell)")
    poses = WindowPoses((int(frame_idx[keep][0]), int(frame_idx[keep][-1]) + 1), frame_idx[keep],
                        T_model_cam[keep])
    return Mend(AlignedWindow(poses, sim, {**window.info, **info, "rms_m": rms_m,
                                           "rms_broken_m": window.info["rms_m"],
                                           "gps_left_out": int(left_out.sum()), "broken": False},
                              T_world_cam[keep]), how)


def _followed(window: AlignedWindow, xyz_gps: np.ndarray, xyz_check: np.ndarray, limit_m: float,
              rows: np.ndarray, min_frames: int
              ) -> tuple[Sim3, dict, np.ndarray, np.ndarray] | None:
    """(similarity, its info, (K,) bool the fixes it follows, (K,) distance of every frame from
    its fix) of the similarity that follows most of the window's fixes (``rows``), each within
    the limit; None when it follows fewer than ``GPS_RUN_MIN_SHARE`` of them or ``min_frames``,
    or not as closely as a good window (rms over ``GOOD_SHARE_OF_LIMIT`` of the limit)."""
    frame_idx, T_model_cam = window.poses.frame_idx, window.poses.T_model_cam
    centres = T_model_cam[:, :3, 3]
    # A fix is followed within the limit: a good window's fixes lie up to it (its rms, not each
    # fix, is 0.6 of it), and so may the first frames past a bend.
    use = rows.copy()
    for k in range(5):
        try:  # started by LO-RANSAC: a plain fit is pulled off by the very run it should find
            sim, info = align_trajectory(centres[use], xyz_gps[frame_idx[use]],
                                         T_model_cam[use, :3, :3], R_fallback=window.sim.R,
                                         robust_max_error_m=limit_m if k == 0 else None)
        except ValueError:
            return None
        off_m = np.linalg.norm(sim.apply(centres) - xyz_check[frame_idx], axis=1)
        now = rows & (off_m <= limit_m)
        if np.array_equal(now, use) or now.sum() < 3:
            break
        use = now
    if use.sum() < max(min_frames, GPS_RUN_MIN_SHARE * rows.sum()) or not (rows & ~use).any():
        return None
    if np.sqrt(np.mean(off_m[use] ** 2)) > GOOD_SHARE_OF_LIMIT * limit_m:
        return None
    return sim, info, use, off_m


def _kept(frame_idx: np.ndarray, T_world_cam: np.ndarray, inside: np.ndarray,
          neighbours: list[AlignedWindow], limit_m: float) -> np.ndarray:
    """(K,) bool, the frames that keep their poses: from the first followed fix (rows
    ``inside``) to the last, and outwards from them as far as the farthest frame a good
    neighbour poses within ``limit_m`` of where ``T_world_cam`` (K, 4, 4) does, stopping at one
    it poses further off. A reconstruction that holds there poses the frames between too."""
    first, last = inside.min(), inside.max()
    keep = np.zeros(len(frame_idx), bool)
    keep[first:last + 1] = True
    for outwards in (range(first - 1, -1, -1), range(last + 1, len(frame_idx))):
        reach = None
        for r in outwards:
            gaps = [float(np.linalg.norm(w.T_world_cam[at, :3, 3] - T_world_cam[r, :3, 3],
                                         axis=1).min())
                    for w in neighbours if (at := w.poses.frame_idx == frame_idx[r]).any()]
            if gaps and min(gaps) > limit_m:
                break
            if gaps:
                reach = r
        if reach is not None:
            keep[min(reach, first):max(reach, last) + 1] = True
    return keep


def _unkept(frame_idx: np.ndarray, keep: np.ndarray) -> str:
    """"a-b, c-d": the frames before the first kept one and after the last."""
    rows = np.flatnonzero(keep)
    first, last = rows.min(), rows.max()
    return ", ".join(([f"{frame_idx[0]}-{frame_idx[first - 1]}"] if first > 0 else [])
                     + ([f"{frame_idx[last + 1]}-{frame_idx[-1]}"]
                        if last < len(frame_idx) - 1 else []))
