"""A dash cam's video journey end to end: the turn journey as video.mp4 (H.264) + a 10 Hz NMEA log,
the camera's clock VIDEO_CLOCK_ERROR_S ahead of GPS time and not declared.

1. ``signmap process video.mp4 --gps gps.nmea --detections detections.csv``: the offset is
   estimated within 0.1 s and the signs land within 1 m of the truth.
2. Uploaded over HTTP to PostgreSQL + Redis + a real Celery worker: the same, through the service.

Both reuse the camera's true calibration (``reuse_known_calibration``, as a camera's later journeys
do): the self-calibration on video frames is the bench's (``signmap bench video``); what these add
is the video path, not the pipeline.
"""

from __future__ import annotations

import json
import re
import zipfile

import pytest

from app.cli import main
from app.commands.usage import EXIT_OK
from app.pipeline.types import CameraModel
from tests.conftest import VIDEO_CLOCK_ERROR_S
from tests.utils.results.service_support import sign_errors_m
from tests.utils.stack import processed_by_celery

pytestmark = [pytest.mark.slow]

OFFSET = re.compile(r"clock offset estimated: the camera's clock is ([-+][\d.]+) s ± ([\d.]+) s")


def _clock_error(details: list[str]) -> tuple[float, float]:
    found = next(m for d in details if (m := OFFSET.search(d)))
    return float(found.group(1)), float(found.group(2))


def test_signmap_process_places_a_video_journey(turn_video_bundle, turn_journey_bundle, tmp_path,
                                                monkeypatch):
    truth = turn_journey_bundle[1]
    with zipfile.ZipFile(turn_video_bundle) as z:  # the files as a dash cam leaves them
        z.extractall(tmp_path / "sd")
    (tmp_path / "cam.json").write_text(json.dumps(truth["camera"]))
    monkeypatch.setenv("SIGNMAP_PIPELINE__REUSE_KNOWN_CALIBRATION", "true")
    out = tmp_path / "signs.geojson"
    sd = tmp_path / "sd"
    assert main(["process", str(sd / "video.mp4"), "--gps", str(sd / "gps.nmea"),
                 "--detections", str(sd / "detections.csv"), "--calibration",
                 str(tmp_path / "cam.json"), "--camera-id", truth["camera_id"],
                 "--out", str(out)]) == EXIT_OK
    report = json.loads(out.with_suffix(".report.json").read_text())
    video = next(s for s in report["report"] if s["stage"] == "video")
    error_s, sigma_s = _clock_error(video["details"])
    assert abs(error_s - VIDEO_CLOCK_ERROR_S) < 0.1, video
    assert sigma_s < 0.1
    features = json.loads(out.read_text())["features"]
    errors = sign_errors_m(features, truth)
    assert len(errors) >= 1 and max(errors.values()) < 1.0, errors
    assert all(len(f["properties"]["observations"][0]["frame"]) == 6 for f in features)


@pytest.mark.postgres
def test_a_video_journey_over_http_with_a_celery_worker(turn_video_bundle, turn_journey_bundle,
                                                        own_pg_url, redis_url, tmp_path):
    truth = turn_journey_bundle[1]
    body, features = processed_by_celery(turn_video_bundle.read_bytes(), truth["camera_id"],
                                         CameraModel(**truth["camera"]), own_pg_url, redis_url,
                                         tmp_path)
    assert body["status"] == "done", body["error"]
    errors = sign_errors_m(features, truth)
    assert len(errors) >= 1 and max(errors.values()) < 1.0, errors
    video = next(s for s in body["report"] if s["stage"] == "video")
    assert abs(_clock_error(video["details"])[0] - VIDEO_CLOCK_ERROR_S) < 0.1
