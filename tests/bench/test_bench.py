"""The benchmark suite: its metrics, tables and CLI on made-up inputs, and ``signmap bench --quick``
end to end (slow: real COLMAP)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from app.pipeline.types import (Calibration, CameraModel, Detection, Frame, Journey,
                                JourneyResult)
from bench import cli as bench_cli
from bench.paper.metrics import sign_summary, snippet_rmse_m, trajectory_metrics
from bench.paper.run_pipeline import prefix
from bench.paper.runner import compare, finite
from bench.paper.plots import plot_sensitivity
from bench.paper.sensitivity import GROUPS, perturbed_cameras, sensitivity_rows, table_sensitivity
from bench.paper import tables
from bench.paper.tables import render_report

CAMERA = CameraModel(1242, 375, 959.2, 952.9, 694.4, 241.7, -0.369, 0.158)
ORIGIN = {"lat": 49.011, "lon": 8.418, "alt_m": 112.0}
REPO = Path(__file__).resolve().parents[2]


def _truth(n: int = 12) -> dict:
    """Truth with cameras on a quarter circle of radius 20 m (ENU at ORIGIN)."""
    a = np.linspace(0.0, np.pi / 2, n)
    frames = []
    for i, (x, y) in enumerate(zip(20 * np.cos(a), 20 * np.sin(a))):
        T = np.eye(4)
        T[:3, 3] = [x, y, 1.65]
        frames.append({"frame": f"{i:06d}", "T_world_cam": T.tolist()})
    return {"origin": ORIGIN, "frames": frames, "signs": [], "camera": CAMERA.params()}


def _result(truth: dict, offset_enu: np.ndarray, rows: list[int]) -> JourneyResult:
    xyz = np.array([truth["frames"][i]["T_world_cam"] for i in rows])[:, :3, 3] + offset_enu
    return JourneyResult(Calibration(CAMERA, "self"), [], [], {},
                         trajectory_frame_ids=[truth["frames"][i]["frame"] for i in rows],
                         trajectory_enu=xyz, gps_enu=xyz,
                         origin_lat_lon_alt=(ORIGIN["lat"], ORIGIN["lon"], ORIGIN["alt_m"]))


def test_ate_separates_georeferencing_offset_from_shape():
    truth = _truth()
    result = _result(truth, np.array([1.0, 0.0, 0.0]), list(range(12)))
    ate = trajectory_metrics(result, truth)
    assert ate["n_posed"] == 12
    assert ate["ate_gps_m"] == pytest.approx(1.0, abs=1e-6)
    assert ate["ate_full_m"] == pytest.approx(0.0, abs=1e-6)
    assert ate["ate5_mean_m"] == pytest.approx(0.0, abs=1e-6)


def test_ate_full_sees_a_distorted_trajectory():
    truth = _truth()
    result = _result(truth, np.zeros(3), list(range(12)))
    result.trajectory_enu = result.trajectory_enu.copy()
    result.trajectory_enu[5] += [0.0, 0.0, 1.2]  # one camera 1.2 m too high
    ate = trajectory_metrics(result, truth)
    assert 0.1 < ate["ate_full_m"] < 1.2 / np.sqrt(12) + 1e-9
    assert ate["ate_gps_m"] == pytest.approx(1.2 / np.sqrt(12), abs=1e-6)


def test_snippets_never_span_a_gap_between_windows():
    idx = np.array([0, 1, 2, 3, 4, 5, 10, 11, 12, 13, 14])
    xyz = np.column_stack([idx * 0.8, np.sin(idx), np.zeros(len(idx))])
    assert len(snippet_rmse_m(idx, xyz, xyz)) == 3  # rows 0-4, 1-5 and 10-14
    assert np.allclose(snippet_rmse_m(idx, xyz, xyz), 0.0, atol=1e-9)


def test_snippets_follow_every_second_frame_posing():
    idx = np.array([0, 2, 4, 6, 8, 10, 20, 22, 24, 26])
    xyz = np.column_stack([idx * 0.8, np.cos(idx), np.zeros(len(idx))])
    assert len(snippet_rmse_m(idx, xyz, xyz)) == 2  # rows 0-4 and 1-5; 20-26 is too short


def test_too_few_posed_frames_give_no_ate():
    truth = _truth()
    ate = trajectory_metrics(_result(truth, np.zeros(3), [0, 1]), truth)
    assert ate["n_posed"] == 2 and np.isnan(ate["ate_full_m"])


def test_sign_summary_means_and_medians():
    errors = {"a": {"abs_m": 1.0, "rel_m": 0.1}, "b": {"abs_m": 2.0, "rel_m": 0.3},
              "c": {"abs_m": 6.0, "rel_m": float("nan")}}
    s = sign_summary(errors)
    assert s["n_signs"] == 3
    assert s["abs_mean_m"] == pytest.approx(3.0) and s["abs_median_m"] == pytest.approx(2.0)
    assert s["rel_mean_m"] == pytest.approx(0.2) and s["rel_median_m"] == pytest.approx(0.2)
    assert np.isnan(sign_summary({})["abs_mean_m"])


def test_compare_uses_the_signs_both_runs_placed():
    ours = {"fps": 2.0, "sign_errors": {"1": {"abs_m": 0.2, "rel_m": 0.1},
                                        "2": {"abs_m": 0.4, "rel_m": 0.1}}}
    naive = {"fps": 0.5, "sign_errors": {"2": {"abs_m": 3.0, "rel_m": 2.0}}}
    c = compare(ours, naive)
    assert c["speed_ratio"] == pytest.approx(4.0)
    assert c["n_common_signs"] == 1
    assert c["abs_mean_m_ours"] == pytest.approx(0.4) and c["abs_mean_m_naive"] == 3.0


def test_finite_makes_strict_json():
    value = finite({"a": float("nan"), "b": [np.float64(1.5), np.int64(2)], 3: float("inf")})
    assert value == {"a": None, "b": [1.5, 2], "3": None}
    json.dumps(value, allow_nan=False)


def test_perturbed_cameras_change_one_group_at_a_time():
    cams = perturbed_cameras(CAMERA, [-15.0, 0.0, 15.0])
    assert len(cams) == 7 and cams[0] == ("none", 0.0, CAMERA)
    by_key = {(g, p): c for g, p, c in cams}
    focal = by_key[("focal length", 15.0)]
    assert (focal.fx, focal.fy) == pytest.approx((959.2 * 1.15, 952.9 * 1.15))
    assert (focal.cx, focal.cy, focal.k1, focal.k2) == (694.4, 241.7, -0.369, 0.158)
    pp = by_key[("principal point", -15.0)]
    assert (pp.cx, pp.cy, pp.fx) == pytest.approx((694.4 * 0.85, 241.7 * 0.85, 959.2))
    dist = by_key[("distortion", 15.0)]
    assert (dist.k1, dist.k2, dist.cx) == pytest.approx((-0.369 * 1.15, 0.158 * 1.15, 694.4))


def test_true_camera_run_is_the_zero_point_of_every_curve():
    run = {"status": "ok", "signs": {"n_signs": 4, "rel_mean_m": 0.1, "abs_mean_m": 0.3}}
    rows = sensitivity_rows([("none", 0.0, run), ("distortion", 15.0, {"status": "failed",
                                                                        "error": "x"})])
    assert sorted(r["group"] for r in rows if r["error_pct"] == 0.0) == [
        "distortion", "focal length", "principal point"]
    assert [r["n_signs"] for r in rows if r["status"] == "failed"] == [0]


def test_sensitivity_table_and_figure(tmp_path):
    ok = {"status": "ok", "signs": {"n_signs": 4, "rel_mean_m": 0.1, "abs_mean_m": 0.3},
          "ate": {"ate_gps_m": 0.2}}
    bad = {"status": "failed", "error": "ego_motion: no window"}
    rows = sensitivity_rows([("none", 0.0, ok), ("focal length", -15.0, bad),
                             ("focal length", 15.0, ok)])
    md = table_sensitivity({"n_signs_mappable": 6, "rows": rows})
    assert "| focal length | -15.0 | 0 / 6 | – | – | – | failed: ego_motion: no window |" in md
    assert "| distortion | +0.0 | 4 / 6 | 0.100 | 0.300 | 0.200 | ok |" in md
    png = plot_sensitivity(rows, list(GROUPS), tmp_path / "s.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_prefix_keeps_the_first_frames_and_their_detections(tmp_path):
    frames = [Frame(f"{i:06d}", tmp_path / f"{i:06d}.png", 0.1 * i) for i in range(6)]
    dets = [Detection(f"{i:06d}", "0", "stop", 1, 1, 5, 5) for i in (1, 3, 5)]
    j = Journey("cam", frames, np.arange(6.0), np.arange(6.0), np.arange(6.0), dets, 64, 48)
    p = prefix(j, 4)
    assert p.frame_ids == ["000000", "000001", "000002", "000003"]
    assert list(p.lat_deg) == [0.0, 1.0, 2.0, 3.0]
    assert [d.frame_id for d in p.detections] == ["000001", "000003"]
    assert len(j.frames) == 6


def test_cli_subcommand_inherits_options_given_before_it():
    parser = argparse.ArgumentParser()
    bench_cli.add_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["bench", "--quick", "sensitivity", "--steps", "3"])
    assert args.func is bench_cli.run_sensitivity_command and args.quick and args.steps == 3
    args = parser.parse_args(["bench"])
    assert args.func is bench_cli.run_suite_command and not args.quick


def test_report_renders_failed_and_missing_runs():
    report = {"meta": {"date": "2025-01-01", "quick": True, "cpus": 2, "pycolmap": "4.2.1"},
              "journeys": {"j": {"description": "d", "n_frames": 10, "n_signs_truth": 3,
                                 "n_signs_mappable": 2, "runs": {
                                     "ours": {"status": "failed", "error": "calibrate: no turn"},
                                     "ours_alt": {"status": "skipped", "error": "no calib"}}}},
              "comparisons": {}}
    md = render_report(report)
    assert "| j | ours | failed | calibrate: no turn |" in md
    assert "### Table I" in md and "### Ours vs naive COLMAP" in md


def test_report_says_where_the_time_went_and_the_ratio_to_plain_sift():
    run = {"status": "ok", "fps": 5.0, "wall_s": 120.0, "n_frames": 600,
           "timings_s": {"read": 10.0, "ego_motion": 80.0},
           "stage_parts_s": {"ego_motion": {"extract": 50.0, "match": 10.0, "map": 19.0,
                                            "map_idle_core_s": 4.5}},
           "windows": [{"stage": "ego_motion", "frames": "0-113", "n_images": 57,
                        "n_registered": 55, "mapping_s": 9.5, "refine_s": 0.0}]}
    report = {"journeys": {"long": {"plain_sift": {"frames": 120, "wall_s": 60.0, "fps": 2.0},
                                    "runs": {"gt": run}}}}
    assert tables.table_time_parts(report).splitlines()[-1] == (
        "| long | gt | ego_motion | 80.0 | extract 50.0, match 10.0, map 19.0, idle core-s 4.5 |")
    assert tables.table_windows(report).splitlines()[-1] == (
        "| long | gt | ego_motion | 0-113 | 55 / 57 | 9.5 |  |")
    assert tables.table_sift_ratio(report).splitlines()[-1] == (
        "| long | gt | 5.00 | 2.00 (120 frames) | 2.50× |")


def test_memory_table_sets_the_whole_journey_beside_its_first_half():
    def run(frames: int, self_mb: float) -> dict:
        return {"status": "ok", "n_frames": frames, "fps": 5.0, "wall_s": 60.0, "timings_s": {},
                "peak_rss_mb": {"self_mb": self_mb, "children_mb": 500.0,
                                "total_mb": self_mb + 500.0}}
    report = {"journeys": {
        "long": {"n_frames": 600, "runs": {"gt": run(600, 1000.0), "gt_half": run(300, 900.0)}},
        "short": {"n_frames": 70, "runs": {"gt": run(70, 600.0)}}}}
    assert tables.table_memory(report).splitlines()[-2:] == [
        "| long | 600 | 1500 | 1000 | 500 | 2500 |",
        "| long | 300 (first of 600) | 1400 | 900 | 500 | 4667 |"]
    # A prefix run's signs are not set against the whole journey's truth.
    report["journeys"] = {"long": {"n_frames": 600, "runs": {"gt_half": run(300, 900.0)}}}
    assert "| long |" not in tables.table_signs(report)


@pytest.mark.slow
@pytest.mark.extended  # a bench end to end (minutes): `pytest -m extended`
def test_quick_bench_writes_tables_json_and_plots(tmp_path):
    from bench.paper.runner import run_bench

    from bench.paper.suite import quick_suite

    # turn-70 only: long-600's runs are the bench's own (minutes more).
    md_path, json_path = run_bench(quick=True, out_dir=tmp_path, cache_dir=REPO / "bench/cache",
                                   suite=quick_suite()[:1])
    report = json.loads(json_path.read_text())
    assert set(report) == {"meta", "journeys", "comparisons"}
    assert report["meta"]["quick"] is True
    journey = report["journeys"]["turn-70"]
    assert set(journey["runs"]) == {"ours", "gt", "naive"}
    assert journey["runs"]["naive"]["alignment"] == "one similarity"
    for variant, run in journey["runs"].items():
        assert run["status"] == "ok", (variant, run.get("error"))
        assert {"calibration", "ate", "signs", "timings_s", "fps", "peak_rss_mb"} <= set(run)
        assert run["peak_rss_mb"]["total_mb"] > 0
    ours = journey["runs"]["ours"]
    assert ours["calibration"]["source"] == "self"
    assert set(ours["calibration"]["errors_pct"]) == {"fx", "fy", "cx", "cy", "k1", "k2"}
    assert ours["signs"]["n_signs"] >= 1
    assert journey["runs"]["naive"]["n_frames"] == 30
    assert report["comparisons"]["turn-70"]["speed_ratio"] > 0
    assert (tmp_path / journey["plot"]).stat().st_size > 10_000
    md = md_path.read_text()
    assert {"calibrate", "ego_motion"} <= set(journey["runs"]["ours"]["stage_parts_s"])
    for heading in ("### Table I", "### Table II", "### Tables III/IV", "### Speed and memory",
                    "### Where the time goes", "### COLMAP windows", "### Ours vs naive COLMAP"):
        assert heading in md
    assert "| turn-70 | self | stage 2 |" in md
