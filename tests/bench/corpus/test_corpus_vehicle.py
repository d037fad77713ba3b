"""The corpus bench's real-vehicle tables: relative error against range, and an antenna offset
left out of the manifest, estimated by the pipeline and compared with the one rendered."""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest

from app.synth.journey import SynthConfig, write_bundle
from bench.corpus import antenna, by_range
from bench.corpus.report import build_report, gps_kind, render_markdown
from bench.corpus.run import read_jsonl, run_corpus

KITTI_OFFSET = (-1.09, 0.25, -0.72)


def _placed(half: str, obs: list[list[float]], white_m: float = 0.25) -> dict:
    return {"kind": "journey", "name": f"j{len(obs)}{half}", "half": half, "status": "ok",
            "params": {"gps_white_sigma_m": white_m, "gps_bias_sigma_m": 0.1},
            "sign_errors": {"1": {"obs_range_err_m": obs}}}


def test_errors_are_binned_by_range_and_the_spread_spans_5_to_40_m():
    records = [_placed("tuning", [[3.0, 0.05], [7.0, 0.1], [8.0, 0.2], [25.0, 0.3], [35.0, 0.2]]),
               _placed("tuning", [[36.0, 0.9]], white_m=2.0),  # phone-like: not in the table
               _placed("check", [[12.0, 0.1]])]
    summary = by_range.range_summary(records, gps_kind)
    bins = {b["lo_m"]: b for b in summary["tuning"]["oxts"]["bins"]}
    assert bins[5.0]["n"] == 2 and bins[5.0]["mean_m"] == pytest.approx(0.15)
    assert bins[30.0]["n"] == 1 and bins[40.0]["n"] == 0 and bins[40.0]["mean_m"] is None
    assert summary["tuning"]["all"]["bins"][4]["n"] == 2  # 30-40 m with the phone's
    # 5-10 m: 0.15, 20-30 m: 0.3, 30-40 m: 0.2; the 0-5 m bin is outside the bar's span.
    assert summary["tuning"]["oxts"]["spread_m"] == pytest.approx(0.15)
    assert summary["check"]["oxts"]["spread_m"] is None  # one bin only
    text = by_range.table_range(summary)
    assert "| 5-10 m | 2: 0.150 / 0.150 / " in text and "| 40+ m | 0 | 0 |" in text


def test_records_without_ranges_say_so():
    text = by_range.table_range(by_range.range_summary([_placed("tuning", [])], gps_kind))
    assert "No observation with its range" in text


def _offset_corpus(root: Path) -> Path:
    """One 70-frame, one-turn journey whose GPS antenna sits at KITTI's offset (declared)."""
    cam = SynthConfig().camera
    write_bundle(SynthConfig(n_frames=70, turns=1, gps_antenna_offset_m=KITTI_OFFSET),
                 root / "c0000")
    params = {"fps": 10.0, "speed_mps": 8.0, "kind": "turn", "width": cam.width,
              "height": cam.height, **cam.params(), "n_frames": 70, "max_turn_deg": 90.0,
              "hfov_deg": math.degrees(2 * math.atan(cam.width / (2 * cam.fx))),
              "gps_white_sigma_m": 0.3, "gps_bias_sigma_m": 0.1,
              "gps_antenna_offset_m": list(KITTI_OFFSET)}
    (root / "corpus.json").write_text(json.dumps({
        "format": "signmap-corpus/1", "seed": 0, "n": 1, "generator_version": "test",
        "journeys": [{"name": "c0000", "seed": 0, "half": "tuning", "dir": "c0000",
                      "params": params}]}))
    return root


@pytest.mark.slow
def test_an_undeclared_offset_is_estimated_and_compared_with_the_rendered_one(tmp_path: Path):
    corpus = _offset_corpus(tmp_path / "corpus")
    paths = run_corpus(corpus, tmp_path / "out", true_camera=True, antenna_undeclared=True,
                       tag="undeclared")
    meta, [record] = read_jsonl(paths.jsonl)
    assert meta["antenna_undeclared"] is True and record["status"] == "ok"
    forward_m, left_m = record["antenna_est_m"]
    assert abs(forward_m - KITTI_OFFSET[0]) < 0.3 and max(record["antenna_sigma_m"]) < 0.5
    [row] = antenna.antenna_rows([record])
    assert row["error_m"] == pytest.approx(math.hypot(forward_m - KITTI_OFFSET[0],
                                                      left_m - KITTI_OFFSET[1]))
    text = paths.markdown.read_text()
    assert "GPS antenna offset, undeclared" in text and "| c0000 | tuning | -1.09 +0.25 |" in text
    assert "Relative error against range" in text and "antenna offsets undeclared" in text
    assert "Windows that disagree with the GPS" in text and record["broken_windows"] == []
    # The corpus's own bundle keeps its declaration: only the bench's copy went without.
    manifest = json.loads(zipfile.ZipFile(corpus / "c0000" / "bundle.zip").read("manifest.json"))
    assert manifest["gps_antenna_offset_m"]["forward"] == KITTI_OFFSET[0]
    # Declared, nothing is estimated and the table has no estimate for it.
    declared = run_corpus(corpus, tmp_path / "out", true_camera=True, tag="declared")
    [plain] = read_jsonl(declared.jsonl)[1]
    assert "antenna_est_m" not in plain
    report = build_report({}, [plain])
    assert report["antenna"]["halves"]["tuning"]["n_estimated"] == 0
    assert "| c0000 | tuning | -1.09 +0.25 | – |" in render_markdown(report)
    errors = [e for s in plain["sign_errors"].values() for _, e in s["obs_range_err_m"]]
    assert len(errors) >= 10 and np.median(errors) < 0.5
