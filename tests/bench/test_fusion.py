"""``signmap bench fusion``: its journeys, map scoring and tables on made-up inputs, and the quick
run end to end (slow: real COLMAP on three rendered journeys)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from app.fusion import FusionConfig, MapSign
from app.pipeline.types import Calibration, CameraModel, JourneyResult, Sign
from app.synth.journey import SynthConfig
from bench import cli as bench_cli
from bench.paper.metrics import match_signs, sign_errors
from bench.paper.fusion import (BAR_K, JourneyRun, bar_verdict, evaluate_map, failed_to_calibrate,
                                fusion_journeys, fusion_row, fusion_rows, self_calibration,
                                table_fusion, table_journeys)
from bench.paper.metrics import mappable_ids, truth_frame
from bench.paper.plots import plot_fusion

CAMERA = CameraModel(1242, 375, 959.2, 952.9, 694.4, 241.7, -0.369, 0.158)
ORIGIN = {"lat": 49.011, "lon": 8.418, "alt_m": 112.0}
REPO = Path(__file__).resolve().parents[2]
# track id -> (class, true plate centre in truth ENU, metres)
TRUE_SIGNS = {"0": ("stop", (10.0, 0.0, 2.0)), "1": ("yield", (20.0, 5.0, 2.0)),
              "2": ("parking", (30.0, -5.0, 2.0))}


def _truth(frames_seen: int = 5) -> dict:
    return {"origin": ORIGIN, "signs": [
        {"track_id": t, "class": cls, "xyz_enu": list(xyz),
         "observations": [{"frame": f"{i:06d}", "x": 0.0, "y": 0.0, "z": 10.0}
                          for i in range(frames_seen)]}
        for t, (cls, xyz) in TRUE_SIGNS.items()]}


def _latlonalt(truth: dict, xyz_enu) -> tuple[float, float, float]:
    lat, lon, alt = truth_frame(truth).to_geodetic(np.asarray(xyz_enu, float).reshape(1, 3))
    return float(lat[0]), float(lon[0]), float(alt[0])


def _map_sign(truth: dict, map_id: str, members: list[str], offset_enu) -> MapSign:
    """A map sign placed ``offset_enu`` from the true sign of its first member."""
    xyz = np.array(TRUE_SIGNS[members[0].rsplit(":", 1)[1]][1]) + np.asarray(offset_enu, float)
    lat, lon, alt = _latlonalt(truth, xyz)
    return MapSign(map_id, "stop", lat, lon, alt, np.eye(3) * 0.04, sorted(members),
                   sorted({m.split(":")[0] for m in members}), len(members), 0.0, 0.0)


def _run(truth: dict, name: str, day: int, offsets: dict[str, tuple]) -> JourneyRun:
    """A journey whose pipeline placed each sign of ``offsets`` that far from the truth (std 0.2 m,
    the fusion's covariance floor, so the fused positions are plain means)."""
    signs = []
    for track, off in offsets.items():
        cls, xyz = TRUE_SIGNS[track]
        est = np.array(xyz) + np.asarray(off, float)
        lat, lon, alt = _latlonalt(truth, est)
        signs.append(Sign(track, cls, est, lat, lon, alt, 0.2, 0.5, []))
    result = JourneyResult(Calibration(CAMERA, "self"), signs, [], {})
    synth = SynthConfig(captured_at=f"2025-06-{day:02d}T10:00:00Z")
    record = {"status": "ok", "sign_errors": sign_errors(result, truth)}
    return JourneyRun(name, synth, record, result, truth)


def test_fusion_journeys_share_one_world_and_camera():
    for quick, n, frames in ((True, 3, 50), (False, 10, 70)):
        specs = fusion_journeys(quick)
        assert len(specs) == n and {s.synth.n_frames for s in specs} == {frames}
        assert len({s.synth.world_spec() for s in specs}) == 1
        assert len({s.synth.seed for s in specs}) == n
        assert len({s.synth.camera for s in specs}) == 1
        assert len({s.synth.captured_at for s in specs}) == n
        assert specs[0].synth.turns == 1 and specs[0].known_from is None
        assert all(s.known_from == specs[0].name for s in specs[1:])
        lanes = {s.synth.lateral_offset_m for s in specs}
        assert 0.0 in lanes and len(lanes) == min(n, 5)
        biases = [np.linalg.norm(s.synth.gps_bias_m) for s in specs]
        assert 0 < sum(b > 0 for b in biases) < n and max(biases) <= 1.0 + 1e-9
    # Quick and full drive the same world: the quick journeys are the full ones, shorter.
    quick, full = fusion_journeys(True)[0].synth, fusion_journeys(False)[0].synth
    assert quick.world_spec() == full.world_spec()


def test_evaluate_map_counts_duplicates_mixed_and_exact_errors():
    truth = _truth()
    signs = [_map_sign(truth, "a", ["j1:0", "j2:0"], (0.1, 0.0, 0.0)),
             _map_sign(truth, "b", ["j3:0"], (0.0, 0.5, 0.0)),  # a second map sign of sign 0
             _map_sign(truth, "c", ["j1:1", "j2:2", "j3:1"], (0.0, 0.0, 0.2)),  # mostly sign 1
             _map_sign(truth, "d", ["j1:2"], (0.3, 0.0, 0.0))]
    ev = evaluate_map(signs, truth)
    assert ev["n_map_signs"] == 4 and ev["n_true_mapped"] == 3
    assert ev["n_duplicates"] == 1 and ev["n_mixed"] == 1
    assert ev["abs_median_m"] == pytest.approx(0.25, abs=1e-6)  # of 0.1, 0.5, 0.2, 0.3
    assert ev["abs_mean_m"] == pytest.approx(0.275, abs=1e-6)
    assert ev["horiz_median_m"] == pytest.approx(0.2, abs=1e-6)  # of 0.1, 0.5, 0.0, 0.3
    assert ev["errors_m"]["c"] == pytest.approx(0.2, abs=1e-6)


def test_evaluate_map_of_no_signs():
    ev = evaluate_map([], _truth())
    assert ev["n_map_signs"] == 0 and ev["n_duplicates"] == 0
    assert np.isnan(ev["abs_median_m"])


def test_fusion_row_fuses_real_signs_and_finds_a_duplicate():
    truth = _truth()
    runs = [_run(truth, "j1", 1, {"0": (0.1, 0.0, 0.0), "1": (0.1, 0.0, 0.0)}),
            # Sign 0 symmetric to j1 (fused: exactly the truth); sign 1 5 m off, beyond the 3 m
            # gate, so the map gets a second sign for it.
            _run(truth, "j2", 2, {"0": (-0.1, 0.0, 0.0), "1": (5.0, 0.0, 0.0)})]
    row = fusion_row(runs, FusionConfig(), min_frames=3)
    assert row["k"] == 2 and row["n_ok"] == 2 and row["n_journey_signs"] == 4
    assert row["n_map_signs"] == 3 and row["n_true_mapped"] == 2 and row["n_mappable"] == 3
    assert row["n_duplicates"] == 1 and row["n_mixed"] == 0 and row["n_biased_flagged"] == 0
    errors = sorted(row["errors_m"].values())
    assert errors == pytest.approx([0.0, 0.1, 5.0], abs=1e-6)
    assert row["abs_median_m"] == pytest.approx(0.1, abs=1e-6)
    assert row["single_abs_mean_m"] == pytest.approx((0.1 + 2.55) / 2, abs=1e-6)
    assert row["single_abs_median_m"] == pytest.approx(0.1, abs=1e-6)
    assert row["reversed"]["n_only_one_order"] == 0
    assert row["reversed"]["max_diff_m"] == pytest.approx(0.0, abs=1e-6)


def test_fusion_rows_only_for_k_up_to_the_journeys_run():
    truth = _truth()
    runs = [_run(truth, f"j{i}", i + 1, {"0": (0.1 * i, 0.0, 0.0)}) for i in range(3)]
    assert [r["k"] for r in fusion_rows(runs, FusionConfig(), 3)] == [1, 2, 3]


def test_bar_verdict_and_table():
    rows = [{"k": k, "n_ok": k, "n_map_signs": 6, "n_true_mapped": 6, "n_mappable": 7,
             "n_duplicates": 0, "n_mixed": 0, "abs_median_m": median, "abs_mean_m": 0.3,
             "horiz_median_m": 0.2, "horiz_mean_m": 0.25, "single_abs_mean_m": 0.4,
             "single_abs_median_m": 0.35, "n_biased_flagged": 0,
             "reversed": {"max_diff_m": 0.0, "n_only_one_order": 0}}
            for k, median in ((1, 0.4), (BAR_K, 0.21))]
    assert bar_verdict(rows).startswith("met: median 0.210")
    assert bar_verdict([{**rows[1], "abs_median_m": 0.3}]).startswith("NOT met")
    assert bar_verdict(rows[:1]).startswith("not measured")
    md = table_fusion(rows)
    assert "| 5 | 5 | 6 | 6 / 7 | 0 | 0 | 0.210 | 0.300 |" in md


def test_calibration_hand_over_and_the_journeys_table():
    truth = _truth()
    calibrated = _run(truth, "j2", 2, {"0": (0.1, 0.0, 0.0)})
    assert self_calibration(calibrated) == ("j2", CAMERA)
    failed = JourneyRun("j1", SynthConfig(), {"status": "failed", "error": "calibrate: no window",
                                              "wall_s": 12.0}, None, truth)
    assert failed_to_calibrate(failed) and self_calibration(failed) is None
    other = JourneyRun("j3", SynthConfig(), {"status": "failed", "error": "ego_motion: lost",
                                             "wall_s": 9.0}, None, truth)
    assert not failed_to_calibrate(other)  # only a missing calibration is made up for
    given = JourneyRun("j4", SynthConfig(), {**failed.record, "calibration_from": "j2"}, None,
                       truth)
    assert not failed_to_calibrate(given)  # it had the calibration already
    rerun = _run(truth, "j1", 1, {"0": (0.2, 0.0, 0.0)})
    rerun.record.update(lane_m=0.8, gps_bias_m=[0.0, 0.0, 0.0], wall_s=30.0, cpu_s=31.0,
                        calibration={"source": "supplied"}, calibration_from="j2",
                        signs={"n_signs": 1, "abs_mean_m": 0.2, "abs_median_m": 0.2},
                        first_attempt={"status": "failed", "error": "calibrate: no window",
                                       "wall_s": 12.0, "cpu_s": 12.0})
    md = table_journeys([rerun])
    assert ("| j1 | +0.8 | +0.0, +0.0, +0.0 | from j2 | 1 | 0.200 | 0.200 | 30.0 | 31 | ok "
            "(re-run; self-calibrating first in 12.0 s: failed: calibrate: no window) |") in md


def test_fusion_plot(tmp_path):
    rows = [{"k": k, "abs_median_m": 0.4 / k, "abs_mean_m": 0.5 / k, "single_abs_mean_m": 0.5}
            for k in (1, 2, 3)]
    png = plot_fusion(rows, 0.25, 5, tmp_path / "f.png")
    assert png.stat().st_size > 10_000


def test_cli_fusion_subcommand_inherits_options():
    parser = argparse.ArgumentParser()
    bench_cli.add_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["bench", "--quick", "fusion", "--out", "/tmp/x"])
    assert args.func is bench_cli.run_fusion_command and args.quick
    assert args.out == Path("/tmp/x")


@pytest.mark.slow
@pytest.mark.extended  # a bench end to end (minutes): `pytest -m extended`
def test_quick_fusion_bench_writes_table_json_and_plot(tmp_path):
    from bench.paper.fusion import run_fusion

    md_path, json_path = run_fusion(quick=True, out_dir=tmp_path, cache_dir=REPO / "bench/cache")
    report = json.loads(json_path.read_text())
    assert {"meta", "bar", "journeys", "rows", "plot", "n_signs_truth"} <= set(report)
    assert report["meta"]["quick"] is True and report["meta"]["complete"] is True
    assert len(report["journeys"]) == 3
    for name, run in report["journeys"].items():
        assert run["status"] == "ok", (name, run.get("error"))
        assert run["wall_s"] > 0
    sources = [run["calibration"]["source"] for run in report["journeys"].values()]
    assert sources == ["self", "supplied", "supplied"]
    assert [r["k"] for r in report["rows"]] == [1, 2, 3]
    last = report["rows"][-1]
    assert {"abs_median_m", "abs_mean_m", "horiz_median_m", "n_duplicates",
            "single_abs_mean_m", "reversed"} <= set(last)
    assert last["n_true_mapped"] >= 1
    # Seen once: median 0.62 m fused from 3 journeys vs 0.93 m single-journey mean (one
    # of the three has a 0.86 m GPS bias), and the same map with the order reversed.
    assert np.isfinite(last["abs_median_m"])
    assert last["abs_median_m"] < last["single_abs_mean_m"]
    assert last["reversed"]["n_only_one_order"] == 0
    assert last["reversed"]["max_diff_m"] < 1e-6
    assert (tmp_path / report["plot"]).stat().st_size > 10_000
    md = md_path.read_text()
    assert "### Map error vs number of journeys" in md and "| journeys | ok | map signs |" in md


def test_signs_without_true_track_ids_are_matched_by_position_false_and_duplicate_counted():
    """Journeys without track ids get the pipeline's own (auto-k): they are matched to the nearest
    true sign within 3 m; one farther than that is false, a second for one true sign a duplicate."""
    truth = _truth()
    placed = [("auto-0", TRUE_SIGNS["0"][1], (0.5, 0.0, 0.0)),
              ("auto-1", TRUE_SIGNS["1"][1], (0.0, -1.0, 0.0)),
              ("auto-2", TRUE_SIGNS["1"][1], (0.3, 0.0, 0.0)),   # the same sign again
              ("auto-3", TRUE_SIGNS["2"][1], (9.0, 0.0, 0.0))]   # 9 m from any true sign
    signs = []
    for track, xyz, off in placed:
        est = np.array(xyz) + np.asarray(off, float)
        signs.append(Sign(track, "stop", est, *_latlonalt(truth, est), 0.2, 0.5, []))
    result = JourneyResult(Calibration(CAMERA, "self"), signs, [], {})
    matched, unmatched = match_signs(result, truth)
    assert sorted((s.track_id, t["track_id"]) for s, t in matched) == [("auto-0", "0"),
                                                                        ("auto-1", "1")]
    assert sorted((u["track_id"], u["kind"]) for u in unmatched) == [("auto-2", "duplicate"),
                                                                     ("auto-3", "false")]
    errors = sign_errors(result, truth)
    assert errors["auto-0"]["abs_m"] == pytest.approx(0.5, abs=1e-6)
    assert errors["auto-1"]["truth_id"] == "1"
    assert mappable_ids(truth, min_frames=5) == ["0", "1", "2"]
    assert mappable_ids(_truth(frames_seen=4), min_frames=5) == []
