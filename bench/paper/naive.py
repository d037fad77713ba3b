"""The naive baseline: what a user gets by hand with COLMAP over every frame.

pycolmap ``extract_features`` + ``match_sequential`` + ``incremental_mapping`` with default options
(SIMPLE_RADIAL camera: one focal length, one distortion coefficient). The one choice made for the
user is ``CameraMode.SINGLE``: COLMAP's default gives every PNG frame its own camera, which leaves no
single camera to triangulate with. The largest model is aligned to GPS with one Umeyama similarity
over all its frames and the signs are triangulated with the pipeline's own triangulation.

Runs pycolmap in the calling process: call it in a child process (a fatal COLMAP error aborts it).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from app.pipeline.colmap.sfm import camera_model, registered_poses
from app.pipeline.config import PipelineConfig
from app.pipeline.geometry import geodesy
from app.pipeline.geometry.similarity import umeyama
from app.pipeline.geometry.triangulation import TriangulationError, triangulate, undistort_pixels
from app.pipeline.steps.sign_tracks import group_detections
from app.pipeline.types import (Calibration, CameraModel, Journey, JourneyResult, PipelineError,
                                ProgressFn, RejectedSign, Sign, SignObservation, no_progress)


def _poses(rec, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(K,) journey frame indices of the registered images and their (K,4,4) T_model_cam."""
    index = {n: i for i, n in enumerate(names)}
    registered, T_model_cam = registered_poses(rec, names)
    return np.array([index[n] for n in registered], dtype=int), T_model_cam


def naive_journey(journey: Journey, config: PipelineConfig, workdir: Path, *,
                  progress: ProgressFn = no_progress) -> JourneyResult:
    """COLMAP over all of ``journey``'s frames, then GPS alignment and triangulation."""
    import pycolmap

    pycolmap.logging.minloglevel = 2
    workdir.mkdir(parents=True, exist_ok=True)
    names = [f.path.name for f in journey.frames]
    image_dir = journey.frames[0].path.parent
    database = workdir / "naive.db"
    timings_s: dict[str, float] = {}
    t0 = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal t0
        timings_s[stage] = round(time.perf_counter() - t0, 3)
        progress(stage, 0.0, f"{timings_s[stage]:.1f} s")
        t0 = time.perf_counter()

    pycolmap.extract_features(database, image_dir, image_names=names,
                              camera_mode=pycolmap.CameraMode.SINGLE, device=pycolmap.Device.cpu)
    lap("extract")
    pycolmap.match_sequential(database, device=pycolmap.Device.cpu)
    lap("match")
    models = pycolmap.incremental_mapping(database, image_dir, workdir / "sparse")
    lap("map")
    if not models:
        raise PipelineError("naive", "COLMAP reconstructed no model")
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    camera = camera_model(next(iter(rec.cameras.values())))
    frame_idx, T_model_cam = _poses(rec, names)

    origin = geodesy.frame_at(journey.lat_deg[0], journey.lon_deg[0],
                              journey.alt_m[0] if journey.has_altitude else None,
                              config.metric_frame)
    xyz_gps = origin.to_local(journey.lat_deg, journey.lon_deg,
                              journey.alt_m if journey.has_altitude else None)
    sim = umeyama(T_model_cam[:, :3, 3], xyz_gps[frame_idx])
    T_world_cam = sim.apply_poses(T_model_cam)
    lap("align")

    signs, rejected = _triangulate(journey, frame_idx, T_world_cam, camera, origin, config)
    lap("triangulate")
    calib = Calibration(camera, "naive", stage1=camera, n_images=len(names),
                        n_registered=len(frame_idx),
                        reprojection_error_px=float(rec.compute_mean_reprojection_error()))
    return JourneyResult(calib, signs, rejected, timings_s,
                         trajectory_frame_ids=[journey.frames[i].frame_id for i in frame_idx],
                         trajectory_enu=T_world_cam[:, :3, 3], gps_enu=xyz_gps[frame_idx],
                         origin_lat_lon_alt=(origin.lat0_deg, origin.lon0_deg, origin.alt0_m))


def plain_sift_s(bundle: Path, workdir: Path, max_frames: int | None) -> tuple[int, float]:
    """(frames, wall seconds) of pycolmap's SIFT extraction with default options over the
    bundle's first ``max_frames`` frames (None: all), the bundle read before the clock starts:
    the speed yardstick ``signmap bench`` divides the pipeline's frames/s by (issue 68)."""
    import pycolmap

    from app.pipeline.bundle import read_bundle

    pycolmap.logging.minloglevel = 2
    journey = read_bundle(bundle, workdir / "bundle")
    names = [f.path.name for f in journey.frames][:max_frames]
    t0 = time.perf_counter()
    pycolmap.extract_features(workdir / "sift.db", journey.frames[0].path.parent,
                              image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              device=pycolmap.Device.cpu)
    return len(names), time.perf_counter() - t0


def _triangulate(journey: Journey, frame_idx: np.ndarray, T_world_cam: np.ndarray,
                 camera: CameraModel, origin: geodesy.LocalFrame, config: PipelineConfig):
    row = {int(i): k for k, i in enumerate(frame_idx)}
    signs: list[Sign] = []
    rejected: list[RejectedSign] = []
    for track in group_detections(journey.detections, journey.frame_ids):
        if len(track.frame_idx) < config.min_track_frames:
            continue
        keep = np.array([int(i) in row for i in track.frame_idx], dtype=bool)
        if keep.sum() < 2:
            rejected.append(RejectedSign(track.track_id, track.cls, "frames not registered"))
            continue
        poses = T_world_cam[[row[int(i)] for i in track.frame_idx[keep]]]
        try:
            point = triangulate(poses, undistort_pixels(camera, track.px[keep]), camera.K,
                                min_ray_angle_deg=config.min_ray_angle_deg,
                                max_rms_px=config.max_reprojection_rms_px)
        except TriangulationError as exc:
            rejected.append(RejectedSign(track.track_id, track.cls, exc.reason))
            continue
        if point.std_m > config.max_sign_std_m:
            rejected.append(RejectedSign(track.track_id, track.cls,
                                         f"uncertainty {point.std_m:.2f} m"))
            continue
        lat, lon, alt = origin.to_geodetic(point.xyz_world[None, :])
        frame_ids = [journey.frames[i].frame_id for i in track.frame_idx[keep]]
        signs.append(Sign(track.track_id, track.cls, point.xyz_world, float(lat[0]),
                          float(lon[0]), float(alt[0]) if journey.has_altitude else None,
                          point.std_m, point.rms_px,
                          [SignObservation(f, tuple(float(v) for v in p))
                           for f, p in zip(frame_ids, point.p_cam)]))
    return signs, rejected
