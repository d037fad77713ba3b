"""Running the detector over a journey: boxes of every kept frame become ``Detection`` s, tracked
as a bundle's own detections without track ids are (``bundle.associate``)."""

from __future__ import annotations

import dataclasses
import time
import zipfile
from pathlib import Path

import cv2

from app.pipeline.bundle.associate import assign_tracks, sort_detections
from app.pipeline.detect.model import Detector, DetectorConfig, DetectorError, load_detector
from app.pipeline.types import Detection, Journey, PipelineError, ProgressFn, StageReport

STAGE = "detect"
NO_DETECTOR = "no detections and no detector configured"


def detect_journey(journey: Journey, detector: Detector,
                   progress: ProgressFn | None = None) -> tuple[list[Detection], StageReport]:
    """The detector's boxes on each frame of ``journey``, tracked and sorted, and the stage's
    report."""
    found: list[Detection] = []
    per_frame: list[str] = []
    t0 = time.perf_counter()
    n = len(journey.frames)
    for i, frame in enumerate(journey.frames):
        bgr = cv2.imread(str(frame.path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise PipelineError(STAGE, f"frame {frame.frame_id}: image {frame.path.name} "
                                       "cannot be read")
        boxes = detector.detect(bgr)
        found += [Detection(frame.frame_id, "", b.cls, b.x1, b.y1, b.x2, b.y2, b.score)
                  for b in boxes]
        if boxes:
            per_frame.append(f"frame {frame.frame_id}: {len(boxes)} boxes")
        if progress is not None and (i + 1 == n or i % max(1, n // 20) == 0):
            progress(STAGE, 0.0, f"frame {i + 1}/{n}")
    elapsed = time.perf_counter() - t0
    ids = journey.frame_ids
    detections = sort_detections(assign_tracks(found, ids), ids)
    n_tracks = len({d.track_id for d in detections})
    summary = (f"model {detector.path.name} (sha256 {detector.sha256[:12]}), input "
               f"{detector.input_size} px, {1000 * elapsed / max(n, 1):.0f} ms per frame, "
               f"{len(detections)} boxes kept in {n_tracks} tracks over {n} frames")
    return detections, StageReport(STAGE, summary, tuple(per_frame))


def bundle_has_detections(bundle: Path) -> bool:
    """Whether the bundle zip holds a ``detections.csv`` (the vehicle's own detections, possibly
    none); False when it is no zip."""
    try:
        with zipfile.ZipFile(bundle) as zf:
            return "detections.csv" in zf.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def apply_detector(journey: Journey, config: DetectorConfig, had_detections: bool,
                   progress: ProgressFn | None = None,
                   detector: Detector | None = None) -> Journey:
    """``journey`` with the detector's detections when its bundle had no ``detections.csv`` and a
    model is configured; with a report saying so when none is; unchanged otherwise. The report
    goes first in ``journey.intake``."""
    if had_detections or journey.detections:
        return journey
    if config.model is None and detector is None:
        report = StageReport(STAGE, NO_DETECTOR)
        return dataclasses.replace(journey, intake=(report, *journey.intake))
    try:
        detector = detector or load_detector(config)
    except DetectorError as exc:
        raise PipelineError(STAGE, str(exc)) from None
    detections, report = detect_journey(journey, detector, progress)
    return dataclasses.replace(journey, detections=detections, intake=(report, *journey.intake))
