"""The journey pipeline end to end: one validated journey in, triangulated signs out.

Stages (each its own module): geodesy -> turns -> features (COLMAP) -> calibrate -> ego-motion ->
align (georeference) -> triangulate. Progress is reported after each stage with the overall
fraction done, weighted by the stages' typical cost.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from app.pipeline import calibration, colmap_sfm, ego_motion, geodesy, georeference, turns
from app.pipeline.config import PipelineConfig
from app.pipeline.sfm_stage import StageSfm
from app.pipeline.facing import facing_deg
from app.pipeline.triangulation import (TriangulationError, largest_std_m, triangulate,
                                        undistort_pixels)
from app.pipeline.types import (Calibration, CameraModel, Journey, JourneyResult, PipelineError,
                                ProgressFn, RejectedSign, Sign, SignObservation, no_progress)

log = logging.getLogger(__name__)

# Seconds per mapped image, measured on the 2-core machine (turn-70 and long-1000, 2026-11-23):
# how the progress fraction divides the journey between calibration and ego-motion.
CALIBRATE_S_PER_IMAGE = 0.65
EGO_MOTION_S_PER_IMAGE = 0.12
OTHER_STAGES = {"turns": 0.01, "align": 0.01, "triangulate": 0.03}


class _Clock:
    """Stage timings, and progress as the fraction of the journey's expected work done."""

    def __init__(self, progress: ProgressFn, weights: dict[str, float]):
        self.timings_s: dict[str, float] = {}
        self.progress = progress
        self.weights = weights
        self.done = 0.0

    @contextmanager
    def stage(self, name: str, message: str = ""):
        self.progress(name, self.done, message)
        t0 = time.perf_counter()
        yield
        self.timings_s[name] = round(time.perf_counter() - t0, 3)
        self.done = min(1.0, self.done + self.weights.get(name, 0.0))
        log.info("stage %s done in %.1f s %s", name, self.timings_s[name], message)

    def within(self, name: str, fraction: float, message: str) -> None:
        """Progress inside the running stage ``name``: ``fraction`` of it is done."""
        self.progress(name, min(1.0, self.done + fraction * self.weights.get(name, 0.0)), message)


def _stage_weights(n_calib_images: int, n_ego_images: int) -> dict[str, float]:
    """Each stage's share of the journey's work, summing to 1."""
    costs = {"calibrate": CALIBRATE_S_PER_IMAGE * n_calib_images,
             "ego_motion": EGO_MOTION_S_PER_IMAGE * n_ego_images}
    rest = 1.0 - sum(OTHER_STAGES.values())
    total = sum(costs.values()) or 1.0
    return {**OTHER_STAGES, **{k: rest * v / total for k, v in costs.items()}}


def process_journey(journey: Journey, config: PipelineConfig, workdir: Path, *,
                    known_camera: CameraModel | None = None, progress: ProgressFn = no_progress,
                    verbose: bool = False) -> JourneyResult:
    """Run every stage on ``journey``. ``known_camera``: an earlier calibration of this camera_id,
    used when the journey cannot calibrate itself (no turn). Raises PipelineError with a reason."""
    clock = _Clock(progress, OTHER_STAGES)
    workdir.mkdir(parents=True, exist_ok=True)
    names = [f.path.name for f in journey.frames]
    n = len(journey.frames)

    origin = geodesy.frame_at(journey.lat_deg[0], journey.lon_deg[0],
                              journey.alt_m[0] if journey.has_altitude else None,
                              config.metric_frame)
    xyz_gps = origin.to_local(journey.lat_deg, journey.lon_deg,
                              journey.alt_m if journey.has_altitude else None)

    with clock.stage("turns"):
        xy_track = turns.smooth_track(xyz_gps[:, :2], np.array([f.timestamp_s for f in
                                                                journey.frames]),
                                      config.turn_smoothing_s)
        turn_windows = turns.find_turns(xy_track, tolerance_m=config.rdp_tolerance_m,
                                        min_angle_deg=config.turn_min_angle_deg,
                                        window_m=config.turn_window_m)
        s_m = turns.track_length_m(xy_track, tolerance_m=config.rdp_tolerance_m)
        calib_windows = calibration.candidate_windows(turn_windows, s_m, config)
        if known_camera is not None and config.reuse_known_calibration:
            calib_windows = []
        # A sign seen again later (after a loop) is mapped once per pass, each from a short window.
        margin = config.sign_window_margin_frames
        tracks = [p for t in ego_motion.sign_tracks(journey.detections, journey.frame_ids)
                  for p in ego_motion.split_passes(
                      t, max_gap=2 * margin,
                      max_frames=max(1, config.ego_max_frames_per_window - 2 * margin))
                  if len(p.frame_idx) >= config.min_track_frames]
        ego_windows = ego_motion.plan_windows(tracks, n, margin=config.sign_window_margin_frames,
                                              max_frames=config.ego_max_frames_per_window,
                                              step=config.ego_frame_step,
                                              overlap=config.ego_window_overlap_frames,
                                              bridge_gap=config.ego_bridge_gap_frames)
    log.info("journey %s: %d frames, %d turns, %d sign tracks, %d ego windows", journey.camera_id,
             n, len(turn_windows), len(tracks), len(ego_windows))
    off_grid = ego_motion.off_grid_frames(tracks, config.ego_frame_step, config.min_track_frames)
    clock.weights = _stage_weights(
        config.calib_images * bool(calib_windows),
        len(ego_motion.mapped_frames(ego_windows, config.ego_frame_step, off_grid)))
    if not calib_windows and known_camera is None:
        raise calibration.no_turn_error(config)

    def sfm_stage(name: str, windows, step: int, front_end: str, **extra) -> StageSfm:
        return StageSfm(workdir / f"sfm_{name}", journey, windows, step, front_end, config,
                        xyz_gps, verbose, **extra)

    def calibrate_window(window: calibration.CalibrationWindow,
                         request: colmap_sfm.WindowRequest) -> colmap_sfm.WindowResult:
        # Each candidate window gets correspondences of its own frames only, when it is tried:
        # the first candidate usually succeeds, and the others' features would be wasted.
        step = int(max(1, np.min(np.diff(window.frame_idx)))) if len(window.frame_idx) > 1 else 1
        stage = sfm_stage(f"calibrate_{window.frame_idx[0]}_{window.frame_idx[-1]}", [], step,
                          config.calib_front_end, frames=window.frame_idx)
        return stage.run([request], None)[0]

    def on_candidate(k: int, total: int, window: calibration.CalibrationWindow) -> None:
        # Most journeys stop at the first candidate: each later one halves what is left.
        clock.within("calibrate", 1.0 - 0.5**k,
                     f"candidate window {k + 1} of at most {total} ({window.label})")

    ego_sfm = sfm_stage("ego", ego_windows, config.ego_frame_step, config.ego_front_end,
                        extra=off_grid)
    calib: Calibration
    with ThreadPoolExecutor(max_workers=1) as background:
        if tracks:  # KLT tracking needs no camera: it runs while COLMAP calibrates
            background.submit(ego_sfm.correspondences)
        with clock.stage("calibrate", f"{len(calib_windows)} candidate windows"):
            calib = _calibrate(journey, calib_windows, names, config, calibrate_window,
                               on_candidate, known_camera)
    camera = calib.camera

    if not tracks:
        return JourneyResult(calib, [], [], clock.timings_s,
                             origin_lat_lon_alt=(origin.lat0_deg, origin.lon0_deg, origin.alt0_m))

    with clock.stage("ego_motion", f"{len(ego_windows)} windows"):
        results = ego_sfm.run(ego_motion.requests(
            ego_windows, names, camera, step=config.ego_frame_step, extra=off_grid,
            position_priors=config.ego_position_priors, init_gap_frames=config.match_overlap),
            camera, on_mapped=lambda k, total: clock.within(
                "ego_motion", k / total, f"{k} of {total} windows mapped"))
        poses = ego_motion.window_poses(ego_windows, results, names)
    if not poses:
        raise PipelineError("ego_motion", "no window around the signs could be reconstructed: "
                            + "; ".join(r.error or "too few frames registered" for r in results))

    with clock.stage("align"):
        # A window that cannot be aligned (the car stood still through it) is logged and dropped.
        aligned = georeference.align_windows(
            poses, xyz_gps, joint=config.alignment_joint,
            sigmas=georeference.JointSigmas(gps_m=config.gps_sigma_m))
    if not aligned:
        raise PipelineError("align", "no reconstructed window could be aligned to GPS "
                            "(the GPS track does not move enough around the signs)")

    with clock.stage("triangulate", f"{len({t.track_id for t in tracks})} tracks"):
        signs, rejected = _triangulate_all(tracks, aligned, xyz_gps, camera, journey, origin,
                                           config)

    # Overlapping windows pose some frames twice: keep the first window's pose.
    traj_idx, first = np.unique(np.concatenate([w.poses.frame_idx for w in aligned]),
                                return_index=True)
    traj_T = np.concatenate([w.T_world_cam for w in aligned])[first]
    progress("done", 1.0, f"{len(signs)} signs")
    return JourneyResult(calib, signs, rejected, clock.timings_s,
                         trajectory_frame_ids=[journey.frames[i].frame_id for i in traj_idx],
                         trajectory_enu=traj_T[:, :3, 3], gps_enu=xyz_gps[traj_idx],
                         trajectory_T_world_cam=traj_T,
                         origin_lat_lon_alt=(origin.lat0_deg, origin.lon0_deg, origin.alt0_m))


def _calibrate(journey: Journey, calib_windows, names: list[str], config: PipelineConfig,
               calibrate_window, on_candidate, known_camera: CameraModel | None) -> Calibration:
    """Self-calibration on the turns, or the stored calibration of the camera when there are no
    candidate windows (none found, or ``reuse_known_calibration``) or every candidate failed."""
    if not calib_windows:
        return Calibration(known_camera, "supplied")
    try:
        return calibration.self_calibrate(calib_windows, names, config, calibrate_window,
                                          hint=journey.camera_prior, width=journey.image_width,
                                          height=journey.image_height, on_candidate=on_candidate)
    except PipelineError:
        if known_camera is None:
            raise
        log.warning("self-calibration failed; using the stored calibration of %s",
                    journey.camera_id)
        return Calibration(known_camera, "supplied")


def _triangulate_all(tracks, aligned, xyz_gps, camera: CameraModel, journey: Journey,
                     origin: geodesy.LocalFrame, config: PipelineConfig):
    """One sign per track id: each pass of a track is triangulated from its own poses, the passes
    that succeed are combined (``_combine``)."""
    passes: dict[str, list] = {}
    classes = {t.track_id: t.cls for t in tracks}  # the passes of a track share its class
    for track in tracks:
        passes.setdefault(track.track_id, []).append(
            _triangulate_pass(track, aligned, xyz_gps, camera, config))
    signs: list[Sign] = []
    rejected: list[RejectedSign] = []
    for track_id, results in passes.items():
        cls = classes[track_id]
        placed = [r for r in results if not isinstance(r, str)]
        if not placed:
            rejected.append(RejectedSign(track_id, cls, "; ".join(dict.fromkeys(results))))
            continue
        xyz, cov, rms_px = _combine(placed)
        std_m = largest_std_m(cov)
        if std_m > config.max_sign_std_m:
            rejected.append(RejectedSign(track_id, cls,
                                         f"uncertainty {std_m:.2f} m > {config.max_sign_std_m} m"))
            continue
        T = np.concatenate([r[1] for r in placed])
        frame_ids = [journey.frames[i].frame_id for r in placed for i in r[2]]
        p_cam = np.einsum("mji,mj->mi", T[:, :3, :3], xyz[None, :] - T[:, :3, 3])
        lat, lon, alt = origin.to_geodetic(xyz[None, :])
        signs.append(Sign(
            track_id, cls, xyz, float(lat[0]), float(lon[0]),
            float(alt[0]) if journey.has_altitude else None, std_m, rms_px,
            [SignObservation(f, tuple(float(v) for v in p)) for f, p in zip(frame_ids, p_cam)],
            facing_deg(xyz, T[:, :3, 3]),
        ))
    return signs, rejected


def _triangulate_pass(track, aligned, xyz_gps, camera: CameraModel, config: PipelineConfig):
    """(point, T_world_cam, frame_idx) of one pass, or the reason it cannot be placed."""
    tp = georeference.track_poses(track, aligned, xyz_gps, mode=config.alignment,
                                  margin=config.sign_window_margin_frames,
                                  min_frames=config.short_alignment_min_frames)
    if tp is None or tp.keep.sum() < 2:
        return "its frames were not reconstructed"
    px = undistort_pixels(camera, track.px[tp.keep])
    try:
        point = triangulate(tp.T_world_cam, px, camera.K,
                            min_ray_angle_deg=config.min_ray_angle_deg,
                            max_rms_px=config.max_reprojection_rms_px)
    except TriangulationError as exc:
        return str(exc)
    if point.std_m > config.max_sign_std_m:
        return f"uncertainty {point.std_m:.2f} m > {config.max_sign_std_m} m"
    return point, tp.T_world_cam, track.frame_idx[tp.keep], tp.alignment_rms_m


def _combine(placed) -> tuple[np.ndarray, np.ndarray, float]:
    """(xyz, cov, rms_px) of one sign from its passes' triangulations ``(point, T, frame_idx,
    alignment_rms_m)``: their weighted mean, weights 1 / (std_m^2 + alignment_rms_m^2).

    Each pass comes from its own stretch of trajectory, placed by the GPS there, whose error (the
    GPS bias over the window or chain, ~0.2-0.5 m) is not in the triangulation's covariance and
    dominates it; a
    full inverse-covariance mean of such passes can land outside both (measured on loop-300,
    short alignment: 0.81 m from passes 0.62 and 0.37 m off). A scalar weight keeps the mean
    between the passes.
    """
    if len(placed) == 1:
        point = placed[0][0]
        return point.xyz_world, point.cov_world, point.rms_px
    w = np.array([1.0 / (r[0].std_m**2 + r[3]**2) for r in placed])
    w /= w.sum()
    xyz = sum(wi * r[0].xyz_world for wi, r in zip(w, placed))
    cov = sum(wi**2 * r[0].cov_world for wi, r in zip(w, placed))
    n = [len(r[2]) for r in placed]
    rms_px = float(np.sqrt(sum(k * r[0].rms_px**2 for k, r in zip(n, placed)) / sum(n)))
    return xyz, cov, rms_px
