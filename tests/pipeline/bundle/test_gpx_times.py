"""Frames on a gps.gpx track that is not one point per frame are placed by their times (the
manifest's captured_at + i / frame_rate_hz, or their EXIF times), shifted by gps_time_offset_s;
without times they are refused, never spread over the track."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest
from PIL import ExifTags, Image

from app.pipeline.bundle import check_bundle, read_bundle
from app.pipeline.bundle.gps import gps_from_gpx, read_gpx
from app.pipeline.bundle.gps_exif import frame_times_utc_s, read_exif_time
from app.pipeline.bundle.manifest import parse_manifest
from app.pipeline.types import BundleError
from tests.utils import bundle_factory as bf

TRACK_T0 = datetime(2024, 5, 1, 12, 29, 57, tzinfo=timezone.utc)  # 3 s before CAPTURED_AT
DLAT_PER_S = 1e-5  # the track runs north at ~1.1 m/s, so a frame's latitude tells its time


def _track(n_points: int = 15) -> bytes:
    """A 1 Hz track from TRACK_T0, 14 s long with the default 15 points."""
    return bf.gpx_bytes([(bf.LAT0 + DLAT_PER_S * k, bf.LON0, bf.ALT0 + k,
                          TRACK_T0 + timedelta(seconds=k)) for k in range(n_points)])


def _lat_at(seconds_after_track_t0) -> np.ndarray:
    return bf.LAT0 + DLAT_PER_S * np.asarray(seconds_after_track_t0, float)


def _files(n_frames: int, manifest: dict | None = None, **frame_kwargs) -> dict[str, bytes]:
    files = bf.valid_files(n_frames, gps="none", detections=False, **frame_kwargs)
    files["gps.gpx"] = _track()
    files["manifest.json"] = bf.manifest_bytes(**(manifest or {}))
    return files


def _read(tmp_path: Path, files: dict[str, bytes]):
    return read_bundle(bf.write_zip(tmp_path / "bundle.zip", files), tmp_path / "extract")


def _error(tmp_path: Path, files: dict[str, bytes]) -> str:
    with pytest.raises(BundleError) as info:
        _read(tmp_path, files)
    return info.value.reason


def _jpeg_with_time(seed: int, when: datetime, *, subsec: bool = True, zone: bool = True) -> bytes:
    exif = Image.Exif()
    ifd = exif.get_ifd(ExifTags.IFD.Exif)
    ifd[ExifTags.Base.DateTimeOriginal] = when.strftime("%Y:%m:%d %H:%M:%S")
    if subsec:
        ifd[ExifTags.Base.SubsecTimeOriginal] = f"{when.microsecond // 1000:03d}"
    if zone:
        ifd[ExifTags.Base.OffsetTimeOriginal] = when.strftime("%z")[:3] + ":" + \
            when.strftime("%z")[3:]
    return bf.image_bytes("jpg", seed=seed, exif=exif)


def _with_exif_frames(files: dict[str, bytes], times: list[datetime], **kwargs) -> dict:
    files = {k: v for k, v in files.items() if not k.startswith("frames/")}
    for i, when in enumerate(times):
        files[f"frames/{i:06d}.jpg"] = _jpeg_with_time(i, when, **kwargs)
    return files


def test_frames_shorter_than_the_track_lie_where_their_times_say(tmp_path):
    # The case: a 14 s track, 160 frames at 20 Hz (7.95 s) from captured_at, 3 s in.
    # Spread evenly, the last frame sat at the track's end (14 s) instead of 10.95 s.
    files = _files(160, {"frame_rate_hz": 20.0})
    journey = _read(tmp_path, files)
    t_s = 3.0 + np.arange(160) / 20.0
    np.testing.assert_allclose([f.timestamp_s for f in journey.frames], t_s, atol=1e-9)
    np.testing.assert_allclose(journey.lat_deg, _lat_at(t_s), atol=1e-10)
    np.testing.assert_allclose(journey.alt_m, bf.ALT0 + t_s, atol=1e-6)
    assert journey.warnings == []


def test_exactly_one_point_per_frame_still_pairs_them(tmp_path):
    # 15 frames, 15 points: point i is frame i, whatever the manifest says of the frame rate.
    journey = _read(tmp_path, _files(15, {"frame_rate_hz": 20.0}))
    np.testing.assert_allclose([f.timestamp_s for f in journey.frames], np.arange(15.0))
    np.testing.assert_allclose(journey.lat_deg, _lat_at(np.arange(15)), atol=1e-10)


def test_gps_time_offset_is_added_to_the_camera_time(tmp_path):
    # The camera's clock is 2.5 s behind GPS: frame i is at 3 + 2.5 + i / 10 s on the track.
    journey = _read(tmp_path, _files(30, {"frame_rate_hz": 10.0, "gps_time_offset_s": 2.5}))
    t_s = 5.5 + np.arange(30) / 10.0
    np.testing.assert_allclose(journey.lat_deg, _lat_at(t_s), atol=1e-10)
    np.testing.assert_allclose([f.timestamp_s for f in journey.frames], t_s, atol=1e-9)


def test_captured_at_with_an_offset_is_converted_to_utc(tmp_path):
    local = "2024-05-01T14:30:04+02:00"  # 12:30:04Z, 7 s after the track's start
    journey = _read(tmp_path, _files(12, {"captured_at": local, "frame_rate_hz": 4.0}))
    np.testing.assert_allclose(journey.lat_deg, _lat_at(7.0 + np.arange(12) / 4.0), atol=1e-10)


def test_exif_times_with_a_zone_place_the_frames(tmp_path):
    cest = timezone(timedelta(hours=2))
    times = [(TRACK_T0 + timedelta(seconds=1.0 + 0.25 * i)).astimezone(cest) for i in range(20)]
    # captured_at (12:30:00Z) disagrees with the EXIF times: the frames' own times win.
    files = _with_exif_frames(_files(20), times)
    journey = _read(tmp_path, files)
    np.testing.assert_allclose(journey.lat_deg, _lat_at(1.0 + 0.25 * np.arange(20)), atol=1e-10)


def test_exif_local_times_keep_their_spacing_from_captured_at(tmp_path):
    # Camera clock at local time (+05:00, not written): only the spacing counts (irregular here:
    # a frame was skipped), anchored at captured_at = 3 s into the track.
    offsets_s = np.array([0.0, 0.5, 1.0, 2.0, 2.5, 3.0, 3.5, 4.0])
    local = datetime(2024, 5, 1, 17, 30, 0)
    times = [local + timedelta(seconds=float(s)) for s in offsets_s]
    journey = _read(tmp_path, _with_exif_frames(_files(8), times, zone=False))
    np.testing.assert_allclose(journey.lat_deg, _lat_at(3.0 + offsets_s), atol=1e-10)


def test_exif_local_times_without_captured_at_are_refused(tmp_path):
    files = _with_exif_frames(_files(8), [datetime(2024, 5, 1, 17, 30, i) for i in range(8)],
                              zone=False)
    files["manifest.json"] = bf.manifest_bytes(captured_at=None)
    reason = _error(tmp_path, files)
    assert "gps.gpx has 15 track points for 8 frames" in reason
    assert "EXIF DateTimeOriginal has no time zone (OffsetTimeOriginal)" in reason
    assert "give captured_at" in reason


def test_exif_whole_seconds_that_repeat_are_refused(tmp_path):
    times = [TRACK_T0 + timedelta(seconds=1 + i // 4) for i in range(8)]  # 4 frames a second
    reason = _error(tmp_path, _with_exif_frames(_files(8), times, subsec=False))
    assert "frames 000000 and 000001 have EXIF times" in reason
    assert "SubSecTimeOriginal" in reason and "frame_rate_hz" in reason


def test_frames_without_any_time_are_refused_not_spread(tmp_path):
    # PNG frames (no EXIF), captured_at but no frame rate: nothing says when the frames were.
    reason = _error(tmp_path, _files(8))
    assert reason.startswith("gps.gpx has 15 track points for 8 frames, so the frames are placed "
                             "on it by time, and the frames have no times")
    assert "(these frames are not all JPEGs)" in reason
    for needed in ("captured_at", "frame_rate_hz", "EXIF DateTimeOriginal"):
        assert needed in reason
    # The upload check says the same, without reading the frames' EXIF first.
    with pytest.raises(BundleError, match="frames have no times"):
        check_bundle(bf.write_zip(tmp_path / "check.zip", _files(8)))


def test_jpeg_frames_without_exif_time_are_refused(tmp_path):
    reason = _error(tmp_path, _files(8, image_format="jpg"))
    assert "JPEG frames with EXIF DateTimeOriginal (frame 000000 has none)" in reason


def test_frame_rate_without_captured_at_is_refused(tmp_path):
    files = _files(8, {"captured_at": None, "frame_rate_hz": 10.0})
    assert "frame_rate_hz but no captured_at" in _error(tmp_path, files)


def test_frames_off_the_track_name_both_spans_in_utc(tmp_path):
    # captured_at an hour late (a local time written as UTC): no frame lies on the track.
    files = _files(8, {"captured_at": "2024-05-01T13:30:00Z", "frame_rate_hz": 10.0})
    reason = _error(tmp_path, files)
    assert ("gps.gpx runs from 2024-05-01T12:29:57.000+00:00 to 2024-05-01T12:30:11.000+00:00, "
            "the frames from 2024-05-01T13:30:00.000+00:00") in reason
    assert "gps_time_offset_s" in reason


def test_gps_from_gpx_without_frame_times_is_refused():
    with pytest.raises(BundleError, match="give captured_at and frame_rate_hz"):
        gps_from_gpx(_track(), bf.frame_ids(8))


def test_read_gpx_gives_the_first_point_time():
    log = read_gpx(_track(3))
    assert log.t0_utc == TRACK_T0 and log.source == "gps.gpx"
    np.testing.assert_array_equal(log.fixes.timestamp_s, [0.0, 1.0, 2.0])


def test_frame_times_from_the_manifest_and_exif():
    ids = bf.frame_ids(3)
    start = "2024-05-01T12:30:00Z"
    t0 = datetime(2024, 5, 1, 12, 30, tzinfo=timezone.utc).timestamp()
    np.testing.assert_allclose(
        frame_times_utc_s(ids, captured_at=start, frame_rate_hz=2.0, exif_times=None,
                          gps_time_offset_s=-1.0), t0 - 1.0 + np.array([0.0, 0.5, 1.0]))
    aware = [datetime(2024, 5, 1, 12, 30, s, tzinfo=timezone.utc) for s in (1, 2, 4)]
    np.testing.assert_allclose(frame_times_utc_s(ids, captured_at=None, frame_rate_hz=None,
                                                 exif_times=aware), t0 + np.array([1, 2, 4]))
    mixed = [aware[0], aware[1].replace(tzinfo=None), aware[2]]
    with pytest.raises(BundleError, match="has a time zone .* and frame 000001's lacks one"):
        frame_times_utc_s(ids, captured_at=start, frame_rate_hz=None, exif_times=mixed)


def test_read_exif_time_keeps_the_zone_only_when_stated():
    when = datetime(2024, 5, 1, 14, 30, 0, 250000, tzinfo=timezone(timedelta(hours=2)))
    assert read_exif_time(_jpeg_with_time(0, when)) == when
    assert read_exif_time(_jpeg_with_time(0, when, zone=False)) == when.replace(tzinfo=None)
    assert read_exif_time(bf.image_bytes("png")) is None
    assert read_exif_time(b"\xff\xd8\xffnot a jpeg") is None


@pytest.mark.parametrize("extra, fragment", [
    ('"frame_rate_hz": 0', "frame_rate_hz: Input should be greater than 0"),
    ('"frame_rate_hz": 1001', "frame_rate_hz: Input should be less than or equal to 1000"),
    ('"frame_rate_hz": "10"', "frame_rate_hz: Input should be a valid number"),
    ('"frame_rate_hz": NaN', "frame_rate_hz: Input should be a finite number"),
    ('"gps_time_offset_s": 1e7', "gps_time_offset_s: Input should be less than or equal to"),
    ('"gps_time_offset_s": -Infinity', "gps_time_offset_s: Input should be a finite number"),
])
def test_manifest_checks_the_new_fields(extra, fragment):
    with pytest.raises(BundleError, match=fragment):
        parse_manifest(b'{"format": "signmap-journey/1", "camera_id": "c", ' + extra.encode()
                       + b"}")
    manifest = parse_manifest(b'{"format": "signmap-journey/1", "camera_id": "c", '
                              b'"frame_rate_hz": 30, "gps_time_offset_s": -2.5}')
    assert (manifest.frame_rate_hz, manifest.gps_time_offset_s) == (30.0, -2.5)
