"""The corpus bench's broken windows: a run of fixes moved off (``--gps-jump``), and the report's
count of windows broken, mended and the signs they cost."""

from __future__ import annotations

import csv
import io
import zipfile
from pathlib import Path

import numpy as np
import pytest

from bench.corpus.broken import broken_summary, gps_jump_of, table_broken, with_gps_jump

LAT0, LON0 = 49.0, 8.4


def _bundle(path: Path) -> Path:
    """A bundle whose gps.csv has 10 fixes at 1 Hz, 10 m apart northwards, and frame rows."""
    rows = ["frame,timestamp_s,lat,lon,alt_m"]
    rows += [f"{i:06d},{i * 0.5:.3f},," for i in range(20)]
    rows += [f",{t:.3f},{LAT0 + 10 * t / 111_320:.9f},{LON0:.9f},100.0" for t in range(10)]
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("manifest.json", "{}")
        z.writestr("gps.csv", "\n".join(rows) + "\n")
    return path


def _fixes(path: Path) -> list[dict]:
    text = zipfile.ZipFile(path).read("gps.csv").decode()
    return [r for r in csv.DictReader(io.StringIO(text)) if r["lat"]]


def test_a_jump_moves_only_the_fixes_of_its_run(tmp_path: Path):
    src = _bundle(tmp_path / "a.zip")
    jump = {"start_share": 0.4, "length_s": 2.0, "offset_m": 6.0, "bearing_deg": 90.0}
    applied = with_gps_jump(src, tmp_path / "b.zip", jump)
    assert applied["start_s"] == pytest.approx(3.6) and applied["n_fixes_moved"] == 2
    before, after = _fixes(src), _fixes(tmp_path / "b.zip")
    for a, b in zip(before, after):
        moved_m = np.hypot((float(b["lat"]) - float(a["lat"])) * 111_320,
                           (float(b["lon"]) - float(a["lon"])) * 111_320 * np.cos(np.radians(LAT0)))
        assert moved_m == pytest.approx(6.0 if float(a["timestamp_s"]) in (4.0, 5.0) else 0.0,
                                        abs=0.01)
    assert zipfile.ZipFile(tmp_path / "b.zip").read("manifest.json") == b"{}"
    with zipfile.ZipFile(tmp_path / "nmea.zip", "w") as z:
        z.writestr("manifest.json", "{}")
    with pytest.raises(ValueError, match="no gps.csv"):
        with_gps_jump(tmp_path / "nmea.zip", tmp_path / "c.zip", jump)
    # Drawn from the name: the same every run, another for another journey.
    assert gps_jump_of("c0001") == gps_jump_of("c0001") != gps_jump_of("c0002")
    assert 4.0 <= gps_jump_of("c0001")["offset_m"] <= 10.0


def _record(name: str, half: str, windows: list[dict], missed: dict, errors: dict) -> dict:
    return {"kind": "journey", "name": name, "half": half, "status": "ok", "params": {},
            "signs": {"n_mappable": 10}, "broken_windows": windows,
            "missed_mappable": missed, "sign_errors": {t: {"abs_m": e} for t, e in errors.items()}}


def test_the_report_counts_windows_broken_mended_and_the_signs_they_cost():
    lost = "the reconstruction around it disagrees with the GPS by 2.10 m rms, more than 5 x"
    records = [
        _record("c0001", "check", [{"frames": [0, 80], "rms_m": 3.9, "limit_m": 1.2,
                                    "mended": True, "how": "mended: ...", "tracks": ["a", "b"]},
                                   {"frames": [70, 150], "rms_m": 2.1, "limit_m": 1.2,
                                    "mended": False, "how": "not mended: ...", "tracks": ["c"]}],
                {"s3": lost, "s4": "rays nearly parallel (0.9 deg)"}, {"a": 0.2, "b": 0.4}),
        _record("c0003", "check", [], {}, {"x": 0.3}),
        _record("c0000", "tuning", [], {}, {}),
    ]
    summary = broken_summary(records)
    assert summary["check"] == {"n_journeys": 2, "n_broken": 2, "n_mended": 1, "n_mappable": 20,
                                "n_lost": 1, "n_kept": 2, "kept_abs_median_m": pytest.approx(0.3),
                                "journeys": ["c0001"]}
    assert summary["tuning"]["n_broken"] == 0 and summary["tuning"]["kept_abs_median_m"] is None
    text = table_broken(summary)
    assert "| mappable signs lost to a window that disagrees with the GPS | 0 | 1 |" in text
