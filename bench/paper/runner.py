"""``signmap bench``: every journey of the suite, every variant, one report (markdown + JSON + plots).
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from app.pipeline.colmap.sfm import colmap_pool
from app.pipeline.config import PipelineConfig
from app.pipeline.types import CameraModel
from bench.paper import plots, tables
from bench.paper.metrics import evaluate_result, mappable_signs
from bench.paper.run_pipeline import RunOutput, RunTask, run_isolated
from bench.paper.suite import JourneySpec, ensure_journey, full_suite, quick_suite

BENCH_DIR = Path(__file__).resolve().parents[1]
OTHER_ALIGNMENT = {"short": "full", "full": "short", "local": "full"}
NAIVE_ALIGNMENT = "one similarity"


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _task(spec: JourneySpec, variant: str, bundle: Path, workdir: Path, base: PipelineConfig,
          truth_camera: CameraModel, calibrations: dict[str, CameraModel]) -> RunTask | str:
    """The run of ``variant``, or the reason it cannot run."""
    label = f"{spec.name}/{variant}"
    config = base.model_dump()
    if variant.endswith("_alt"):
        config["alignment"] = OTHER_ALIGNMENT[base.alignment]
    if variant == "ours":
        known = calibrations.get(spec.known_from) if spec.known_from else None
        if spec.known_from and known is None:
            return f"{spec.known_from} produced no calibration to supply"
        return RunTask(label, bundle, workdir, config, known_camera=known)
    if variant == "ours_alt":
        if spec.name not in calibrations:
            return "ours produced no calibration"
        return RunTask(label, bundle, workdir, {**config, "reuse_known_calibration": True},
                       known_camera=calibrations[spec.name])
    if variant in ("gt", "gt_alt"):
        return RunTask(label, bundle, workdir, {**config, "reuse_known_calibration": True},
                       known_camera=truth_camera)
    if variant == "gt_half":  # the first half: peak memory against the journey's length
        return RunTask(label, bundle, workdir, {**config, "reuse_known_calibration": True},
                       known_camera=truth_camera, max_frames=spec.synth.n_frames // 2)
    if variant == "naive":
        return RunTask(label, bundle, workdir, config, naive=True,
                       max_frames=spec.naive_max_frames)
    raise ValueError(f"unknown variant {variant}")


def run_summary(out: RunOutput, truth: dict, task: RunTask) -> dict:
    """JSON-ready record of one run."""
    peak = dict(out.peak_rss_mb)
    if peak:  # the child's own peak plus its largest child's: an upper bound of the run's peak
        peak["total_mb"] = peak["self_mb"] + peak["children_mb"]
    record = {"status": "ok" if out.result is not None else "failed", "error": out.error,
              "alignment": NAIVE_ALIGNMENT if task.naive else task.config["alignment"],
              "n_frames": out.n_frames, "wall_s": round(out.wall_s, 2), "fps": out.fps,
              "cpu_s": round(out.cpu_s, 1),
              "timings_s": out.timings_s, "peak_rss_mb": peak}
    if out.result is not None:
        record["stage_parts_s"] = out.result.stage_parts_s
        record["windows"] = [dataclasses.asdict(w) for w in out.result.window_times]
        record.update(evaluate_result(out.result, truth))
    return record


def run_journey(spec: JourneySpec, cache_dir: Path, base: PipelineConfig,
                calibrations: dict[str, CameraModel]) -> tuple[dict, dict[str, RunOutput], dict]:
    """Render (or reuse) the journey, run its variants. Returns (record, outputs, truth); adds the
    ``ours`` calibration to ``calibrations``."""
    t0 = time.perf_counter()
    bundle, truth = ensure_journey(spec, cache_dir)
    log(f"{spec.name}: bundle ready in {time.perf_counter() - t0:.0f} s")
    cam = truth["camera"]
    truth_camera = CameraModel.from_params(cam["width"], cam["height"], cam)
    record = {"description": spec.description, "n_frames": spec.synth.n_frames,
              "n_signs_truth": len(truth["signs"]),
              "n_signs_mappable": mappable_signs(truth, base.min_track_frames),
              "naive_max_frames": spec.naive_max_frames, "known_from": spec.known_from,
              "runs": {}}
    outputs: dict[str, RunOutput] = {}
    for variant in spec.variants:
        with tempfile.TemporaryDirectory(prefix=f"bench-{spec.name}-") as tmp:
            task = _task(spec, variant, bundle, Path(tmp), base, truth_camera, calibrations)
            if isinstance(task, str):
                record["runs"][variant] = {"status": "skipped", "error": task}
                continue
            log(f"{task.label}: running")
            out = run_isolated(task)
        outputs[variant] = out
        record["runs"][variant] = run_summary(out, truth, task)
        log(f"{task.label}: {record['runs'][variant]['status']} in {out.wall_s:.0f} s"
            + (f" ({out.error})" if out.error else ""))
        if variant == "ours" and out.result is not None:
            calibrations[spec.name] = out.result.calibration.camera
    if spec.sift_frames:
        record["plain_sift"] = _plain_sift(bundle, spec.sift_frames)
        log(f"{spec.name}: plain SIFT extraction at {record['plain_sift']['fps']:.2f} frames/s")
    return record, outputs, truth


def _plain_sift(bundle: Path, frames: int) -> dict:
    """Plain SIFT extraction's frames/s over the bundle's first ``frames``, in a child process
    of its own like the runs it is compared with."""
    from bench.paper.naive import plain_sift_s

    with tempfile.TemporaryDirectory(prefix="bench-sift-") as tmp, colmap_pool(1) as pool:
        n, wall_s = pool.submit(plain_sift_s, bundle, Path(tmp), frames).result()
    return {"frames": n, "wall_s": round(wall_s, 2), "fps": n / wall_s}


def compare(ours: dict, naive: dict) -> dict:
    """Speed ratio and accuracy difference (ours minus naive), the latter on the signs both
    placed so that a prefix-limited naive run is compared like for like."""
    common = sorted(set(ours.get("sign_errors", {})) & set(naive.get("sign_errors", {})))

    def mean(run: dict, key: str) -> float:
        vals = [run["sign_errors"][t][key] for t in common]
        return float(np.nanmean(vals)) if vals else float("nan")
    return {"fps_ours": ours["fps"], "fps_naive": naive["fps"],
            "speed_ratio": ours["fps"] / naive["fps"] if naive.get("fps") else float("nan"),
            "n_common_signs": len(common),
            "abs_mean_m_ours": mean(ours, "abs_m"), "abs_mean_m_naive": mean(naive, "abs_m"),
            "rel_mean_m_ours": mean(ours, "rel_m"), "rel_mean_m_naive": mean(naive, "rel_m")}


def finite(value):
    """``value`` with NaN/inf floats as None and numpy scalars as Python numbers: strict JSON."""
    if isinstance(value, dict):
        return {str(k): finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def run_meta(quick: bool, base: PipelineConfig) -> dict:
    import pycolmap
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=BENCH_DIR,
                                capture_output=True, text=True, check=True).stdout.strip()
        dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                                    cwd=BENCH_DIR, capture_output=True, text=True).stdout.strip())
    except (OSError, subprocess.CalledProcessError):
        commit, dirty = None, None
    return {"date": dt.date.today().isoformat(), "quick": quick, "commit": commit,
            "uncommitted_changes": dirty, "load_avg_at_start": os.getloadavg()[0],
            "cpus": os.cpu_count(), "python": platform.python_version(),
            "pycolmap": pycolmap.__version__, "pipeline_config": base.model_dump()}


def run_bench(*, quick: bool, out_dir: Path, cache_dir: Path,
              suite: list[JourneySpec] | None = None) -> tuple[Path, Path]:
    """Run the suite; write ``<date>[-quick].md`` / ``.json`` and one PNG per journey into
    ``out_dir``. Returns the markdown and JSON paths."""
    from app.settings import Settings

    base = Settings().pipeline
    suite = suite if suite is not None else (quick_suite() if quick else full_suite())
    out_dir.mkdir(parents=True, exist_ok=True)
    cache_dir.mkdir(parents=True, exist_ok=True)
    stem = dt.date.today().isoformat() + ("-quick" if quick else "")
    report = {"meta": run_meta(quick, base), "journeys": {}, "comparisons": {}}
    md_path, json_path = out_dir / f"{stem}.md", out_dir / f"{stem}.json"
    t0 = time.perf_counter()
    calibrations: dict[str, CameraModel] = {}
    for i, spec in enumerate(suite):
        record, outputs, truth = run_journey(spec, cache_dir, base, calibrations)
        png = out_dir / f"{stem}-{spec.name}.png"
        plots.plot_journey(spec.name, truth, {v: o.result for v, o in outputs.items()}, png)
        record["plot"] = png.name
        report["journeys"][spec.name] = record
        runs = record["runs"]
        if runs.get("ours", {}).get("status") == "ok" and runs.get("naive", {}).get("status") == "ok":
            report["comparisons"][spec.name] = compare(runs["ours"], runs["naive"])
        # Written after every journey: an interrupted full run still leaves its results.
        report["meta"]["wall_s"] = round(time.perf_counter() - t0, 1)
        report["meta"]["complete"] = i == len(suite) - 1
        md_path.write_text(tables.render_report(report))
        json_path.write_text(json.dumps(finite(report), indent=1, allow_nan=False))
    return md_path, json_path
