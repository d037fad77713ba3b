"""``signmap bench turns``: the turn finder against the truth, on a corpus journey drawn without
its pixels."""

import pytest

from app.pipeline.config import PipelineConfig
from bench.cli import main
from bench.turn_detection import (candidate_frames, journey_track, largest_found_deg, moved_table,
                                  parse_variant, table)


def test_a_fast_turn_with_sparse_gps_is_missed_unless_smoothing_is_capped_in_metres():
    # Corpus c0058: a 51 deg turn at 18 m/s, 1 Hz GPS, 68 frames.
    track = journey_track(58)
    assert track.half == "tuning" and 45.0 <= track.true_largest_deg <= 60.0
    uncapped = PipelineConfig(turn_smoothing_max_m=0.0)
    assert largest_found_deg(track, uncapped) == 0.0
    assert 30.0 <= largest_found_deg(track, PipelineConfig()) <= 70.0
    rows = table([track], {"uncapped": uncapped, "defaults": PipelineConfig()}).splitlines()
    assert "| uncapped | tuning | 0/1 | c0058 (51 / 0) | – |" in rows
    assert "| defaults | tuning | 1/1 | – | – |" in rows


def test_variants_are_parsed_and_bad_ones_refused(capsys):
    assert parse_variant("cap:turn_smoothing_max_m=6,rdp_tolerance_m=3") == (
        "cap", {"turn_smoothing_max_m": "6", "rdp_tolerance_m": "3"})
    with pytest.raises(SystemExit, match="expected name:knob=value"):
        main(["turns", "--n", "1", "--variant", "nocolon"])


def test_a_variant_moves_the_candidate_frames_only_where_it_changes_the_plan():
    # c0058 (tuning): fewer images per candidate moves its frames; a knob that only judges the
    # mapped windows (the sharp-image error) does not, so its calibration cannot change.
    track = journey_track(58)
    frames = candidate_frames(track, PipelineConfig())
    assert frames and all(len(w) == PipelineConfig().calib_images for w in frames)
    rows = moved_table([track], {"fewer": PipelineConfig(calib_images=14),
                                 "judge": PipelineConfig(calib_accept_reprojection_px=0.3)},
                       PipelineConfig()).splitlines()
    assert "| fewer | tuning | 1: c0058 |" in rows
    assert "| judge | tuning | 0: – |" in rows
