"""One stage's COLMAP work (self-calibration or ego-motion) over frame windows of a journey:
correspondences into the stage's own database (SIFT, or KLT tracks read from the frames), then
the windows mapped (``colmap_sfm``).

Correspondences need no camera, so ``run.process_journey`` computes the ego-motion stage's KLT
tracks in a thread while COLMAP calibrates in its child process (OpenCV releases the GIL).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from app.pipeline import colmap_sfm, ego_motion
from app.pipeline.config import PipelineConfig
from app.pipeline.track_features import KltOptions
from app.pipeline.types import CameraModel, Journey, PipelineError

log = logging.getLogger(__name__)


class StageSfm:
    """COLMAP mapping of the frame ``windows`` of ``journey``, every ``step``-th frame and the
    ``extra`` frames (``ego_motion.window_frames``), with correspondences by ``front_end`` ("sift"
    or "klt"). The first ``run`` puts the correspondences of all those frames into the stage's
    database under ``workdir``; later runs map more windows from it."""

    def __init__(self, workdir: Path, journey: Journey, windows: list[tuple[int, int]], step: int,
                 front_end: str, config: PipelineConfig, xyz_gps: np.ndarray, verbose: bool, *,
                 extra: np.ndarray = np.zeros(0, int), frames: np.ndarray | None = None):
        self.workdir, self.journey, self.step = workdir, journey, step
        self.front_end, self.config, self.verbose = front_end, config, verbose
        # ``frames``: the journey frames to map, given outright (self-calibration picks them by
        # distance travelled) instead of by windows and a step.
        self.frame_idx = (np.asarray(frames, int) if frames is not None
                          else ego_motion.mapped_frames(windows, step, extra))
        self.priors = {journey.frames[i].path.name: tuple(xyz_gps[i]) for i in self.frame_idx}
        self._lock = threading.Lock()
        self._features: tuple[list[str], colmap_sfm.ImportedFeatures | None] | None = None
        self._stored = False

    def correspondences(self) -> tuple[list[str], colmap_sfm.ImportedFeatures | None]:
        """(names for COLMAP to extract SIFT from, or KLT tracks to import); computed once."""
        with self._lock:
            if self._features is None:
                self._features = self._compute()
            return self._features

    def _compute(self) -> tuple[list[str], colmap_sfm.ImportedFeatures | None]:
        frames = [self.journey.frames[i] for i in self.frame_idx]
        if self.front_end == "sift":
            return [f.path.name for f in frames], None
        t0 = time.perf_counter()
        imported = ego_motion.tracked_features(
            self.frame_idx, (_gray(f.path) for f in frames),
            [f.path.name for f in self.journey.frames], None, step=self.step,
            overlap=self.config.klt_pair_overlap,
            options=KltOptions(max_corners=self.config.klt_max_corners))
        log.info("KLT: %d frames tracked in %.1f s, %d tentative pairs", len(frames),
                 time.perf_counter() - t0, len(imported.matches))
        return [], imported

    def run(self, requests: list[colmap_sfm.WindowRequest], camera: CameraModel | None, *,
            on_mapped: Callable[[int, int], None] | None = None
            ) -> list[colmap_sfm.WindowResult]:
        """Map ``requests``; ``camera`` None: intrinsics unknown (pairs verified uncalibrated).
        ``on_mapped(k, total)`` is called as windows finish."""
        cfg = self.config
        extract, imported = ([], None) if self._stored else self.correspondences()
        if imported is not None:
            imported = replace(imported, camera=camera)
        self._stored = True
        job = colmap_sfm.SfmJob(
            self.journey.frames[0].path.parent, self.workdir, self.journey.image_width,
            self.journey.image_height, extract, requests,
            colmap_sfm.FeatureOptions(
                max_features=cfg.sift_max_features, max_image_size=cfg.sift_max_image_size,
                first_octave=(-1 if self.journey.image_width < cfg.sift_upsample_below_px
                              else cfg.sift_first_octave),
                overlap=cfg.match_overlap,
                threads=cfg.colmap_threads, ba_max_refinements=cfg.ba_max_refinements,
                ba_function_tolerance=cfg.ba_function_tolerance,
                map_workers=cfg.colmap_map_workers,
                aspect_prior_sigma=cfg.calib_aspect_prior_sigma),
            self.verbose, prior_enu=self.priors,
            prior_std_m=(cfg.gps_sigma_m, cfg.gps_alt_sigma_m), imported=imported)
        return colmap_sfm.run_sfm(job, on_mapped=on_mapped)


def _gray(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:  # the bundle reader decoded every frame already; this is disk trouble
        raise PipelineError("ego_motion", f"frame {path.name} could not be read back")
    return image
