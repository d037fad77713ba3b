"""GPS read from a video's own GoPro GPMF or CAMM track, on the video's clock."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from app.pipeline.bundle.video.embedded_gps import UERE_M, read_embedded_gps
from app.pipeline.types import BundleError
from tests.pipeline.video.gps_videos import (CREATION_TIME, camm_type6, klv, write_camm_video,
                                   write_gpmf_video, write_video)

GPS_UTC = datetime(2024, 5, 1, 12, 0, 7, 250000, tzinfo=timezone.utc)  # not the creation time


def _track(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    k = np.arange(n)
    return 49.0110123 + 1.1e-5 * k, 8.4183456 - 2.3e-5 * k, 112.3 + 0.05 * k


def test_gpmf_round_trip(tmp_path):
    lat, lon, alt = _track(54)
    path = write_gpmf_video(tmp_path / "gopro.mp4", lat, lon, alt, dop=1.5, t0_utc=GPS_UTC)

    log = read_embedded_gps(path)

    assert log.source == "GoPro GPMF" and log.notes == ()
    fixes = log.fixes
    np.testing.assert_allclose(fixes.timestamp_s, np.arange(54) / 18, atol=1e-3)
    np.testing.assert_allclose(fixes.lat_deg, lat, atol=1e-6)
    np.testing.assert_allclose(fixes.lon_deg, lon, atol=1e-6)
    np.testing.assert_allclose(fixes.alt_m, alt, atol=1e-3)
    np.testing.assert_allclose(fixes.accuracy_m, 1.5 * UERE_M)
    assert abs(log.t0_utc - GPS_UTC) < timedelta(milliseconds=1)
    assert fixes.labels[0] == "gopro.mp4 GoPro GPMF track sample 1"


def test_gpmf_gps9_round_trip(tmp_path):
    lat, lon, alt = _track(20)
    path = write_gpmf_video(tmp_path / "hero11.mp4", lat, lon, alt, rate_hz=10, fix=[3, 0],
                            dop=0.8, t0_utc=GPS_UTC, gps9=True)

    log = read_embedded_gps(path)

    np.testing.assert_allclose(log.fixes.timestamp_s, np.arange(10) / 10, atol=1e-3)
    np.testing.assert_allclose(log.fixes.lat_deg, lat[:10], atol=1e-6)
    np.testing.assert_allclose(log.fixes.alt_m, alt[:10], atol=1e-3)
    np.testing.assert_allclose(log.fixes.accuracy_m, 0.8 * UERE_M)
    assert abs(log.t0_utc - GPS_UTC) < timedelta(milliseconds=1)
    assert log.notes == ("hero11.mp4 GoPro GPMF track: 10 of 20 GPS samples without a fix "
                         "skipped",)


def test_gpmf_samples_without_fix_are_skipped_and_counted(tmp_path):
    lat, lon, alt = _track(54)
    path = write_gpmf_video(tmp_path / "gopro.mp4", lat, lon, alt, fix=[3, 0, 2])

    log = read_embedded_gps(path)

    kept = np.r_[0:18, 36:54]
    np.testing.assert_allclose(log.fixes.timestamp_s, kept / 18, atol=1e-3)
    np.testing.assert_allclose(log.fixes.lat_deg, lat[kept], atol=1e-6)
    assert log.fixes.labels[18] == "gopro.mp4 GoPro GPMF track sample 37"
    assert log.notes == ("gopro.mp4 GoPro GPMF track: 18 of 54 GPS samples without a fix skipped",)


def test_gpmf_without_gps_time_takes_the_creation_time_and_says_msl(tmp_path):
    lat, lon, alt = _track(18)
    path = write_gpmf_video(tmp_path / "gopro.mp4", lat, lon, alt, t0_utc=None,
                            extra=klv(b"GPSA", "F", 4, 1, b"MSLV"))

    log = read_embedded_gps(path)

    assert log.t0_utc == CREATION_TIME
    assert any("creation time" in note for note in log.notes)
    assert any("mean sea level" in note for note in log.notes)


def test_gpmf_without_any_fix_is_refused(tmp_path):
    lat, lon, alt = _track(18)
    path = write_gpmf_video(tmp_path / "gopro.mp4", lat, lon, alt, fix=[0])
    with pytest.raises(BundleError, match="none of its 18 GPS samples has a fix"):
        read_embedded_gps(path)


def test_camm_round_trip(tmp_path):
    t_s = np.arange(30) * 0.1 + 0.037
    lat, lon, alt = _track(30)
    path = write_camm_video(tmp_path / "camm.mp4", t_s, lat, lon, alt, t0_utc=GPS_UTC,
                            accuracy_m=4.5)

    log = read_embedded_gps(path)

    assert log.source == "CAMM" and log.notes == ()
    np.testing.assert_allclose(log.fixes.timestamp_s, t_s, atol=1e-3)
    np.testing.assert_allclose(log.fixes.lat_deg, lat, atol=1e-6)
    np.testing.assert_allclose(log.fixes.lon_deg, lon, atol=1e-6)
    np.testing.assert_allclose(log.fixes.alt_m, alt, atol=1e-3)  # a float in CAMM type 6
    np.testing.assert_allclose(log.fixes.accuracy_m, 4.5)
    assert abs(log.t0_utc - GPS_UTC) < timedelta(milliseconds=1)


def test_camm_samples_without_fix_are_skipped_and_counted(tmp_path):
    t_s = np.arange(10) * 0.2
    lat, lon, alt = _track(10)
    path = write_camm_video(tmp_path / "camm.mp4", t_s, lat, lon, alt,
                            fix_type=[0, 0, 3, 3, 2, 0, 3, 3, 3, 3])

    log = read_embedded_gps(path)

    kept = [2, 3, 4, 6, 7, 8, 9]
    np.testing.assert_allclose(log.fixes.timestamp_s, t_s[kept], atol=1e-3)
    np.testing.assert_allclose(log.fixes.lon_deg, lon[kept], atol=1e-6)
    assert log.notes == ("camm.mp4 CAMM track: 3 of 10 GPS samples without a fix skipped",)


def test_camm_type5_takes_the_creation_time(tmp_path):
    t_s = np.arange(10) * 0.2
    lat, lon, alt = _track(10)
    path = write_camm_video(tmp_path / "camm.mp4", t_s, lat, lon, alt, packet_type=5)

    log = read_embedded_gps(path)

    np.testing.assert_allclose(log.fixes.lat_deg, lat, atol=1e-9)
    assert log.fixes.accuracy_m is None
    assert log.t0_utc == CREATION_TIME


def test_video_without_gps_gives_none(tmp_path):
    assert read_embedded_gps(write_video(tmp_path / "plain.mp4")) is None


def test_corrupt_gpmf_payload_is_a_bundle_error(tmp_path):
    lat, lon, alt = _track(36)
    path = write_gpmf_video(tmp_path / "gopro.mp4", lat, lon, alt)
    data = bytearray(path.read_bytes())
    at = data.index(b"GPS5l", data.index(b"GPS5l") + 1)  # the second payload's GPS5
    data[at + 6:at + 8] = b"\xff\xff"  # repeat: far more samples than the payload holds
    path.write_bytes(bytes(data))

    with pytest.raises(BundleError, match=r"GoPro GPMF GPS track \(stream 1\) is damaged: "
                                          r"payload 2 at 1\.000 s: GPS5 claims"):
        read_embedded_gps(path)


def test_corrupt_camm_packet_is_a_bundle_error(tmp_path):
    t_s = np.arange(5) * 0.2
    lat, lon, alt = _track(5)
    path = write_camm_video(tmp_path / "camm.mp4", t_s, lat, lon, alt)
    data = bytearray(path.read_bytes())
    record = camm_type6(CREATION_TIME + timedelta(seconds=0.4), 3, lat[2], lon[2], alt[2])
    at = data.index(record)
    data[at + 2:at + 4] = b"\x63\x00"  # packet type 99
    path.write_bytes(bytes(data))

    with pytest.raises(BundleError, match=r"CAMM GPS track .* damaged: payload 3 .*type 99"):
        read_embedded_gps(path)


@pytest.mark.parametrize("content", [b"", b"frame,timestamp_s\n000000,0.0\n" * 50])
def test_not_a_video_is_a_bundle_error(tmp_path, content):
    path = tmp_path / "journey.mp4"
    path.write_bytes(content)
    with pytest.raises(BundleError, match="journey.mp4 is not a video file"):
        read_embedded_gps(path)


def test_more_fixes_than_allowed_is_a_bundle_error(tmp_path):
    lat, lon, alt = _track(36)
    path = write_gpmf_video(tmp_path / "gopro.mp4", lat, lon, alt)
    assert len(read_embedded_gps(path, max_points=36).fixes.timestamp_s) == 36
    with pytest.raises(BundleError, match="more than 20 fixes"):
        read_embedded_gps(path, max_points=20)
