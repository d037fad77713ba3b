"""Polishing a calibration candidate (``colmap.sfm._polished``) with real COLMAP: the window is
mapped again with a first stage 2's camera held, and stage 2 runs once more."""

from __future__ import annotations

import dataclasses

import numpy as np
import pycolmap
import pytest

from app.pipeline.bundle import read_bundle
from app.pipeline.colmap import sfm
from app.pipeline.colmap.stage import StageSfm, _mapping, _process
from app.pipeline.config import PipelineConfig
from app.pipeline.geometry.geodesy import frame_at
from app.pipeline.steps import plan
from app.pipeline.types import CameraModel

pytestmark = pytest.mark.slow


def test_a_window_held_at_a_camera_5_percent_long_polishes_back_to_the_lens(
        turn_journey_bundle, tmp_path):
    # What a first stage 2 stuck in a warped reconstruction hands over: every intrinsic right
    # but the focal length, 5 % long. Held, the mapping is not warped by free intrinsics, and
    # stage 2 on it finds the lens.
    bundle, truth = turn_journey_bundle
    journey = dataclasses.replace(read_bundle(bundle, tmp_path / "bundle"), detections=[])
    config = PipelineConfig(colmap_reproducible=True)
    origin = frame_at(journey.lat_deg[0], journey.lon_deg[0], journey.alt_m[0])
    xyz_gps = origin.to_local(journey.lat_deg, journey.lon_deg, journey.alt_m)
    window = plan.plan_journey(journey, xyz_gps, config, None).calib_windows[0]
    names = [journey.frames[i].path.name for i in window.frame_idx]
    true = CameraModel.from_params(journey.image_width, journey.image_height, truth["camera"])
    stage = StageSfm("calibrate", tmp_path / "sfm", journey, window.frame_idx,
                     step=int(np.min(np.diff(window.frame_idx))), front_end=config.calib_front_end,
                     config=config, xyz_gps=xyz_gps, verbose=False)
    request = sfm.WindowRequest(image_names=names, camera=true, calibrate=True)
    first = stage.run([request], None)[0]  # also writes the window's feature database
    assert not first.error
    long = dataclasses.replace(first, camera=true.replace(fx=1.05 * true.fx, fy=1.05 * true.fy),
                               reprojection_error_px=float("inf"))
    job = sfm.SfmJob(image_dir=journey.frames[0].path.parent, workdir=stage.workdir,
                     extract_names=[], windows=[request], mapping=_mapping(config),
                     process=_process(config))
    polished = sfm._polished(pycolmap, job, 0, request, long)
    assert polished.polish.endswith(f"kept (fx {1.05 * true.fx:.1f} before)"), polished.polish
    assert polished.camera.fx == pytest.approx(true.fx, rel=0.01)
    assert polished.camera.fy == pytest.approx(true.fy, rel=0.01)
    assert len(polished.image_names) >= len(first.image_names)
    assert polished.stage1_camera == first.stage1_camera

    # A polish that fits worse than what it started from is not kept.
    sharp = dataclasses.replace(long, reprojection_error_px=0.0)
    kept = sfm._polished(pycolmap, job, 0, request, sharp)
    assert kept.camera == sharp.camera and kept.polish.endswith("not kept"), kept.polish
