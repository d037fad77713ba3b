"""gps.nmea: RMC + GGA fixes round-trip at any rate; bad, foreign and fix-less lines are skipped and
counted, never fatal; a log without any usable fix or without a date is refused with counts."""

from __future__ import annotations

import io
from datetime import datetime, timedelta, timezone
from functools import reduce
from operator import xor

import numpy as np
import pytest

from app.pipeline.bundle.gps import read_gpx
from app.pipeline.bundle.video.nmea import MAX_LINE_CHARS, UERE_M, parse_nmea
from app.pipeline.types import BundleError
from app.synth.video.gps_logs import gpx_track, nmea_log

T0 = datetime(2024, 5, 1, 12, 30, 0, tzinfo=timezone.utc)
LAT0, LON0 = 49.0110123, 8.4183456


def _track(n: int, rate_hz: float):
    t = np.arange(n) / rate_hz
    return t, LAT0 + 3e-6 * t + 1e-8 * t**2, LON0 - 4e-6 * t, 112.3 + 0.1 * t


def _sentence(body: str) -> str:
    return f"${body}*{reduce(xor, body.encode(), 0):02X}"


def _lines(text: str) -> list[str]:
    return text.splitlines()


@pytest.mark.parametrize("rate_hz", [1.0, 10.0])
def test_round_trip(rate_hz):
    t, lat, lon, alt = _track(50, rate_hz)
    log = parse_nmea(nmea_log(T0, t, lat, lon, alt, talker="GN").encode())
    assert log.t0_utc == T0 and log.source == "gps.nmea"
    np.testing.assert_allclose(log.fixes.timestamp_s, t, atol=1e-9)
    np.testing.assert_allclose(log.fixes.lat_deg, lat, atol=1e-7)
    np.testing.assert_allclose(log.fixes.lon_deg, lon, atol=1e-7)
    np.testing.assert_allclose(log.fixes.alt_m, alt, atol=1e-6)  # ellipsoidal, as written
    np.testing.assert_allclose(log.fixes.accuracy_m, 0.9 * UERE_M)
    assert log.fixes.labels[0] == "line 1" and log.fixes.labels[1] == "line 3"  # GGA first
    assert log.notes == (f"50 fixes over {t[-1]:.1f} s: GGA at {rate_hz:g} Hz, "
                         f"RMC at {rate_hz:g} Hz",)


def test_southern_western_positions_and_a_stream():
    t, lat, lon, alt = _track(5, 1.0)
    text = nmea_log(T0, t, -lat, -lon, alt)
    log = parse_nmea(io.BytesIO(text.encode()))
    np.testing.assert_allclose(log.fixes.lat_deg, -lat, atol=1e-7)
    np.testing.assert_allclose(log.fixes.lon_deg, -lon, atol=1e-7)


def test_gga_at_10_hz_rmc_at_1_hz_merge_by_epoch():
    t, lat, lon, alt = _track(30, 10.0)
    lines = _lines(nmea_log(T0, t, lat, lon, alt))
    # Keep every GGA, and the RMC of every 10th epoch only (RMC comes second in each pair).
    kept = [ln for i, ln in enumerate(lines) if i % 2 == 0 or (i // 2) % 10 == 0]
    log = parse_nmea("\n".join(kept).encode())
    np.testing.assert_allclose(log.fixes.timestamp_s, t, atol=1e-9)
    np.testing.assert_allclose(log.fixes.alt_m, alt, atol=1e-6)
    assert log.notes[-1] == "30 fixes over 2.9 s: GGA at 10 Hz, RMC at 1 Hz"


def test_bad_lines_are_skipped_and_counted():
    t, lat, lon, alt = _track(6, 1.0)
    lines = _lines(nmea_log(T0, t, lat, lon, alt))
    good_gga = lines[0]
    bad_checksum = good_gga[:-2] + ("00" if good_gga[-2:] != "00" else "01")
    junk = [
        bad_checksum,                                            # line 3
        good_gga.split("*")[0],                                  # no checksum
        "hello world",                                           # not a sentence
        "\x00\xff\xfe binary \x80",                              # binary (latin-1 bytes)
        "$GPGGA" + "," * 300 + "*00",                            # too long
        _sentence("GPGGA,123004.000,4900.0,N,00825.0,E,0,00,,,M,,M,,"),   # quality 0
        _sentence("GPRMC,123004.000,V,4900.0,N,00825.0,E,,,010524,,,N"),  # status V
        _sentence("GPGGA,123004.000,4975.0,N,00825.0,E,1,08,0.9,1,M,1,M,,"),  # minutes 75
        _sentence("GPGSV,3,1,11,10,63,137,17,07,61,098,15,05,59,290,20,08,54,157,30"),
        _sentence("PGRMC,A,218.8,100,,,,,,,,,"),
    ]
    text = "\r\n".join(lines[:2] + junk + lines[2:]) + "\r\n"
    log = parse_nmea(text.encode("latin-1"))
    np.testing.assert_allclose(log.fixes.timestamp_s, t, atol=1e-9)
    assert log.fixes.labels[1] == "line 13"  # the second fix's GGA, after the 10 junk lines
    assert log.notes[:6] == (
        f"1 line longer than {MAX_LINE_CHARS} characters skipped (first: line 7)",
        "2 lines not in NMEA form ($...*HH, printable ASCII) skipped (first: line 5)",
        "1 line without a checksum skipped (first: line 4)",
        "1 line with a bad checksum skipped (first: line 3)",
        "1 line with RMC/GGA fields that do not parse skipped (first: line 10)",
        "2 lines without a fix (GGA quality 0, RMC status V) skipped (first: line 8)")
    assert log.notes[6] == "2 other sentences ignored (GSV, PGRMC)"


def test_a_huge_line_without_an_end_is_never_held():
    t, lat, lon, alt = _track(3, 1.0)
    text = nmea_log(T0, t, lat, lon, alt).encode()
    log = parse_nmea(text + b"$" + b"A" * 5_000_000)
    assert len(log.fixes.timestamp_s) == 3
    assert log.notes[0] == f"1 line longer than {MAX_LINE_CHARS} characters skipped (first: line 7)"


def test_duplicates_dropped_and_out_of_order_counted():
    t, lat, lon, alt = _track(5, 1.0)
    lines = _lines(nmea_log(T0, t, lat, lon, alt))
    # Epoch 3 (lines 7-8) written twice, epochs 1 and 2 again at the end.
    text = "\n".join(lines[:8] + lines[6:8] + lines[8:] + lines[2:6])
    log = parse_nmea(text.encode())
    np.testing.assert_allclose(log.fixes.timestamp_s, t, atol=1e-9)
    assert log.notes == ("1 fix repeating an earlier fix's time dropped (first: line 9)",
                         "2 fixes earlier than a fix before them dropped (first: line 13)",
                         "5 fixes over 4.0 s: GGA at 1 Hz, RMC at 1 Hz")


def test_midnight_rollover():
    start = datetime(2024, 12, 31, 23, 59, 58, tzinfo=timezone.utc)
    t, lat, lon, alt = _track(5, 1.0)
    lines = _lines(nmea_log(start, t, lat, lon, alt))
    log = parse_nmea("\n".join(lines).encode())
    assert log.t0_utc == start
    np.testing.assert_allclose(log.fixes.timestamp_s, t, atol=1e-9)
    # GGA only after the first RMC: the date runs on past midnight by itself.
    gga_after_first = [lines[0], lines[1]] + lines[2::2]
    np.testing.assert_allclose(parse_nmea("\n".join(gga_after_first).encode()).fixes.timestamp_s,
                               t, atol=1e-9)
    # GGA only before the only RMC (after midnight): the earlier fixes count back from it.
    gga_before = lines[0:8:2] + lines[8:10]
    log = parse_nmea("\n".join(gga_before).encode())
    assert log.t0_utc == start
    np.testing.assert_allclose(log.fixes.timestamp_s, t, atol=1e-9)


def test_missing_geoid_separation_leaves_altitude_out():
    gga = _sentence("GPGGA,123000.000,4900.6607380,N,00825.1007360,E,1,08,1.2,65.300,M,,M,,")
    rmc = _sentence("GPRMC,123000.000,A,4900.6607380,N,00825.1007360,E,,,010524,,,A")
    log = parse_nmea(f"{gga}\n{rmc}\n".encode())
    assert np.isnan(log.fixes.alt_m[0])
    assert log.fixes.accuracy_m[0] == pytest.approx(1.2 * UERE_M)
    assert log.notes[0].startswith("altitude left out of 1 GGA sentence without a geoid "
                                   "separation (first: line 1)")


def test_all_garbage_is_refused_with_counts():
    t, lat, lon, alt = _track(3, 1.0)
    lines = _lines(nmea_log(T0, t, lat, lon, alt))
    bad = [ln[:-2] + ("00" if ln[-2:] != "00" else "01") for ln in lines[:4]]
    no_fix = _sentence("GPGGA,123004.000,,,,,0,00,,,M,,M,,")
    with pytest.raises(BundleError) as info:
        parse_nmea("\n".join(bad + [no_fix, no_fix, "junk"]).encode())
    assert info.value.reason == (
        "gps.nmea has no usable fix: 7 lines read, 1 not in NMEA form ($...*HH, printable ASCII), "
        "4 with a bad checksum, 2 without a fix (GGA quality 0, RMC status V); it needs RMC or "
        "GGA sentences with a fix (checksummed, one per line)")
    with pytest.raises(BundleError, match="gps.nmea has no usable fix: 0 lines read"):
        parse_nmea(b"")
    with pytest.raises(BundleError, match=r"has no usable fix: 2 lines read, 1 longer than 200 "
                                          r"characters, 1 not in NMEA form"):
        parse_nmea(bytes(range(11, 256)) * 3 + b"\n$\x00\x00*00")


def test_gga_only_is_refused_for_the_date():
    t, lat, lon, alt = _track(5, 1.0)
    gga = _lines(nmea_log(T0, t, lat, lon, alt))[::2]
    with pytest.raises(BundleError, match="no RMC sentence with a fix: GGA gives the time of day "
                                          "only, the date comes from RMC"):
        parse_nmea("\n".join(gga).encode())


def test_max_lines():
    t, lat, lon, alt = _track(5, 1.0)
    text = nmea_log(T0, t, lat, lon, alt).encode()
    assert len(parse_nmea(text, max_lines=10).fixes.timestamp_s) == 5
    with pytest.raises(BundleError, match="gps.nmea has more than 9 lines, the limit per journey"):
        parse_nmea(text, max_lines=9)


def test_gpx_track_round_trip():
    t, lat, lon, alt = _track(20, 10.0)
    log = read_gpx(gpx_track(T0 + timedelta(hours=2) - timedelta(hours=2), t, lat, lon,
                             alt).encode())
    assert log.t0_utc == T0
    np.testing.assert_allclose(log.fixes.timestamp_s, t, atol=1e-9)
    np.testing.assert_allclose(log.fixes.lat_deg, lat, atol=1e-7)
    np.testing.assert_allclose(log.fixes.alt_m, alt, atol=1e-3)
