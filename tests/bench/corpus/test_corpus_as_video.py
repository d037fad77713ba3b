"""``signmap bench corpus --as-video``: a corpus journey run as the video bundle a dash cam would
upload, on the one-journey corpus of ``test_corpus`` (real H.264 encoding and decoding)."""

from __future__ import annotations

import math
from pathlib import Path

from bench.corpus import report as cr
from bench.corpus.run import (CLOCK_ERROR_MAX_S, bundle_digest, clock_error_of, read_jsonl,
                              run_corpus)
from tests.bench.corpus.test_corpus import _fake_corpus


def test_a_journeys_clock_error_is_whole_seconds_never_zero_and_follows_its_name():
    errors = [clock_error_of(f"c{i:04d}") for i in range(400)]
    assert set(errors) == set(range(-CLOCK_ERROR_MAX_S, CLOCK_ERROR_MAX_S + 1)) - {0}
    assert errors == [clock_error_of(f"c{i:04d}") for i in range(400)]


def test_a_journey_runs_as_a_video_bundle_and_its_clock_error_is_recorded(tmp_path: Path):
    corpus = _fake_corpus(tmp_path / "corpus")
    # The true camera and no detections: the run stops once the bundle is read, which is what is
    # under test here (a self-calibration on the video's frames is minutes, the bench's own job).
    paths = run_corpus(corpus, tmp_path / "out", calibrate_only=True, true_camera=True,
                       as_video=True, tag="video")
    meta, [rec] = read_jsonl(paths.jsonl)
    assert meta["as_video"]
    assert rec["status"] == "ok", rec["error"]
    assert rec["clock_error_s"] == clock_error_of("c0000")
    assert rec["video_convert_s"] > 0 and "video_convert_s" not in rec["timings_s"]
    assert rec["n_frames"] == 70  # every frame of the 10 Hz journey kept from the video
    # The corpus's frames bundle is the input both kinds of run share: compare finds no change.
    assert rec["bundle_digest"] == bundle_digest(corpus / "c0000" / "bundle.zip")
    if rec["clock_error_est_s"] is not None:
        assert math.isfinite(rec["clock_error_sigma_s"])
        assert abs(rec["clock_error_est_s"] - rec["clock_error_s"]) < 1.0
    else:
        assert rec["clock_offset_reason"]
    md = paths.markdown.read_text()
    assert "### Camera clock (video bundles)" in md and "as dash cam video bundles" in md
    # The conversion went into the run's temporary directory, not into the corpus.
    assert sorted(p.name for p in (corpus / "c0000").iterdir()) == ["bundle.zip", "truth.json"]


def test_a_frames_run_report_has_no_clock_table():
    rec = {"kind": "journey", "name": "t1", "half": "tuning", "params": {}, "status": "ok",
           "error": None, "wall_s": 1.0, "calib_s": 1.0, "calibration": None}
    assert "Camera clock" not in cr.render_markdown(cr.build_report({}, [rec]))
    clock = cr.clock_summary([{**rec, "clock_error_s": 3, "clock_error_est_s": 2.9,
                               "clock_offset_reason": None},
                              {**rec, "clock_error_s": -2, "clock_error_est_s": None,
                               "clock_offset_reason": "no turn to match: at most 12.5 deg"}])
    assert clock["n_estimated"] == 1 and clock["n_within_close"] == 1
    assert clock["n_not_estimated"] == 1 and clock["commonest_reason"] == (
        "no turn to match: at most X deg")
