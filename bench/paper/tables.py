"""Markdown tables of a bench report (the dict ``bench.paper.runner.run_bench`` writes as JSON).

One function per table, each ``report -> markdown``; ``REPORT_TABLES`` is the order of the report.
A later per-journey table is one more function appended there (multi-journey fusion has its own
report: ``bench.paper.fusion``).
"""

from __future__ import annotations

import math
from typing import Callable

from bench.paper.metrics import CALIB_KEYS

# Averages over KITTI from the paper (Chawla et al. 2020), for scale.
PAPER_CALIB_PCT = {"fx": 1.60, "fy": 0.30, "cx": 0.74, "cy": 0.94, "k1": -9.17, "k2": -26.23}
PAPER_SIGNS = {"rel_mean_m": 0.241, "abs_mean_m": 1.295}  # Table IV, short trajectories, w/ LC
PAPER_ATE = {"ate_full_m": 35.135, "ate5_mean_m": 0.012, "ate5_std_m": 0.031}  # Colmap calib, LC

CALIBRATION = {"ours": "self", "ours_alt": "self", "gt": "ground truth",
               "gt_alt": "ground truth", "gt_half": "ground truth",
               "naive": "naive (SIMPLE_RADIAL)"}
# Runs on a prefix of the journey, for their cost only: their signs and poses are not compared.
PREFIX_RUNS = ("gt_half",)


# What each table's numbers mean, printed under its heading.
NOTE_ATE = (
    "ATE full and ATE-5: after a least-squares similarity onto the truth (over all posed frames / "
    "every 5 consecutive frames); as georeferenced: the pipeline's own GPS alignment, no further "
    "fit. Ours poses only the frames near signs.")
NOTE_SIGNS = (
    "Relative: camera-frame position error averaged over the observing frames; absolute: ENU "
    "distance to the true plate centre. Mappable: true signs detected in at least "
    "`min_track_frames` frames.")
NOTE_SPEED = (
    "Total: bundle extraction and pipeline, wall clock, one process per run. CPU s: user + system "
    "time of the run and its children (less sensitive to other load on the machine). Peak MB: the "
    "run's own peak RSS plus its largest child's (COLMAP runs in a child).")
NOTE_BASELINES = (
    "Errors over the signs both placed. The naive run may cover only the journey's first frames "
    "(see the speed table); its cost grows faster than linearly, so the ratio understates the gap "
    "on the whole journey.")


def fmt(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, int):
        return str(value)
    return f"{value:.{digits}f}"


def md_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def section(title: str, header: list[str], rows: list[list[str]], note: str = "") -> str:
    """A table under its heading, with the note that says how to read it."""
    return f"### {title}\n\n" + (f"{note}\n\n" if note else "") + md_table(header, rows)


def _runs(report: dict, variants=None):
    """(journey name, journey record, variant, run) of the runs that finished."""
    for name, journey in report["journeys"].items():
        for variant, run in journey["runs"].items():
            if run.get("status") == "ok" and (variants is None or variant in variants):
                yield name, journey, variant, run


def _calibration_label(journey: dict, variant: str, run: dict) -> str:
    source = run["calibration"]["source"]
    if variant in ("ours", "ours_alt") and journey.get("known_from") and source == "supplied":
        return f"supplied by {journey['known_from']}"
    return CALIBRATION[variant]


def _frames(journey: dict, variant: str, run: dict) -> str:
    if variant in PREFIX_RUNS or variant == "naive" and journey.get("naive_max_frames"):
        return f"{run['n_frames']} (first of {journey['n_frames']})"
    return str(run["n_frames"])


def table_calibration(report: dict) -> str:
    rows = []
    for name, journey, variant, run in _runs(report, ("ours", "naive")):
        cal = run["calibration"]
        label = _calibration_label(journey, variant, run)
        if cal["stage1_errors_pct"] and variant == "ours":
            rows.append([name, label, "stage 1"]
                        + [fmt(cal["stage1_errors_pct"][k], 2) for k in CALIB_KEYS])
        stage = "stage 2" if variant == "ours" and cal["source"] == "self" else "final"
        rows.append([name, label, stage] + [fmt(cal["errors_pct"][k], 2) for k in CALIB_KEYS])
    rows.append(["paper (KITTI avg)", "Colmap", "final"]
                + [fmt(PAPER_CALIB_PCT[k], 2) for k in CALIB_KEYS])
    header = ["journey", "calibration", "stage"] + [f"δ{k} %" for k in CALIB_KEYS]
    return section("Table I: self-calibration errors (% of the true value)", header, rows)


def table_ego_motion(report: dict) -> str:
    rows = []
    for name, journey, variant, run in _runs(report, ("gt", "ours", "naive")):
        ate = run["ate"]
        rows.append([name, _calibration_label(journey, variant, run), _frames(journey, variant, run),
                     fmt(ate["n_posed"]), fmt(ate["ate_full_m"]), fmt(ate["ate5_mean_m"], 4),
                     fmt(ate["ate5_std_m"], 4), fmt(ate["ate_gps_m"])])
    rows.append(["paper (KITTI avg)", "Colmap, ORB-SLAM w/ LC", "", "", fmt(PAPER_ATE["ate_full_m"]),
                 fmt(PAPER_ATE["ate5_mean_m"], 4), fmt(PAPER_ATE["ate5_std_m"], 4), ""])
    header = ["journey", "calibration", "frames", "posed", "ATE full (m)", "ATE-5 mean (m)",
              "ATE-5 std (m)", "ATE as georeferenced (m)"]
    return section("Table II: ego-motion ATE (camera centres vs truth)", header, rows, NOTE_ATE)


def table_signs(report: dict) -> str:
    rows = []
    for name, journey, variant, run in _runs(report, set(CALIBRATION) - set(PREFIX_RUNS)):
        s = run["signs"]
        rows.append([name, _calibration_label(journey, variant, run), run["alignment"],
                     f"{s['n_signs']} / {journey['n_signs_mappable']}", fmt(s["rel_mean_m"]),
                     fmt(s["rel_median_m"]), fmt(s["abs_mean_m"]), fmt(s["abs_median_m"])])
    rows.append(["paper (KITTI avg)", "Colmap", "short", "42 / 73", fmt(PAPER_SIGNS["rel_mean_m"]),
                 "", fmt(PAPER_SIGNS["abs_mean_m"]), ""])
    header = ["journey", "calibration", "alignment", "signs / mappable", "rel mean (m)",
              "rel median (m)", "abs mean (m)", "abs median (m)"]
    return section("Tables III/IV: sign positioning errors", header, rows, NOTE_SIGNS)


def table_speed(report: dict) -> str:
    rows = []
    for name, journey, variant, run in _runs(report):
        stages = ", ".join(f"{k} {v:.1f}" for k, v in run["timings_s"].items())
        rows.append([name, variant, _frames(journey, variant, run), stages, fmt(run["wall_s"], 1),
                     fmt(run["fps"], 2), fmt(run.get("cpu_s"), 0),
                     fmt(run["peak_rss_mb"].get("total_mb"), 0)])
    header = ["journey", "variant", "frames", "stages (s)", "total (s)", "frames/s", "CPU s",
              "peak MB"]
    return section("Speed and memory", header, rows, NOTE_SPEED)


def table_baselines(report: dict) -> str:
    rows = []
    for name, c in report.get("comparisons", {}).items():
        rows.append([name, fmt(c["fps_ours"], 2), fmt(c["fps_naive"], 2),
                     f"{fmt(c['speed_ratio'], 1)}×", fmt(c["n_common_signs"]),
                     f"{fmt(c['abs_mean_m_ours'])} / {fmt(c['abs_mean_m_naive'])}",
                     f"{fmt(c['rel_mean_m_ours'])} / {fmt(c['rel_mean_m_naive'])}"])
    if not rows:
        return "### Ours vs naive COLMAP\n\nNo journey had both runs finish."
    header = ["journey", "ours frames/s", "naive frames/s", "speed ours/naive", "common signs",
              "abs mean ours / naive (m)", "rel mean ours / naive (m)"]
    return section("Ours vs naive COLMAP", header, rows, NOTE_BASELINES)


def table_failures(report: dict) -> str:
    rows = [[name, variant, run.get("status"), (run.get("error") or "").replace("|", "/")]
            for name, journey in report["journeys"].items()
            for variant, run in journey["runs"].items() if run.get("status") != "ok"]
    if not rows:
        return "### Failed runs\n\nNone."
    return section("Failed runs", ["journey", "variant", "status", "reason"], rows)


# Where a run's time goes (issue 68): each stage's parts, each COLMAP window, and the speed as a
# ratio to plain SIFT extraction of the same frames in the same run (the machine's noise divides
# out of a ratio, not out of seconds).
NOTE_PARTS = (
    "Seconds per part of the COLMAP stages (`JourneyResult.stage_parts_s`). extract / match: "
    "SIFT; klt / import / verify: KLT tracks (tracked in a thread while calibration runs), "
    "imported into COLMAP, verified; wait: the stage waiting for those tracks; map: all windows, "
    "mapped side by side (bundle adjustment included); refine: of map, self-calibration's stage 2; "
    "idle core-s: the core-seconds mapping processes had no window left (wall x processes minus "
    "the windows' own seconds).")
NOTE_WINDOWS = "Each COLMAP window: the frames it spans, images asked for and registered, seconds."
NOTE_RATIO = (
    "Plain SIFT: pycolmap's `extract_features` with its default options over the journey's first "
    "frames, timed in the same run, its own child process. Ratio: the run's frames/s end to end "
    "(bundle read included) over plain SIFT's; issue 68's bar is 2.5.")


def table_time_parts(report: dict) -> str:
    rows = []
    for name, _, variant, run in _runs(report):
        for stage, parts in run.get("stage_parts_s", {}).items():
            shown = ", ".join(f"{'idle core-s' if k == 'map_idle_core_s' else k} {v:.1f}"
                              for k, v in parts.items())
            rows.append([name, variant, stage, fmt(run["timings_s"].get(stage), 1), shown])
    if not rows:
        return "### Where the time goes\n\nNo run mapped with COLMAP."
    return section("Where the time goes", ["journey", "variant", "stage", "stage (s)", "parts (s)"],
                   rows, NOTE_PARTS)


def table_windows(report: dict) -> str:
    rows = [[name, variant, w["stage"], w["frames"], f"{w['n_registered']} / {w['n_images']}",
             fmt(w["mapping_s"], 1), fmt(w["refine_s"], 1) if w["refine_s"] else ""]
            for name, _, variant, run in _runs(report) for w in run.get("windows", [])]
    if not rows:
        return "### COLMAP windows\n\nNone."
    return section("COLMAP windows", ["journey", "variant", "stage", "frames",
                                      "registered / images", "mapping (s)", "of which refine (s)"],
                   rows, NOTE_WINDOWS)


def table_sift_ratio(report: dict) -> str:
    rows = []
    for name, journey, variant, run in _runs(report, ("ours", "gt")):
        sift = journey.get("plain_sift")
        if sift:
            rows.append([name, variant, fmt(run["fps"], 2),
                         f"{fmt(sift['fps'], 2)} ({sift['frames']} frames)",
                         f"{fmt(run['fps'] / sift['fps'], 2)}×"])
    if not rows:
        return "### Ratio to plain SIFT extraction\n\nNo journey timed plain SIFT."
    return section("Ratio to plain SIFT extraction",
                   ["journey", "variant", "frames/s", "plain SIFT frames/s", "ratio"], rows,
                   NOTE_RATIO)


NOTE_MEMORY = (
    "The calibrated camera's run on the whole journey and on its first half (issue 68: memory "
    "must not grow with the length). Peak MB as in the speed table (the pipeline's process, whose "
    "peak includes reading the bundle, plus its largest COLMAP child); per 1,000 frames: that "
    "peak over the frames, x 1000.")


def table_memory(report: dict) -> str:
    rows = []
    for name, journey, variant, run in _runs(report, ("gt_half", "gt")):
        if "gt_half" not in journey["runs"]:
            continue
        peak = run["peak_rss_mb"]
        total = peak.get("total_mb")
        rows.append([name, _frames(journey, variant, run), fmt(total, 0),
                     fmt(peak.get("self_mb"), 0), fmt(peak.get("children_mb"), 0),
                     fmt(total * 1000 / run["n_frames"] if total else None, 0)])
    if not rows:
        return "### Peak memory against length\n\nNo journey ran on its first half."
    return section("Peak memory against length",
                   ["journey", "frames", "peak MB", "pipeline MB", "COLMAP child MB",
                    "peak MB per 1,000 frames"], rows, NOTE_MEMORY)


REPORT_TABLES: list[Callable[[dict], str]] = [
    table_calibration, table_ego_motion, table_signs, table_speed, table_time_parts,
    table_windows, table_sift_ratio, table_memory, table_baselines, table_failures]


def render_report(report: dict) -> str:
    meta = report["meta"]
    dirty = " with uncommitted changes" if meta.get("uncommitted_changes") else ""
    partial = "" if meta.get("complete", True) else " (interrupted: journeys so far)"
    head = [f"# Signmap benchmark {meta['date']}" + (" (quick)" if meta["quick"] else "")
            + partial, "",
            f"Commit {meta.get('commit')}{dirty}, {meta['cpus']} CPUs (load average "
            f"{fmt(meta.get('load_avg_at_start'), 1)} at the start), pycolmap {meta['pycolmap']}, "
            f"whole run {fmt(meta.get('wall_s'), 0)} s. Synthetic journeys "
            "(`bench/paper/suite.py`), KITTI-like camera (fx 959.2, k1 -0.369, k2 0.158).", ""]
    for name, j in report["journeys"].items():
        head.append(f"- **{name}**: {j['description']}; {j['n_signs_truth']} signs "
                    f"({j['n_signs_mappable']} mappable); plot `{j.get('plot', '')}`")
    return "\n".join(head) + "\n\n" + "\n\n".join(t(report) for t in REPORT_TABLES) + "\n"
