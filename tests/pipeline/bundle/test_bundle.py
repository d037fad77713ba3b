"""Reading journey bundles: the valid variants round-trip, every contract violation is a BundleError
whose message names the fact to fix, and hostile zips are refused."""

from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.pipeline.bundle import check_bundle, read_bundle
from app.pipeline.config import BundleLimits
from app.pipeline.bundle.gps import GpsFixes, interpolate_to_frames
from app.pipeline.bundle.gps_exif import ExifFix, gps_from_exif
from app.pipeline.types import AntennaOffset, BundleError, CameraModel
from tests.utils import bundle_factory as bf


def _read(tmp_path: Path, files, **kwargs):
    zip_path = tmp_path / "bundle.zip"
    zip_path.write_bytes(files if isinstance(files, bytes) else bf.zip_bytes(files))
    return read_bundle(zip_path, tmp_path / "extract", **kwargs)


def _error(tmp_path: Path, files, **kwargs) -> str:
    with pytest.raises(BundleError) as info:
        _read(tmp_path, files, **kwargs)
    return info.value.reason


def test_valid_bundle_round_trips_with_interpolated_fixes(tmp_path):
    files = bf.valid_files()
    journey = _read(tmp_path, files)
    assert journey.camera_id == "test-cam" and journey.vehicle_id == "car-7"
    assert journey.captured_at == "2024-05-01T12:30:00+00:00"
    assert journey.camera_prior is None
    assert (journey.image_width, journey.image_height) == (64, 48)
    assert journey.frame_ids == ["000000", "000001", "000002", "000003", "000004"]
    for frame in journey.frames:
        assert frame.path == tmp_path / "extract" / "frames" / f"{frame.frame_id}.png"
        assert frame.path.read_bytes() == files[f"frames/{frame.frame_id}.png"]
    np.testing.assert_allclose([f.timestamp_s for f in journey.frames],
                               [0.05, 0.15, 0.25, 0.35, 0.45], atol=1e-12)
    # Fixes at 0, .2, .4, .6 s with lat = LAT0 + 1e-5 k^2: frames sit 1/4 and 3/4 between fixes.
    np.testing.assert_allclose(journey.lat_deg - bf.LAT0,
                               [0.25e-5, 0.75e-5, 1.75e-5, 3.25e-5, 5.25e-5], atol=1e-12)
    np.testing.assert_allclose(journey.lon_deg - bf.LON0,
                               [0.5e-5, 1.5e-5, 2.5e-5, 3.5e-5, 4.5e-5], atol=1e-12)
    np.testing.assert_allclose(journey.alt_m, [112.125, 112.375, 112.625, 112.875, 113.125])
    assert journey.has_altitude
    assert [(d.track_id, d.frame_id) for d in journey.detections] == \
        [("0", f) for f in journey.frame_ids] + [("1", "000001"), ("1", "000002"), ("1", "000003")]
    first = journey.detections[0]
    assert (first.cls, first.x1, first.y1, first.x2, first.y2, first.score) == \
        ("stop", 10.0, 10.0, 18.0, 18.0, 0.9)
    assert journey.detections[-1].score is None


def test_per_frame_positions_and_camera_prior(tmp_path):
    files = bf.valid_files(fix_rows=False)
    files["manifest.json"] = bf.manifest_bytes(
        camera_prior={"fx": 50, "fy": 51.5, "cx": 31.5, "cy": 23.5, "k1": -0.1, "k2": 0.01})
    journey = _read(tmp_path, files)
    lat, lon, alt = bf.frame_positions()
    np.testing.assert_allclose(journey.lat_deg, lat, atol=1e-9)
    np.testing.assert_allclose(journey.lon_deg, lon, atol=1e-9)
    np.testing.assert_allclose(journey.alt_m, alt, atol=1e-9)
    assert journey.camera_prior == CameraModel(64, 48, 50.0, 51.5, 31.5, 23.5, -0.1, 0.01)


def test_the_gps_antenna_offset_reaches_the_journey(tmp_path):
    assert _read(tmp_path, bf.valid_files()).gps_antenna_offset is None
    files = bf.valid_files()
    files["manifest.json"] = bf.manifest_bytes(
        gps_antenna_offset_m={"forward": -1.09, "left": 0.25, "up": -0.72})
    assert _read(tmp_path, files).gps_antenna_offset == \
        AntennaOffset(forward_m=-1.09, left_m=0.25, up_m=-0.72)


@pytest.mark.parametrize("offset, detail", [
    ({"forward": 10.5, "left": 0, "up": 0}, "forward: Input should be less than or equal to 10"),
    ({"forward": 0, "left": -109, "up": 0}, "left: Input should be greater than or equal to -10"),
    ({"forward": "1.09", "left": 0, "up": 0}, "forward: Input should be a valid number"),
    ({"forward": 1.09, "left": 0.25}, "up: Field required"),
    ({"forward": 0, "left": 0, "up": float("nan")}, "up: Input should be a finite number"),
    ([-1.09, 0.25, -0.72], ": Input should be a valid dictionary"),
])
def test_a_bad_gps_antenna_offset_is_refused_by_name(tmp_path, offset, detail):
    files = bf.valid_files()
    files["manifest.json"] = bf.manifest_bytes(gps_antenna_offset_m=offset)
    assert _error(tmp_path, files).startswith(
        f"manifest.json is invalid: gps_antenna_offset_m{'.' if detail[0] != ':' else ''}{detail}")


def test_altitude_absent_or_partly_empty(tmp_path):
    rows = [r[:4] for r in bf.gps_rows()]
    journey = _read(tmp_path, {**bf.valid_files(), "gps.csv": bf.csv_bytes(bf.GPS_HEADER[:4], rows)})
    assert np.all(np.isnan(journey.alt_m)) and not journey.has_altitude
    rows = [list(r) for r in bf.gps_rows()]
    rows[-1][4] = ""  # the last fix (0.6 s) has no altitude
    rows[6][4] = ""   # nor the fix at 0.4 s: altitudes come from 0.0 and 0.2 s, and frames after
    # 0.2 s hold the last one (they are within the extrapolation bound)
    journey = _read(tmp_path, {**bf.valid_files(), "gps.csv": bf.csv_bytes(bf.GPS_HEADER, rows)})
    np.testing.assert_allclose(journey.alt_m, [112.125, 112.375, 112.5, 112.5, 112.5])


def test_gpx_with_one_point_per_frame(tmp_path):
    journey = _read(tmp_path, bf.valid_files(gps="gpx"))
    np.testing.assert_allclose([f.timestamp_s for f in journey.frames], [0, .1, .2, .3, .4],
                               atol=1e-9)
    lat, lon, alt = bf.frame_positions()
    np.testing.assert_allclose(journey.lat_deg, lat, atol=1e-9)
    np.testing.assert_allclose(journey.alt_m, alt, atol=1e-9)


def test_gpx_with_fewer_points_places_frames_by_time(tmp_path):
    # The track crosses midnight UTC; frames are at captured_at + i / frame_rate_hz on it, and
    # their times count from its first point.
    t0, t1, t2 = (datetime(2024, 5, 1, 23, 59, 59, tzinfo=timezone.utc),
                  datetime(2024, 5, 2, 0, 0, 0, tzinfo=timezone.utc),
                  datetime(2024, 5, 2, 0, 0, 1, tzinfo=timezone.utc))
    points = [(bf.LAT0, bf.LON0, None, t0), (bf.LAT0 + 2e-5, bf.LON0, None, t1),
              (bf.LAT0 + 6e-5, bf.LON0 + 4e-5, None, t2)]
    files = {**bf.valid_files(), "gps.gpx": bf.gpx_bytes(points),
             "manifest.json": bf.manifest_bytes(captured_at="2024-05-01T23:59:59Z",
                                                frame_rate_hz=2.0)}
    del files["gps.csv"]
    journey = _read(tmp_path, files)
    np.testing.assert_allclose([f.timestamp_s for f in journey.frames], [0, .5, 1, 1.5, 2])
    np.testing.assert_allclose(journey.lat_deg - bf.LAT0, [0, 1e-5, 2e-5, 4e-5, 6e-5], atol=1e-12)
    np.testing.assert_allclose(journey.lon_deg - bf.LON0, [0, 0, 0, 2e-5, 4e-5], atol=1e-12)
    assert np.all(np.isnan(journey.alt_m))


def test_gps_csv_takes_precedence_over_gpx(tmp_path):
    files = {**bf.valid_files(), "gps.gpx": b"<not xml"}
    assert _read(tmp_path, files).lat_deg[0] == pytest.approx(bf.LAT0 + 0.25e-5, abs=1e-12)
    del files["gps.csv"]
    assert "gps.gpx is not valid XML" in _error(tmp_path, files)


def test_exif_gps_from_jpeg_frames(tmp_path):
    journey = _read(tmp_path, bf.valid_files(gps="exif", image_format="jpg"))
    assert journey.frames[0].path.name == "000000.jpg"
    np.testing.assert_allclose([f.timestamp_s for f in journey.frames], [0, .1, .2, .3, .4],
                               atol=1e-6)
    lat, lon, alt = bf.frame_positions()
    np.testing.assert_allclose(journey.lat_deg, lat, atol=1e-8)
    np.testing.assert_allclose(journey.lon_deg, lon, atol=1e-8)
    np.testing.assert_allclose(journey.alt_m, alt, atol=1e-6)


def test_exif_whole_second_clock_allows_shared_timestamps_but_not_going_back():
    def fix(second: int, lat: float) -> ExifFix:
        when = datetime(2024, 5, 1, 12, 0, second, tzinfo=timezone.utc)
        return ExifFix(lat, 8.0, math.nan, None, when, None)
    gps = gps_from_exif([fix(0, 49.0), fix(0, 49.00001), fix(1, 49.00002)], ["a", "b", "c"])
    np.testing.assert_allclose(gps.timestamp_s, [0, 0, 1])
    with pytest.raises(BundleError, match="frame b at -1.000 s comes after frame a at 0.000 s"):
        gps_from_exif([fix(1, 49.0), fix(0, 49.00001)], ["a", "b"])


def test_interpolation_across_the_antimeridian():
    fixes = GpsFixes(np.array([0.0, 1.0]), np.array([10.0, 10.0]), np.array([179.9999, -179.9999]),
                     np.array([np.nan, np.nan]), ("a", "b"))
    gps = interpolate_to_frames(fixes, np.array([0.25, 0.75]), ["f0", "f1"])
    np.testing.assert_allclose(gps.lon_deg, [179.99995, -179.99995], atol=1e-9)


@pytest.mark.parametrize("case", bf.BROKEN_CASES)
def test_each_contract_violation_is_a_bundle_error_naming_the_fact(tmp_path, case):
    data, fragment = bf.broken_bundle(case)
    assert fragment in _error(tmp_path, data)


def test_hostile_names_write_nothing_outside_the_extract_dir(tmp_path):
    _error(tmp_path, bf.broken_bundle("path_traversal")[0])
    assert not (tmp_path / "evil.png").exists() and not (tmp_path / "extract").exists()


def test_unknown_files_are_ignored_and_detections_are_optional(tmp_path):
    files = {**bf.valid_files(detections=False), "notes.txt": b"hi", "frames/readme.txt": b"x",
             "frames/sub/000009.png": bf.image_bytes(), "__MACOSX/frames/._000000.png": b"junk",
             "frames/._000000.png": b"junk"}
    journey = _read(tmp_path, files)
    assert journey.frame_ids == bf.frame_ids() and journey.detections == []


def test_decode_images_false_checks_headers_only(tmp_path):
    data, _ = bf.broken_bundle("truncated_image")
    journey = _read(tmp_path, data, decode_images=False)
    assert (journey.image_width, journey.image_height) == (64, 48)
    assert "is 32x24, expected 64x48" in _error(tmp_path, bf.broken_bundle("image_size_mismatch")[0],
                                                  decode_images=False)


@pytest.mark.parametrize("limits, fragment", [
    (BundleLimits(max_files=7), "8 entries, more than the limit of 7"),
    (BundleLimits(max_frames=4), "5 frames, more than the limit of 4"),
    (BundleLimits(max_member_bytes=5000), "more than the limit of 5000 bytes for this file"),
    (BundleLimits(max_frame_pixels=64 * 47), "is 64x48, more than the limit of 3008 pixels"),
    (BundleLimits(max_detections=7), "detections.csv has more than 7 rows, the limit per journey"),
    (BundleLimits(max_boxes_per_frame=1),
     "detection row 4: frame 000001 has more than 1 detection boxes, the limit per frame"),
    (BundleLimits(max_gps_rows=5), "gps.csv has more than 5 rows"),
])
def test_limits(tmp_path, limits, fragment):
    assert fragment in _error(tmp_path, bf.valid_files(), limits=limits)


def test_gpx_point_limit(tmp_path):
    reason = _error(tmp_path, bf.valid_files(gps="gpx"), limits=BundleLimits(max_gps_rows=3))
    assert "gps.gpx has more than 3 track points, the limit per journey" in reason


def test_zip_bomb_over_the_declared_limit(tmp_path):
    data = bf.zip_bytes(bf.zip_bomb_files(3 * 2**20))
    assert len(data) - len(bf.zip_bytes(bf.valid_files())) < 10_000  # 3 MiB of zeros in < 10 kB
    reason = _error(tmp_path, data, limits=BundleLimits(max_uncompressed_bytes=2 * 2**20))
    assert reason.startswith("bundle unpacks to 3.") and "more than the limit of 2.0 MiB" in reason


def test_zip_inflating_many_times_its_size_is_refused_before_unpacking(tmp_path):
    data = bf.zip_bytes(bf.zip_bomb_files(3 * 2**20))
    limits = BundleLimits(max_unpack_ratio=20, max_unpack_ratio_floor_bytes=2**20)
    reason = _error(tmp_path, data, limits=limits)
    assert reason.startswith("bundle unpacks to 3.") and "more than 20 times its size" in reason
    # Under the floor, a small bundle is not held to the ratio.
    assert _read(tmp_path, data, limits=BundleLimits(max_unpack_ratio=20)).frame_ids


def test_check_bundle_writes_nothing_and_builds_no_tracks(tmp_path):
    zip_path = bf.write_zip(tmp_path / "b.zip", bf.valid_files(blank_track_ids=True))
    checked = check_bundle(zip_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.zip"]
    assert (checked.camera_id, checked.vehicle_id, checked.n_frames, checked.n_detections) == \
        ("test-cam", "car-7", 5, 8)
    truncated = tmp_path / "c.zip"
    truncated.write_bytes(bf.broken_bundle("truncated_image")[0])
    with pytest.raises(BundleError, match="frame 000002.png is not a readable image"):
        check_bundle(truncated)  # frames are decoded: the header alone looks fine


def test_entry_lying_about_its_size_is_refused(tmp_path):
    data = bf.zip_bytes(bf.valid_files())
    reason = _error(tmp_path, bf.with_declared_size(data, "gps.csv", 20))
    assert "gps.csv in the bundle is corrupt or unreadable" in reason


@pytest.mark.parametrize("name, data, fragment", [
    ("manifest.json", b"[" * 100_000, "nested too deeply"),
    ("manifest.json", b'{"format": "signmap-journey/1"}', "camera_id: Field required"),
    ("manifest.json", b"\xff\xfe{}", "manifest.json is not UTF-8"),
    ("detections.csv", bf.csv_bytes(bf.DETECTIONS_HEADER, bf.detection_rows()) + b"\xff\xfe\n",
     "detections.csv is not UTF-8 text"),
    ("frames/000001.png", bf.image_bytes("png")[:8] + b"\x00" * 40, "not a readable image"),
    ("gps.csv", bf.csv_bytes(bf.GPS_HEADER, [("000000", "0.0", "49", "8", "")] +
                             [(f, "1.0", "", "", "") for f in bf.frame_ids()[1:]]),
     "frame timestamps are not increasing: frame 000002 at 1.000 s"),
    ("gps.csv", bf.csv_bytes(bf.GPS_HEADER, [*bf.gps_rows(), ("000001", "0.9", "", "", "")]),
     "row 11 gives frame 000001 timestamp 0.9, but row 4 gave it 0.15"),
    ("gps.csv", bf.csv_bytes(["frame;timestamp_s;lat;lon"], [["x;1;2;3"]]), "no header row"),
    ("gps.csv", bf.csv_bytes(bf.GPS_HEADER, [("", "0.0", "", "", "")]), "neither a frame nor"),
    ("detections.csv", bf.csv_bytes(bf.DETECTIONS_HEADER, [*bf.detection_rows(),
                                                           ("000002", "0", "stop", 1, 1, 5, 5, "")]),
     "track 0 already has a box in frame 000002 (row 5)"),
    ("detections.csv", bf.csv_bytes(bf.DETECTIONS_HEADER, [("000002", "0", "stop", 1, "nan", 5, 5, "")]),
     "detection row 2: y1 is 'nan', expected a finite number"),
])
def test_more_violations(tmp_path, name, data, fragment):
    assert fragment in _error(tmp_path, {**bf.valid_files(), name: data})


def test_box_within_one_pixel_of_the_border_is_accepted(tmp_path):
    rows = [("000000", "5", "stop", -1.5, -1.5, 64.5, 48.5, "")]
    files = {**bf.valid_files(), "detections.csv": bf.csv_bytes(bf.DETECTIONS_HEADER, rows)}
    assert len(_read(tmp_path, files).detections) == 1
    rows = [("000000", "5", "stop", -1.6, 0, 10, 10, "")]
    files["detections.csv"] = bf.csv_bytes(bf.DETECTIONS_HEADER, rows)
    assert "lies outside the 64x48 image" in _error(tmp_path, files)


def test_non_jpeg_png_frame_and_nested_bundle_folder(tmp_path):
    ok, bmp = cv2.imencode(".bmp", np.zeros((48, 64, 3), np.uint8))
    assert "is a BMP image; frames must be JPEG or PNG" in \
        _error(tmp_path, {**bf.valid_files(), "frames/000001.png": bmp.tobytes()})
    nested = {f"journey/{k}": v for k, v in bf.valid_files().items()}
    assert "found journey/manifest.json: zip the bundle's contents" in _error(tmp_path, nested)


def test_blank_track_ids_are_associated(tmp_path):
    journey = _read(tmp_path, bf.valid_files(blank_track_ids=True))
    groups = {(d.track_id, d.cls) for d in journey.detections}
    assert groups == {("auto-0", "stop"), ("auto-1", "yield")}
    assert [d.frame_id for d in journey.detections if d.track_id == "auto-1"] == \
        ["000001", "000002", "000003"]
