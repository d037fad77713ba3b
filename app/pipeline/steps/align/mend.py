"""A broken window mended: one whose own alignment leaves more GPS residual than the limit
(``place_signs.alignment_limit_m``: 5x the GPS's noise, at least 1 m), whose signs would
otherwise all be rejected.

Two faults leave that residual, and where it lies tells them apart:

- **the GPS**: a run of fixes metres off (multipath by a building, a receiver's jump) between
  fixes that one similarity follows to the GPS's noise, or at the window's end where a good
  neighbouring window poses those frames as that similarity does. The reconstruction is whole;
  it is aligned on those fixes and the run is left out (``_without_gps_run``).
- **the reconstruction**: it bent at one frame (its scale or heading changed through a sharp
  turn, or depth was poorly known at a slow start), and each side is a good reconstruction by
  itself: each side is aligned on its own (``_split``), and a side that still disagrees is split
  once more. The sides must meet where they were cut: a bend leaves the path whole, a side that
  followed bad fixes leaves it jumping (``_continuous``).

What neither explains stays broken, and its signs are rejected with the reason. Frames: model
(a window's reconstruction) and world (the journey's ENU, metres), as in ``window``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from app.pipeline.geometry.similarity import align_trajectory
from app.pipeline.steps.align.window import AlignedWindow, align_window, fit_rows
from app.pipeline.steps.ego_motion import WindowPoses

# The fixes a whole reconstruction follows must be most of the window's, and follow it as a good
# window does (<= 3.1x the GPS noise, docs/decisions/broken-window-limit.md: 0.6 of the limit).
GPS_RUN_MIN_SHARE = 2 / 3
GOOD_SHARE_OF_LIMIT = 0.6
# A piece must travel this many limits: over a shorter path, a similarity follows any bend
# and its scale is the GPS noise's.
PIECE_MIN_EXTENT_LIMITS = 4.0
SPLIT_DEPTH = 2


@dataclass(frozen=True)
class Mend:
    """What became of a broken window: ``pieces`` replace it in the alignment (those whose
    ``info["rms_m"]`` is still over the limit stay broken); ``how`` says it in one line."""

    pieces: list[AlignedWindow]
    how: str

    @property
    def mended(self) -> bool:
        return any(not p.info.get("broken") for p in self.pieces)


def mend_window(window: AlignedWindow, xyz_gps: np.ndarray, limit_m: float, *,
                xyz_check: np.ndarray | None = None, trusted: np.ndarray | None = None,
                min_frames: int = 10, neighbours: Sequence[AlignedWindow] = ()) -> Mend:
    """``window`` (its ``info["rms_m"]`` over ``limit_m``) mended where it can be.
    ``xyz_gps`` (N, 3): the positions windows are fitted to; ``xyz_check`` (N, 3): those they are
    judged against (the fixes as read, where ``xyz_gps`` is smoothed; default ``xyz_gps``);
    ``trusted`` (N,) bool as in ``fit_rows``; ``min_frames``: the fewest fixes a piece is
    aligned on; ``neighbours``: the windows that are not broken, which may vouch for it."""
    xyz_check = xyz_gps if xyz_check is None else xyz_check
    whole = _without_gps_run(window, xyz_gps, xyz_check, limit_m, trusted, min_frames,
                             list(neighbours))
    if whole is not None:
        return whole
    pieces = _split(window, xyz_gps, xyz_check, limit_m, trusted, min_frames, SPLIT_DEPTH,
                    list(neighbours))
    if pieces is None:
        return Mend([_judged(window, xyz_check, limit_m, trusted)],
                    "not mended: no GPS run explains it and it is too short to align in parts")
    good = [p for p in pieces if not p.info.get("broken")]
    parts = ", ".join(f"{p.poses.window[0]}-{p.poses.window[1] - 1} {p.info['rms_m']:.2f} m"
                      + (f" (the path jumps {p.info['cut_jump_m']:.1f} m where it was cut)"
                         if "cut_jump_m" in p.info else
                         " (still broken)" if p.info.get("broken") else "") for p in pieces)
    if not good:
        return Mend([_judged(window, xyz_check, limit_m, trusted)],
                    f"not mended: aligned in parts it still disagrees ({parts})")
    # A bend, or bad fixes in a part left broken: the window alone cannot tell which.
    return Mend(pieces, f"mended: aligned in {len(pieces)} parts, each on its own ({parts})")


def _without_gps_run(window: AlignedWindow, xyz_gps: np.ndarray, xyz_check: np.ndarray,
                     limit_m: float, trusted: np.ndarray | None, min_frames: int,
                     neighbours: list[AlignedWindow]) -> Mend | None:
    """The window aligned on the fixes one similarity follows, when those left out lie between
    them, or a good neighbour poses them where this alignment does."""
    frame_idx, T_model_cam = window.poses.frame_idx, window.poses.T_model_cam
    rows = fit_rows(frame_idx, trusted)
    centres = T_model_cam[:, :3, 3]
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
        if now.sum() < max(min_frames, GPS_RUN_MIN_SHARE * rows.sum()):
            return None
        if np.array_equal(now, use):
            break
        use = now
    left_out = rows & ~use
    inside = np.flatnonzero(use)
    rms_m = float(np.sqrt(np.mean(off_m[use] ** 2)))
    if not left_out.any() or rms_m > GOOD_SHARE_OF_LIMIT * limit_m:
        return None
    T_world_cam = sim.apply_poses(T_model_cam)
    bracketed = inside.min() < np.flatnonzero(left_out).min() <= np.flatnonzero(
        left_out).max() < inside.max()
    # At the window's end a bent reconstruction looks the same; a good neighbour that poses
    # those frames where this alignment puts them says the reconstruction held.
    gap_m = _disagreement_m(frame_idx[left_out], T_world_cam[left_out], neighbours)
    vouched = not bracketed and gap_m is not None and gap_m <= limit_m
    if not (bracketed or vouched):
        return None
    run = frame_idx[left_out]
    mended = AlignedWindow(window.poses, sim,
                           {**window.info, **info, "rms_m": rms_m, "rms_broken_m":
                            window.info["rms_m"], "gps_left_out": int(left_out.sum()),
                            "broken": False}, T_world_cam)
    return Mend([mended], f"mended: the GPS was off by up to {off_m[left_out].max():.1f} m at "
                          f"{left_out.sum()} frames within {run.min()}-{run.max()}"
                          f"{' (a neighbouring window agrees)' if vouched else ''}; aligned "
                          f"without them ({rms_m:.2f} m)")


def _disagreement_m(frame_idx: np.ndarray, T_world_cam: np.ndarray,
                    neighbours: list[AlignedWindow]) -> float | None:
    """The largest distance (m) between a centre of ``T_world_cam`` (K, 4, 4), posing frames
    ``frame_idx`` (K,), and the same frame's centre in ``neighbours``; None: they share none."""
    gaps = [np.linalg.norm(w.T_world_cam[w.poses.frame_idx == f, :3, 3] - T[:3, 3], axis=1)
            for w in neighbours for f, T in zip(frame_idx, T_world_cam)
            if (w.poses.frame_idx == f).any()]
    return float(np.max(np.concatenate(gaps))) if gaps else None


def _piece(poses: WindowPoses, rows: slice) -> WindowPoses:
    idx = poses.frame_idx[rows]
    return WindowPoses((int(idx[0]), int(idx[-1]) + 1), idx, poses.T_model_cam[rows])


def _judged(piece: AlignedWindow, xyz_check: np.ndarray, limit_m: float,
            trusted: np.ndarray | None, neighbours: Sequence[AlignedWindow] = ()
            ) -> AlignedWindow:
    """``piece`` with its residual to the fixes as read (``info["rms_m"]``) and whether it is
    broken (``info["broken"]``): that residual more than a good window's (``GOOD_SHARE_OF_LIMIT``
    of the limit: a piece fits fewer fixes, and a reconstruction wrong within it still follows
    them to 4x their noise), or its frames posed more than the limit away from where a good
    neighbour poses them (a short piece follows a run of bad fixes at a window's end as well as
    it follows good ones)."""
    use = fit_rows(piece.poses.frame_idx, trusted)
    off = piece.T_world_cam[use, :3, 3] - xyz_check[piece.poses.frame_idx[use]]
    rms_m = float(np.sqrt(np.mean(np.sum(off ** 2, axis=1))))
    gap_m = _disagreement_m(piece.poses.frame_idx, piece.T_world_cam, list(neighbours))
    return replace(piece, info={**piece.info, "rms_m": rms_m,
                                "broken": rms_m > GOOD_SHARE_OF_LIMIT * limit_m
                                or (gap_m is not None and gap_m > limit_m)})


def _split(window: AlignedWindow, xyz_gps: np.ndarray, xyz_check: np.ndarray, limit_m: float,
           trusted: np.ndarray | None, min_frames: int, depth: int,
           neighbours: list[AlignedWindow]) -> list[AlignedWindow] | None:
    """The window in two pieces, cut where their own alignments leave the least residual; a
    piece still broken is split again while ``depth`` lasts. None: no cut leaves two pieces of
    ``min_frames`` fixes, each travelling ``PIECE_MIN_EXTENT_LIMITS`` limits."""
    poses = window.poses
    rows = np.flatnonzero(fit_rows(poses.frame_idx, trusted))
    best, best_cost = None, np.inf
    for k in range(min_frames, len(rows) - min_frames + 1):
        cut = rows[k]
        halves = [_piece(poses, slice(0, cut)), _piece(poses, slice(cut, None))]
        if any(_extent_m(xyz_check[h.frame_idx]) < PIECE_MIN_EXTENT_LIMITS * limit_m
               for h in halves):
            continue
        try:
            pieces = [_judged(align_window(h, xyz_gps, trusted), xyz_check, limit_m, trusted,
                              neighbours) for h in halves]
        except ValueError:
            continue
        cost = sum(len(p.poses.frame_idx) * p.info["rms_m"] ** 2 for p in pieces)
        if cost < best_cost:
            best, best_cost = pieces, cost
    if best is None:
        return None
    out = []
    for p in best:
        again = (_split(p, xyz_gps, xyz_check, limit_m, trusted, min_frames, depth - 1,
                        neighbours)
                 if p.info["broken"] and depth > 1 else None)
        out += again or [p]
    return _continuous(out, limit_m, neighbours) if depth == SPLIT_DEPTH else out


def _continuous(pieces: list[AlignedWindow], limit_m: float,
                neighbours: list[AlignedWindow]) -> list[AlignedWindow]:
    """``pieces`` (in frame order) with both sides of a cut marked broken where the path jumps
    there by more than ``limit_m`` beyond the step the pieces' speeds make, unless a good
    neighbour poses a side where it lies. A reconstruction that bent keeps the path whole once
    each side is aligned; a side that followed a run of bad fixes does not, and which side did
    cannot be told from the window alone."""
    broken = [bool(p.info.get("broken")) for p in pieces]
    jumps: dict[int, float] = {}
    for k, (a, b) in enumerate(zip(pieces, pieces[1:])):
        if broken[k] or broken[k + 1]:
            continue
        gap_m = np.linalg.norm(b.T_world_cam[0, :3, 3] - a.T_world_cam[-1, :3, 3])
        frames = b.poses.frame_idx[0] - a.poses.frame_idx[-1]
        step_m = frames * np.mean([_speed_m_per_frame(a, -1), _speed_m_per_frame(b, 0)])
        if abs(gap_m - step_m) > limit_m:
            for j, p in ((k, a), (k + 1, b)):
                vouch = _disagreement_m(p.poses.frame_idx, p.T_world_cam, neighbours)
                broken[j] = vouch is None or vouch > limit_m
                jumps[j] = max(jumps.get(j, 0.0), float(abs(gap_m - step_m)))
    return [replace(p, info={**p.info, "broken": True, "cut_jump_m": jumps[j]})
            if b and not p.info.get("broken") else p
            for j, (p, b) in enumerate(zip(pieces, broken))]


def _speed_m_per_frame(piece: AlignedWindow, end: int) -> float:
    """Distance per journey frame (m) of the piece's step at its start (``end`` 0) or its end
    (-1)."""
    rows = [0, 1] if end == 0 else [-2, -1]
    T, f = piece.T_world_cam[rows], piece.poses.frame_idx[rows]
    return float(np.linalg.norm(T[1, :3, 3] - T[0, :3, 3]) / max(f[1] - f[0], 1))


def _extent_m(xyz: np.ndarray) -> float:
    """Distance (m) between the first and the last of the positions (K, 3)."""
    return float(np.linalg.norm(xyz[-1] - xyz[0]))
