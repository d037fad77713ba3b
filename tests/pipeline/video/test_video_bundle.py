"""A video bundle's upload check (container header, GPS, limits) and the worker's frame choice."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from app.pipeline.bundle import check_bundle, read_bundle
from app.pipeline.config import BundleLimits
from app.pipeline.types import AntennaOffset, BundleError
from tests.conftest import VIDEO_CLOCK_ERROR_S
from tests.pipeline.video import bundles
from tests.utils.journeys import video_journey


def _write(tmp_path: Path, data: bytes) -> Path:
    path = tmp_path / "journey.zip"
    path.write_bytes(data)
    return path


def test_a_video_with_an_nmea_log_passes_the_upload_check(tmp_path):
    check = check_bundle(_write(tmp_path, bundles.valid()))
    assert (check.camera_id, check.n_frames, check.n_detections) == ("dashcam-test", 40, 0)


@pytest.mark.parametrize("build, detail", [
    (bundles.not_a_video, "video.mp4 is not a video this service can read"),
    (bundles.truncated_container, "video.mp4 is not a video this service can read"),
    (bundles.no_decodable_frame, "video.mp4: no frame of its h264 stream decodes"),
    (bundles.two_videos, "bundle has 2 videos (video.mov, video.mp4)"),
    (bundles.video_and_frames, "bundle has both video.mp4 and frames/"),
    (bundles.gps_a_day_later, "the GPS does not overlap the video in time"),
    (bundles.garbage_nmea, "gps.nmea has no usable fix"),
    (bundles.no_gps, "no GPS: video.mp4 carries no GPS track"),
])
def test_a_bad_video_bundle_is_refused_with_a_reason(tmp_path, build, detail):
    with pytest.raises(BundleError) as err:
        check_bundle(_write(tmp_path, build()))
    assert detail in err.value.reason


@pytest.mark.parametrize("limit, detail", [
    ({"max_frame_pixels": 320 * 240 - 1}, "video.mp4 is 320x240, more than the limit of 76799"),
    ({"max_video_s": 2.0}, "video.mp4 lasts 4 s, more than the limit of 2 s"),
    ({"max_video_frames": 30}, "video.mp4 has 40 frames, more than the limit of 30"),
    ({"max_video_bytes": 1000}, "video.mp4 is "),
])
def test_a_video_over_the_limits_is_refused_before_decoding(tmp_path, limit, detail):
    with pytest.raises(BundleError) as err:
        check_bundle(_write(tmp_path, bundles.valid()), BundleLimits(**limit))
    assert detail in err.value.reason


def test_a_deflated_video_is_read_when_small_and_refused_when_large(tmp_path):
    path = _write(tmp_path, bundles.deflated())
    assert check_bundle(path).n_frames == 40
    with pytest.raises(BundleError) as err:
        check_bundle(path, BundleLimits(max_member_bytes=1000))
    assert "video.mp4 is deflated in the zip; store it uncompressed (zip -0" in err.value.reason


def test_the_worker_keeps_10_frames_a_second_and_says_so(tmp_path):
    journey = read_bundle(_write(tmp_path, bundles.valid()), tmp_path / "x")
    # 10 fps noise: every frame is on the 10 Hz grid; no turn, so the offset is not estimated.
    assert [f.frame_id for f in journey.frames][:3] == ["000000", "000001", "000002"]
    assert len(journey.frames) == 40
    assert sorted(p.name for p in (tmp_path / "x" / "frames").iterdir())[0] == "000000.jpg"
    report = journey.intake[0]
    assert report.stage == "video"
    assert "40 of 40 decoded frames kept" in " ".join(report.details)
    assert "creation_time" in report.summary and "stands" in report.summary
    # The GPS log starts 2 s before the video on the same clock: frame i is 2 + i/10 s in.
    np.testing.assert_allclose([f.timestamp_s for f in journey.frames[:3]], [2.0, 2.1, 2.2],
                               atol=1e-3)



def test_a_video_journey_takes_the_manifests_gps_antenna_offset(tmp_path):
    manifest = {**bundles.MANIFEST, "gps_antenna_offset_m": {"forward": 1.5, "left": 0, "up": 0.3}}
    data = bundles.bundle({"video.mp4": bundles.tiny_video(), "gps.nmea": bundles.nmea()},
                          manifest)
    journey = read_bundle(_write(tmp_path, data), tmp_path / "x")
    assert journey.gps_antenna_offset == AntennaOffset(forward_m=1.5, left_m=0.0, up_m=0.3)


_OFFSET = re.compile(r"the camera's clock is ([-+][\d.]+) s ± ([\d.]+) s off GPS time")


# GPX at 1 Hz; NMEA at 10 Hz is the e2e tests' bundle (tests/e2e/test_video_journey.py checks its
# offset within 0.1 s through `signmap process` and the service).
@pytest.mark.parametrize("gps_format, rate_hz", [("gpx", 1.0)])
def test_an_undeclared_clock_error_is_estimated_from_the_turn(tmp_path_factory, tmp_path,
                                                              turn_journey_bundle, gps_format,
                                                              rate_hz):
    bundle = video_journey(tmp_path_factory, turn_journey_bundle[0], "turn-video",
                           gps_format=gps_format, gps_rate_hz=rate_hz,
                           clock_error_s=VIDEO_CLOCK_ERROR_S)
    journey = read_bundle(bundle, tmp_path / "x")
    found = _OFFSET.search(journey.intake[0].summary)
    error_s, sigma_s = float(found.group(1)) - VIDEO_CLOCK_ERROR_S, float(found.group(2))
    assert abs(error_s) < 4 * sigma_s  # honest
    if rate_hz == 10.0:
        assert abs(error_s) < 0.1 and sigma_s < 0.1
    else:
        # One 4 s turn holds four 1 Hz fixes: the estimate is within 0.3 s and says so
        # (docs/decisions/clock-offset-from-turns.md).
        assert abs(error_s) < 0.3 and sigma_s < 0.15
    # The frames' GPS times are the video's plus the estimated offset: frame i of the 10 fps
    # video lies i / 10 s after frame 0 on the GPS clock.
    t = np.array([f.timestamp_s for f in journey.frames])
    np.testing.assert_allclose(np.diff(t), 0.1, atol=2e-3)
