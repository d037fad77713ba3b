"""Run one variant (ours / ground-truth camera / naive) on one journey bundle, in a fresh child.

A fresh spawned process per run isolates a COLMAP abort and makes its peak memory its own.
"""

from __future__ import annotations

import concurrent.futures as cf
import pickle
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from app.pipeline.bundle import read_bundle
from app.pipeline.colmap.sfm import colmap_pool
from app.pipeline.config import PipelineConfig
from app.pipeline.types import CameraModel, Journey, JourneyResult, PipelineError, StageReport

if TYPE_CHECKING:
    from app.pipeline.run import Reconstruction


@dataclass(frozen=True)
class RunTask:
    label: str  # for progress lines, e.g. "loop-300/ours"
    bundle: Path
    workdir: Path
    config: dict  # PipelineConfig.model_dump(): rebuilt in the child, with its defaults
    naive: bool = False
    known_camera: CameraModel | None = None  # with config.reuse_known_calibration: skip calibrating
    max_frames: int | None = None  # run on this many first frames only
    # Drop the detections: with no sign track process_journey returns right after calibrating,
    # so a calibration study does not pay for ego-motion and triangulation.
    calibrate_only: bool = False
    # Pickle what the stages up to ego-motion gave to this file (``keep``).
    keep_reconstruction: Path | None = None


@dataclass
class RunOutput:
    label: str
    result: JourneyResult | None
    error: str | None
    n_frames: int
    wall_s: float  # bundle reading + pipeline
    timings_s: dict[str, float]  # per stage, with "read" (bundle extraction) first
    peak_rss_mb: dict[str, float]
    cpu_s: float = float("nan")  # CPU time of the run and its children
    # (frame_id, track_id, x1, y1, x2, y2) of every detection as the pipeline tracked it (track ids
    # ``auto-k`` where the bundle had none): lets a bench say which track a true sign became.
    detections: tuple[tuple[str, str, float, float, float, float], ...] = ()
    # The stage reports of a failed run (a run that succeeded has them in ``result.report``).
    failure_report: tuple[StageReport, ...] = ()

    @property
    def fps(self) -> float:
        return self.n_frames / self.wall_s if self.wall_s > 0 else float("nan")


def prefix(journey: Journey, n_frames: int) -> Journey:
    """The journey's first ``n_frames`` frames, their GPS and detections."""
    ids = set(journey.frame_ids[:n_frames])
    return replace(journey, frames=journey.frames[:n_frames], lat_deg=journey.lat_deg[:n_frames],
                   lon_deg=journey.lon_deg[:n_frames], alt_m=journey.alt_m[:n_frames],
                   detections=[d for d in journey.detections if d.frame_id in ids])


def _progress(label: str):
    t0 = time.perf_counter()

    def progress(stage: str, fraction: float, message: str = "") -> None:
        print(f"  [{time.perf_counter() - t0:7.1f}s] {label}: {stage} {message}",
              file=sys.stderr, flush=True)
    return progress


def _run_in_child(task: RunTask) -> RunOutput:
    from bench.paper.metrics import cpu_seconds, peak_rss_mb
    from bench.paper.naive import naive_journey

    t0 = time.perf_counter()
    journey = read_bundle(task.bundle, task.workdir / "bundle")
    if task.max_frames is not None:
        journey = prefix(journey, task.max_frames)
    if task.calibrate_only:
        journey = replace(journey, detections=[])
    read_s = time.perf_counter() - t0
    progress = _progress(task.label)
    config = PipelineConfig(**task.config)
    result, error, failure_report, failure = None, None, (), None
    try:
        if task.naive:
            result = naive_journey(journey, config, task.workdir / "naive", progress=progress)
        else:
            result = _process(task, journey, config, progress)
    except PipelineError as exc:
        error, failure_report, failure = str(exc), tuple(exc.report), exc
    wall_s = time.perf_counter() - t0
    timings = {"read": round(read_s, 3),
               **(result.timings_s if result else failure.timings_s if failure else {})}
    return RunOutput(task.label, result, error, len(journey.frames), wall_s, timings,
                     peak_rss_mb(), cpu_seconds(), detections_of(journey), failure_report)


def _process(task: RunTask, journey: Journey, config: PipelineConfig, progress) -> JourneyResult:
    """``process_journey``, keeping the reconstruction (or why there is none) when asked."""
    from app.pipeline.run import georeference, reconstruct

    path = task.keep_reconstruction
    try:
        recon = reconstruct(journey, config, task.workdir / "work",
                            known_camera=task.known_camera, progress=progress)
    except PipelineError as exc:
        if path is not None:
            keep(path, journey, config, None, str(exc))
        raise
    if path is not None:
        keep(path, journey, config, recon, None)
    return georeference(journey, recon, config, progress=progress)


def keep(path: Path, journey: Journey, config: PipelineConfig,
         recon: Reconstruction | None, error: str | None) -> None:
    """Pickle one journey's reconstruction (or the error that ended the run before it) with the
    journey and the configuration it ran with, for ``bench.corpus.replay``; written whole or not
    at all."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with tmp.open("wb") as f:
        pickle.dump({"config": config.model_dump(), "journey": journey, "recon": recon,
                     "error": error}, f, protocol=pickle.HIGHEST_PROTOCOL)
    tmp.replace(path)


def detections_of(journey: Journey) -> tuple[tuple[str, str, float, float, float, float], ...]:
    return tuple((d.frame_id, d.track_id, d.x1, d.y1, d.x2, d.y2) for d in journey.detections)


def run_isolated(task: RunTask) -> RunOutput:
    """Run ``task`` in a fresh spawned process; a crash of that process becomes ``error``.
    The pipeline's own ``colmap_pool``, whose process dies with this one: a bench stopped with a
    signal left its naive COLMAP child running for minutes, and the next run's timings with it."""
    t0 = time.perf_counter()
    with colmap_pool(1) as pool:
        try:
            return pool.submit(_run_in_child, task).result()
        except cf.process.BrokenProcessPool:
            return RunOutput(task.label, None, "the process died (COLMAP abort?)", 0,
                             time.perf_counter() - t0, {}, {})
