"""A video journey (contract 1a) from an opened bundle: checked at upload, read by the worker.

Time. Frame times come from the container's presentation timestamps (``t_video_s``, seconds from
the first frame). The GPS log has its own clock (``GpsLog.t0_utc``); ``offset_s`` is the seconds
to add to video time to get GPS log time (``t_gps_s = t_video_s + offset_s``), which is:

* given: the manifest's ``gps_time_offset_s`` (the contract's "video time to GPS time"), turned
  into the log's clock through ``creation_time``; used as given;
* zero for ``gps.csv`` (its ``timestamp_s`` counts from the video's first frame) and for the
  video's own GPS track (the container times both: one clock);
* otherwise estimated (``geometry.clock_offset``: the camera's rotation in the images against the
  GPS course) within ``SEARCH_S`` of what ``creation_time`` says; when it cannot be estimated,
  ``creation_time`` stands and the report says so. Without a ``creation_time`` the search spans
  every offset at which video and GPS overlap.

The upload check reads the container header, the GPS file and the detections; it decodes one
frame. The worker decodes the video as a stream (``frames``) and keeps the frames it needs.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, replace
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from app.pipeline.bundle.associate import assign_tracks, sort_detections
from app.pipeline.bundle.detections import DetectionTable, read_detections
from app.pipeline.bundle.gps import (FrameGps, GpsLog, check_plausible_motion, gps_from_csv,
                                     interpolate_to_frames, read_gpx)
from app.pipeline.bundle.manifest import Manifest
from app.pipeline.bundle.video.embedded_gps import read_embedded_gps
from app.pipeline.bundle.video.frames import FrameChoice, decode_frames
from app.pipeline.bundle.video.motion import ImageMotion
from app.pipeline.bundle.video.nmea import parse_nmea
from app.pipeline.bundle.video.probe import VideoHeader, probe_video
from app.pipeline.bundle.zip import BundleZip
from app.pipeline.config import BundleLimits
from app.pipeline.geometry import geodesy
from app.pipeline.geometry.clock_offset import estimate_clock_offset
from app.pipeline.types import BundleError, Frame, GpsTrack, Journey, StageReport

SEARCH_S = 30.0  # how far a dash cam's clock may be off GPS time (they are set by hand, or drift)
GPS_FILES = ("gps.nmea", "gps.gpx", "gps.csv")
# Handler names of the metadata tracks that carry GPS (as ``embedded_gps`` tells them apart).
EMBEDDED_HANDLERS = ("gopro met", "camm", "cameramotionmetadata")
FRAME_RATE_HZ = 10.0
UNKNOWN_START = datetime(1970, 1, 1, tzinfo=timezone.utc)  # a log on a clock nobody set


@dataclass(frozen=True)
class VideoCheck:
    """What the upload learns of a valid video bundle. ``gps`` None: the video's own track,
    read by the worker."""

    header: VideoHeader
    gps: GpsLog | None
    detections: DetectionTable | None


def _frame_ids(header: VideoHeader) -> list[str]:
    # Detections may name any frame the video could hold (its declared count is an estimate for
    # some containers: a second's worth of margin).
    return [f"{i:06d}" for i in range(header.n_frames + int(np.ceil(header.fps)))]


def _gps_log(bz: BundleZip, header: VideoHeader, limits: BundleLimits) -> GpsLog | None:
    given = [n for n in GPS_FILES if n in bz.files]
    if len(given) > 1:
        raise BundleError(f"bundle has {' and '.join(given)}; a video journey takes one GPS "
                          "source")
    if not given:
        if not any(h in handler for handler in header.data_handlers for h in EMBEDDED_HANDLERS):
            raise BundleError(f"no GPS: {header.name} carries no GPS track (GoPro GPMF or CAMM) "
                              "and the bundle has no gps.nmea, gps.gpx or gps.csv")
        return None
    name = given[0]
    bz.check_sizes({name: limits.max_member_bytes})
    with bz.open(name) as fp:
        if name == "gps.nmea":
            return parse_nmea(fp, max_lines=limits.max_gps_rows)
        if name == "gps.gpx":
            return read_gpx(fp, max_points=limits.max_gps_rows)
        fixes = gps_from_csv(fp, [], max_rows=limits.max_gps_rows).fixes
    # Its times count from the video's first frame: the log's t0 is the video's start.
    return GpsLog(fixes, header.creation_utc or UNKNOWN_START, "gps.csv")


@dataclass(frozen=True)
class _Prior:
    offset_s: float  # video time -> log time, as far as is known before the images are seen
    search_s: float  # 0: known, not estimated
    how: str


def _prior(manifest: Manifest, header: VideoHeader, log: GpsLog, embedded: bool) -> _Prior:
    span_s = float(log.fixes.timestamp_s[-1])
    if log.source == "gps.csv" or embedded:
        return _Prior(0.0, 0.0, f"{log.source} is timed on the video's clock")
    start = header.creation_utc
    if manifest.gps_time_offset_s is not None:
        if start is None:
            raise BundleError(f"gps_time_offset_s is given but {header.name} has no "
                              "creation_time to apply it to")
        log_s = (start - log.t0_utc).total_seconds() + manifest.gps_time_offset_s
        return _Prior(log_s, 0.0, f"declared in manifest.json: {manifest.gps_time_offset_s:+.3f} s")
    if start is None:  # every offset at which the two overlap
        centre = (span_s - header.duration_s) / 2
        return _Prior(centre, (span_s + header.duration_s) / 2,
                      f"{header.name} has no creation_time")
    return _Prior((start - log.t0_utc).total_seconds(), SEARCH_S,
                  f"creation_time {start.isoformat()}")


def _check_overlap(header: VideoHeader, log: GpsLog, prior: _Prior) -> None:
    span_s = float(log.fixes.timestamp_s[-1])
    lo, hi = prior.offset_s - prior.search_s, prior.offset_s + prior.search_s
    if hi + header.duration_s < 0 or lo > span_s:
        end = log.t0_utc + timedelta(seconds=span_s)
        clock = header.creation_utc.isoformat() if header.creation_utc else "?"
        raise BundleError(
            f"the GPS does not overlap the video in time: {log.source} runs from "
            f"{log.t0_utc.isoformat()} to {end.isoformat()}, {header.name} for "
            f"{header.duration_s:.1f} s from {clock} (its clock; {prior.how}), and the clocks "
            f"may differ by at most {prior.search_s:.0f} s")


def check_video(bz: BundleZip, manifest: Manifest, name: str, limits: BundleLimits,
                video_path: Path | None = None) -> VideoCheck:
    """Validate the video bundle's header, GPS and detections (the upload's check)."""
    bz.check_sizes({name: limits.max_video_bytes})
    info = bz.files[name]
    if info.compress_type != zipfile.ZIP_STORED and info.file_size > limits.max_member_bytes:
        # Its header may sit at its end: reading it would inflate the whole video in the request.
        raise BundleError(f"{name} is deflated in the zip; store it uncompressed (zip -0, as "
                          "signmap pack does): a video does not shrink, and a deflated one must "
                          "be inflated to be read")
    if video_path is not None:
        header = probe_video(video_path, name, limits)
    else:
        with bz.open(name) as fp:
            header = probe_video(fp, name, limits)
    log = _gps_log(bz, header, limits)
    if log is not None:
        _check_overlap(header, log, _prior(manifest, header, log, embedded=False))
    detections = None
    if "detections.csv" in bz.files:
        bz.check_sizes({"detections.csv": limits.max_member_bytes})
        with bz.open("detections.csv") as fp:
            detections = read_detections(fp, _frame_ids(header), header.width, header.height,
                                         max_rows=limits.max_detections,
                                         max_boxes_per_frame=limits.max_boxes_per_frame)
    return VideoCheck(header, log, detections)


def _offset(prior: _Prior, motion: ImageMotion, log: GpsLog) -> tuple[float, list[str]]:
    if prior.search_s == 0.0:
        return prior.offset_s, [f"clock offset: {prior.how}"]
    signal = motion.signal()
    fixes = log.fixes
    origin = geodesy.frame_at(fixes.lat_deg[0], fixes.lon_deg[0], None)
    xy_enu = origin.to_local(fixes.lat_deg, fixes.lon_deg)[:, :2]
    found = estimate_clock_offset(signal.t_video_s, signal.dx_px, fixes.timestamp_s, xy_enu,
                                  prior_offset_s=prior.offset_s, search_s=prior.search_s)
    if found.offset_s is None:
        if "no creation_time" in prior.how:
            raise BundleError(f"the clock offset between video and GPS could not be estimated "
                              f"({found.reason}) and {prior.how}; give gps_time_offset_s in "
                              "manifest.json")
        return prior.offset_s, [f"clock offset not estimated ({found.reason}); {prior.how} "
                                "stands"]
    # The camera's clock error: what creation_time says minus the truth, in GPS time.
    error_s = prior.offset_s - found.offset_s
    return found.offset_s, [f"clock offset estimated: the camera's clock is {error_s:+.2f} s "
                            f"± {found.sigma_s:.2f} s off GPS time ({prior.how})",
                            f"clock offset: {found.reason}"]


def read_video(bz: BundleZip, manifest: Manifest, name: str, extract_dir: Path,
               limits: BundleLimits, progress: Callable[[float], None] | None = None) -> Journey:
    """Check, decode and time the video bundle's frames into a Journey (frames under
    ``extract_dir/frames``)."""
    video_path = bz.extract(name, extract_dir / name)
    check = check_video(bz, manifest, name, limits, video_path)
    header, log = check.header, check.gps
    embedded = log is None
    if embedded:
        log = read_embedded_gps(video_path, max_points=limits.max_gps_rows)
        if log is None:
            raise BundleError(f"no GPS: {header.name} has no readable GPS track and the bundle "
                              "has no gps.nmea, gps.gpx or gps.csv")
    prior = _prior(manifest, header, log, embedded)
    ids = _frame_ids(header)
    must_keep = set(np.unique(check.detections.frame).tolist()) if check.detections else set()
    motion = ImageMotion()

    def on_kept(t_video_s: float, bgr: np.ndarray) -> None:
        if prior.search_s:
            motion.add(t_video_s, cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))

    decoded = decode_frames(video_path, name, FrameChoice(FRAME_RATE_HZ, must_keep),
                            extract_dir / "frames", on_kept=on_kept,
                            progress=progress and (lambda n: progress(min(1.0, n / header.n_frames))))
    video_path.unlink()
    offset_s, notes = _offset(prior, motion, log)
    frame_ids = [ids[i] if i < len(ids) else f"{i:06d}" for i in decoded.index]
    t_gps = decoded.t_video_s + offset_s
    frame_gps: FrameGps = interpolate_to_frames(log.fixes, t_gps, frame_ids)
    kept = frame_gps.kept
    check_plausible_motion(frame_gps.timestamp_s, frame_gps.lat_deg, frame_gps.lon_deg,
                           [f"frame {f}" for f in frame_ids[kept]])
    frame_gps = replace(frame_gps, fixes=log.fixes)
    for path in decoded.paths[:kept.start or 0] + decoded.paths[kept.stop or len(frame_ids):]:
        path.unlink()
    warnings = [w for w in (decoded.warning,) if w] + list(frame_gps.warnings)
    detections = []
    if check.detections is not None:
        keep = np.zeros(max(len(ids), int(decoded.index[-1]) + 1), bool)
        keep[decoded.index[kept]] = True
        detections = check.detections.to_detections(ids, keep[:len(ids)])
        kept_ids = list(frame_ids[kept])
        detections = sort_detections(assign_tracks(detections, kept_ids), kept_ids)
    frames = [Frame(fid, path, float(t)) for fid, path, t in
              zip(frame_ids[kept], decoded.paths[kept], frame_gps.timestamp_s)]
    start_utc = log.t0_utc + timedelta(seconds=float(offset_s))
    details = (f"{header.name}: {header.codec} {header.width}x{header.height}, "
               f"{header.fps:.2f} fps, {header.duration_s:.1f} s", decoded.summary(),
               f"GPS: {log.source}, {len(log.fixes.timestamp_s)} fixes", *log.notes, *notes,
               *warnings)
    intake = StageReport("video", f"{len(frames)} frames kept of {decoded.n_decoded}; "
                         + notes[0], details)
    prior_cam = manifest.camera_prior.camera(header.width, header.height) \
        if manifest.camera_prior else None
    return Journey(camera_id=manifest.camera_id, frames=frames, lat_deg=frame_gps.lat_deg,
                   lon_deg=frame_gps.lon_deg, alt_m=frame_gps.alt_m, detections=detections,
                   image_width=header.width, image_height=header.height,
                   vehicle_id=manifest.vehicle_id, captured_at=start_utc.isoformat(),
                   camera_prior=prior_cam, warnings=warnings, gps_noise_m=frame_gps.noise_m,
                   gps_accuracy_m=frame_gps.accuracy_m, intake=(intake,),
                   gps_fixes=GpsTrack(log.fixes.timestamp_s, log.fixes.lat_deg,
                                      log.fixes.lon_deg, log.fixes.alt_m),
                   gps_antenna_offset=manifest.gps_antenna_offset_m.offset()
                   if manifest.gps_antenna_offset_m else None)


def read_gps_log(bz: BundleZip, name: str, scratch: Path, limits: BundleLimits) -> GpsLog:
    """The video bundle's GPS fixes without decoding the video (the dashboard's map of a
    journey); the video is extracted under ``scratch`` only when its own track holds them."""
    with bz.open(name) as fp:
        header = probe_video(fp, name, limits, decode_first=False)
    log = _gps_log(bz, header, limits)
    if log is None:
        log = read_embedded_gps(bz.extract(name, scratch / name), max_points=limits.max_gps_rows)
    if log is None:
        raise BundleError(f"no GPS: {name} has no readable GPS track")
    return log
