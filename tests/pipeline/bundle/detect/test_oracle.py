"""The oracle detector of the end-to-end test (``oracle``): the frame index it stamps is invisible
in grey, survives JPEG and the letterbox, and the model returns each frame's own boxes."""

from __future__ import annotations

import zipfile

import cv2
import numpy as np
import pytest

from app.pipeline.detect import DetectorConfig, load_detector
from tests.pipeline.bundle.detect.models import HEIGHT, WIDTH
from tests.pipeline.bundle.detect.oracle import BITS, STRIP, oracle_model, stamp, stamp_bundle

# Per frame: (x1, y1, x2, y2, class); frame 1 has none.
BOXES = [[(600, 100, 660, 160, "stop"), (900, 200, 940, 240, "yield")], [],
         [(100, 150, 180, 230, "yield")]]


def _bundle(path, boxes=BOXES):
    rng = np.random.default_rng(0)
    rows = ["frame,track_id,class,x1,y1,x2,y2,score"]
    with zipfile.ZipFile(path, "w") as z:
        for i, frame in enumerate(boxes):
            image = rng.integers(0, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8)
            z.writestr(f"frames/{i:06d}.png", cv2.imencode(".png", image)[1].tobytes())
            rows += [f"{i:06d},,{c},{x1},{y1},{x2},{y2},0.8" for x1, y1, x2, y2, c in frame]
        z.writestr("detections.csv", "\n".join(rows) + "\n")
    return path


def test_the_stamp_is_flat_in_grey_for_every_index():
    blank = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    x1, y1, x2, y2 = STRIP
    for index in (0, 1, 2 ** BITS - 1, 0b1010101010):
        grey = cv2.cvtColor(stamp(blank, index), cv2.COLOR_BGR2GRAY)[y1:y2, x1:x2]
        assert abs(int(grey.max()) - int(grey.min())) <= 1
    with pytest.raises(ValueError):
        stamp(blank, 2 ** BITS)


@pytest.mark.parametrize("quality", [None, 70])
def test_the_oracle_returns_each_stamped_frames_boxes(tmp_path, quality):
    original = _bundle(tmp_path / "b.zip")
    stamped = stamp_bundle(original, tmp_path / "s.zip", jpeg_quality=quality)
    detector = load_detector(DetectorConfig(model=oracle_model(tmp_path / "o.onnx", original)))
    assert detector.labels == ["stop", "yield"]
    with zipfile.ZipFile(stamped) as z:
        assert "detections.csv" not in z.namelist()
        frames = sorted(n for n in z.namelist() if n.startswith("frames/"))
        assert all(n.endswith(".png" if quality is None else ".jpg") for n in frames)
        for name, expected in zip(frames, BOXES):
            found = detector.detect(cv2.imdecode(np.frombuffer(z.read(name), np.uint8), 1))
            assert sorted((b.cls, round(b.x1), round(b.y1), round(b.x2), round(b.y2))
                          for b in found) == sorted((c, x1, y1, x2, y2)
                                                    for x1, y1, x2, y2, c in expected), name


def test_a_box_on_the_strip_is_refused(tmp_path):
    bundle = _bundle(tmp_path / "b.zip", [[(10, 10, 50, 50, "stop")]])
    with pytest.raises(ValueError, match="touch the index strip"):
        oracle_model(tmp_path / "o.onnx", bundle)
