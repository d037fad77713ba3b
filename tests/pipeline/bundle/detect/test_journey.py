"""A journey without detections gets the detector's boxes: per frame, in original pixels, tracked;
without a detector it says so; startup refuses a model that cannot be loaded, in one line."""

from __future__ import annotations

import zipfile

import cv2
import numpy as np
import pytest

from app.pipeline.bundle import read_bundle
from app.pipeline.detect import (DetectorConfig, apply_detector, bundle_has_detections,
                                 detect_journey, load_detector)
from app.pipeline.detect.journey import NO_DETECTOR
from app.pipeline.types import Frame, Journey, PipelineError, StageReport
from app.service import startup
from app.service.db.session import upgrade
from tests.pipeline.bundle.detect.models import HEIGHT, STOP, WIDTH, constant_model, output
from tests.utils.stack import make_settings

ONE_STOP = (STOP,)


def _journey(tmp_path, n: int = 3) -> Journey:
    frames = []
    for i in range(n):
        path = tmp_path / f"{i:06d}.png"
        cv2.imwrite(str(path), np.full((HEIGHT, WIDTH, 3), 40 * i, np.uint8))
        frames.append(Frame(f"{i:06d}", path, float(i)))
    zeros = np.zeros(n)
    return Journey("cam", frames, zeros, zeros, zeros, [], WIDTH, HEIGHT,
                   intake=(StageReport("video", "earlier"),))


def test_a_journey_gets_the_models_boxes_as_one_track(tmp_path):
    journey = _journey(tmp_path)
    model = constant_model(tmp_path / "nms.onnx", output("nms", ONE_STOP))
    detections, report = detect_journey(journey, load_detector(DetectorConfig(model=model)))
    assert [d.frame_id for d in detections] == journey.frame_ids
    assert {d.track_id for d in detections} == {"auto-0"}
    assert {d.cls for d in detections} == {"class0"}
    for d in detections:
        assert np.allclose((d.x1, d.y1, d.x2, d.y2), STOP[0], atol=0.02)
    assert report.stage == "detect" and "nms.onnx" in report.summary
    assert "3 boxes kept" in report.summary and "640 px" in report.summary

    applied = apply_detector(journey, DetectorConfig(model=model), had_detections=False)
    assert applied.detections == detections
    assert [r.stage for r in applied.intake] == ["detect", "video"]
    assert journey.detections == []  # replaced, not changed in place


def test_without_a_detector_the_report_says_so_and_given_detections_stay(tmp_path):
    journey = _journey(tmp_path, 1)
    bare = apply_detector(journey, DetectorConfig(), had_detections=False)
    assert bare.detections == [] and bare.intake[0] == StageReport("detect", NO_DETECTOR)
    model = constant_model(tmp_path / "nms.onnx", output("nms", ONE_STOP))
    # A detections.csv, even an empty one, is the vehicle's word: the detector does not run.
    assert apply_detector(journey, DetectorConfig(model=model), had_detections=True) is journey
    with pytest.raises(PipelineError, match="^detect: detector model .* does not exist$"):
        apply_detector(journey, DetectorConfig(model=tmp_path / "gone.onnx"), False)


def test_turn_bundle_without_detections_csv_is_detected(tmp_path, turn_journey_bundle):
    bundle, _ = turn_journey_bundle
    stripped = tmp_path / "no-detections.zip"
    with zipfile.ZipFile(bundle) as src, zipfile.ZipFile(stripped, "w") as dst:
        for item in src.infolist():
            if item.filename != "detections.csv":
                dst.writestr(item, src.read(item.filename))
    assert bundle_has_detections(bundle) and not bundle_has_detections(stripped)
    journey = read_bundle(stripped, tmp_path / "x")
    assert journey.detections == []
    size = 640
    w, h = journey.image_width, journey.image_height
    r = min(size / w, size / h)
    left, top = round((size - round(w * r)) / 2 - 0.1), round((size - round(h * r)) / 2 - 0.1)
    box = (0.25 * w, 0.25 * h, 0.5 * w, 0.5 * h)  # original OpenCV pixels
    inp = [(box[0] + 0.5) * r + left, (box[1] + 0.5) * r + top,
           (box[2] + 0.5) * r + left, (box[3] + 0.5) * r + top]
    model = constant_model(tmp_path / "m.onnx", np.array([[[*inp, 0.9, 0]]], np.float32),
                           names="{0: 'stop'}")
    detected = apply_detector(journey, DetectorConfig(model=model),
                              bundle_has_detections(stripped))
    assert [d.frame_id for d in detected.detections] == journey.frame_ids
    assert {(d.cls, d.track_id) for d in detected.detections} == {("stop", "auto-0")}
    assert np.allclose([(d.x1, d.y1, d.x2, d.y2) for d in detected.detections], box, atol=0.05)


def test_startup_refuses_a_model_that_cannot_be_loaded(tmp_path):
    junk = tmp_path / "model.onnx"
    junk.write_bytes(b"\x00not an onnx model" * 100)
    settings = make_settings(tmp_path / "data", detector=DetectorConfig(model=junk))
    upgrade(settings.effective_database_url)
    with pytest.raises(startup.StartupError) as info:
        startup.check(settings)
    message = str(info.value)
    assert message.startswith(f"detector model {junk} cannot be loaded: ") and "\n" not in message
    startup.check(make_settings(tmp_path / "data"))  # no detector configured: up
    good = constant_model(tmp_path / "good.onnx", output("v8"))
    startup.check(make_settings(tmp_path / "data", detector=DetectorConfig(model=good)))
