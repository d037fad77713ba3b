"""The journey pipeline end to end: one validated journey in, triangulated signs out.

Stages (``steps``, one module each): turns (and the plan made from them, ``steps.plan``) ->
calibrate -> ego_motion (``reconstruct``) -> align -> triangulate (``steps.place_signs``;
``georeference``). This module only orchestrates: it times the stages, reports progress as the
fraction of the journey's expected work done (weighted once the plan says how many images each
stage maps) and collects one ``StageReport`` per stage that ran.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np

from app.pipeline.colmap.sfm import SfmRun, WindowRequest, WindowResult
from app.pipeline.colmap.stage import REDUCED_READ, StageSfm, read_gray
from app.pipeline.cameras import check_on_turn
from app.pipeline.config import PipelineConfig
from app.pipeline.geometry import antenna, geodesy, gps_noise, gps_track
from app.pipeline.steps import align, calibrate, ego_motion, image_turns, place_signs, plan
from app.pipeline.steps.calibrate import CalibrationWindow
from app.pipeline.steps.sign_tracks import SignTrack
from app.pipeline.types import (AntennaEstimate, AntennaOffset, BrokenWindow, Calibration,
                                CameraModel, Journey, JourneyResult, PipelineError, ProgressFn,
                                RejectedSign, StageReport, WindowTime, no_progress)

log = logging.getLogger(__name__)

# Seconds per mapped image, measured on a 2-core machine (turn-70 and long-1000): how the
# progress fraction divides the journey between calibration and ego-motion.
CALIBRATE_S_PER_IMAGE = 0.65
EGO_MOTION_S_PER_IMAGE = 0.12
OTHER_STAGES = {"turns": 0.01, "align": 0.01, "triangulate": 0.03}


class _Clock:
    """Stage timings (and their parts: ``JourneyResult.stage_parts_s``), and progress as the
    fraction of the journey's expected work done."""

    def __init__(self, progress: ProgressFn, weights: dict[str, float], *,
                 timings_s: dict[str, float] | None = None, done: float = 0.0):
        self.timings_s: dict[str, float] = timings_s if timings_s is not None else {}
        self.parts_s: dict[str, dict[str, float]] = {}
        self.windows: list[WindowTime] = []
        self.progress = progress
        self.weights = weights
        self.done = done

    @contextmanager
    def stage(self, name: str, message: str = ""):
        self.progress(name, self.done, message)
        t0 = time.perf_counter()
        try:
            yield
        except PipelineError as exc:
            self.timings_s[name] = round(time.perf_counter() - t0, 3)
            exc.timings_s = dict(self.timings_s)
            raise
        self.finished(name, time.perf_counter() - t0, message)

    def finished(self, name: str, seconds: float, message: str = "") -> None:
        """Stage ``name`` took ``seconds`` (also for the planning stage, timed before the clock
        existed because its weights come from the plan)."""
        self.timings_s[name] = round(seconds, 3)
        self.done = min(1.0, self.done + self.weights.get(name, 0.0))
        log.info("stage %s done in %.1f s %s", name, self.timings_s[name], message)

    def add_sfm(self, name: str, done: SfmRun, frames: list[str]) -> None:
        """Stage ``name``'s COLMAP run ``done`` (windows of the journey ``frames``, each a
        label like "12-125"): its parts add to what the stage already spent."""
        parts = dict(done.timings_s)
        refine_s = sum(w.refine_s for w in done.windows)
        if refine_s:
            parts["refine"] = refine_s
        mine = self.parts_s.setdefault(name, {})
        for part, seconds in parts.items():
            mine[part] = round(mine.get(part, 0.0) + seconds, 3)
        self.windows += [WindowTime(name, label, w.n_input, len(w.image_names), w.mapping_s,
                                    w.refine_s) for label, w in zip(frames, done.windows)]

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


@dataclass
class _Entry:
    """The report of the running stage, filled in as it goes."""

    summary: str = ""
    details: list[str] = field(default_factory=list)

    def take(self, report: StageReport) -> None:
        """Use what a step's own report says."""
        self.summary, self.details = report.summary, list(report.details)


class _Journal:
    """One StageReport per stage that ran, in order; a PipelineError leaving a stage carries them
    all, the failing stage's last."""

    def __init__(self, reports: list[StageReport] | None = None) -> None:
        self.reports: list[StageReport] = reports if reports is not None else []

    @contextmanager
    def stage(self, name: str):
        entry = _Entry()
        try:
            yield entry
        except PipelineError as exc:
            self.reports.append(StageReport(name, f"failed: {exc.reason}", tuple(entry.details)))
            exc.report = list(self.reports)
            raise
        self.reports.append(StageReport(name, entry.summary, tuple(entry.details)))

    def add(self, report: StageReport) -> None:
        self.reports.append(report)


@dataclass(frozen=True)
class Reconstruction:
    """The journey up to ego-motion, as the georeferencing stages (align, triangulate) take it.

    Plain data, so the corpus bench can keep it and run only the later stages again with other
    knobs (``signmap bench corpus --replay``). ``xyz_gps`` (N, 3): frame positions in
    ``origin``'s frame, straight lines between fixes; ``xyz_align`` (N, 3): the positions the
    alignment takes (the smoothing spline's with ``gps_smoothing``); both the camera's, moved from
    the GPS antenna when the manifest says where it is. ``tracks`` empty: the
    journey has no sign track, and no ego-motion ran."""

    calib: Calibration
    tracks: list[SignTrack]
    poses: list[ego_motion.WindowPoses]
    xyz_gps: np.ndarray
    xyz_align: np.ndarray
    origin: geodesy.LocalFrame
    timings_s: dict[str, float]
    reports: list[StageReport]
    # Tracks the plan could not triangulate (too few frames), with the reason.
    too_short: tuple[RejectedSign, ...] = ()
    # What the align stage's report says of the positions (the GPS antenna offset applied).
    gps_notes: tuple[str, ...] = ()
    stage_parts_s: dict[str, dict[str, float]] = field(default_factory=dict)
    window_times: tuple[WindowTime, ...] = ()


def process_journey(journey: Journey, config: PipelineConfig, workdir: Path, *,
                    known_camera: CameraModel | None = None, progress: ProgressFn = no_progress,
                    verbose: bool = False) -> JourneyResult:
    """Run every stage on ``journey``. ``known_camera``: an earlier calibration of this camera_id,
    checked on the journey's turn (``cameras.check_on_turn``) and used when the turn confirms
    it or the journey cannot calibrate itself (no turn). Raises PipelineError with a reason
    and the reports of the stages that ran (``PipelineError.report``)."""
    recon = reconstruct(journey, config, workdir, known_camera=known_camera, progress=progress,
                        verbose=verbose)
    return georeference(journey, recon, config, progress=progress)


def reconstruct(journey: Journey, config: PipelineConfig, workdir: Path, *,
                known_camera: CameraModel | None = None, progress: ProgressFn = no_progress,
                verbose: bool = False) -> Reconstruction:
    """The stages up to ego-motion: turns and plan, calibrate, ego_motion."""
    workdir.mkdir(parents=True, exist_ok=True)
    origin = geodesy.frame_at(journey.lat_deg[0], journey.lon_deg[0],
                              journey.alt_m[0] if journey.has_altitude else None,
                              config.metric_frame)
    xyz_gps = origin.to_local(journey.lat_deg, journey.lon_deg,
                              journey.alt_m if journey.has_altitude else None)
    # Turn finding keeps the straight-line positions it was tuned on; alignment takes the spline's.
    xyz_align = frame_positions(journey, origin, xyz_gps) if config.gps_smoothing else xyz_gps
    # From the antenna to the camera, before anything looks at the positions.
    xyz_gps, xyz_align, antenna_notes = _at_camera(journey, xyz_gps, xyz_align)
    journal = _Journal(list(journey.intake))
    the_plan, clock = _plan_stage(journey, xyz_gps, config, known_camera, journal, progress)
    job = _Job(journey, config, workdir, verbose, journal, clock)
    ego_sfm = StageSfm("ego_motion", workdir / "sfm_ego", journey, the_plan.ego_frames,
                       step=the_plan.ego_step, front_end=the_plan.ego_front_end, config=config,
                       verbose=verbose)
    calib = _calibrate_stage(job, the_plan, known_camera, ego_sfm)
    poses = _ego_motion_stage(job, the_plan, calib.camera, ego_sfm) if the_plan.tracks else []
    return Reconstruction(calib, the_plan.tracks, poses, xyz_gps, xyz_align, origin,
                          clock.timings_s, journal.reports, the_plan.too_short, antenna_notes,
                          clock.parts_s, tuple(clock.windows))


def _at_camera(journey: Journey, xyz_gps: np.ndarray,
               xyz_align: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """``xyz_gps`` and ``xyz_align`` moved from the GPS antenna to the camera by the manifest's
    ``gps_antenna_offset_m`` (``_moved``), and what the align stage's report says of it;
    unchanged without one."""
    offset = journey.gps_antenna_offset
    if offset is None:
        return xyz_gps, xyz_align, ()
    return _moved(journey, offset, xyz_gps, xyz_align)


def _moved(journey: Journey, offset: AntennaOffset, xyz_gps: np.ndarray, xyz_align: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """``xyz_gps`` and ``xyz_align`` minus ``offset`` (``gps_track.antenna_to_camera``; the
    direction of travel taken from ``xyz_align``), and the align report's line on it."""
    t_s = journey.timestamps_s
    forward = gps_track.camera_travel_direction(t_s, xyz_align, offset)
    moved_align = gps_track.antenna_to_camera(xyz_align, offset, forward)
    moved_gps = moved_align if xyz_gps is xyz_align else gps_track.antenna_to_camera(
        xyz_gps, offset, forward)
    note = (f"GPS antenna offset applied ({offset.source}): forward {offset.forward_m:+.2f} m, left "
            f"{offset.left_m:+.2f} m, up {offset.up_m:+.2f} m")
    if forward is None:
        note += (f"; the vehicle never moved faster than {gps_track.MIN_HEADING_SPEED_MPS:g} m/s, "
                 "so only the up part was applied")
    return moved_gps, moved_align, (note,)


def _estimated_offset(journey: Journey, recon: Reconstruction, config: PipelineConfig
                      ) -> tuple[Reconstruction, AntennaEstimate | None]:
    """``recon`` with its positions moved to the camera by the antenna offset its turning windows
    tell (``geometry.antenna``), combined with the vehicle's earlier journeys'
    (``journey.antenna_prior``), when nobody declared one and the sigma is below
    ``antenna_offset_max_sigma_m``; and this journey's own estimate. The align report says what
    was estimated either way."""
    if journey.gps_antenna_offset is not None or not recon.poses:
        return recon, None
    t_s = journey.timestamps_s
    if journey.gps_fixes is None:  # one fix per frame (EXIF): the frames' positions are the fixes
        t_fix_s, xyz_fix = t_s, recon.xyz_gps
    else:
        t_fix_s, xyz_fix = journey.gps_fixes.timestamp_s, fixes_local(journey, recon.origin)
    found = antenna.estimate_offset([(t_s[p.frame_idx], p.T_model_cam[:, :3, 3])
                                     for p in recon.poses], t_fix_s, xyz_fix)
    own = found.estimate() if found is not None else None
    prior = journey.antenna_prior
    use = AntennaEstimate.combined([e for e in (own, prior) if e is not None])
    if use is None:
        note = (f"GPS antenna offset not declared, nor estimated: no reconstructed window turns "
                f"{antenna.MIN_TURN_DEG:g}° or more")
        return replace(recon, gps_notes=recon.gps_notes + (note,)), None
    apply = use.sigma_m < config.antenna_offset_max_sigma_m
    decision = ("applied" if apply else
                f"not applied (sigma over {config.antenna_offset_max_sigma_m:g} m)")
    where = journey.antenna_prior_source or "the vehicle"
    if found is None:
        note = (f"GPS antenna offset not estimated here (no window turns "
                f"{antenna.MIN_TURN_DEG:g}° or more); {where}'s {prior.n_journeys} earlier "
                f"journey(s) tell {_offset_text(prior)}: {decision}")
    else:
        note = (f"GPS antenna offset estimated: {_offset_text(own)} ({found.n_windows} "
                f"window(s), {found.n_fixes} fixes, turning up to {found.turn_deg:.0f}°); "
                + (decision if prior is None else
                   f"{decision} with {where}'s {prior.n_journeys} earlier journey(s) "
                   f"({_offset_text(prior)}; together {_offset_text(use)})"))
    recon = replace(recon, gps_notes=recon.gps_notes + (note,))
    if not apply:
        return recon, own
    source = "estimated" if prior is None else f"estimated with {where}'s journeys"
    xyz_gps, xyz_align, _ = _moved(journey, use.offset(source), recon.xyz_gps, recon.xyz_align)
    return replace(recon, xyz_gps=xyz_gps, xyz_align=xyz_align), own


def _offset_text(est: AntennaEstimate) -> str:
    return (f"forward {est.forward_m:+.2f} ± {est.sigma_forward_m:.2f} m, left "
            f"{est.left_m:+.2f} ± {est.sigma_left_m:.2f} m")


@dataclass(frozen=True)
class _Job:
    """One journey's run up to ego-motion: what its stages read, and where they report."""

    journey: Journey
    config: PipelineConfig
    workdir: Path
    verbose: bool
    journal: _Journal
    clock: _Clock

    @property
    def names(self) -> list[str]:
        return [f.path.name for f in self.journey.frames]


def _plan_stage(journey: Journey, xyz_gps: np.ndarray, config: PipelineConfig,
                known_camera: CameraModel | None, journal: _Journal,
                progress: ProgressFn) -> tuple[plan.JourneyPlan, _Clock]:
    """The turns stage: the journey's plan (turns, calibration candidates, ego-motion windows),
    and the clock whose stage weights the plan gives."""
    progress("turns", 0.0, "")
    t0 = time.perf_counter()
    with journal.stage("turns") as entry:
        the_plan = plan.plan_journey(journey, xyz_gps, config, known_camera)
        if not the_plan.turns and known_camera is None and config.turn_image_look:
            the_plan = _image_look(journey, the_plan, xyz_gps, config)
        entry.take(plan.report(the_plan, config))
    clock = _Clock(progress, _stage_weights(config.calib_images * bool(the_plan.calib_windows),
                                            len(the_plan.ego_frames)))
    clock.finished("turns", time.perf_counter() - t0)
    log.info("journey %s: %d frames, %d turns, %d sign tracks, %d ego windows", journey.camera_id,
             len(journey.frames), len(the_plan.turns), len(the_plan.tracks),
             len(the_plan.ego_windows))
    return the_plan, clock


# The calibration candidates' SIFT, extracted once per frame (``colmap.sift_cache``).
SHARED_SIFT = "sift_calibrate.db"


def _calibrate_stage(job: _Job, the_plan: plan.JourneyPlan, known_camera: CameraModel | None,
                     ego_sfm: StageSfm) -> Calibration:
    """The calibrate stage; the ego-motion stage's KLT tracks, which need no camera, are made
    meanwhile in a thread."""
    # Keyed by image name: a work directory used again for another journey must not lend it
    # the last one's features.
    (job.workdir / SHARED_SIFT).unlink(missing_ok=True)
    with job.journal.stage("calibrate") as entry:
        if not the_plan.calib_windows and known_camera is None:
            raise calibrate.no_turn_error(job.config, the_plan.image_frames_compared)
        with ThreadPoolExecutor(max_workers=1) as background:
            if the_plan.tracks:
                background.submit(ego_sfm.correspondences)
            with job.clock.stage("calibrate",
                                 f"{len(the_plan.calib_windows)} candidate windows"):
                return _calibrate(job, the_plan.calib_windows, known_camera, entry)


class _CandidateProgress:
    """Progress through the calibrate stage as its candidates are tried. Most journeys stop at
    the first, so candidate k (from 0) spans the k+1-th half of what is left of the stage,
    [1 - 0.5**k, 1 - 0.5**(k + 1)]; its features, extracted and matched, the first
    ``FEATURES_SHARE`` of that."""

    FEATURES_SHARE = 0.5

    def __init__(self, clock: _Clock) -> None:
        self.clock, self.k, self.label = clock, 0, ""

    def trying(self, k: int, total: int, window: CalibrationWindow) -> None:
        self.k, self.label = k, f"candidate window {k + 1} of at most {total} ({window.label})"
        self._at(0.0, self.label)

    def features_matched(self) -> None:
        self._at(self.FEATURES_SHARE, f"{self.label}: features matched")

    def mapped(self, done: int, total: int) -> None:
        self._at(done / max(total, 1), f"{self.label}: mapped")

    def _at(self, share: float, message: str) -> None:
        self.clock.within("calibrate", 1.0 - 0.5**self.k * (1.0 - 0.5 * share), message)


def _map_candidate(job: _Job, candidates: _CandidateProgress, window: CalibrationWindow,
                   start: CameraModel) -> WindowResult:
    """Self-calibration's mapping of one candidate window from the camera ``start``. Each
    candidate gets correspondences of its own frames only, when it is tried: the first usually
    succeeds, and the others' features would be wasted. Frames an earlier candidate extracted
    come from the journey's ``SHARED_SIFT``."""
    config, names = job.config, job.names
    first, last = window.frame_idx[0], window.frame_idx[-1]
    stage = _window_stage(job, window, f"sfm_calibrate_{first}_{last}")
    request = WindowRequest(
        image_names=[names[i] for i in window.frame_idx], camera=start, calibrate=True,
        retry_focals_px=tuple(f * start.width for f in config.calib_retry_focal_factors),
        retry_below=int(np.ceil(config.calib_retry_below_ratio * len(window.frame_idx))))
    done = stage.run([request], None, on_mapped=candidates.mapped,
                     on_prepared=candidates.features_matched)
    job.clock.add_sfm("calibrate", done, [f"{first}-{last}"])
    return done.windows[0]


def _check_stored(job: _Job, window: CalibrationWindow,
                  stored: CameraModel) -> check_on_turn.CameraCheck:
    """The camera's stored calibration checked on ``window`` (``cameras.check_on_turn``). Its
    SIFT goes into the journey's ``SHARED_SIFT``: a self-calibration after it extracts none of
    these frames again."""
    first, last = window.frame_idx[0], window.frame_idx[-1]
    job.clock.within("calibrate", 0.0, f"checking the stored calibration on {window.label}")
    stage = _window_stage(job, window, f"sfm_check_{first}_{last}")
    request = WindowRequest(image_names=[job.names[i] for i in window.frame_idx],
                            camera=stored, check=True)
    done = stage.run([request], stored)
    job.clock.add_sfm("calibrate", done, [f"{first}-{last}"])
    return check_on_turn.judge(stored, window, done.windows[0], job.config)


def _window_stage(job: _Job, window: CalibrationWindow, name: str) -> StageSfm:
    """COLMAP's work on one calibration window's frames, under ``name`` in the work directory;
    frames another window extracted come from the journey's ``SHARED_SIFT``."""
    config = job.config
    step = int(max(1, np.min(np.diff(window.frame_idx)))) if len(window.frame_idx) > 1 else 1
    return StageSfm("calibrate", job.workdir / name, job.journey, window.frame_idx, step=step,
                    front_end=config.calib_front_end, config=config, verbose=job.verbose,
                    feature_cache=job.workdir / SHARED_SIFT if config.calib_share_features
                    else None)


def _ego_motion_stage(job: _Job, the_plan: plan.JourneyPlan, camera: CameraModel,
                      ego_sfm: StageSfm) -> list[ego_motion.WindowPoses]:
    """The ego_motion stage: the windows around the signs mapped with the calibrated camera."""
    ego_windows, clock = the_plan.ego_windows, job.clock
    with job.journal.stage("ego_motion") as entry, \
            clock.stage("ego_motion", f"{len(ego_windows)} windows"):
        done = ego_sfm.run(ego_motion.requests(
            ego_windows, job.names, camera, step=the_plan.ego_step, extra=the_plan.off_grid,
            init_gap_frames=job.config.match_overlap,
            more_init_pairs=job.config.ego_more_init_pairs),
            camera, on_mapped=lambda k, total: clock.within(
                "ego_motion", k / total, f"{k} of {total} windows mapped"))
        clock.add_sfm("ego_motion", done, [f"{a}-{b - 1}" for a, b in ego_windows])
        results = done.windows
        poses = ego_motion.window_poses(ego_windows, results, job.names)
        entry.take(ego_motion.report(ego_windows, results, poses))
        if not poses:
            raise PipelineError("ego_motion", "no window around the signs could be "
                                "reconstructed: " + "; ".join(r.error or "too few frames registered"
                                                              for r in results))
    return poses


def georeference(journey: Journey, recon: Reconstruction, config: PipelineConfig, *,
                 progress: ProgressFn = no_progress) -> JourneyResult:
    """The stages after ego-motion: align the windows to the GPS, triangulate the signs."""
    origin = recon.origin
    origin_lat_lon_alt = (origin.lat0_deg, origin.lon0_deg, origin.alt0_m)
    too_short = list(recon.too_short)
    if not recon.tracks:
        return JourneyResult(recon.calib, [], too_short, dict(recon.timings_s),
                             origin_lat_lon_alt=origin_lat_lon_alt, report=list(recon.reports),
                             stage_parts_s=dict(recon.stage_parts_s),
                             window_times=list(recon.window_times))
    journal = _Journal(list(recon.reports))
    clock = _Clock(progress, OTHER_STAGES, timings_s=dict(recon.timings_s),
                   done=1.0 - OTHER_STAGES["align"] - OTHER_STAGES["triangulate"])
    tracks, poses, camera = recon.tracks, recon.poses, recon.calib.camera

    with journal.stage("align") as entry, clock.stage("align"):
        # A window that cannot be aligned (the car stood still through it) is dropped; one that
        # disagrees with the GPS is mended where it can be (align.mend).
        notes: list[str] = []
        trusted = gps_trusted(journey, config)
        recon, antenna_estimate = _estimated_offset(journey, recon, config)
        xyz_gps, xyz_align = recon.xyz_gps, recon.xyz_align
        untrusted = ([] if trusted is None or trusted.all() else
                     [f"{int((~trusted).sum())} frames in GPS dropouts: their interpolated "
                      "positions neither align nor judge a window"])
        limit_m = place_signs.alignment_limit_m(place_signs.judging_noise_m(journey), config)
        if limit_m is None:
            why = ("one EXIF position per frame" if journey.gps_fixes is None else
                   f"fewer than {gps_noise.MIN_FIXES_TO_JUDGE} fixes")
            notes.append(f"the GPS's noise is unknown ({why}): no window is judged against it")
        broken: list[BrokenWindow] = []

        def on_broken(w: align.AlignedWindow, fix: align.Mend) -> None:
            first, last = int(w.poses.frame_idx[0]), int(w.poses.frame_idx[-1])
            broken.append(BrokenWindow(
                first, last, float(w.info["rms_m"]), float(limit_m), fix.mended, fix.how,
                tuple(sorted({t.track_id for t in tracks
                              if ((t.frame_idx >= first) & (t.frame_idx <= last)).any()}))))
            notes.append(f"frames {first}-{last}: GPS rms {w.info['rms_m']:.2f} m, over the "
                           f"{limit_m:.2f} m limit; {fix.how}")

        aligned = align.align_windows(
            poses, xyz_align, joint=config.alignment_joint,
            sigmas=align.JointSigmas(gps_m=config.gps_sigma_m),
            max_independent_rms_m=(limit_m if config.alignment_unlink_broken
                                   or config.alignment_mend_broken else None),
            on_dropped=lambda p, why: notes.append(
                f"frames {p.window[0]}-{p.window[1] - 1} dropped: {why}"),
            xyz_check=xyz_gps if config.gps_smoothing else None, trusted=trusted,
            mend_broken=config.alignment_mend_broken, on_broken=on_broken,
            min_fixes=config.short_alignment_min_frames)
        entry.take(align.report(len(poses), aligned,
                                list(recon.gps_notes) + untrusted + notes))
        if not aligned:
            raise PipelineError("align", "no reconstructed window could be aligned to GPS "
                                "(the GPS track does not move enough around the signs)")

    with clock.stage("triangulate", f"{len({t.track_id for t in tracks})} tracks"):
        signs, rejected = place_signs.place_signs(tracks, aligned, xyz_align, camera, journey,
                                                  origin, config, trusted)
        rejected += too_short
    journal.add(place_signs.report(signs, rejected))

    # Overlapping windows pose some frames twice: keep the first window's pose.
    traj_idx, first = np.unique(np.concatenate([w.poses.frame_idx for w in aligned]),
                                return_index=True)
    traj_T = np.concatenate([w.T_world_cam for w in aligned])[first]
    progress("done", 1.0, f"{len(signs)} signs")
    return JourneyResult(recon.calib, signs, rejected, clock.timings_s,
                         trajectory_frame_ids=[journey.frames[i].frame_id for i in traj_idx],
                         trajectory_enu=traj_T[:, :3, 3], gps_enu=xyz_align[traj_idx],
                         trajectory_T_world_cam=traj_T,
                         origin_lat_lon_alt=origin_lat_lon_alt, report=journal.reports,
                         stage_parts_s=dict(recon.stage_parts_s),
                         window_times=list(recon.window_times),
                         antenna_estimate=antenna_estimate, broken_windows=broken)


def _image_look(journey: Journey, the_plan: plan.JourneyPlan, xyz_gps: np.ndarray,
                config: PipelineConfig) -> plan.JourneyPlan:
    """``the_plan`` with the turns the journey's frames show (``steps.image_turns``)."""
    timestamp_s = journey.timestamps_s
    frame_idx = image_turns.sample_frames(timestamp_s, config.turn_image_interval_s,
                                          config.turn_image_max_frames)
    reduce = max(k for k in REDUCED_READ
                 if journey.image_width / k >= config.turn_image_width_px or k == 1)
    images = [image_turns.scaled_to(read_gray(journey.frames[i].path, "turns", reduce=reduce),
                                    config.turn_image_width_px) for i in frame_idx]
    guess = calibrate.initial_camera(journey.image_width, journey.image_height, config,
                                     journey.camera_prior)
    headings = image_turns.heading_deg(images, guess.fx * images[0].shape[1] / journey.image_width,
                                       frame_idx)
    log.info("journey %s: no turn on the GPS track; the images turn %.0f deg at most "
             "(%d frames compared, %d pairs unmeasured)", journey.camera_id,
             np.ptp(headings.heading_deg), len(frame_idx), headings.unmeasured)
    return plan.with_image_turns(the_plan, xyz_gps, timestamp_s, headings, config,
                                 plan.gps_sigma_m(journey))


def gps_trusted(journey: Journey, config: PipelineConfig) -> np.ndarray | None:
    """(N,) bool: the frames whose GPS position is pinned by fixes near them
    (``gps_track.in_dropout``); None when the journey kept no fixes."""
    if journey.gps_fixes is None:
        return None
    t_frame_s = journey.timestamps_s
    return ~gps_track.in_dropout(t_frame_s, journey.gps_fixes.timestamp_s,
                                 config.gps_dropout_gap_factor)


def fixes_local(journey: Journey, origin: geodesy.LocalFrame) -> np.ndarray:
    """(M, 3) the journey's GPS fixes (``journey.gps_fixes``, not None) in ``origin``'s frame."""
    fixes = journey.gps_fixes
    return origin.to_local(fixes.lat_deg, fixes.lon_deg,
                           fixes.alt_m if journey.has_altitude else None)


def frame_positions(journey: Journey, origin: geodesy.LocalFrame,
                    xyz_linear: np.ndarray) -> np.ndarray:
    """(N, 3) frame positions in ``origin``'s frame from a smoothing spline through the journey's
    GPS fixes (``geometry.gps_track``); ``xyz_linear`` where the journey kept no fixes."""
    fixes = journey.gps_fixes
    if fixes is None:
        return xyz_linear
    xyz_fix = fixes_local(journey, origin)
    if not (journey.has_altitude and np.all(np.isfinite(fixes.alt_m))):
        xyz_fix[:, 2] = np.nan  # altitude missing somewhere: the vertical stays as read
    t_frame_s = journey.timestamps_s
    return gps_track.smoothed_positions(t_frame_s, xyz_linear, fixes.timestamp_s, xyz_fix,
                                        journey.gps_noise_m)


def known_camera_used(camera_id: str) -> str:
    """How the calibrate stage's report says it used ``known_camera``, in the service's words (the
    camera's stored calibration); ``signmap process``, which was given it as a file, says so."""
    return f"stored calibration of camera {camera_id} used"


def _calibrate(job: _Job, calib_windows: list[CalibrationWindow],
               known_camera: CameraModel | None, entry: _Entry) -> Calibration:
    """The stored calibration of the camera when its turn confirms it (``check_on_turn``),
    else self-calibration on the turns; the stored calibration unchecked when there are no
    candidate windows (none found, or ``reuse_known_calibration``) or every candidate failed.
    Fills in the calibrate stage's report ``entry``."""
    journey, config = job.journey, job.config
    stored = known_camera_used(journey.camera_id)
    if not calib_windows:
        entry.summary = (f"{stored} (reuse_known_calibration is set)"
                         if config.reuse_known_calibration else
                         f"{stored}: no candidate window to self-calibrate on")
        return Calibration(known_camera, "supplied")
    if known_camera is not None and config.check_known_calibration:
        check = _check_stored(job, calib_windows[0], known_camera)
        said = check.summary()
        log.info("journey %s: %s", journey.camera_id, said)
        if check.confirmed:
            entry.summary = said
            return check.calibration()
        entry.details.append(said + "; self-calibrating")
    candidates = _CandidateProgress(job.clock)
    try:
        calib = calibrate.self_calibrate(
            calib_windows, config, partial(_map_candidate, job, candidates),
            start=calibrate.initial_camera(journey.image_width, journey.image_height, config,
                                           journey.camera_prior),
            on_candidate=candidates.trying, trials=entry.details, frame_names=job.names)
    except PipelineError as exc:
        if known_camera is None:
            raise
        log.warning("self-calibration failed; using the stored calibration of %s",
                    journey.camera_id)
        entry.summary = f"self-calibration failed, {stored}"
        entry.details.append(exc.reason)
        return Calibration(known_camera, "supplied")
    entry.summary = calibrate.summary(calib)
    return calib
