"""Frames outside the GPS fixes' time span: extrapolated when a little outside, dropped from the
journey's ends when further, the journey refused only when too little is left (app.pipeline.bundle.gps)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from app.pipeline.bundle import read_bundle
from app.pipeline.bundle.gps import GpsFixes, extrapolation_bound_s, gps_from_gpx, interpolate_to_frames
from app.commands.process_report import report
from app.pipeline.types import BundleError, Calibration, CameraModel, JourneyResult
from tests.utils import bundle_factory as bf

LAT_RATE_DEG_PER_S = 1e-4  # ~11 m/s northwards


def _fixes(t_s, lat_deg, alt_m=None) -> GpsFixes:
    t_s = np.asarray(t_s, float)
    alt = np.full(len(t_s), np.nan) if alt_m is None else np.asarray(alt_m, float)
    return GpsFixes(t_s, np.asarray(lat_deg, float), np.full(len(t_s), bf.LON0), alt,
                    tuple(f"fix {k}" for k in range(len(t_s))))


def _ids(n: int) -> list[str]:
    return bf.frame_ids(n)


def _bundle(tmp_path: Path, frame_t_s: np.ndarray, fix_t_s: np.ndarray) -> Path:
    """A bundle whose fixes move north at LAT_RATE_DEG_PER_S (lat = LAT0 at t = 0, alt 100 + t);
    detections: track "0" in every frame, track "1" in frames 0..2 only."""
    n = len(frame_t_s)
    files = bf.valid_files(n, detections=False)
    rows = [(t, (f, f"{t:.3f}", "", "", "")) for f, t in zip(_ids(n), frame_t_s)]
    rows += [(t, ("", f"{t:.3f}", f"{bf.LAT0 + LAT_RATE_DEG_PER_S * t:.9f}", f"{bf.LON0:.7f}",
                  f"{100 + t:.3f}")) for t in fix_t_s]
    files["gps.csv"] = bf.csv_bytes(bf.GPS_HEADER, [r for _, r in sorted(rows)])
    detections = [(f, "0", "stop", 10, 10, 18, 18, 0.9) for f in _ids(n)]
    detections += [(f, "1", "yield", 40, 20, 48, 28, "") for f in _ids(3)]
    files["detections.csv"] = bf.csv_bytes(bf.DETECTIONS_HEADER, detections)
    return bf.write_zip(tmp_path / "bundle.zip", files)


def test_bound_grows_with_the_fix_interval_within_limits():
    assert extrapolation_bound_s(np.array([0.0])) == 1.5
    assert extrapolation_bound_s(np.arange(0, 5, 0.1)) == 1.5  # 10 Hz
    assert extrapolation_bound_s(np.arange(0, 10, 1.6)) == pytest.approx(2.4)
    assert extrapolation_bound_s(np.arange(0, 50, 5.0)) == 3.0  # capped


def test_frames_within_the_bound_continue_the_end_fixes_motion():
    # lat = 49 + 1e-4 t^2 at fixes 1..5 s: end velocities 3e-4 (1-2 s) and 9e-4 deg/s (4-5 s).
    t_fix = np.arange(1.0, 6.0)
    frames_t = np.array([0.0, 0.5, 1.0, 3.5, 5.0, 6.2])
    gps = interpolate_to_frames(_fixes(t_fix, 49 + 1e-4 * t_fix**2, alt_m=100 + t_fix),
                                frames_t, _ids(6))
    assert gps.kept == slice(0, 6) and gps.warnings == ()
    expected = 49 + 1e-4 * np.array([1 - 3 * 1.0, 1 - 3 * 0.5, 1, (9 + 16) / 2, 25, 25 + 9 * 1.2])
    np.testing.assert_allclose(gps.lat_deg, expected, atol=1e-12)
    np.testing.assert_allclose(gps.lon_deg, bf.LON0, atol=1e-12)
    # Altitude is held at the end fixes' values, not extrapolated.
    np.testing.assert_allclose(gps.alt_m, [101, 101, 101, 103.5, 105, 105])


def test_end_fixes_too_close_in_time_hold_the_end_position():
    t_fix = np.array([1.0, 1.01, 2.0])
    gps = interpolate_to_frames(_fixes(t_fix, [49.0, 49.1, 49.0001]), np.array([0.0, 1.5]),
                                _ids(2))
    assert gps.lat_deg[0] == 49.0  # not 49 - 10 deg from a 0.01 s "velocity"


def test_dropout_in_the_middle_is_interpolated_across():
    t_fix = np.array([0.0, 1.0, 2.0, 3.0, 8.0, 9.0, 10.0])  # 5 s without a fix
    lat = 49 + 1e-4 * t_fix
    frames_t = 0.05 + 0.1 * np.arange(100)
    gps = interpolate_to_frames(_fixes(t_fix, lat), frames_t, _ids(100))
    assert gps.kept == slice(0, 100) and gps.warnings == ()
    np.testing.assert_allclose(gps.lat_deg, 49 + 1e-4 * frames_t, atol=1e-12)


def test_frames_beyond_the_bound_are_dropped_from_both_ends(tmp_path, caplog):
    # 60 frames 0.05 .. 5.95 s; 1 Hz fixes 2.02..4.02 s place frames in 0.52 .. 5.52 s: 5..54.
    frames_t = bf.frame_times_s(60)
    with caplog.at_level(logging.WARNING, logger="app.pipeline.bundle"):
        journey = read_bundle(_bundle(tmp_path, frames_t, np.array([2.02, 3.02, 4.02])),
                              tmp_path / "extract")
    kept = _ids(60)[5:55]
    assert journey.frame_ids == kept
    assert journey.warnings == [
        "dropped 5 frames 000000-000004 (up to 2.0 s before the first GPS fix at 2.020 s; frames "
        "more than 1.5 s outside the GPS fixes cannot be placed)",
        "dropped 5 frames 000055-000059 (up to 1.9 s after the last GPS fix at 4.020 s; frames "
        "more than 1.5 s outside the GPS fixes cannot be placed)"]
    assert [r.getMessage() for r in caplog.records] == \
        [f"bundle.zip: {w}" for w in journey.warnings]
    # Per-frame arrays stay aligned with the kept frames; the motion continues linearly.
    t_kept = frames_t[5:55]
    np.testing.assert_allclose([f.timestamp_s for f in journey.frames], t_kept, atol=1e-9)
    np.testing.assert_allclose(journey.lat_deg, bf.LAT0 + LAT_RATE_DEG_PER_S * t_kept, atol=1e-9)
    assert len(journey.lon_deg) == len(journey.alt_m) == 50 and journey.has_altitude
    np.testing.assert_allclose(journey.alt_m, 100 + np.clip(t_kept, 2.02, 4.02), atol=1e-6)
    # Detections of dropped frames are gone, with track "1" that lived only there.
    assert [(d.track_id, d.frame_id) for d in journey.detections] == [("0", f) for f in kept]
    # The extracted frames/ holds exactly the journey's frames.
    assert sorted(p.stem for p in (tmp_path / "extract" / "frames").iterdir()) == kept


def test_real_receiver_starting_after_the_first_frame_is_extrapolated(tmp_path):
    # 10 Hz frames from 0 s, 1 Hz fixes from 0.624 s: the first frames lie 0.624 s before them.
    frames_t = 0.1 * np.arange(30)
    journey = read_bundle(_bundle(tmp_path, frames_t, 0.624 + np.arange(3.0)),
                          tmp_path / "extract")
    assert journey.frame_ids == _ids(30) and journey.warnings == []
    np.testing.assert_allclose(journey.lat_deg, bf.LAT0 + LAT_RATE_DEG_PER_S * frames_t,
                               atol=1e-9)


def test_journey_with_too_little_gps_is_refused(tmp_path):
    # One fix at 5 s covers 3.5 .. 6.5 s: 30 of the 100 frames 0.05 .. 9.95 s.
    with pytest.raises(BundleError) as info:
        read_bundle(_bundle(tmp_path, bf.frame_times_s(100), np.array([5.0])), tmp_path / "x")
    assert info.value.reason == (
        "GPS covers only 30 of 100 frames (30 %): the fixes span 5.000 .. 5.000 s, the frames "
        "0.050 .. 9.950 s, and a frame may lie at most 1.5 s outside the fixes; at least 50% of "
        "the frames and 10 frames must be covered")


def test_at_least_ten_frames_must_remain_when_frames_are_dropped():
    frames_t = 0.05 + 0.2 * np.arange(15)  # 0.05 .. 2.85 s
    # A fix at 2.62 s covers 1.12 .. 4.12 s: frames 6..14, 9 of 15 (60 %, but fewer than 10).
    with pytest.raises(BundleError, match=r"GPS covers only 9 of 15 frames \(60 %\)"):
        interpolate_to_frames(_fixes([2.62], [49.0]), frames_t, _ids(15))
    # Fixes at 2.42 and 2.62 s cover 0.92 .. 4.12 s: frames 5..14 are kept.
    gps = interpolate_to_frames(_fixes([2.42, 2.62], [49.0, 49.00001]), frames_t, _ids(15))
    assert gps.kept == slice(5, 15) and len(gps.lat_deg) == 10
    assert gps.warnings == ("dropped 5 frames 000000-000004 (up to 2.4 s before the first GPS "
                            "fix at 2.420 s; frames more than 1.5 s outside the GPS fixes cannot "
                            "be placed)",)
    # A journey of fewer than 10 frames, all covered, is fine.
    assert interpolate_to_frames(_fixes([0.0, 1.0], [49.0, 49.0]), frames_t[:3],
                                 _ids(3)).kept == slice(0, 3)


def test_gpx_frames_placed_by_time_past_the_track_are_dropped_like_csv():
    # Fixes at 0, 1, 2 s (bound 1.5 s); frames every 0.2 s from 0 to 3.8 s: 3.6 and 3.8 go.
    points = [(bf.LAT0 + 1e-5 * k, bf.LON0, None, bf.CAPTURED_AT.replace(second=k))
              for k in range(3)]
    frame_utc_s = bf.CAPTURED_AT.timestamp() + 0.2 * np.arange(20)
    gps = gps_from_gpx(bf.gpx_bytes(points), _ids(20), frame_utc_s=frame_utc_s)
    assert gps.kept == slice(0, 18)
    assert gps.warnings[0].startswith("dropped 2 frames 000018-000019 (up to 1.8 s after the last "
                                      "GPS fix at 2.000 s")


def test_cli_report_lists_the_bundle_warnings():
    cal = Calibration(CameraModel(64, 48, 50, 50, 32, 24), "prior")
    result = JourneyResult(cal, [], [], {})
    assert report(result, ["dropped 5 frames 000000-000004 (...)"])["warnings"] == \
        ["dropped 5 frames 000000-000004 (...)"]
    assert report(result)["warnings"] == []
