"""Ego-motion of the calibrated camera, only where it is needed: near the sign tracks.

Each sign needs camera poses for the frames that see it plus a margin of frames for a
well-conditioned alignment to GPS. The frames near signs form stretches; each stretch is mapped as
a chain of windows of at most ``ego_max_frames_per_window`` frames that share a few frames with
their neighbours (``plan_windows``), so mapping cost stays linear in the journey length and every
frame is mapped about once; the shared frames let the alignment tie the chain together
(``align.align_windows``). A sign seen on two passes (a loop) has one track per pass
(``sign_tracks.split_passes``).

Correspondences come from KLT feature tracks (``colmap.klt_features``) by default, or from SIFT
(OpenCV's, ``colmap.cv_sift``) where the mapped frames lie metres apart. Each window starts from
two frames a few metres apart (``requests(init_gap_frames=...)``): left to itself, COLMAP starts
from the most-matched pair, i.e. neighbouring frames, and on loop-300 that short forward baseline
towards a facade fixed a wrong relative pose which the whole window then kept (bent trajectories,
2-8 m ATE after a similarity, at 0.6 px mean reprojection error while the true poses fit the same
tracks at 0.12 px). COLMAP maps each window with the intrinsics held fixed at the self-calibrated
values; its camera model applies the calibrated distortion exactly, which is the same geometry as
undistorting the images first without resampling them (no interpolation blur, no time).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.pipeline.colmap.sfm import WindowRequest, WindowResult
from app.pipeline.steps.sign_tracks import SignTrack
from app.pipeline.types import CameraModel, StageReport


def plan_windows(tracks: list[SignTrack], n_frames: int, *, margin: int, max_frames: int,
                 step: int = 1, overlap: int = 0, bridge_gap: int = 0) -> list[tuple[int, int]]:
    """Frame ranges [start, end) to reconstruct: every frame within ``margin`` of a sign track.

    The frames needed are merged into stretches (two closer than ``bridge_gap`` frames become one,
    so that the joint alignment to GPS can tie them together and average the GPS bias over the
    whole stretch); each stretch is cut into the fewest windows of at most ``max_frames`` frames in
    which consecutive windows share ``overlap`` frames. Windows start on multiples of ``step`` so
    that shared frames are mapped by both. A sign's frames may span two windows of a stretch:
    jointly aligned, they agree on their shared frames to millimetres (``align``), and
    every frame is mapped about once instead of once per sign window around it.
    """
    spans = sorted((max(0, a - margin), min(n_frames, b + margin)) for a, b in
                   (t.span for t in tracks))
    stretches: list[list[int]] = []
    for a, b in spans:
        if stretches and a <= stretches[-1][1] + bridge_gap:
            stretches[-1][1] = max(stretches[-1][1], b)
        else:
            stretches.append([a // step * step, b])
    windows = []
    longest = max(step, (max_frames - overlap) // step * step)  # stride between window starts
    for a, b in stretches:
        count = max(1, _ceil_div(b - a - overlap, longest))
        # Equal windows rather than full ones and a stub of a few frames that cannot be mapped.
        stride = _ceil_div(_ceil_div(b - a - overlap, count), step) * step
        starts = [a + k * stride for k in range(count)]
        windows += [(s, min(b, s + stride + overlap)) for s in starts[:-1]] + [(starts[-1], b)]
    return windows


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


def requests(windows: list[tuple[int, int]], frame_names: list[str], camera: CameraModel, *,
             step: int = 1, extra: np.ndarray = np.zeros(0, int),
             init_gap_frames: int | None = None, more_init_pairs: int = 0) -> list[WindowRequest]:
    """One mapping request per window: its frames on the ``step`` grid (at 10 frames/s
    consecutive frames add little geometry but cost tracking, matching and registration time),
    and those of the ``extra`` frames that fall inside it (``off_grid_frames``).

    ``init_gap_frames``: start each reconstruction from two frames about this far apart in the
    window's middle (``init_pair``) instead of COLMAP's most-matched pair. It must not exceed the
    matching overlap, or the two frames may never have been matched. ``more_init_pairs``: how
    many of the other pairs of ``_INIT_PAIRS`` to try when the window cannot start from that one,
    before COLMAP's own choice.
    """
    out = []
    for a, b in windows:
        idx = window_frames((a, b), step, extra)
        pairs: list[tuple[str, str]] = []
        for share, at in (_INIT_PAIRS[:1 + more_init_pairs] if init_gap_frames else ()):
            pair = _init_pair(list(range(a, b, step)), frame_names, step,
                              max(1, int(share * init_gap_frames)), at)
            if pair is not None and pair not in pairs:
                pairs.append(pair)
        out.append(WindowRequest(image_names=[frame_names[i] for i in idx], camera=camera,
                                 init_pair=pairs[0] if pairs else None,
                                 more_init_pairs=tuple(pairs[1:])))
    return out


# (gap as a share of init_gap_frames, where in the window): the first pair, then the others
# tried when a window cannot start from it.
_INIT_PAIRS = ((1.0, 0.5), (0.5, 0.5), (1.0, 0.25), (1.0, 0.75))


def _init_pair(idx: list[int], frame_names: list[str], step: int,
               gap_frames: int | None, at: float = 0.5) -> tuple[str, str] | None:
    """Names of two mapped frames ``gap_frames`` (rounded down to the step) apart around the
    ``at`` share of the window (0.5: its middle); None when no gap is asked for or the window is
    too short for it."""
    if gap_frames is None:
        return None
    k = max(1, gap_frames // step)
    if len(idx) <= k:
        return None
    first = int(at * (len(idx) - k))
    return frame_names[idx[first]], frame_names[idx[first + k]]


def off_grid_frames(tracks: list[SignTrack], step: int, min_frames: int) -> np.ndarray:
    """(E,) sorted frames to map besides the ``step`` grid: all frames of each track that has fewer
    than ``min_frames`` frames on the grid (a sign seen in 3 consecutive frames would otherwise
    keep 1 or 2 of them and could not be triangulated: 2 of loop-300's 22 signs)."""
    extra = {int(i) for t in tracks if (t.frame_idx % step == 0).sum() < min_frames
             for i in t.frame_idx if i % step}
    return np.array(sorted(extra), dtype=int)


def window_frames(window: tuple[int, int], step: int,
                  extra: np.ndarray = np.zeros(0, int)) -> list[int]:
    """Frames a window maps: every ``step``-th from its start, plus the ``extra`` inside it."""
    a, b = window
    inside = extra[(extra >= a) & (extra < b)]
    return sorted(set(range(a, b, step)) | set(inside.tolist()))


def mapped_frames(windows: list[tuple[int, int]], step: int,
                  extra: np.ndarray = np.zeros(0, int)) -> np.ndarray:
    """(F,) sorted journey frame indices that ``requests(windows, step=step, extra=extra)`` maps."""
    return np.array(sorted({i for w in windows for i in window_frames(w, step, extra)}), dtype=int)


@dataclass(frozen=True)
class WindowPoses:
    """A window's reconstruction: ``frame_idx`` (K,) journey frame indices of the registered frames,
    ``T_model_cam`` (K, 4, 4) in the window's own model frame (arbitrary scale)."""

    window: tuple[int, int]
    frame_idx: np.ndarray
    T_model_cam: np.ndarray


def window_poses(windows: list[tuple[int, int]], results: list[WindowResult],
                 frame_names: list[str]) -> list[WindowPoses]:
    """The reconstructed windows: those that registered at least 3 frames."""
    index = {name: i for i, name in enumerate(frame_names)}
    return [WindowPoses(w, np.array([index[n] for n in r.image_names], dtype=int), r.T_model_cam)
            for w, r in zip(windows, results) if len(r.image_names) >= 3]


def report(windows: list[tuple[int, int]], results: list[WindowResult],
           poses: list[WindowPoses]) -> StageReport:
    """The ego_motion stage's report: each window's registration, or why it failed."""
    details = tuple(f"frames {a}-{b - 1}: " + (r.error or f"{len(r.image_names)}/{r.n_input} "
                                                f"registered, {r.reprojection_error_px:.2f} px")
                    + f", mapped in {r.mapping_s:.1f} s" for (a, b), r in zip(windows, results))
    return StageReport("ego_motion", f"{len(poses)} of {len(windows)} windows reconstructed",
                       details)
