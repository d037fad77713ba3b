"""Ego-motion of the calibrated camera, only where it is needed: near the sign tracks.

Each sign needs camera poses for the frames that see it plus a margin of frames for a
well-conditioned alignment to GPS. The frames near signs form stretches; each stretch is mapped as
a chain of windows of at most ``ego_max_frames_per_window`` frames that share a few frames with
their neighbours (``plan_windows``), so mapping cost stays linear in the journey length and every
frame is mapped about once; the shared frames let the alignment tie the chain together
(``georeference.align_windows``). A sign seen on two passes (a loop) is split into one track per
pass (``split_passes``).

Correspondences come from KLT tracks (``track_features``, ``tracked_features``) by default, or from
COLMAP's SIFT. Each window starts from two frames a few metres apart (``requests(init_gap_frames=
...)``): left to itself, COLMAP starts from the most-matched pair, i.e. neighbouring frames, and on
loop-300 that short forward baseline towards a facade fixed a wrong relative pose which the whole
window then kept (bent trajectories, 2-8 m ATE after a similarity, at 0.6 px mean reprojection
error while the true poses fit the same tracks at 0.12 px). COLMAP maps each window with the
intrinsics held fixed at the self-calibrated values; its camera model applies the calibrated
distortion exactly, which is the same geometry as undistorting the images first without
resampling them (no interpolation blur, no time).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from app.pipeline.colmap_sfm import ImportedFeatures, WindowRequest, WindowResult
from app.pipeline.track_features import KltOptions, track_features
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


def plan_windows(tracks: list[SignTrack], n_frames: int, *, margin: int, max_frames: int,
                 step: int = 1, overlap: int = 0, bridge_gap: int = 0) -> list[tuple[int, int]]:
    """Frame ranges [start, end) to reconstruct: every frame within ``margin`` of a sign track.

    The frames needed are merged into stretches (two closer than ``bridge_gap`` frames become one,
    so that the joint alignment to GPS can tie them together and average the GPS bias over the
    whole stretch); each stretch is cut into the fewest windows of at most ``max_frames`` frames in
    which consecutive windows share ``overlap`` frames. Windows start on multiples of ``step`` so
    that shared frames are mapped by both. A sign's frames may span two windows of a stretch:
    jointly aligned, they agree on their shared frames to millimetres (``georeference``), and
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
             step: int = 1, extra: np.ndarray = np.zeros(0, int), position_priors: bool = False,
             init_gap_frames: int | None = None) -> list[WindowRequest]:
    """One mapping request per window: its frames on the ``step`` grid (at 10 frames/s
    consecutive frames add little geometry but cost tracking, matching and registration time),
    and those of the ``extra`` frames that fall inside it (``off_grid_frames``).

    ``init_gap_frames``: start each reconstruction from two frames about this far apart in the
    window's middle (``init_pair``) instead of COLMAP's most-matched pair. It must not exceed the
    matching overlap, or the two frames may never have been matched.
    """
    out = []
    for a, b in windows:
        idx = window_frames((a, b), step, extra)
        out.append(WindowRequest([frame_names[i] for i in idx], camera,
                                 use_position_priors=position_priors,
                                 init_pair=_init_pair(list(range(a, b, step)), frame_names, step,
                                                      init_gap_frames)))
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


def tracked_features(frame_idx: np.ndarray, images: Iterable[np.ndarray], frame_names: list[str],
                     camera: CameraModel | None, *, step: int, overlap: int,
                     options: KltOptions = KltOptions(), min_matches: int = 15
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
