"""Loading ONNX detectors and decoding their three output layouts into original pixels."""

from __future__ import annotations

import numpy as np
import pytest

from app.pipeline.detect import DetectorConfig, DetectorError, load_detector
from app.pipeline.detect.model import letterbox, parse_names
from tests.pipeline.bundle.detect.models import (HEIGHT, LEFT, SCALE, SIZE, STOP, TOP, WIDTH,
                                                 YIELD, constant_model, output, to_input)

IMAGE = np.random.default_rng(0).integers(0, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8)


def _coords(box) -> tuple:
    return (box.x1, box.y1, box.x2, box.y2)


@pytest.mark.parametrize("layout", ["v8", "v5", "nms"])
def test_each_layout_gives_the_boxes_in_original_pixels_after_nms(tmp_path, layout):
    names = "{0: 'stop', 1: 'yield'}" if layout == "v8" else None
    labels = ["stop", "yield"] if layout == "v5" else None
    path = constant_model(tmp_path / f"{layout}.onnx", output(layout), names=names)
    detector = load_detector(DetectorConfig(model=path, labels=labels))
    assert detector.input_size == SIZE
    boxes = detector.detect(IMAGE)
    # The overlapping stop is suppressed, the weak yield is under score_min.
    expected = {("stop" if layout != "nms" else "class0"): STOP,
                ("yield" if layout != "nms" else "class1"): YIELD}
    assert sorted(b.cls for b in boxes) == sorted(expected)
    for box in boxes:
        coords, score, _ = expected[box.cls]
        assert np.allclose(_coords(box), coords, atol=0.02), (box, coords)
        assert box.score == pytest.approx(score, abs=1e-5)


def test_class_filter_and_score_min(tmp_path):
    path = constant_model(tmp_path / "v8.onnx", output("v8"), names="{0: 'stop', 1: 'yield'}")
    only_yield = load_detector(DetectorConfig(model=path, classes=["yield"])).detect(IMAGE)
    assert [(b.cls, round(b.score, 3)) for b in only_yield] == [("yield", 0.7)]
    everything = load_detector(DetectorConfig(model=path, score_min=0.05, iou_nms=0.95))
    assert len(everything.detect(IMAGE)) == 4  # no NMS at IoU 0.95, the weak one kept


def test_letterbox_is_centred_with_gray_padding():
    img, r, left, top = letterbox(IMAGE, SIZE)
    assert img.shape == (SIZE, SIZE, 3)
    assert (r, left, top) == (pytest.approx(SCALE), LEFT, TOP)
    assert (img[:top] == 114).all() and (img[top + round(HEIGHT * SCALE):] == 114).all()
    assert not (img[top + 1:top + 5] == 114).all()


def test_names_metadata_forms():
    assert parse_names("{0: 'stop', 1: 'yield'}") == ["stop", "yield"]
    assert parse_names("{1: 'yield'}") == ["class0", "yield"]
    assert parse_names("['a', 'b']") == ["a", "b"]
    assert parse_names("not python") is None


def _refusal(config: DetectorConfig) -> str:
    with pytest.raises(DetectorError) as info:
        load_detector(config)
    message = str(info.value)
    assert "\n" not in message and message
    return message


def test_bad_models_are_refused_in_one_line(tmp_path):
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(np.random.default_rng(1).bytes(4096))
    assert "cannot be loaded" in _refusal(DetectorConfig(model=junk))
    assert "does not exist" in _refusal(DetectorConfig(model=tmp_path / "missing.onnx"))
    flat = constant_model(tmp_path / "flat.onnx", np.zeros((1, 7), np.float32))
    assert "[1, 7]" in _refusal(DetectorConfig(model=flat))
    tiny = constant_model(tmp_path / "tiny.onnx", np.zeros((1, 3, 3), np.float32))
    assert "none of" in _refusal(DetectorConfig(model=tiny))
    assert "takes 640 px" in _refusal(DetectorConfig(model=constant_model(
        tmp_path / "v8.onnx", output("v8")), input_size=320))


def test_a_single_class_yolov5_export_needs_its_layout_named(tmp_path):
    # [1, N, 6] is NMS built in unless told: cx, cy, w, h, objectness, score of the one class.
    box, score, _ = STOP
    x1, y1, x2, y2 = to_input(box)
    row = [(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1, 0.5, 2 * score]
    path = constant_model(tmp_path / "v5-one.onnx", np.array([[row]], np.float32))
    as_v5 = load_detector(DetectorConfig(model=path, layout="v5")).detect(IMAGE)
    assert [b.cls for b in as_v5] == ["class0"]
    assert np.allclose(_coords(as_v5[0]), box, atol=0.02)
    assert as_v5[0].score == pytest.approx(score, abs=1e-5)
    guessed = load_detector(DetectorConfig(model=path)).detect(IMAGE)
    assert not any(np.allclose(_coords(b), box, atol=1) for b in guessed)
    # A layout the output cannot have is refused at load.
    assert "layout nms" in _refusal(DetectorConfig(model=constant_model(
        tmp_path / "v8.onnx", output("v8")), layout="nms"))
