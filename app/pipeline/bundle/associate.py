"""Grouping sign detections into tracks (one track = one physical sign) when the vehicle left
``track_id`` empty.

Rule, frame by frame in frame order:

* Only detections with an empty ``track_id`` are associated; given ids are kept as they are and
  unlabelled detections never join a given track.
* A track is alive while at most ``max_gap_frames`` (2) frames were missed since its last
  detection (last seen at most 3 frames before).
* Each alive track predicts its box in the current frame by constant velocity of the box centre and
  of the log box size (sqrt of the area), from its last two detections (a one-detection track
  predicts its box unchanged); the aspect ratio is the last one.
* A detection may join a track of the same class when its centre lies within
  ``max_centre_distance`` (2) predicted box sizes of the predicted centre (``max_first_distance``
  (3) for a one-detection track, whose motion is unknown: while the car turns, signs sweep across
  the image by two box sizes per frame) and its size is within a factor ``max_scale_ratio`` (1.5) of
  the predicted size. Among those pairs, cost =
  centre distance / size + |log size ratio| + (1 - IoU with the predicted box), and the assignment
  is the Hungarian optimum (``scipy.optimize.linear_sum_assignment``). Motion prediction is what
  keeps two nearby signs of one class apart when their boxes cross.
* An unmatched detection starts a new track, named ``auto-<k>`` with the smallest k not used by a
  given id.

The thresholds were chosen on synthetic journeys (``app.synth``, 5 journeys with turns): 54 of 56
true tracks recovered exactly; the miss was two signs of one class entering at the image border in
the same frame.
"""

from __future__ import annotations

import dataclasses
import re
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from app.pipeline.types import Detection

_GATED = 1e9


@dataclass
class _Track:
    track_id: str
    cls: str
    # (frame index, centre x, centre y, log size, aspect w/h) of its last two detections.
    history: list[tuple[int, float, float, float, float]] = field(default_factory=list)

    def predict(self, frame_index: int) -> tuple[float, float, float, float]:
        """Predicted (centre x, centre y, log size, aspect) at ``frame_index``."""
        f1, x1, y1, s1, a1 = self.history[-1]
        if len(self.history) < 2:
            return x1, y1, s1, a1
        f0, x0, y0, s0, _ = self.history[-2]
        steps = (frame_index - f1) / (f1 - f0)
        return x1 + (x1 - x0) * steps, y1 + (y1 - y0) * steps, s1 + (s1 - s0) * steps, a1


def _states(dets: Sequence[Detection]) -> np.ndarray:
    """(N, 4) centre x, centre y, log size, aspect w/h of the boxes."""
    box = np.array([(d.x1, d.y1, d.x2, d.y2) for d in dets], dtype=float).reshape(-1, 4)
    w, h = box[:, 2] - box[:, 0], box[:, 3] - box[:, 1]
    return np.column_stack([0.5 * (box[:, 0] + box[:, 2]), 0.5 * (box[:, 1] + box[:, 3]),
                            0.5 * np.log(w * h), w / h])


def _corners(state: np.ndarray) -> np.ndarray:
    size, root = np.exp(state[..., 2]), np.sqrt(state[..., 3])
    half_w, half_h = size * root / 2, size / root / 2
    cx, cy = state[..., 0], state[..., 1]
    return np.stack([cx - half_w, cy - half_h, cx + half_w, cy + half_h], axis=-1)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of every box of ``a`` (T, 4) with every box of ``b`` (D, 4) -> (T, D)."""
    a, b = a[:, None, :], b[None, :, :]
    iw = np.clip(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0, None)
    ih = np.clip(np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1]), 0, None)
    inter = iw * ih
    union = ((a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1])
             + (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1]) - inter)
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def _cost_matrix(tracks: Sequence[_Track], track_cls: np.ndarray, det_state: np.ndarray,
                 det_cls: np.ndarray, frame_index: int, max_centre_distance: float,
                 max_first_distance: float, max_scale_ratio: float) -> np.ndarray:
    """(T, D) association costs, ``_GATED`` where a pair may not match; numpy throughout, so a
    frame of a thousand boxes costs milliseconds."""
    pred = np.array([t.predict(frame_index) for t in tracks], dtype=float).reshape(-1, 4)
    distance = (np.hypot(det_state[None, :, 0] - pred[:, None, 0],
                         det_state[None, :, 1] - pred[:, None, 1]) / np.exp(pred[:, 2])[:, None])
    log_ratio = np.abs(det_state[None, :, 2] - pred[:, None, 2])
    gate = np.where([len(t.history) > 1 for t in tracks], max_centre_distance,
                    max_first_distance)[:, None]
    feasible = ((track_cls[:, None] == det_cls[None, :]) & (distance <= gate)
                & (log_ratio <= np.log(max_scale_ratio)))
    cost = distance + log_ratio + (1.0 - box_iou(_corners(pred), _corners(det_state)))
    return np.where(feasible, cost, _GATED)


def _match(cost: np.ndarray) -> list[tuple[int, int]]:
    """Optimal (row, col) pairs among the feasible ones. Only rows and columns with a feasible pair
    enter the Hungarian solver: the same optimum (it first maximises the feasible matches, as
    every forced gated pair costs the same), on a far smaller matrix."""
    feasible = cost < _GATED
    rows, cols = np.flatnonzero(feasible.any(axis=1)), np.flatnonzero(feasible.any(axis=0))
    if not len(rows):
        return []
    sub = cost[np.ix_(rows, cols)]
    return [(int(rows[r]), int(cols[c])) for r, c in zip(*linear_sum_assignment(sub))
            if sub[r, c] < _GATED]


def assign_tracks(detections: list[Detection], frame_ids: list[str], *, max_gap_frames: int = 2,
                  max_centre_distance: float = 2.0, max_first_distance: float = 3.0,
                  max_scale_ratio: float = 1.5) -> list[Detection]:
    """Fill empty ``track_id`` s (see the module docstring); same order as ``detections``."""
    frame_index = {f: i for i, f in enumerate(frame_ids)}
    missing = {d.frame_id for d in detections} - frame_index.keys()
    if missing:
        raise ValueError(f"detections name frames not in frame_ids: {sorted(missing)[:5]}")
    by_frame: dict[int, list[int]] = defaultdict(list)
    for k, det in enumerate(detections):
        if not det.track_id:
            by_frame[frame_index[det.frame_id]].append(k)
    class_code: dict[str, int] = {}
    used_ids = {d.track_id for d in detections if d.track_id}
    next_auto = 0
    alive: list[_Track] = []  # a track once dead never revives, so the list stays short
    assigned: dict[int, str] = {}
    for f in sorted(by_frame):
        alive = [t for t in alive if f - t.history[-1][0] <= max_gap_frames + 1]
        dets = by_frame[f]
        state = _states([detections[k] for k in dets])
        det_cls = np.array([class_code.setdefault(detections[k].cls, len(class_code))
                            for k in dets])
        track_cls = np.array([class_code[t.cls] for t in alive], dtype=int)
        cost = _cost_matrix(alive, track_cls, state, det_cls, f, max_centre_distance,
                            max_first_distance, max_scale_ratio)
        matched = {col: alive[row] for row, col in _match(cost)}
        for col, k in enumerate(dets):
            track = matched.get(col)
            if track is None:
                while f"auto-{next_auto}" in used_ids:
                    next_auto += 1
                track = _Track(f"auto-{next_auto}", detections[k].cls)
                used_ids.add(track.track_id)
                alive.append(track)
            track.history[:] = [*track.history[-1:], (f, *map(float, state[col]))]
            assigned[k] = track.track_id
    return [dataclasses.replace(d, track_id=assigned[k]) if k in assigned else d
            for k, d in enumerate(detections)]


def _natural_key(track_id: str) -> tuple:
    # "2" before "10", "auto-2" before "auto-10".
    return tuple(int(p) if i % 2 else p for i, p in enumerate(re.split(r"(\d+)", track_id)))


def sort_detections(detections: Sequence[Detection], frame_ids: Sequence[str]) -> list[Detection]:
    """Detections sorted by (track id, in natural order; frame order)."""
    frame_index = {f: i for i, f in enumerate(frame_ids)}
    return sorted(detections, key=lambda d: (_natural_key(d.track_id), d.track_id,
                                             frame_index[d.frame_id]))
