"""The corpus bench: its report on hand-made journey records, JSONL resume and CLI parsing, and
one real calibration-only run on a one-journey corpus (slow: real COLMAP)."""

from __future__ import annotations

import argparse
import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest

from app.synth.journey import SynthConfig, write_bundle
from bench import cli as bench_cli
from bench.corpus import report as cr
from bench.corpus.run import (bundle_digest, camera_errors, load_corpus, read_jsonl, run_corpus,
                              select_journeys)

TRUE = {"fx": 1000.0, "fy": 1000.0, "cx": 640.0, "cy": 360.0, "k1": -0.2, "k2": 0.0}


def _record(name: str, half: str, *, fx_pct: float | None = 0.5, error: str | None = None,
            max_turn: float = 90.0, kind: str = "turn", hfov: float = 60.0, fps: float = 10.0,
            calib_s: float | None = 20.0, cy_px: float = 1.0, k1_pct: float = 2.0) -> dict:
    params = {"max_turn_deg": max_turn, "kind": kind, "hfov_deg": hfov, "fps": fps,
              "width": 1280, "height": 720, "k1": -0.2, "scene": "town"}
    rec = {"kind": "journey", "name": name, "half": half, "params": params,
           "status": "failed" if error else "ok", "error": error, "wall_s": 30.0,
           "calib_s": None if error else calib_s, "calibration": None}
    if not error:
        errors = {"fx_pct": fx_pct, "fy_pct": fx_pct, "cx_px": -1.0, "cy_px": cy_px,
                  "k1_pct": k1_pct, "k2_pct": None, "k1_abs": 0.004, "k2_abs": 0.01}
        rec["calibration"] = {"source": "self", "errors": errors}
    return rec


CALIB_FAIL = ("calibrate: self-calibration failed on every turn window: frames 10-53: only 3/22 "
              "frames registered; frames 80-123: fx/fy = 1.14 is implausible")
NO_TURN = ("calibrate: the journey has no turn (RDP found no heading change of >= 30 deg on the "
           "GPS track); a straight road cannot calibrate the camera. Upload a journey with a "
           "turn first, or supply a calibration for this camera_id")


def _records() -> list[dict]:
    return [_record("t1", "tuning", fx_pct=0.2, fps=10),
            _record("t2", "tuning", fx_pct=-0.8, fps=10, calib_s=40.0),
            _record("t3", "tuning", fx_pct=4.0, fps=10, calib_s=60.0),  # accepted but wrong
            _record("t4", "tuning", error=CALIB_FAIL, max_turn=25.0, kind="gentle", fps=5,
                    hfov=100.0),
            _record("c1", "check", fx_pct=0.1, cy_px=6.0),
            _record("c2", "check", error="calibrate: self-calibration failed on every turn "
                    "window: frames 0-43: only 12/22 frames registered", max_turn=50.0, fps=5),
            _record("c3", "check", error="ego_motion: no window around the signs could be "
                    "reconstructed: too few frames registered")]


def test_camera_errors_units():
    est = {**TRUE, "fx": 1010.0, "cx": 643.0, "k1": -0.21, "k2": 0.05}
    e = camera_errors(est, TRUE)
    assert e["fx_pct"] == pytest.approx(1.0)
    assert e["cx_px"] == pytest.approx(3.0)
    assert e["k1_pct"] == pytest.approx(-5.0)  # relative to |true|: k1 more negative
    assert e["k1_abs"] == pytest.approx(-0.01)
    assert e["k2_pct"] is None and e["k2_abs"] == pytest.approx(0.05)  # true k2 = 0


def test_distortion_error_is_the_largest_shift_in_the_image():
    true = {"fx": 500.0, "fy": 500.0, "cx": 500.0, "cy": 500.0, "k1": 0.0, "k2": 0.0,
            "width": 1001, "height": 1001}
    assert camera_errors(true, true)["distortion_px"] == pytest.approx(0.0, abs=1e-9)
    # k1 0.01 off moves the corner (normalised radius sqrt 2) by 500 * sqrt(2) * 0.01 * 2 px.
    e = camera_errors({**true, "k1": 0.01}, true)
    assert e["distortion_px"] == pytest.approx(500 * math.sqrt(2) * 0.02, rel=1e-6)
    # k1 and k2 errors that cancel at the corner leave less than either alone.
    both = camera_errors({**true, "k1": 0.01, "k2": -0.005}, true)["distortion_px"]
    assert both < 0.5 * e["distortion_px"]
    assert "distortion_px" not in camera_errors(true, TRUE)  # no image size: not computed
    # Within 250 px of the centre (normalised radius 0.5): 500 * 0.5 * 0.01 * 0.5^2 px at most.
    from app.pipeline.types import CameraModel
    from bench.paper.metrics import distortion_error_px

    within = distortion_error_px({**true, "k1": 0.01}, CameraModel.from_params(1001, 1001, true),
                                 within_px=250.0)
    assert within == pytest.approx(500 * 0.5 * 0.01 * 0.25, rel=1e-6)


def test_projection_error_counts_a_focal_length_the_distortion_makes_up_for():
    from app.synth.camera.lens import undistort_radius

    true = {"fx": 500.0, "fy": 500.0, "cx": 500.0, "cy": 500.0, "k1": -0.05, "k2": 0.0,
            "width": 1001, "height": 1001}
    # fx 1 % long alone: no distortion error, but the corner of the image (500 sqrt(2) px from
    # the centre) moves by 1 % of that.
    e = camera_errors({**true, "fx": 505.0, "fy": 505.0}, true)
    assert e["distortion_px"] == pytest.approx(0.0, abs=1e-9)
    assert e["projection_px"] == pytest.approx(0.01 * 500 * math.sqrt(2), rel=1e-3)
    # A k1 that takes the long focal length back at the corner: its distortion is pixels off,
    # the camera as a whole far closer.
    r2 = float(undistort_radius(math.sqrt(2.0), -0.05, 0.0)) ** 2
    k1 = ((1 - 0.05 * r2) / 1.01 - 1) / r2
    both = camera_errors({**true, "fx": 505.0, "fy": 505.0, "k1": k1}, true)
    assert both["distortion_px"] > 5.0 and both["projection_px"] < 0.5 * e["projection_px"]


def test_records_written_before_the_distortion_error_get_it_from_their_parameters():
    rec = _record("t9", "tuning")
    rec["params"].update({"fx": 1000.0, "fy": 1000.0, "cx": 640.0, "cy": 360.0, "k2": 0.0})
    rec["calibration"]["camera"] = {**TRUE, "k1": -0.21}
    assert cr.error(rec, "distortion_px") > 0.5
    report = cr.build_report({}, [rec])
    assert any(row[0] == "\\|distortion\\| px median / p90" for row in cr.summary_rows(report))


def test_failure_reasons_are_normalised_and_grouped():
    assert cr.failure_reasons(CALIB_FAIL) == ["calibrate: fx/fy = X is implausible",
                                              "calibrate: only N/M frames registered"]
    assert cr.normalise("distortion k1=-0.52, k2=1.60 is implausible") == \
        "distortion k1=-X, k2=X is implausible"
    assert cr.failure_reasons(NO_TURN)[0].startswith("calibrate: the journey has no turn "
                                                     "(RDP found no heading change of >= X deg")
    groups = {g["reason"]: g for g in cr.group_failures(_records())}
    registered = groups["calibrate: only N/M frames registered"]
    assert (registered["tuning"], registered["check"]) == (1, 1)
    assert registered["names"] == ["t4", "c2"]
    assert cr.group_failures(_records())[0] is not None
    assert len(groups) == 3


def test_outcomes_and_success_rates():
    recs = {r["name"]: r for r in _records()}
    assert [cr.outcome(recs[n]) for n in ("t1", "t4", "c3")] == ["accepted", "failed", "later"]
    assert cr.is_wrong(recs["t3"]) and not cr.is_wrong(recs["t2"])
    assert cr.is_gentle(recs["t4"]) and not cr.is_steep(recs["t4"])
    assert cr.is_steep(recs["c2"]) and not cr.is_gentle(recs["c2"])
    s = cr.half_summary([r for r in _records() if r["half"] == "tuning"])
    assert s["rate_all"] == {"accepted": 3, "n": 4}
    assert s["rate_steep"] == {"accepted": 3, "n": 3}
    assert s["rate_gentle"] == {"accepted": 0, "n": 1}
    assert s["wrong"] == ["t3"]
    c = cr.half_summary([r for r in _records() if r["half"] == "check"])
    assert c["rate_all"] == {"accepted": 1, "n": 2}  # the ego-motion failure is not counted
    assert (c["failed"], c["later"]) == (1, 1)
    assert c["within"]["cx, cy ≤ 4 px"] == 0 and c["within"]["fx, fy ≤ 1 %"] == 1


def test_quantiles_over_accepted_calibrations():
    s = cr.half_summary([r for r in _records() if r["half"] == "tuning"])
    assert s["median"]["fx_pct"] == pytest.approx(0.8)  # |0.2|, |-0.8|, |4.0|
    assert s["p90"]["fx_pct"] == pytest.approx(0.8 + 0.8 * 3.2)  # numpy's linear percentile
    assert s["median"]["k2_pct"] is None  # no true k2 to be relative to
    assert s["calib_s_median"] == pytest.approx(40.0)
    assert s["within"]["all (the bar)"] == 2
    assert cr.quantile([None, float("nan"), 1.0, 3.0], 50) == pytest.approx(2.0)


def test_near_zero_k1_and_stage_2s_own_sigma_are_reported_beside_the_bar():
    small_k1 = _record("t5", "tuning", fx_pct=0.2, k1_pct=20.0)  # k1_abs 0.004: under the floor
    big_k1 = _record("t6", "tuning", fx_pct=0.2, k1_pct=20.0)
    big_k1["calibration"]["errors"]["k1_abs"] = 0.04
    for r, std in ((small_k1, [2.0, 2.0, 0.5, 2.0, 1e-3, 1e-3]), (big_k1, [])):
        r["calibration"].update(camera={**TRUE}, intrinsics_std=std)
    s = cr.half_summary([small_k1, big_k1])
    assert s["within"]["all (the bar)"] == 0
    assert s["within"]["all, k1 also within ±0.005 (not the bar)"] == 1
    # fx 0.2 % off with sigma 0.2 %, cx 1 px with 0.5, cy 1 px with 2: only t5 has a covariance.
    assert s["sigma_ratio"] == {"fx": (pytest.approx(1.0), pytest.approx(1.0)),
                                "cx": (pytest.approx(2.0), pytest.approx(2.0)),
                                "cy": (pytest.approx(0.5), pytest.approx(0.5))}
    table = cr.table_summary(cr.build_report({}, [small_k1, big_k1]))
    assert "| \\|error\\| / stage 2's own sigma, fx, cx, cy: median / p90 | 1.0 / 1.0, 2.0" in table


def _with_sigmas(name: str, half: str, *, fx_pct: float, fx_std_px: float, k1: float,
                 k1_pct: float, k1_std: float) -> dict:
    r = _record(name, half, fx_pct=fx_pct, k1_pct=k1_pct)
    r["params"]["k1"] = k1
    r["calibration"].update(camera={**TRUE},
                            intrinsics_std=[fx_std_px, fx_std_px / 2, 0.5, 0.5, k1_std, 1e-3])
    return r


def test_misses_are_binned_by_stage_2s_own_sigma():
    records = [
        # fx sigma 0.05 % (0.5 px of 1000), inside; k1 bar 0.01 = 10 sigmas of 1e-3.
        _with_sigmas("t1", "tuning", fx_pct=0.3, fx_std_px=0.5, k1=-0.2, k1_pct=2.0, k1_std=1e-3),
        # fx sigma 0.25 %, 1.2 % off; k1 -0.01 has a bar of 5e-4, half its sigma, and misses it.
        _with_sigmas("t2", "tuning", fx_pct=1.2, fx_std_px=2.5, k1=-0.01, k1_pct=30.0,
                     k1_std=1e-3),
        # fx sigma 0.25 %, inside; k1 bar 2 sigmas, inside.
        _with_sigmas("c1", "check", fx_pct=-0.4, fx_std_px=2.5, k1=-0.04, k1_pct=3.0,
                     k1_std=1e-3),
        _record("t3", "tuning")]  # no covariance: in no bin
    by_bin = {label: (n, m) for label, n, m in cr.misses_by_sigma(records)}
    assert by_bin["fx, fy sigma (the larger) < 0.1 %"] == (1, 0)
    assert by_bin["fx, fy sigma (the larger) 0.2-0.3 %"] == (2, 1)
    assert by_bin["k1 bar (5 % of \\|k1\\|) in sigmas of k1 < 1"] == (1, 1)
    assert by_bin["k1 bar (5 % of \\|k1\\|) in sigmas of k1 1-4"] == (1, 0)
    assert by_bin["k1 bar (5 % of \\|k1\\|) in sigmas of k1 ≥ 4"] == (1, 0)
    assert sum(n for n, _ in by_bin.values()) == 6  # three records, each in one bin of each kind
    table = cr.table_sigma(cr.build_report({}, records))
    assert "| fx, fy sigma (the larger) 0.2-0.3 % | 1, 1 | 1, 0 |" in table
    assert "| fx, fy sigma (the larger) ≥ 0.3 % | – | – |" in table


def test_corpus_report_rereads_runs_and_keeps_a_journeys_last_record(tmp_path: Path, capsys):
    first, second = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    meta = json.dumps({"kind": "meta", "tag": ""})
    first.write_text("\n".join([meta, json.dumps(_record("t1", "tuning", fx_pct=2.0)),
                                json.dumps(_record("c1", "check"))]) + "\n")
    second.write_text("\n".join([meta, json.dumps(_record("t1", "tuning", fx_pct=0.2))]) + "\n")
    out = tmp_path / "report.md"
    assert bench_cli.main(["corpus-report", str(first), str(second), "--out", str(out)]) == 0
    md = out.read_text()
    assert md == capsys.readouterr().out.rstrip("\n") + "\n"
    assert "2 journeys from" in md and "1 earlier records of the same journeys left out" in md
    assert "| accepted with fx, fy ≤ 1 % | 1/1 | 1/1 |" in md  # t1's re-run, not its 2.0 %
    assert "### Misses by stage 2's own sigma" in md
    with pytest.raises(SystemExit, match="no such file"):
        bench_cli.main(["corpus-report", str(tmp_path / "missing.jsonl")])


def test_sign_rows_only_on_full_runs():
    records = _records()
    records[0]["signs"] = {"n_signs": 5, "n_mappable": 6, "n_mappable_found": 5, "n_false": 1,
                           "abs_median_m": 0.4}
    records[1]["signs"] = {"n_signs": 3, "n_mappable": 3, "n_mappable_found": 2, "n_duplicate": 1,
                           "abs_median_m": 0.2}
    s = cr.half_summary(records[:4])
    assert (s["signs_placed"], s["signs_mappable"], s["signs_mappable_found"]) == (10, 9, 7)
    assert (s["signs_false"], s["signs_duplicate"]) == (1, 1)
    assert s["abs_median_m"] == pytest.approx(0.3)
    table = cr.table_summary(cr.build_report({}, records))
    assert "| recall: mappable signs placed (≥ 5 frames, ≥ 12 px) | 7/9 (78 %) | 0/0 |" in table
    assert "| false signs / duplicates (> 3 m from any true sign / a second for one) | 1 / 1 |" in table
    assert "signs placed" not in cr.table_summary(cr.build_report({}, _records()))


def test_coverage_and_relative_error_come_with_an_interval_over_journeys():
    """Signs of one journey share its errors: the interval resamples journeys, so ten signs of
    one journey all outside widen it as one journey would, not as ten independent signs."""
    def journey(inside: list[bool], rel_m: float) -> dict:
        return {"status": "accepted", "signs": {"n_signs": len(inside)},
                "params": {"gps_white_sigma_m": 0.25, "gps_bias_sigma_m": 0.1},
                "sign_errors": {str(i): {"within_r95": v, "rel_m": rel_m, "abs_m": 0.2}
                                for i, v in enumerate(inside)}}

    stats = cr.sign_error_stats([journey([True] * 10, 0.1)] * 8 + [journey([False] * 10, 0.9)] * 2)
    assert stats["r95_coverage"] == pytest.approx(0.8)
    low, high = stats["r95_coverage_ci90"]
    assert low <= 0.65 and 0.9 <= high <= 1.0  # a journey moves the share by ten points
    low, high = stats["rel_mean_ci90_m"]
    assert low < 0.26 < high
    same = cr.sign_error_stats([journey([True, False], 0.2)] * 5)
    assert same["r95_coverage_ci90"] == pytest.approx([0.5, 0.5])
    assert cr.sign_error_stats([journey([True], 0.2)])["r95_coverage_ci90"] is None


def test_param_comparison():
    p = cr.param_comparison(_records())
    assert p["numeric"]["fps"]["tuning"] == {"failed": 5.0, "accepted": 10.0}
    assert p["numeric"]["hfov_deg"]["tuning"]["failed"] == 100.0
    assert p["numeric"]["fps"]["check"] == {"failed": 5.0, "accepted": 10.0}
    assert p["categorical"]["kind = gentle"]["tuning"] == {"failed": 1, "n": 1}
    assert p["categorical"]["kind = turn"]["check"] == {"failed": 1, "n": 2}  # c3 undecided
    assert "scene = town" in p["categorical"]


def test_report_markdown_json_and_plot(tmp_path: Path):
    md = cr.write_report({"date": "2026-11-24", "tag": "x", "calibrate_only": True}, _records(),
                         tmp_path / "r.md", tmp_path / "r.json", tmp_path / "r.png", 12.0)
    for text in ("### Summary", "| tuning | check |", "3/4 (75 %)", "**1**: t3",
                 "only N/M frames registered", "kind = gentle", "t3 | tuning", "**WRONG**"):
        assert text in md
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["summary"]["tuning"]["wrong"] == ["t3"]
    assert (tmp_path / "r.png").stat().st_size > 10_000


def test_select_and_resume_file(tmp_path: Path):
    index = {"format": "signmap-corpus/1", "journeys": [
        {"name": f"c{i:04d}", "half": "tuning" if i % 2 else "check"} for i in range(6)]}
    assert [j["name"] for j in select_journeys(index, half="check", limit=2)] == ["c0000",
                                                                               "c0002"]
    assert [j["name"] for j in select_journeys(index, names=["c0003"])] == ["c0003"]
    with pytest.raises(ValueError):
        select_journeys(index, names=["nope"])
    (tmp_path / "corpus.json").write_text(json.dumps({**index, "format": "other"}))
    with pytest.raises(ValueError):
        load_corpus(tmp_path)
    jsonl = tmp_path / "r.jsonl"
    jsonl.write_text('{"kind": "meta", "tag": ""}\n{"kind": "journey", "name": "a"}\n{"kind": "jo')
    meta, records = read_jsonl(jsonl)  # the last line was cut short by a kill
    assert meta["tag"] == "" and [r["name"] for r in records] == ["a"]


def test_cli_parses_corpus_options(tmp_path: Path):
    parser = argparse.ArgumentParser()
    bench_cli.add_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["bench", "corpus", "--corpus", str(tmp_path), "--half", "check",
                              "--set", "calib_max_candidates=3", "--set", "calib_front_end=klt",
                              "--names", "a,b", "--calibrate-only", "--resume", "--tag", "t"])
    assert args.func is bench_cli.run_corpus_command
    assert dict(args.set) == {"calib_max_candidates": 3, "calib_front_end": "klt"}
    assert args.out == bench_cli.BENCH_DIR / "results" and args.calibrate_only and args.resume
    with pytest.raises(SystemExit):
        parser.parse_args(["bench", "corpus", "--corpus", "x", "--set", "novalue"])


def test_a_focal_scale_without_the_true_camera_is_refused(tmp_path: Path):
    parser = argparse.ArgumentParser()
    bench_cli.add_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["bench", "corpus", "--corpus", str(tmp_path),
                              "--true-camera-focal-scale", "0.97"])
    with pytest.raises(SystemExit, match="give --true-camera or --stored-camera too"):
        args.func(args)
    both = parser.parse_args(["bench", "corpus", "--corpus", str(tmp_path), "--true-camera",
                              "--stored-camera"])
    with pytest.raises(SystemExit, match="give one"):
        both.func(both)


def test_unknown_knob_is_an_error(tmp_path: Path):
    with pytest.raises(ValueError, match="unknown pipeline knob"):
        run_corpus(tmp_path, tmp_path / "out", config_overrides={"calib_fram_step": 3})


def _fake_corpus(root: Path) -> Path:
    """One 70-frame, one-turn journey laid out as ``signmap synth corpus`` writes a corpus."""
    cam = SynthConfig().camera
    write_bundle(SynthConfig(n_frames=70, turns=1), root / "c0000")
    params = {"fps": 10.0, "speed_mps": 8.0, "kind": "turn", "width": cam.width,
              "height": cam.height, **cam.params(), "n_frames": 70, "max_turn_deg": 90.0,
              "hfov_deg": math.degrees(2 * math.atan(cam.width / (2 * cam.fx)))}
    (root / "corpus.json").write_text(json.dumps({
        "format": "signmap-corpus/1", "seed": 0, "n": 1, "generator_version": "test",
        "journeys": [{"name": "c0000", "seed": 0, "half": "tuning", "dir": "c0000",
                      "params": params}]}))
    return root


def test_a_run_written_before_a_setup_field_existed_resumes_and_another_setup_does_not(
        tmp_path: Path):
    from bench.corpus.run import run_corpus

    corpus = tmp_path / "corpus"
    corpus.mkdir()
    (corpus / "corpus.json").write_text(json.dumps({
        "format": "signmap-corpus/1", "seed": 0, "n": 1, "journeys": [
            {"name": "t1", "seed": 0, "half": "tuning", "dir": "t1", "params": {}}]}))
    out = tmp_path / "out"
    out.mkdir()
    old_meta = {"kind": "meta", "corpus": str(corpus.resolve()), "calibrate_only": True,
                "true_camera": False, "config_overrides": {}, "replay_of": None, "tag": "old"}
    jsonl = out / "2026-11-01-corpus-old.jsonl"  # its only journey is done: nothing runs
    jsonl.write_text(json.dumps(old_meta) + "\n" + json.dumps(_record("t1", "tuning")) + "\n")
    paths = run_corpus(corpus, out, calibrate_only=True, tag="old", resume=True)
    assert paths.jsonl == jsonl and "t1" in paths.markdown.read_text()
    with pytest.raises(ValueError, match="stored_camera"):
        run_corpus(corpus, out, calibrate_only=True, tag="old", resume=True, stored_camera=True)


@pytest.mark.slow
@pytest.mark.extended  # a bench end to end (minutes): `pytest -m extended`
def test_calibrate_only_run_on_a_fake_corpus(tmp_path: Path):
    corpus = _fake_corpus(tmp_path / "corpus")
    paths = run_corpus(corpus, tmp_path / "out", calibrate_only=True, limit=1, tag="test")
    assert paths.jsonl.name.endswith("-corpus-test.jsonl")
    meta, records = read_jsonl(paths.jsonl)
    assert meta["calibrate_only"] and len(records) == 1
    rec = records[0]
    assert rec["status"] in ("ok", "failed")
    assert rec["bundle_digest"] == bundle_digest(corpus / "c0000" / "bundle.zip")
    if rec["status"] == "ok":
        assert rec["calibration"]["source"] == "self"
        assert math.isfinite(rec["calibration"]["errors"]["fx_pct"])
        assert "calibrate" in rec["timings_s"] and "signs" not in rec  # stopped after calibrating
    else:
        assert rec["error"]
    assert "| c0000 | tuning |" in paths.markdown.read_text()
    # A resumed run skips the journey it already has.
    again = run_corpus(corpus, tmp_path / "out", calibrate_only=True, limit=1, tag="test",
                       resume=True)
    assert again.jsonl == paths.jsonl and len(read_jsonl(paths.jsonl)[1]) == 1


def test_corpus_compare_puts_before_and_after_side_by_side(tmp_path):
    from bench.corpus.compare import compare

    before = _records()
    after = [dict(r) for r in _records()]
    after[0]["signs"] = {"n_signs": 5, "n_mappable": 6, "n_mappable_found": 5, "abs_median_m": 0.4}
    table = compare(before, after)
    assert table.startswith(f"{len(before)} journeys run on both sides.")
    assert "| journeys run | 4 | 4 | 3 | 3 |" in table
    # A row only the after side has is shown, with a dash before.
    assert "| recall: mappable signs placed (≥ 5 frames, ≥ 12 px) | – | 5/6 (83 %) | – | 0/0 |" in table


def _zip(path: Path, members: dict[str, bytes], year: int) -> Path:
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(zipfile.ZipInfo(name, date_time=(year, 1, 1, 0, 0, 0)), data)
    return path


def test_a_bundle_digest_follows_the_contents_not_the_write_time(tmp_path):
    members = {"manifest.json": b"{}", "frames/000000.jpg": b"\xff\xd8pixels"}
    a = bundle_digest(_zip(tmp_path / "a.zip", members, 2025))
    assert a == bundle_digest(_zip(tmp_path / "b.zip", dict(reversed(members.items())), 2026))
    other = {**members, "frames/000000.jpg": b"\xff\xd8pixelz"}
    assert a != bundle_digest(_zip(tmp_path / "c.zip", other, 2025))
    # An unreadable bundle has none: its run fails with the pipeline's reason, the bench goes on.
    (tmp_path / "broken.zip").write_bytes(b"not a zip")
    assert bundle_digest(tmp_path / "broken.zip") is None
    assert bundle_digest(tmp_path / "missing.zip") is None


def test_corpus_compare_names_journeys_rendered_differently(tmp_path):
    from bench.corpus.compare import compare

    before = [{**r, "bundle_digest": "aaaa"} for r in _records()]
    after = [{**r, "bundle_digest": "aaaa"} for r in _records()]
    assert "Not the same input" not in compare(before, after)
    after[1]["bundle_digest"] = "bbbb"
    assert (f"**Not the same input:** rendered differently on the two sides: "
            f"{after[1]['name']};") in compare(before, after)


def test_a_missed_sign_of_a_bundle_without_track_ids_gets_the_reason_of_the_track_it_became():
    from bench.corpus.run import _why_not, track_of_sign

    def sign(sid, boxes):
        return {"id": sid, "track_id": "", "observations": [
            {"frame": f, "box_true": b} for f, b in boxes]}

    truth = {"signs": [sign("s00", [("000001", [10, 10, 30, 30]), ("000002", [12, 10, 32, 30])]),
                       sign("s01", [("000001", [100, 50, 120, 70])]),
                       sign("s02", [("000003", [200, 50, 220, 70])]),
                       sign("s03", [("000004", [300, 50, 320, 70])])]}
    detections = [("000001", "auto-0", 11, 10, 31, 30), ("000002", "auto-0", 12, 11, 32, 31),
                  ("000001", "auto-1", 101, 50, 121, 70), ("000003", "auto-2", 200, 50, 220, 70),
                  ("000004", "auto-3", 400, 50, 420, 70)]  # s03's box was not detected there
    became = track_of_sign(truth, detections)
    assert became == {"s00": "auto-0", "s01": "auto-1", "s02": "auto-2"}
    rejected = {"auto-0": "reprojection rms 9.1 px > 4.0"}
    unmatched = {"auto-1": {"track_id": "auto-1", "nearest_true_m": 5.2, "kind": "false"}}
    placed = {"s09": "auto-2"}
    assert _why_not("s00", truth, rejected, became["s00"]) == "reprojection rms 9.1 px > 4.0"
    assert _why_not("s01", truth, rejected, became["s01"], placed, unmatched) == (
        "placed as auto-1 5.2 m from the nearest true sign (counted false)")
    assert _why_not("s02", truth, rejected, became["s02"], placed, unmatched) == (
        "its track auto-2 was placed and matched to s09")
    assert _why_not("s03", truth, rejected, None) == (
        "not placed: none of its detections is in a track")


@pytest.mark.slow
def test_a_replay_georeferences_the_kept_reconstruction_as_the_full_run_did(tmp_path: Path):
    corpus = _fake_corpus(tmp_path / "corpus")
    kept = tmp_path / "kept"
    full = run_corpus(corpus, tmp_path / "out", true_camera=True, tag="full", keep_dir=kept)
    [full_rec] = read_jsonl(full.jsonl)[1]
    assert full_rec["status"] == "ok" and len(full_rec["sign_errors"]) >= 3
    assert (kept / "c0000.pkl").is_file()

    same = run_corpus(corpus, tmp_path / "out", true_camera=True, tag="same", replay_dir=kept)
    meta, [same_rec] = read_jsonl(same.jsonl)
    assert meta["replay_of"] == str(kept.resolve())
    assert same_rec["sign_errors"] == full_rec["sign_errors"]  # bit for bit
    assert same_rec["missed_mappable"] == full_rec["missed_mappable"]

    # The pose-error split re-triangulates the same placed signs: its "placed" error is the
    # bench's, and the renderer's own poses place them closer than the estimated ones do.
    from bench.studies.pose_error import collect, table
    rows = collect(kept, corpus)
    by_track = {r.track_id: r for r in rows}
    assert set(by_track) <= set(full_rec["sign_errors"]) and len(rows) >= 3
    for track_id, r in by_track.items():
        assert r.rel_m["placed"] == pytest.approx(full_rec["sign_errors"][track_id]["rel_m"])
    assert (np.mean([r.rel_m["true poses"] for r in rows])
            < np.mean([r.rel_m["placed"] for r in rows]))
    assert "| phone | " in table(rows)

    # A georeferencing knob changes the outcome without mapping again...
    short = run_corpus(corpus, tmp_path / "out", true_camera=True, tag="short", replay_dir=kept,
                       config_overrides={"alignment": "short"})
    [short_rec] = read_jsonl(short.jsonl)[1]
    assert short_rec["status"] == "ok"
    assert short_rec["sign_errors"] != full_rec["sign_errors"]
    # ...and a knob that acts before the align stage is refused by name.
    with pytest.raises(ValueError, match="klt_max_corners act before the align stage"):
        run_corpus(corpus, tmp_path / "out", true_camera=True, tag="klt", replay_dir=kept,
                   config_overrides={"klt_max_corners": 1200})
    with pytest.raises(ValueError, match="not both"):
        run_corpus(corpus, tmp_path / "out", keep_dir=kept, replay_dir=kept)
    with pytest.raises(ValueError, match="no such directory"):
        run_corpus(corpus, tmp_path / "out", replay_dir=tmp_path / "nothing")
    # A journey whose kept run left nothing (its process died) is a failed record.
    (kept / "c0000.pkl").unlink()
    gone = run_corpus(corpus, tmp_path / "out", true_camera=True, tag="gone", replay_dir=kept)
    [gone_rec] = read_jsonl(gone.jsonl)[1]
    assert gone_rec["status"] == "failed" and "no reconstruction kept" in gone_rec["error"]


def test_the_pooled_slope_removes_each_journeys_own_offset():
    s = np.linspace(0.0, 200.0, 9)
    # Error growing 0.2 m per 100 m in both journeys, one of them 1 m worse throughout: the median
    # of each journey's slope and the pooled slope both say 0.2; noise-free, so no error.
    journeys = [np.column_stack([s, 0.3 + 0.002 * s]), np.column_stack([s, 1.3 + 0.002 * s])]
    slope, se = cr.pooled_slope(journeys)
    assert slope == pytest.approx(0.2) and se == pytest.approx(0.0, abs=1e-9)
    # Scattered signs with no trend: the slope stays within its standard error of 0.
    rng = np.random.default_rng(0)
    flat = [np.column_stack([s, 0.3 + rng.normal(0.0, 0.1, len(s))]) for _ in range(8)]
    slope, se = cr.pooled_slope(flat)
    assert abs(slope) < 3 * se and se > 0
    assert cr.pooled_slope([]) == (None, None)
