"""A window whose GPS jumps away (multipath) is mended through ``signmap process``: the run of
bad fixes is named and left out, and the signs it would have cost are placed (with mending off
the window stays broken and refuses them: ``tests/pipeline/georeference/test_mend.py``; through
``signmap process`` none of the 6 was placed, docs/decisions/broken-window-mend.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.commands.usage import EXIT_OK
from bench.corpus.broken import with_gps_jump
from tests.utils.results.service_support import signs_enu

# 10 m east for 1.5 s from the middle of the 80-frame turn journey (frames 40-54 at 10 Hz).
JUMP = {"start_share": 0.5, "length_s": 1.5, "offset_m": 10.0, "bearing_deg": 90.0}


def _process(bundle: Path, truth: dict, out_dir: Path) -> tuple[dict[str, float], dict]:
    """``signmap process`` with the true camera: (per track, the distance to its true sign;
    the report)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "cam.json").write_text(json.dumps(truth["camera"]))
    out = out_dir / "signs.geojson"
    assert main(["process", str(bundle), "--calibration", str(out_dir / "cam.json"),
                 "--out", str(out)]) == EXIT_OK
    true = signs_enu([{"properties": {"track_id": str(s["track_id"])},
                       "geometry": {"coordinates": [s["lon"], s["lat"], s["alt_m"]]}}
                      for s in truth["signs"]], truth)
    placed = signs_enu(json.loads(out.read_text())["features"], truth)
    return ({t: float(np.linalg.norm(xyz - true[t])) for t, xyz in placed.items()},
            json.loads(out.with_suffix(".report.json").read_text()))


@pytest.mark.slow
def test_a_gps_jump_is_left_out_and_its_signs_placed(offset_journey_bundle, tmp_path,
                                                     monkeypatch, capsys):
    bundle, truth = offset_journey_bundle
    monkeypatch.setenv("SIGNMAP_PIPELINE__REUSE_KNOWN_CALIBRATION", "true")
    jump = with_gps_jump(bundle, tmp_path / "jumped.zip", JUMP)
    assert jump["n_fixes_moved"] == 15

    errors, report = _process(tmp_path / "jumped.zip", truth, tmp_path / "mended")
    align = next(s for s in report["report"] if s["stage"] == "align")
    [line] = [d for d in align["details"] if "over the" in d]
    assert "mended: the GPS was off by up to 10." in line and "within 40-54" in line
    assert len(errors) == 6 and max(errors.values()) < 0.8, errors

    with capsys.disabled():
        print(f"\nGPS 10 m off for 1.5 s: mended, {len(errors)} signs, 3D error median "
              f"{np.median(list(errors.values())):.2f} m, max {max(errors.values()):.2f} m")
