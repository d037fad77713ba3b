"""A journey without detections.csv mapped from a configured ONNX detector's boxes (issue 69).

The turn journey's frames carry their index (``oracle.stamp_bundle``, frames re-encoded as JPEG)
and its detections.csv is gone; the "oracle" model reads the index from its input and returns that
frame's true boxes, so the boxes differ frame by frame as a real detector's do, and the signs must
land where they put them.

1. ``signmap process`` with SIGNMAP_DETECTOR__MODEL: signs within 1 m of the truth, the report
   naming the model; without a model the same bundle finishes with no signs and says why.
2. Uploaded over HTTP to PostgreSQL + Redis + a real Celery worker whose settings name the model.

Both reuse the camera's true calibration (``reuse_known_calibration``), as test_video_journey does:
what these add is the detector's path, not the self-calibration.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from app.cli import main
from app.commands.usage import EXIT_OK
from app.pipeline.detect import DetectorConfig
from app.pipeline.detect.journey import NO_DETECTOR
from app.pipeline.types import CameraModel
from tests.pipeline.bundle.detect.oracle import oracle_model, stamp_bundle
from tests.utils.results.service_support import nearest_sign_errors_m
from tests.utils.stack import processed_by_celery

pytestmark = [pytest.mark.slow]

# The bundle's own detections place 9 of the journey's 10 signs (one is seen in 2 frames only).
MIN_SIGNS = 7


@pytest.fixture(scope="module")
def stamped(tmp_path_factory, turn_journey_bundle) -> tuple[Path, Path]:
    """(the turn journey stamped, its frames as JPEG, without detections.csv; its oracle
    model)."""
    out = tmp_path_factory.mktemp("oracle")
    bundle = turn_journey_bundle[0]
    return (stamp_bundle(bundle, out / "stamped.zip", jpeg_quality=90),
            oracle_model(out / "oracle.onnx", bundle))


def _detect_stage(report: list[dict]) -> dict:
    return next(s for s in report if s["stage"] == "detect")


def _check_signs(features: list[dict], truth: dict) -> None:
    errors = nearest_sign_errors_m(features, truth)
    assert all(track.startswith("auto-") for track in errors), errors  # the detector's tracks
    assert len(errors) >= MIN_SIGNS and max(errors.values()) < 1.0, errors


def test_signmap_process_places_signs_from_the_detectors_boxes(stamped, turn_journey_bundle,
                                                               tmp_path, monkeypatch):
    bundle, model = stamped
    truth = turn_journey_bundle[1]
    (tmp_path / "cam.json").write_text(json.dumps(truth["camera"]))
    monkeypatch.setenv("SIGNMAP_PIPELINE__REUSE_KNOWN_CALIBRATION", "true")
    monkeypatch.delenv("SIGNMAP_DETECTOR__MODEL", raising=False)

    def process(out: Path) -> tuple[list[dict], dict]:
        assert main(["process", str(bundle), "--calibration", str(tmp_path / "cam.json"),
                     "--out", str(out)]) == EXIT_OK
        return (json.loads(out.read_text())["features"],
                json.loads(out.with_suffix(".report.json").read_text()))

    # No detector configured: the journey still finishes, without signs, and says why.
    features, report = process(tmp_path / "bare" / "signs.geojson")
    assert features == [] and _detect_stage(report["report"])["summary"] == NO_DETECTOR
    assert report["calibration"]["source"] == "supplied"

    monkeypatch.setenv("SIGNMAP_DETECTOR__MODEL", str(model))
    features, report = process(tmp_path / "detected" / "signs.geojson")
    _check_signs(features, truth)
    summary = _detect_stage(report["report"])["summary"]
    sha = hashlib.sha256(model.read_bytes()).hexdigest()[:12]
    assert (f"model oracle.onnx (sha256 {sha}), input 640 px, " in summary
            and " ms per frame, " in summary and " boxes kept in " in summary
            and summary.endswith(f" over {len(truth['frames'])} frames")), summary


@pytest.mark.postgres
def test_a_journey_without_detections_over_http_with_a_celery_worker(stamped, turn_journey_bundle,
                                                                      own_pg_url, redis_url,
                                                                      tmp_path):
    bundle, model = stamped
    truth = turn_journey_bundle[1]
    body, features = processed_by_celery(bundle.read_bytes(), truth["camera_id"],
                                         CameraModel(**truth["camera"]), own_pg_url, redis_url,
                                         tmp_path, detector=DetectorConfig(model=model))
    assert body["status"] == "done", body["error"]
    _check_signs(features, truth)
    assert _detect_stage(body["report"])["summary"].startswith("model oracle.onnx (sha256 ")
