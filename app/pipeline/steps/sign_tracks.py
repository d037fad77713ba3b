"""A sign's detections as tracks: ``group_detections`` gathers the detections of each track id
(given in the bundle, or associated by ``bundle.associate``) into one ``SignTrack`` per physical
sign, and ``split_passes`` cuts a track into the passes of the car (a loop sees a sign twice).

Not to be confused with KLT feature tracks (``colmap.klt_features``), which follow image corners
for ego-motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.pipeline.types import Detection


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


def group_detections(detections: list[Detection], frame_ids: list[str]) -> list[SignTrack]:
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
