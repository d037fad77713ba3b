"""One stage's COLMAP work (self-calibration or ego-motion) over chosen frames of a journey:
correspondences of those frames into the stage's own database (SIFT, or KLT feature tracks read
from the frames), then the stage's windows mapped from it (``sfm``).

Correspondences need no camera, so ``run.process_journey`` computes the ego-motion stage's KLT
tracks in a thread while COLMAP calibrates in its child process (OpenCV releases the GIL).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from app.pipeline.colmap import sfm
from app.pipeline.colmap.klt_features import KltOptions, klt_correspondences
from app.pipeline.colmap.presets import MappingOptions, ProcessOptions, SiftOptions
from app.pipeline.config import PipelineConfig
from app.pipeline.types import CameraModel, Journey, PipelineError

log = logging.getLogger(__name__)

READ_AHEAD = 8  # frames decoded ahead of KLT tracking (``read_ahead``)


@dataclass(frozen=True)
class Correspondences:
    """What a stage's database is made from: SIFT extracted by COLMAP from ``extract_names``, or
    ``imported`` KLT tracks (then ``extract_names`` is empty)."""

    extract_names: list[str]
    imported: sfm.ImportedFeatures | None = None
    tracked_s: float = 0.0  # wall seconds spent tracking the KLT features


class StageSfm:
    """COLMAP mapping for the stage named ``stage`` of the journey frames ``frame_idx`` (sorted
    indices; ``step``: the spacing of the regular ones, where KLT tracks may continue), with
    correspondences by ``front_end`` ("sift" or "klt").

    ``correspondences()`` computes them once (and may run early, in a thread); ``run`` writes
    them into a new database under ``workdir`` and maps the requested windows from it. Each stage
    runs once: a calibration candidate is a stage of its own."""

    def __init__(self, stage: str, workdir: Path, journey: Journey, frame_idx: np.ndarray, *,
                 step: int, front_end: str, config: PipelineConfig, verbose: bool,
                 feature_cache: Path | None = None):
        self.stage, self.workdir, self.journey, self.step = stage, workdir, journey, step
        self.feature_cache = feature_cache  # SIFT shared with other stages (``sfm.SfmJob``)
        self.front_end, self.config, self.verbose = front_end, config, verbose
        self.frame_idx = np.asarray(frame_idx, int)
        self._lock = threading.Lock()
        self._features: Correspondences | None = None
        self._tracked_by: int | None = None  # the thread that computed them

    def correspondences(self) -> Correspondences:
        """The stage's correspondences; computed once."""
        with self._lock:
            if self._features is None:
                self._features = self._compute()
                self._tracked_by = threading.get_ident()
            return self._features

    def _compute(self) -> Correspondences:
        frames = [self.journey.frames[i] for i in self.frame_idx]
        if self.front_end == "sift":
            return Correspondences([f.path.name for f in frames])
        t0 = time.perf_counter()
        imported = klt_correspondences(
            self.frame_idx, read_ahead([f.path for f in frames], self._gray),
            [f.path.name for f in self.journey.frames], None, step=self.step,
            overlap=self.config.klt_pair_overlap,
            options=KltOptions(max_corners=self.config.klt_max_corners))
        tracked_s = time.perf_counter() - t0
        log.info("KLT: %d frames tracked in %.1f s, %d tentative pairs", len(frames), tracked_s,
                 len(imported.matches))
        return Correspondences([], imported, tracked_s)

    def run(self, requests: list[sfm.WindowRequest], camera: CameraModel | None, *,
            on_mapped: Callable[[int, int], None] | None = None,
            on_prepared: Callable[[], None] | None = None) -> sfm.SfmRun:
        """Map ``requests``; ``camera`` None: intrinsics unknown (imported pairs are verified
        without them). ``on_prepared()`` is called when the features are matched,
        ``on_mapped(k, total)`` as windows finish. Its ``timings_s`` add ``klt`` (tracking, in
        whichever thread did it) and ``wait`` (for tracking begun in another thread)."""
        cfg = self.config
        t0 = time.perf_counter()
        features = self.correspondences()
        waited_s = time.perf_counter() - t0
        if self._tracked_by == threading.get_ident():
            waited_s -= features.tracked_s
        extract, imported = features.extract_names, features.imported
        if imported is not None:
            imported = replace(imported, camera=camera)
        job = sfm.SfmJob(
            image_dir=self.journey.frames[0].path.parent, workdir=self.workdir,
            extract_names=extract, windows=requests,
            sift=self._sift(),
            mapping=_mapping(cfg), process=_process(cfg),
            verbose=self.verbose, imported=imported, feature_cache=self.feature_cache,
            camera=camera)
        done = sfm.run_sfm(job, on_mapped=on_mapped, on_prepared=on_prepared)
        klt = {"klt": round(features.tracked_s, 3), "wait": round(max(0.0, waited_s), 3)}
        return replace(done, timings_s={**(klt if imported is not None else {}),
                                        **done.timings_s})

    def _sift(self) -> SiftOptions:
        cfg = self.config
        return SiftOptions(
            max_features=cfg.sift_max_features, max_image_size=cfg.sift_max_image_size,
            first_octave=(-1 if self.journey.image_width < cfg.sift_upsample_below_px
                          else cfg.sift_first_octave),
            overlap=cfg.match_overlap,
            # Ego-motion's SIFT by OpenCV: faster, as precise (docs/decisions/ego-opencv-sift.md).
            # Self-calibration keeps COLMAP's, whose calibrations were measured.
            extractor="opencv" if self.stage == "ego_motion" else "colmap")

    def _gray(self, path: Path) -> np.ndarray:
        return read_gray(path, self.stage)


def read_ahead(paths: list[Path], read: Callable[[Path], np.ndarray],
               ahead: int = READ_AHEAD) -> Iterator[np.ndarray]:
    """``read(path)`` of each of ``paths`` in order, decoded in a thread up to ``ahead`` frames
    before they are wanted: decoding was a third of KLT tracking's time, and OpenCV releases the
    GIL while it decodes. Holds at most ``ahead`` frames, whatever the journey's length."""
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending: deque = deque()
        for path in paths:
            pending.append(pool.submit(read, path))
            if len(pending) > ahead:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


# JPEG decodes at a half, quarter or eighth of the size for a fraction of the time: the reductions
# ``read_gray`` takes, and OpenCV's flag for each.
REDUCED_READ = {1: cv2.IMREAD_GRAYSCALE, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2,
                4: cv2.IMREAD_REDUCED_GRAYSCALE_4, 8: cv2.IMREAD_REDUCED_GRAYSCALE_8}


def read_gray(path: Path, stage: str, *, reduce: int = 1) -> np.ndarray:
    """The frame at ``path``, 8-bit grayscale, decoded at 1/``reduce`` of its size (1, 2, 4, 8);
    an unreadable frame fails ``stage``."""
    image = cv2.imread(str(path), REDUCED_READ[reduce])
    if image is None:  # the bundle reader decoded every frame already; this is disk trouble
        raise PipelineError(stage, f"frame {path.name} could not be read back")
    return image


def _mapping(cfg: PipelineConfig) -> MappingOptions:
    return MappingOptions(ba_max_refinements=cfg.ba_max_refinements,
                          ba_function_tolerance=cfg.ba_function_tolerance,
                          aspect_prior_sigma=cfg.calib_aspect_prior_sigma,
                          stage1_k2=cfg.calib_stage1_k2,
                          stage2_max_iterations=cfg.calib_stage2_max_iterations,
                          stage2_probe=cfg.calib_stage2_probe,
                          stage2_probe_points=cfg.calib_stage2_probe_points)


def _process(cfg: PipelineConfig) -> ProcessOptions:
    # Threads change COLMAP's results: verification writes pairs in the order they finish (and
    # that order feeds the mapper), and bundle adjustments sum in thread order. One calibration
    # window accepted at fx +0.14 % on one run was at +0.09 % on the next; a window of another
    # journey was refused on one run and accepted on another.
    return ProcessOptions(threads=1 if cfg.colmap_reproducible else cfg.colmap_threads,
                          map_workers=cfg.colmap_map_workers)
