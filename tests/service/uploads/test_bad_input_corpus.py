"""The bad-input corpus: every hostile or broken upload found by probing the service (issue 13 and
later), against the real app. Each case is one row of ``CASES``: how to build the upload, the
exact status, a fragment of the JSON ``detail``. For each, nothing may be stored (no journey row,
no file under incoming/ or bundles/) and the server must still answer.

Grow it with every finding: add a builder (``tests/utils/hostile_bundles.py`` or ``tests/utils/
bundle_factory.py``) and a row. ``bench/service/hostile_uploads.py`` measures what the cases cost.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import pytest

from tests.pipeline.video import bundles as vb
from tests.utils import hostile_bundles as hb
from tests.utils.stack import auth, sqlite_stack


@dataclass(frozen=True)
class Case:
    build: Callable[[], bytes]
    status: int
    detail: str
    # Upper bound on the request's wall time: the point of several cases is that the answer
    # comes before the work the upload asks for (generous, for a loaded 2-core machine).
    max_s: float = 10.0


CASES: dict[str, Case] = {
    # Finding 1: 1,000,000 detection rows (7 MB zipped) took 1.5 GB and 14.5 s of the API.
    "million_detection_rows": Case(
        hb.million_detection_rows, 422,
        "detections.csv has more than 300000 rows, the limit per journey"),
    # Finding 2: 3 frames x 1000 unlabelled boxes were associated in the request (17.8 s).
    "thousand_boxes_per_frame": Case(
        hb.thousand_boxes_per_frame, 422,
        "detection row 202: frame 000000 has more than 200 detection boxes, the limit per frame",
        max_s=5.0),
    # Finding 3: 8 frames padded to 250 MiB each (2 MB zipped) were unpacked to disk (2000 MB)
    # before the bad GPS was noticed.
    "frames_padded_to_250_mib": Case(
        hb.padded_frames, 422, "bundle unpacks to 2000.1 MiB from a 2.0 MiB zip, more than 20 "
        "times its size", max_s=5.0),
    # ... and within the limits, the cheap checks (GPS) come before any frame is unpacked.
    "bad_gps_is_found_before_padded_frames": Case(
        lambda: hb.padded_frames(4, 8 * 2**20, unreadable_last=True), 422,
        "no GPS timestamp for frame 000001", max_s=5.0),
    "png_header_claiming_20000_squared": Case(
        hb.png_header_claiming_20000, 422,
        "frame 000000.png is 20000x20000, more than the limit of 16777216 pixels"),
    "jpeg_header_claiming_65000_squared": Case(
        hb.jpeg_header_claiming_65000, 422,
        "frame 000000.jpg is 65000x65000, more than the limit of 16777216 pixels"),
    "real_8192_squared_frames": Case(
        hb.real_8192_frames, 422,
        "frame 000000.png is 8192x8192, more than the limit of 16777216 pixels", max_s=5.0),
    "frame_declaring_1000_bytes_inflating_to_250_mib": Case(
        hb.frame_lying_about_its_size, 422,
        "frames/000002.png in the bundle is corrupt or unreadable (Bad CRC-32", max_s=5.0),
    # Video journeys (issue 65): the upload reads the container header and one frame only.
    "video_not_a_video": Case(vb.not_a_video, 422, "video.mp4 is not a video this service can"),
    "video_truncated_container": Case(vb.truncated_container, 422, "video.mp4 is not a video"),
    "video_no_decodable_frame": Case(vb.no_decodable_frame, 422,
                                     "video.mp4: no frame of its h264 stream decodes"),
    "video_two_videos": Case(vb.two_videos, 422, "bundle has 2 videos"),
    "video_gps_a_day_later": Case(vb.gps_a_day_later, 422,
                                  "the GPS does not overlap the video in time"),
    "video_garbage_nmea": Case(vb.garbage_nmea, 422, "gps.nmea has no usable fix"),
    "video_no_gps": Case(vb.no_gps, 422, "no GPS: video.mp4 carries no GPS track"),
}


def _assert_nothing_stored_and_alive(stack, client, key: str) -> None:
    assert stack.count_journeys(key) == 0
    assert stack.stored_files() == []
    incoming = stack.settings.data_dir / "incoming"
    assert not incoming.exists() or list(incoming.iterdir()) == []  # no .d folders either
    assert client.get("/api/v1/health").status_code == 200


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_is_refused_fast_and_leaves_nothing(stack, name):
    case = CASES[name]
    data = case.build()
    key = stack.key("fleet")
    with stack.client() as client:
        t0 = time.perf_counter()
        response = client.post("/api/v1/journeys", headers=auth(key),
                               files={"bundle": ("journey.zip", data, "application/zip")})
        elapsed_s = time.perf_counter() - t0
        assert response.status_code == case.status, response.text
        assert case.detail in response.json()["detail"]
        assert elapsed_s < case.max_s, f"{name}: answered after {elapsed_s:.1f} s"
        _assert_nothing_stored_and_alive(stack, client, key)


def test_unlabelled_boxes_are_not_associated_in_the_request(tmp_path):
    """With the per-frame limit raised to 1000, 3 frames x 1000 unlabelled boxes are accepted
    promptly: the request checks the contract; tracks are built in the job."""
    stack = sqlite_stack(tmp_path / "data", bundle={"max_boxes_per_frame": 1000})
    key = stack.key("fleet")
    with stack.client() as client:
        t0 = time.perf_counter()
        response = client.post("/api/v1/journeys", headers=auth(key), files={
            "bundle": ("journey.zip", hb.thousand_boxes_per_frame(), "application/zip")})
        elapsed_s = time.perf_counter() - t0
    assert response.status_code == 202, response.text
    assert elapsed_s < 5.0
    assert stack.count_journeys(key) == 1
