"""``detections.csv`` of a journey bundle: the vehicle's sign detections, checked against the frames.

Columns ``frame,track_id,class,x1,y1,x2,y2[,score]`` (a missing ``track_id`` column means every
track id is empty). Boxes are OpenCV pixels of the original image, whose pixels cover
[-0.5, width - 0.5] x [-0.5, height - 0.5]; a box may reach ``BORDER_TOLERANCE_PX`` beyond that, since
clients round or use exclusive end coordinates. A given track id may have one box per frame.

The table streams (``bundle.csv_table``) and what is kept of it is columns of numbers, not an
object per row: validating a 300,000-row table costs tens of MB, and the row and per-frame box
limits (``BundleLimits``) stop a longer one as soon as it passes them.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from math import inf, isfinite
from typing import BinaryIO, Sequence

import numpy as np

from app.pipeline.bundle.csv_table import (MAX_TEXT_CHARS, check_text, iter_table, parse_float,
                                           shown)
from app.pipeline.types import BundleError, Detection

BORDER_TOLERANCE_PX = 1.0
# The longest class the map stores (journey_signs.class, map_signs.class are this wide): a longer
# one is refused at the upload rather than failing the job when its signs are written.
MAX_CLASS_CHARS = MAX_TEXT_CHARS


@dataclass(frozen=True)
class DetectionTable:
    """The rows of ``detections.csv`` in file order, as columns. ``track`` and ``cls`` index
    ``track_ids`` and ``classes`` (track -1: empty id); ``score`` is NaN where none was given."""

    frame: np.ndarray  # (N,) int32 index into the bundle's frame ids
    track: np.ndarray  # (N,) int32
    cls: np.ndarray  # (N,) int32
    box: np.ndarray  # (N, 4) float64 x1, y1, x2, y2
    score: np.ndarray  # (N,) float64
    row: np.ndarray  # (N,) int64 line of the file (for messages)
    track_ids: tuple[str, ...]
    classes: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.frame)

    def to_detections(self, frame_ids: Sequence[str], keep: np.ndarray | None = None
                      ) -> list[Detection]:
        """Detection objects of the rows whose frame ``keep`` (bool per frame) marks, file order."""
        rows = np.arange(len(self)) if keep is None else np.flatnonzero(keep[self.frame])
        # Plain Python values first: indexing numpy arrays element by element is slow.
        frame, track, cls = (a[rows].tolist() for a in (self.frame, self.track, self.cls))
        box, score = self.box[rows].tolist(), self.score[rows].tolist()
        return [Detection(frame_ids[f], self.track_ids[t] if t >= 0 else "", self.classes[c],
                          *b, None if s != s else s)  # s != s: NaN, no score given
                for f, t, c, b, s in zip(frame, track, cls, box, score)]


def _box(coords: list[str], row: int) -> tuple[float, float, float, float]:
    """The box of a row whose coordinates are not four finite numbers: the error naming the first
    bad one (or, when only their sum overflowed, the box)."""
    x1, y1, x2, y2 = (parse_float(text, f"detection row {row}: {c}")
                      for text, c in zip(coords, ("x1", "y1", "x2", "y2")))
    return x1, y1, x2, y2


def _shown(x1: float, y1: float, x2: float, y2: float) -> str:
    return f"({x1:g},{y1:g})-({x2:g},{y2:g})"


def read_detections(source: str | BinaryIO, frame_ids: Sequence[str], width: int, height: int, *,
                    max_rows: int | None = None,
                    max_boxes_per_frame: int | None = None) -> DetectionTable:
    """``detections.csv`` (text, or a binary stream read as it goes) -> its checked rows."""
    rows = iter_table(source, "detections.csv", ("frame", "class", "x1", "y1", "x2", "y2"),
                      ("track_id", "score"), max_rows=max_rows)
    known = {f: i for i, f in enumerate(frame_ids)}
    lo_x = lo_y = -0.5 - BORDER_TOLERANCE_PX
    hi_x, hi_y = width - 0.5 + BORDER_TOLERANCE_PX, height - 0.5 + BORDER_TOLERANCE_PX
    per_frame = [0] * len(frame_ids)
    max_boxes = max_boxes_per_frame if max_boxes_per_frame is not None else inf
    tracks: dict[str, int] = {}
    classes: dict[str, int] = {}
    frame_col, track_col, cls_col, line_col = array("i"), array("i"), array("i"), array("q")
    box_col, score_col = array("d"), array("d")
    for row, (frame, cls, *coords, track_id, score) in rows:
        f = known.get(frame)
        if f is None:
            where = f"detection row {row}"
            raise BundleError(f"{where} has no frame" if not frame else
                              f"{where} names frame {shown(frame)} which is not in frames/")
        per_frame[f] += 1
        if per_frame[f] > max_boxes:
            raise BundleError(f"detection row {row}: frame {frame} has more than {max_boxes} "
                              "detection boxes, the limit per frame")
        if not cls:
            raise BundleError(f"detection row {row} has an empty class")
        if cls not in classes:  # each distinct value is checked once
            check_text(cls, f"detection row {row}: class", MAX_CLASS_CHARS)
        if track_id and track_id not in tracks:
            # Ids are free text, but bounded: a 5000-digit id broke the job's natural sort.
            check_text(track_id, f"detection row {row}: track_id")
        try:  # the fast path formats no message for a valid row
            x1, y1, x2, y2 = map(float, coords)
        except ValueError:
            x1, y1, x2, y2 = _box(coords, row)
        if not isfinite(x1 + y1 + x2 + y2):
            x1, y1, x2, y2 = _box(coords, row)
        if not (lo_x <= x1 <= hi_x and lo_x <= x2 <= hi_x and lo_y <= y1 <= hi_y
                and lo_y <= y2 <= hi_y):
            name, value = next((n, v) for n, v, lo, hi in (
                ("x1", x1, lo_x, hi_x), ("y1", y1, lo_y, hi_y), ("x2", x2, lo_x, hi_x),
                ("y2", y2, lo_y, hi_y)) if not lo <= v <= hi)
            raise BundleError(f"detection row {row}: box {_shown(x1, y1, x2, y2)} lies outside "
                              f"the {width}x{height} image ({name} is {value:g})")
        if not (x1 < x2 and y1 < y2):
            raise BundleError(f"detection row {row}: box {_shown(x1, y1, x2, y2)} is empty or "
                              "inverted; need x1 < x2 and y1 < y2")
        frame_col.append(f)
        track_col.append(tracks.setdefault(track_id, len(tracks)) if track_id else -1)
        cls_col.append(classes.setdefault(cls, len(classes)))
        line_col.append(row)
        box_col.extend((x1, y1, x2, y2))
        score_col.append(parse_float(score, f"detection row {row}: score") if score else np.nan)
    table = DetectionTable(np.frombuffer(frame_col, np.int32), np.frombuffer(track_col, np.int32),
                           np.frombuffer(cls_col, np.int32),
                           np.frombuffer(box_col, np.float64).reshape(-1, 4),
                           np.frombuffer(score_col, np.float64), np.frombuffer(line_col, np.int64),
                           tuple(tracks), tuple(classes))
    _check_one_box_per_track_and_frame(table, frame_ids)
    return table


def _check_one_box_per_track_and_frame(table: DetectionTable, frame_ids: Sequence[str]) -> None:
    labelled = np.flatnonzero(table.track >= 0)
    key = table.track[labelled].astype(np.int64) * len(frame_ids) + table.frame[labelled]
    order = np.argsort(key, kind="stable")  # equal keys stay in file order
    repeat = np.flatnonzero(key[order][1:] == key[order][:-1]) + 1
    if not len(repeat):
        return
    # Report the repeat that comes first in the file, with the row it repeats.
    later = labelled[order[repeat]]
    first_pos = int(np.argmin(later))
    k = later[first_pos]
    earlier = labelled[order[np.searchsorted(key[order], key[order][repeat[first_pos]])]]
    raise BundleError(f"detection row {table.row[k]}: track {table.track_ids[table.track[k]]} "
                      f"already has a box in frame {frame_ids[table.frame[k]]} "
                      f"(row {table.row[earlier]}); one box per track per frame")
