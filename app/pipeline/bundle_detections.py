"""``detections.csv`` of a journey bundle: the vehicle's sign detections, checked against the frames.

Columns ``frame,track_id,class,x1,y1,x2,y2[,score]`` (a missing ``track_id`` column means every
track id is empty). Boxes are OpenCV pixels of the original image, whose pixels cover
[-0.5, width - 0.5] x [-0.5, height - 0.5]; a box may reach ``BORDER_TOLERANCE_PX`` beyond that, since
clients round or use exclusive end coordinates. A given track id may have one box per frame.
"""

from __future__ import annotations

from typing import Sequence

from app.pipeline.csv_table import parse_float, read_table
from app.pipeline.types import BundleError, Detection

BORDER_TOLERANCE_PX = 1.0


def parse_detections(text: str, frame_ids: Sequence[str], width: int,
                     height: int) -> list[Detection]:
    """``detections.csv`` text -> detections in file order (track ids may be empty)."""
    rows = read_table(text, "detections.csv",
                               ("frame", "class", "x1", "y1", "x2", "y2"), ("track_id", "score"))
    known = set(frame_ids)
    lo_x = lo_y = -0.5 - BORDER_TOLERANCE_PX
    hi_x, hi_y = width - 0.5 + BORDER_TOLERANCE_PX, height - 0.5 + BORDER_TOLERANCE_PX
    seen: dict[tuple[str, str], int] = {}
    detections = []
    for r in rows:
        where = f"detection row {r.row}"
        frame = r["frame"]
        if not frame:
            raise BundleError(f"{where} has no frame")
        if frame not in known:
            raise BundleError(f"{where} names frame {frame} which is not in frames/")
        cls = r["class"]
        if not cls:
            raise BundleError(f"{where} has an empty class")
        x1, y1, x2, y2 = (parse_float(r[c], f"{where}: {c}") for c in ("x1", "y1", "x2", "y2"))
        box = f"({x1:g},{y1:g})-({x2:g},{y2:g})"
        if not (x1 < x2 and y1 < y2):
            raise BundleError(f"{where}: box {box} is empty or inverted; need x1 < x2 and y1 < y2")
        if x1 < lo_x or y1 < lo_y or x2 > hi_x or y2 > hi_y:
            raise BundleError(f"{where}: box {box} lies outside the {width}x{height} image")
        score = parse_float(r["score"], f"{where}: score") if r["score"] else None
        track_id = r["track_id"]
        if track_id:
            if (track_id, frame) in seen:
                raise BundleError(f"{where}: track {track_id} already has a box in frame {frame} "
                                  f"(row {seen[(track_id, frame)]}); one box per track per frame")
            seen[(track_id, frame)] = r.row
        detections.append(Detection(frame, track_id, cls, x1, y1, x2, y2, score))
    return detections
