"""``signmap bench fleet`` on hand-made kept windows and records: the joint fits, issue 66's
tables, and every journey processed again with its camera's joint calibration."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import bench.corpus.fleet as fleet
from app.pipeline.types import CameraModel
from app.synth.corpus import CORPUS_FORMAT
from bench.corpus.fleet import run_fleet
from bench.corpus.fleet_report import again_rows
from tests.utils.results.turn_windows import turn_window

TRUE = CameraModel(1280, 720, 1000.0, 1004.0, 652.0, 355.0, -0.20, 0.08)


def _kept_camera(tmp_path, turns: list[tuple[float, bool]]) -> Path:
    """A corpus index and kept records of one camera's journeys (each turning one calibrated
    ``scale`` times the true focal length), as a first run of the bench leaves them."""
    keep, entries = tmp_path / "keep", []
    keep.mkdir()
    for k, (scale, turning) in enumerate(turns):
        name = f"f0001-{k}"
        params = {**TRUE.params(), "width": 1280, "height": 720, "camera_id": "fleet-0001",
                  "journey_index": k, "max_turn_deg": 90.0 if turning else 0.0}
        entries.append({"name": name, "seed": k, "half": "check", "dir": name, "params": params})
        record = {"name": name, "camera_id": "fleet-0001", "index": k, "half": "check",
                  "error": None if turning else "no turn", "calibrate_s": 20.0}
        if turning:
            own = TRUE.replace(fx=TRUE.fx * scale, fy=TRUE.fy * scale)
            record.update(camera=own.params(), intrinsics_std=[1.0] * 6, width=1280, height=720)
            np.savez_compressed(keep / f"{name}.npz", **turn_window(TRUE, k).arrays())
        (keep / f"{name}.json").write_text(json.dumps(record))
    (tmp_path / "corpus.json").write_text(json.dumps({"format": CORPUS_FORMAT,
                                                      "journeys": entries}))
    return keep


def test_fleet_bench_fits_each_camera_from_its_kept_windows(tmp_path):
    """``signmap bench fleet`` on journeys whose calibrations are kept already (as a first run
    leaves them): the joint fit of each camera beside the consensus, and issue 66's tables."""
    keep = _kept_camera(tmp_path, [(1.015, True), (0.99, True), (1.0, False), (1.02, True)])
    # The second journey's run given the first's calibration, kept too: it confirmed it.
    (keep / "f0001-1.check.json").write_text(json.dumps({
        "name": "f0001-1", "first": "f0001-0", "error": None, "calibrate_s": 5.0,
        "source": "checked", "errors": {"fx_pct": 1.5}, "turn_errors": {"fx_pct": -0.4},
        "summary": "stored calibration confirmed on frames 3-40"}))
    md = run_fleet(tmp_path, tmp_path / "out", keep, half="check", tag="t")
    report = json.loads(md.with_suffix(".json").read_text())
    final = report["history"][-1]
    assert [(r["after"], r["windows"]) for r in report["history"]] == [(1, 1), (2, 2), (4, 3)]
    assert abs(final["joint_errors"]["fx_pct"]) < 0.3 < abs(final["consensus_errors"]["fx_pct"])
    # The windows' features reach part of the image; the distortion within that reach is no
    # worse than over the whole image.
    assert 0 < final["seen_px"] < final["corner_px"]
    assert final["distortion_seen_px"] <= final["joint_errors"]["distortion_px"]
    text = md.read_text()
    assert "| turning journeys calibrated | 3/3 (100 %) |" in text
    assert "| fx within 0.3 % | 1/1 (100 %) | 0/1 (0 %) |" in text
    assert "| fleet-0001 | 4 (3) | 0 |" in text
    # The first journey and the second side by side: self-calibrating, and checked.
    assert [(s["first"]["name"], s["self"]["name"]) for s in report["second_journeys"]] == [
        ("f0001-0", "f0001-1")]
    assert ("| fleet-0001 | 20.0 (+1.50 %) | 20.0 (-1.00 %) | 5.0 | confirmed | +1.50 % | "
            "-0.40 % |") in text
    assert "Confirmed 1 of 1; calibrate time checked / self-calibrating, median 0.25" in text


def _run_record(name: str, found: int, abs_m: list[float], source: str) -> dict:
    """A full run's corpus record, as ``bench.corpus.run.run_journey`` writes it."""
    return {"name": name, "error": None, "wall_s": 30.0, "status": "ok",
            "calibration": {"source": source},
            "signs": {"n_mappable": 5, "n_mappable_found": found, "n_false": 0},
            "sign_errors": {f"t{k}": {"abs_m": a} for k, a in enumerate(abs_m)}}


def test_fleet_bench_processes_each_journey_again_with_the_joint_calibration(tmp_path,
                                                                             monkeypatch):
    """``--again``: every journey of the camera run with its true camera and given the camera's
    joint calibration (after all its journeys) as its stored one; kept, so a second bench run
    reads them instead of running them again."""
    keep = _kept_camera(tmp_path, [(1.015, True), (0.99, True), (1.0, False)])
    calls = []

    def run_journey(corpus_dir, entry, config, calibrate_only, true_camera=False, *,
                    stored_camera=False, camera=None):
        calls.append((entry["name"], true_camera, stored_camera, camera))
        if true_camera:
            return _run_record(entry["name"], 5, [0.20, 0.20, 0.30], "supplied")
        return _run_record(entry["name"], 5, [0.20, 0.21, 0.30], "checked")

    monkeypatch.setattr(fleet, "run_journey", run_journey)
    md = run_fleet(tmp_path, tmp_path / "out", keep, half="check", tag="t", again=True)
    report = json.loads(md.with_suffix(".json").read_text())
    joint = report["history"][-1]["joint"]
    assert abs(joint["fx"] / TRUE.fx - 1) < 0.003  # the fit, not a window's own 1.5 % or -1 %
    assert sorted((n, t, s) for n, t, s, _ in calls) == sorted(
        (f"f0001-{k}", way, not way) for k in range(3) for way in (True, False))
    given = [c for _, t, _, c in calls if not t]
    assert all(c.params() == joint for c in given) and all(c is None for _, t, _, c in calls if t)
    text = md.read_text()
    assert ("| fleet-0001 | 3 | 15 / 15, 0, 0.200 | 15 / 15, 0, 0.210 | 3 checked | yes |"
            in text)
    assert ("Cameras whose journeys, processed again, are within 10 % of their true-camera recall"
            " and abs median: 1/1 (100 %).") in text
    calls.clear()
    run_fleet(tmp_path, tmp_path / "out", keep, half="check", tag="t", again=True)
    assert calls == []


def test_processed_again_misses_the_bar_by_recall_or_by_abs_median():
    true = [{"found": 10, "mappable": 10, "false": 0, "abs_m": [0.2] * 10, "source": "supplied"}]
    fewer = [{**true[0], "found": 8, "source": "checked"}]
    worse = [{**true[0], "abs_m": [0.23] * 10, "source": "self"}]
    rows = again_rows([{"camera_id": "a", "true": true, "again": true},
                       {"camera_id": "b", "true": true, "again": fewer},
                       {"camera_id": "c", "true": true, "again": worse}])
    # Per camera; "all" pools the three (28 of 30 found, median 0.20 m): within.
    assert [r.rsplit("|", 2)[1].strip() for r in rows[2:6]] == ["yes", "no", "no", "yes"]
    assert rows[-1].endswith(": 1/3 (33 %).")
