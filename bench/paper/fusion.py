"""``signmap bench fusion``: absolute error of the fused map against the number of journeys.

N rendered journeys drive ONE synthetic world (same ``world_seed`` and ``world_travel_m``, one
turn), each with its own noise seed, lane (lateral offset) and, for a few, a constant GPS bias. The
real pipeline runs on each in its own process: the first journey self-calibrates, the others are
given that calibration with ``reuse_known_calibration=True`` (should the first fail to calibrate,
the first that does serves the rest, and those that failed before it run again with it). The
first k journeys' signs (k in 1, 2, 3, 5, 10, up to N) are fused with ``app.fusion.fuse_map``
exactly as the service converts stored signs, and every map sign is scored against the true sign
its members were detected from (the synthetic track id is the true sign's identity, as in
``bench.paper.metrics``).

Issue 5's bar: median absolute error <= 0.25 m with 5 journeys.
"""

from __future__ import annotations

import datetime as dt
import json
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.fusion import FusionConfig, JourneySign, MapSign, fuse_map
from app.pipeline.config import PipelineConfig
from app.pipeline.types import CameraModel, JourneyResult
from app.service.db import map_rows
from app.service.jobs import fusion
from app.service.db.models import JourneyRow, JourneySignRow
from app.synth.journey import SynthConfig
from bench.paper import metrics, plots
from bench.paper.metrics import truth_frame, truth_id
from bench.paper.run_pipeline import RunTask, run_isolated
from bench.paper.runner import run_meta, finite, log, run_summary
from bench.paper.suite import JourneySpec, ensure_journey
from bench.paper.tables import fmt, md_table

K_JOURNEYS = (1, 2, 3, 5, 10)
BAR_MEDIAN_M = 0.25
BAR_K = 5
# The quick suite's turn-70 world, where a journey self-calibrates. (In world 5, journeys 1 and 2 of
# this bench both failed to: "only 3-9/30 frames registered" on every turn window.)
WORLD_SEED = 0
# Every journey drives the same road length's world: a WorldSpec is (seed, turns, loop, travel,
# ...), so fixing travel_m (the least a one-turn road needs) makes quick and full share it too.
WORLD_TRAVEL_M = 59.0
LANES_M = (0.0, 0.8, -0.8, 1.6, -1.6)  # right of the centreline, cycled over the journeys
# Constant GPS biases (east, north, up; metres) of a few journeys, on top of every journey's white
# noise and slowly wandering bias (SynthConfig defaults): what a cheap receiver is off by.
GPS_BIAS_M = {2: (0.7, -0.5, 0.0), 5: (-0.6, -0.8, 0.0), 8: (0.3, 0.9, 0.0)}

KnownCamera = tuple[str, CameraModel]  # (journey that calibrated it, camera)


@dataclass
class JourneyRun:
    """One journey's pipeline run: its record (``run_summary`` plus the journey's set-up), result
    and truth."""

    name: str
    synth: SynthConfig
    record: dict
    result: JourneyResult | None
    truth: dict


def fusion_journeys(quick: bool) -> list[JourneySpec]:
    """N journeys over one world: N = 3 of 50 frames (quick) or 10 of 70 frames."""
    n, frames = (3, 50) if quick else (10, 70)
    specs = []
    for i in range(n):
        synth = SynthConfig(world_seed=WORLD_SEED, seed=100 + i, n_frames=frames, turns=1,
                            world_travel_m=WORLD_TRAVEL_M,
                            lateral_offset_m=LANES_M[i % len(LANES_M)],
                            gps_bias_m=GPS_BIAS_M.get(i, (0.0, 0.0, 0.0)),
                            captured_at=f"2025-06-{i + 1:02d}T10:00:00Z")
        name = f"fusion-j{i + 1:02d}-{frames}"
        specs.append(JourneySpec(name, synth, ("ours",), f"{frames} frames, lane "
                                 f"{synth.lateral_offset_m:+.1f} m, GPS bias "
                                 f"{np.linalg.norm(synth.gps_bias_m):.2f} m",
                                 known_from=None if i == 0 else specs[0].name))
    if len({s.synth.world_spec() for s in specs}) != 1:
        raise AssertionError("the fusion journeys must share one world")
    return specs


def run_one(spec: JourneySpec, cache_dir: Path, base: PipelineConfig,
            known: KnownCamera | None) -> JourneyRun:
    """Render (or reuse) and process one journey in its own process; given ``known``, the journey
    uses that camera instead of calibrating itself."""
    bundle, truth = ensure_journey(spec, cache_dir)
    config = base.model_dump()
    if known is not None:
        config["reuse_known_calibration"] = True
    with tempfile.TemporaryDirectory(prefix=f"bench-{spec.name}-") as tmp:
        task = RunTask(f"{spec.name}/ours", bundle, Path(tmp), config,
                       known_camera=known[1] if known else None)
        log(f"{task.label}: running ("
            + (f"calibration of {known[0]}" if known else "self-calibrating") + ")")
        out = run_isolated(task)
    record = {"lane_m": spec.synth.lateral_offset_m, "gps_bias_m": list(spec.synth.gps_bias_m),
              "seed": spec.synth.seed, "captured_at": spec.synth.captured_at,
              "calibration_from": known[0] if known else None,
              **run_summary(out, truth, task)}
    log(f"{task.label}: {record['status']} in {out.wall_s:.0f} s"
        + (f" ({out.error})" if out.error else ""))
    return JourneyRun(spec.name, spec.synth, record, out.result, truth)


def self_calibration(run: JourneyRun) -> KnownCamera | None:
    """The camera the run calibrated itself, if it did: like the service's stored calibration of
    a camera_id, the first one serves every later journey."""
    if run.result is not None and run.result.calibration.source == "self":
        return run.name, run.result.calibration.camera
    return None


def failed_to_calibrate(run: JourneyRun) -> bool:
    """The run had no calibration to fall back on and could not calibrate itself."""
    return (run.result is None and run.record.get("calibration_from") is None
            and (run.record.get("error") or "").startswith("calibrate:"))


def rerun_with(spec: JourneySpec, failed: JourneyRun, cache_dir: Path, base: PipelineConfig,
               known: KnownCamera) -> JourneyRun:
    """A journey whose self-calibration failed before any calibration was known, run again with
    the one found since (what the service's fallback to the stored calibration gives it once one
    exists); the failed attempt stays in the record."""
    run = run_one(spec, cache_dir, base, known)
    first = failed.record
    run.record["first_attempt"] = {"status": first["status"], "error": first.get("error"),
                                   "wall_s": first["wall_s"], "cpu_s": first.get("cpu_s")}
    return run


def journey_signs(run: JourneyRun, rank: int) -> list[JourneySign]:
    """The run's signs as the service hands them to fusion (``map_rows.journey_sign`` of the rows
    ``state.store_result`` would write). The service's journey key is ``<bundle sha256>/<id>``;
    here the rank comes first so that the bench chooses the order fusion processes journeys in."""
    if run.result is None:
        return []
    captured_s = fusion.captured_at_s(JourneyRow(captured_at=run.synth.captured_at))
    rows = [JourneySignRow(id=f"{run.name}:{s.track_id}", cls=s.cls, lat_deg=float(s.lat_deg),
                           lon_deg=float(s.lon_deg),
                           alt_m=float(s.alt_m) if s.alt_m is not None and np.isfinite(s.alt_m)
                           else None, std_m=float(s.std_m))
            for s in run.result.signs]
    return [map_rows.journey_sign(r, f"{rank:02d}/{run.name}", captured_s) for r in rows]


def track_of(sign_id: str) -> str:
    return sign_id.rsplit(":", 1)[1]


def true_track(sign: MapSign) -> str:
    """The true sign (track id) most of the map sign's members were detected from; ties go to the
    smallest id."""
    counts = Counter(track_of(m) for m in sign.members)
    return min(counts, key=lambda t: (-counts[t], t))


def map_sign_xyz(signs: list[MapSign], truth: dict) -> np.ndarray:
    """(M, 3) map sign positions in truth ENU; up is NaN for a sign without altitude."""
    if not signs:
        return np.zeros((0, 3))
    alt = [s.alt_m if s.alt_m is not None else np.nan for s in signs]
    return truth_frame(truth).to_local([s.lat_deg for s in signs], [s.lon_deg for s in signs], alt)


def evaluate_map(signs: list[MapSign], truth: dict) -> dict:
    """Count and error of map signs against the true signs (``truth["signs"]`` by track id).

    Every map sign is scored against its majority true sign, so a duplicate's error counts too.
    ``n_duplicates``: map signs beyond the first of a true sign; ``n_mixed``: map signs whose
    members come from more than one true sign (a wrong merge)."""
    true_xyz = {str(s["track_id"]): np.asarray(s["xyz_enu"], float) for s in truth["signs"]}
    tracks = [true_track(s) for s in signs]
    per_true = Counter(tracks)
    d = map_sign_xyz(signs, truth) - np.array([true_xyz[t] for t in tracks]).reshape(-1, 3)
    err_3d, err_h = np.linalg.norm(d, axis=1), np.linalg.norm(d[:, :2], axis=1)

    def stat(fn, a: np.ndarray) -> float:
        a = a[np.isfinite(a)]
        return float(fn(a)) if len(a) else float("nan")
    return {"n_map_signs": len(signs), "n_true_mapped": len(per_true),
            "n_duplicates": sum(c - 1 for c in per_true.values()),
            "n_mixed": sum(len({track_of(m) for m in s.members}) > 1 for s in signs),
            "abs_median_m": stat(np.median, err_3d), "abs_mean_m": stat(np.mean, err_3d),
            "horiz_median_m": stat(np.median, err_h), "horiz_mean_m": stat(np.mean, err_h),
            "errors_m": {s.map_id: float(e) for s, e in zip(signs, err_3d)}}


def single_journey_errors(runs: list[JourneyRun]) -> dict:
    """Each journey's own sign errors (``bench.paper.metrics.sign_errors`` via ``run_summary``): the
    mean over journeys of their mean absolute error, and the median of all their signs' errors."""
    ok = [r.record for r in runs if r.record.get("status") == "ok" and r.record["sign_errors"]]
    means = [np.mean([e["abs_m"] for e in rec["sign_errors"].values()]) for rec in ok]
    pooled = [e["abs_m"] for rec in ok for e in rec["sign_errors"].values()]
    return {"single_abs_mean_m": float(np.mean(means)) if means else float("nan"),
            "single_abs_median_m": float(np.median(pooled)) if pooled else float("nan")}


def order_difference(a: list[MapSign], b: list[MapSign], truth: dict) -> dict:
    """Two maps of the same journeys: map signs only one has (by ``map_id``, which depends on the
    members only) and the largest position difference (m) of the signs both have."""
    ids_a, ids_b = {s.map_id: s for s in a}, {s.map_id: s for s in b}
    common = sorted(set(ids_a) & set(ids_b))
    xa = map_sign_xyz([ids_a[i] for i in common], truth)
    xb = map_sign_xyz([ids_b[i] for i in common], truth)
    diff = np.linalg.norm(np.nan_to_num(xa - xb), axis=1)
    return {"n_only_one_order": len(set(ids_a) ^ set(ids_b)),
            "max_diff_m": float(diff.max()) if len(diff) else float("nan")}


def mappable_ids(runs: list[JourneyRun], min_frames: int) -> set[str]:
    """Track ids of the true signs that must be mapped: by ``bench.paper.metrics.mappable_ids``
    (``min_frames`` frames with a box of at least 12 px) in at least one of the journeys."""
    out: set[str] = set()
    for r in runs:
        ids = set(metrics.mappable_ids(r.truth, min_frames))
        out |= {str(s["track_id"]) for s in r.truth["signs"] if truth_id(s) in ids}
    return out


def fusion_row(runs: list[JourneyRun], config: FusionConfig, min_frames: int) -> dict:
    """Fuse the runs' signs in their order and in the reverse order; score the first map."""
    forward = [s for rank, r in enumerate(runs) for s in journey_signs(r, rank)]
    backward = [s for rank, r in enumerate(reversed(runs)) for s in journey_signs(r, rank)]
    fused, fused_rev = fuse_map(forward, config=config), fuse_map(backward, config=config)
    truth = runs[0].truth
    row = {"k": len(runs), "n_ok": sum(r.result is not None for r in runs),
           "n_journey_signs": len(forward),
           "n_mappable": len(mappable_ids(runs, min_frames)),
           "n_biased_flagged": len(fused.biased_journeys),
           **evaluate_map(fused.signs, truth), **single_journey_errors(runs)}
    rev = evaluate_map(fused_rev.signs, truth)
    row["reversed"] = {"abs_median_m": rev["abs_median_m"], "abs_mean_m": rev["abs_mean_m"],
                       **order_difference(fused.signs, fused_rev.signs, truth)}
    return row


def fusion_rows(runs: list[JourneyRun], config: FusionConfig, min_frames: int) -> list[dict]:
    return [fusion_row(runs[:k], config, min_frames) for k in K_JOURNEYS if k <= len(runs)]


def bar_verdict(rows: list[dict]) -> str:
    row = next((r for r in rows if r["k"] == BAR_K), None)
    if row is None:
        return f"not measured (fewer than {BAR_K} journeys)"
    met = np.isfinite(row["abs_median_m"]) and row["abs_median_m"] <= BAR_MEDIAN_M
    return (f"{'met' if met else 'NOT met'}: median {fmt(row['abs_median_m'])} m with {BAR_K} "
            "journeys")


def table_fusion(rows: list[dict]) -> str:
    body = [[r["k"], r["n_ok"], r["n_map_signs"], f"{r['n_true_mapped']} / {r['n_mappable']}",
             r["n_duplicates"], r["n_mixed"], fmt(r["abs_median_m"]), fmt(r["abs_mean_m"]),
             fmt(r["horiz_median_m"]), fmt(r["horiz_mean_m"]), fmt(r["single_abs_mean_m"]),
             fmt(r["single_abs_median_m"]), r["n_biased_flagged"],
             f"{fmt(r['reversed']['max_diff_m'], 4)} ({r['reversed']['n_only_one_order']})"]
            for r in rows]
    header = ["journeys", "ok", "map signs", "true signs mapped / mappable (≥ 5 frames, ≥ 12 px)",
              "duplicates", "mixed", "abs median (m)", "abs mean (m)", "horiz median (m)", "horiz mean (m)",
              "single-journey abs mean (m)", "single-journey abs median (m)", "flagged biased",
              "reversed order: max Δ (m) (signs in one map only)"]
    return md_table(header, body)


def _calibration_label(rec: dict) -> str:
    source = rec.get("calibration", {}).get("source")
    if source == "supplied" and rec.get("calibration_from"):
        return f"from {rec['calibration_from']}"
    return source or "–"


def _run_label(rec: dict) -> str:
    """Status and reason, of the failed first attempt too."""
    def reason(r: dict) -> str:
        return r["status"] if r["status"] == "ok" else (
            f"{r['status']}: {(r.get('error') or '').replace('|', '/')}")
    first = rec.get("first_attempt")
    if first is None:
        return reason(rec)
    return (f"{reason(rec)} (re-run; self-calibrating first in {fmt(first['wall_s'], 1)} s: "
            f"{reason(first)})")


def table_journeys(runs: list[JourneyRun]) -> str:
    body = []
    for r in runs:
        rec = r.record
        signs = rec.get("signs", {})
        body.append([r.name, f"{rec['lane_m']:+.1f}",
                     ", ".join(f"{v:+.1f}" for v in rec["gps_bias_m"]), _calibration_label(rec),
                     fmt(signs.get("n_signs")), fmt(signs.get("abs_mean_m")),
                     fmt(signs.get("abs_median_m")), fmt(rec["wall_s"], 1),
                     fmt(rec.get("cpu_s"), 0), _run_label(rec)])
    header = ["journey", "lane (m)", "GPS bias E, N, U (m)", "calibration", "signs",
              "abs mean (m)", "abs median (m)", "total (s)", "CPU s", "run"]
    return md_table(header, body)


def render_fusion(report: dict, runs: list[JourneyRun]) -> str:
    meta = report["meta"]
    partial = "" if meta.get("complete") else " (interrupted: journeys so far)"
    return "\n".join([
        f"# Multi-journey fusion {meta['date']}" + (" (quick)" if meta["quick"] else "") + partial,
        "",
        f"Commit {meta.get('commit')}"
        + (" with uncommitted changes" if meta.get("uncommitted_changes") else "")
        + f", {meta['cpus']} CPUs (load average {fmt(meta.get('load_avg_at_start'), 1)} at the "
        f"start), whole run {fmt(meta.get('wall_s'), 0)} s. {len(runs)} journeys over one "
        f"synthetic world (world_seed {WORLD_SEED}, one turn, {report['n_signs_truth']} signs); "
        "the first journey that calibrates itself gives its camera to the others "
        "(`reuse_known_calibration`); one whose own self-calibration failed before that is run "
        f"again with it. Plot: "
        f"`{report.get('plot', '')}`.", "",
        f"**Bar (median ≤ {BAR_MEDIAN_M} m with {BAR_K} journeys): {report['bar']['verdict']}.**",
        "",
        "### Journeys", "", table_journeys(runs), "",
        "### Map error vs number of journeys", "",
        "The first k journeys fused with `app.fusion.fuse_map` (service settings). Each map sign "
        "is scored against the true sign most of its members come from; abs: ENU 3-D distance, "
        "horiz: east/north only. Duplicates: map signs beyond the first of one true sign; mixed: "
        "map signs with members from several true signs. Single-journey: each journey's own "
        "signs, mean of the journeys' means and median of all. Reversed order: the same "
        "journeys fused with the processing order reversed.", "",
        table_fusion(report["rows"]), ""])


def _write(report: dict, runs: list[JourneyRun], md_path: Path, json_path: Path) -> None:
    md_path.write_text(render_fusion(report, runs))
    json_path.write_text(json.dumps(finite(report), indent=1, allow_nan=False))


def run_fusion(*, quick: bool, out_dir: Path, cache_dir: Path) -> tuple[Path, Path]:
    """Run the study; write ``<date>-fusion[-quick].md`` / ``.json`` / ``.png`` into ``out_dir``.
    Returns the markdown and JSON paths."""
    from app.settings import Settings

    settings = Settings()
    base, fusion_config = settings.pipeline, settings.fusion
    specs = fusion_journeys(quick)
    out_dir.mkdir(parents=True, exist_ok=True)
    cache_dir.mkdir(parents=True, exist_ok=True)
    stem = dt.date.today().isoformat() + "-fusion" + ("-quick" if quick else "")
    md_path, json_path, png = (out_dir / f"{stem}.{ext}" for ext in ("md", "json", "png"))
    report = {"meta": {**run_meta(quick, base), "fusion_config": fusion_config.model_dump()},
              "bar": {"median_m": BAR_MEDIAN_M, "k": BAR_K}, "n_signs_truth": None,
              "journeys": {}, "rows": []}
    t0 = time.perf_counter()
    runs: list[JourneyRun] = []
    known: KnownCamera | None = None

    def update(complete: bool) -> None:
        report["journeys"] = {r.name: r.record for r in runs}
        report["n_signs_truth"] = len(runs[0].truth["signs"])
        report["rows"] = fusion_rows(runs, fusion_config, metrics.RECALL_MIN_FRAMES)
        report["bar"]["verdict"] = bar_verdict(report["rows"])
        report["meta"]["wall_s"] = round(time.perf_counter() - t0, 1)
        report["meta"]["complete"] = complete
        # Written after every run: an interrupted run still leaves its results.
        _write(report, runs, md_path, json_path)

    for spec in specs:
        runs.append(run_one(spec, cache_dir, base, known))
        known = known or self_calibration(runs[-1])
        update(False)
    for i, spec in enumerate(specs):
        if known is not None and failed_to_calibrate(runs[i]):
            runs[i] = rerun_with(spec, runs[i], cache_dir, base, known)
            update(False)
    plots.plot_fusion(report["rows"], BAR_MEDIAN_M, BAR_K, png)
    report["plot"] = png.name
    update(True)
    return md_path, json_path
