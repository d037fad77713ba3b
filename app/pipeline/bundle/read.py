"""Reading and validating an uploaded journey bundle (wire contract, section 1).

``check_bundle`` validates (the API, on the upload request: it writes nothing and associates no
tracks); ``read_bundle`` validates, extracts the frames and fills empty track ids (the job).

Every violation of the contract becomes a ``BundleError`` whose message tells the uploader what to
fix; the zip is treated as hostile (``app.pipeline.bundle.zip``) and the work it may cost is bounded
by ``BundleLimits`` before it is spent. Checks run cheapest first: the zip's entries and the sizes
they declare (before anything is unpacked), manifest, the first frame's header, GPS, detections
(streamed), then each frame in turn: its header (pixel limit before any decoding), then with
``decode_images`` a full decode. ``check_bundle`` also checks that each frame ends as its format
ends (a JPEG's end-of-image marker, a PNG's IEND chunk, in the last ``FRAME_TAIL_BYTES``): this
catches a frame cut short for the cost of reading bytes, where decoding even a black 4096x4096
PNG costs 0.17 s of CPU (the zip's CRC of each entry is checked as it streams anyway). So the
API, which checks without decoding, answers a broken upload in a fraction of a second; a frame
whose pixels are broken in the middle is found only when it is decoded, in the job. One entry is
in memory at a time.

Frames are ``frames/<stem>.jpg|.jpeg|.png`` (extensions are case-sensitive like every name in the
bundle; other files under ``frames/``, hidden ones such as macOS ``._000000.png`` and sub-folders
are ignored), ordered by stem. Every frame's header must be a JPEG or PNG of the first frame's size
(decoding uses raw pixel orientation: the EXIF orientation tag is ignored, as detections refer to
the stored pixels). GPS comes from ``bundle.gps`` / ``bundle.gps_exif``; frames on a ``gps.gpx``
track that is not one point per frame are placed by their times (``captured_at`` +
``frame_rate_hz``, else their EXIF times, read with the frames); detections from
``bundle.detections``, with empty track ids filled by ``bundle.associate``.

Frames lying too far outside the GPS fixes' time span are dropped from the journey's ends
(``bundle.gps``): their files are removed again, their detections left out (a detection may
still name them: the bundle is valid), and ``Journey.warnings`` says so (also logged).
"""

from __future__ import annotations

import io
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Callable

import cv2
import numpy as np
from PIL import Image, JpegImagePlugin, PngImagePlugin

from app.pipeline.bundle.associate import assign_tracks, sort_detections
from app.pipeline.bundle.csv_table import check_text, shown
from app.pipeline.bundle.detections import DetectionTable, read_detections
from app.pipeline.bundle.gps import FrameGps, GpsLog, gps_from_csv, gps_from_gpx, read_gpx
from app.pipeline.bundle.gps_exif import (frame_times_utc_s, gps_from_exif, read_exif_fix,
                                          read_exif_time)
from app.pipeline.bundle.manifest import Manifest, parse_manifest
from app.pipeline.bundle.zip import BundleLimits, BundleZip, open_bundle
from app.pipeline.types import BundleError, Frame, GpsTrack, Journey

__all__ = ["BundleCheck", "BundleLimits", "check_bundle", "read_bundle"]

log = logging.getLogger(__name__)

FRAME_EXTENSIONS = ("jpg", "jpeg", "png")
VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv")
MAX_MANIFEST_BYTES = 2**20
_DECODE_FLAGS = cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION
# Pillow's format classes are used directly: they parse the header only, and (unlike Image.open,
# whose own bomb check fails with a generic error) leave the size limit to us, so the message can
# name the size.
_HEADER_PARSERS = ((b"\x89PNG\r\n\x1a\n", PngImagePlugin.PngImageFile),
                   (b"\xff\xd8\xff", JpegImagePlugin.JpegImageFile))
# Where a complete frame's end lies: the window is wider than the marker because decoders ignore
# bytes after it, and some cameras append their own data there (Samsung phones add a trailer of
# tens of kB after a JPEG's EOI).
FRAME_TAIL_BYTES = 64 * 2**10
_FRAME_ENDS = {b"\x89PNG": (b"IEND\xaeB`\x82", "a PNG ends with an IEND chunk"),
               b"\xff\xd8\xff": (b"\xff\xd9", "a JPEG ends with an end-of-image marker")}


@dataclass(frozen=True)
class BundleCheck:
    """What the API needs of a valid bundle (the frames kept after GPS trimming)."""

    camera_id: str
    vehicle_id: str | None
    captured_at: str | None
    n_frames: int
    n_detections: int
    warnings: tuple[str, ...]


@dataclass
class _Valid:
    manifest: Manifest
    frame_ids: list[str]
    paths: list[Path]
    width: int
    height: int
    gps: FrameGps
    detections: DetectionTable | None


def _frame_entries(names: list[str]) -> list[tuple[str, str]]:
    """(stem, entry name) of the frames, sorted by stem."""
    by_stem: dict[str, str] = {}
    for name in names:
        folder, _, base = name.partition("/")
        stem, dot, ext = base.rpartition(".")
        if (folder != "frames" or "/" in base or not dot or not stem or stem.startswith(".")
                or ext not in FRAME_EXTENSIONS):
            continue
        # The stem is the frame id stored with every observation and echoed in messages.
        check_text(stem, f"frame file name {shown(base)}")
        if stem in by_stem:
            raise BundleError(f"frames {by_stem[stem].split('/')[1]} and {base} have the same "
                              "stem; keep one file per frame")
        by_stem[stem] = name
    return sorted(by_stem.items())


def _no_frames_error(names: list[str]) -> BundleError:
    hint = ""
    odd_case = [n for n in names if n.startswith("frames/") and n.count("/") == 1
                and n.rpartition(".")[2].lower() in FRAME_EXTENSIONS]
    if odd_case:
        hint = (f" (found {odd_case[0]}: names are case-sensitive, use lower-case "
                ".jpg, .jpeg or .png)")
    return BundleError(f"bundle has no frames under frames/{hint}")


def _manifest_error(names: list[str]) -> BundleError:
    nested = next((n for n in names if n.endswith("/manifest.json")), None)
    hint = (f" (found {nested}: zip the bundle's contents, not the folder holding them)"
            if nested else "")
    return BundleError(f"bundle has no manifest.json at its top level{hint}")


def _header_size(fp: BinaryIO, base: str, limits: BundleLimits) -> tuple[int, int]:
    """(width, height) from a frame's JPEG/PNG header (only the header is read), within the pixel
    limit."""
    unreadable = BundleError(f"frame {base} is not a readable image")
    magic = fp.read(8)
    fp.seek(0)
    parser = next((p for prefix, p in _HEADER_PARSERS if magic.startswith(prefix)), None)
    try:
        if parser is None:
            with Image.open(fp) as img:  # only to name the format in the message
                fmt = img.format
            raise BundleError(f"frame {base} is a {fmt} image; frames must be JPEG or PNG")
        width, height = parser(fp).size
    except BundleError:
        raise
    except Exception:  # Pillow's parsers raise many types on hostile bytes; all mean "unreadable"
        raise unreadable from None
    if width * height > limits.max_frame_pixels:
        raise BundleError(f"frame {base} is {width}x{height}, more than the limit of "
                          f"{limits.max_frame_pixels} pixels ({limits.max_frame_pixels / 1e6:.1f} "
                          "megapixels); scale the frames down")
    if width <= 0 or height <= 0:
        raise unreadable
    return width, height


def _check_tail(data: bytes, base: str) -> None:
    """Refuse a frame whose end marker is missing from its last ``FRAME_TAIL_BYTES`` (its header
    was parsed already, so it starts like a JPEG or PNG)."""
    marker, rule = next(end for magic, end in _FRAME_ENDS.items() if data.startswith(magic))
    # In a JPEG's entropy-coded data 0xFF is always escaped (FF 00), so FF D9 is a real marker;
    # a PNG chunk type of IEND with its CRC is not found by chance.
    if data.rfind(marker, max(0, len(data) - FRAME_TAIL_BYTES)) < 0:
        raise BundleError(f"frame {base} is not a readable image: it is cut short ({rule}); "
                          "export it again")


def _decoded_size(data: bytes, base: str) -> tuple[int, int]:
    try:
        pixels = cv2.imdecode(np.frombuffer(data, np.uint8), _DECODE_FLAGS)
    except cv2.error:
        pixels = None
    if pixels is None:
        raise BundleError(f"frame {base} is not a readable image")
    return pixels.shape[1], pixels.shape[0]


def _read_frames(bz: BundleZip, entries: list[tuple[str, str]], size: tuple[int, int],
                 frames_dir: Path | None, limits: BundleLimits, decode: bool, want_exif: bool,
                 want_times: bool = False, tail: bool = False):
    """Check every frame, one in memory at a time; write it under ``frames_dir`` if given.
    ``want_exif``/``want_times``: also collect each frame's EXIF fix / EXIF time. ``tail``: also
    check that each frame ends as its format ends (before it is decoded, if it is)."""
    if frames_dir is not None:
        frames_dir.mkdir(parents=True, exist_ok=True)
    paths, exif_fixes, exif_times = [], [], []
    for _, name in entries:
        base = name.split("/", 1)[1]
        data = bz.read(name)
        width, height = _header_size(io.BytesIO(data), base, limits)
        if tail:
            _check_tail(data, base)
        if decode:
            width, height = _decoded_size(data, base)
        if (width, height) != size:
            raise BundleError(f"frame {base} is {width}x{height}, expected {size[0]}x{size[1]} "
                              "like the first frame; all frames must have one size")
        if want_exif:
            exif_fixes.append(read_exif_fix(data))
        if want_times:
            exif_times.append(read_exif_time(data))
        if frames_dir is not None:
            (frames_dir / base).write_bytes(data)
            paths.append(frames_dir / base)
    return paths, exif_fixes, exif_times


def _gpx_wants_exif(log: GpsLog, manifest: Manifest, entries: list[tuple[str, str]]) -> bool:
    """Whether the frames' EXIF times are needed to place them on the track (read with the
    frames, so only when nothing else times them and they can carry EXIF)."""
    return (len(log.fixes.timestamp_s) != len(entries) and manifest.frame_rate_hz is None
            and all(name.rpartition(".")[2] in ("jpg", "jpeg") for _, name in entries))


def _gpx_frames(log: GpsLog, manifest: Manifest, frame_ids: list[str],
                exif_times: list | None) -> FrameGps:
    """Frames on a ``gps.gpx`` track: point i is frame i when the counts match, else by time."""
    frame_utc_s = None
    if len(log.fixes.timestamp_s) != len(frame_ids):
        try:
            frame_utc_s = frame_times_utc_s(
                frame_ids, captured_at=manifest.captured_at, frame_rate_hz=manifest.frame_rate_hz,
                exif_times=exif_times, gps_time_offset_s=manifest.gps_time_offset_s)
        except BundleError as exc:
            raise BundleError(f"gps.gpx has {len(log.fixes.timestamp_s)} track points for "
                              f"{len(frame_ids)} frames, so the frames are placed on it by "
                              f"time, and {exc.reason}") from None
    return gps_from_gpx(log, frame_ids, frame_utc_s=frame_utc_s)


def _validate(bz: BundleZip, limits: BundleLimits, decode: bool,
              frames_dir: Path | None, tail: bool = False) -> _Valid:
    names = list(bz.files)
    if "manifest.json" not in bz.files:
        raise _manifest_error(names)
    entries = _frame_entries(names)
    if not entries:
        raise _no_frames_error(names)
    if len(entries) > limits.max_frames:
        raise BundleError(f"bundle has {len(entries)} frames, more than the limit of "
                          f"{limits.max_frames}")
    tables = [n for n in ("gps.csv", "gps.gpx", "detections.csv") if n in bz.files]
    bz.check_sizes({"manifest.json": MAX_MANIFEST_BYTES,
                    **{n: limits.max_member_bytes for n in tables},
                    **{name: limits.max_member_bytes for _, name in entries}})
    manifest = _manifest(bz)
    frame_ids = [stem for stem, _ in entries]
    with bz.open(entries[0][1]) as fp:
        width, height = _header_size(fp, entries[0][1].split("/", 1)[1], limits)
    gps, gpx_log = None, None
    if "gps.csv" in bz.files:
        with bz.open("gps.csv") as fp:
            gps = gps_from_csv(fp, frame_ids, max_rows=limits.max_gps_rows)
    elif "gps.gpx" in bz.files:
        with bz.open("gps.gpx") as fp:
            gpx_log = read_gpx(fp, max_points=limits.max_gps_rows)
        if not _gpx_wants_exif(gpx_log, manifest, entries):
            gps = _gpx_frames(gpx_log, manifest, frame_ids, exif_times=None)
    detections = None
    if "detections.csv" in bz.files:
        with bz.open("detections.csv") as fp:
            detections = read_detections(fp, frame_ids, width, height,
                                         max_rows=limits.max_detections,
                                         max_boxes_per_frame=limits.max_boxes_per_frame)
    paths, exif_fixes, exif_times = _read_frames(
        bz, entries, (width, height), frames_dir, limits, decode,
        want_exif=gps is None and gpx_log is None, want_times=gps is None and gpx_log is not None,
        tail=tail)
    if gps is None and gpx_log is not None:
        gps = _gpx_frames(gpx_log, manifest, frame_ids, exif_times)
    elif gps is None:
        gps = gps_from_exif(exif_fixes, frame_ids)
    return _Valid(manifest, frame_ids, paths, width, height, gps, detections)


def _kept_mask(valid: _Valid) -> np.ndarray:
    keep = np.zeros(len(valid.frame_ids), bool)
    keep[valid.gps.kept] = True
    return keep


def video_entry(bz: BundleZip) -> str | None:
    """The bundle's video (contract 1a: one video file at its top level), None for frames."""
    videos = [n for n in bz.files if "/" not in n and n.lower().endswith(VIDEO_SUFFIXES)]
    if len(videos) > 1:
        raise BundleError(f"bundle has {len(videos)} videos ({', '.join(sorted(videos)[:3])}); a "
                          "journey is one video: upload each as its own bundle")
    if videos and _frame_entries(list(bz.files)):
        raise BundleError(f"bundle has both {videos[0]} and frames/; a journey is one or the "
                          "other")
    return videos[0] if videos else None


def _manifest(bz: BundleZip) -> Manifest:
    if "manifest.json" not in bz.files:
        raise _manifest_error(list(bz.files))
    bz.check_sizes({"manifest.json": MAX_MANIFEST_BYTES})
    return parse_manifest(bz.read("manifest.json", MAX_MANIFEST_BYTES))


def _check_video(bz: BundleZip, video: str, limits: BundleLimits) -> BundleCheck:
    from app.pipeline.bundle.video.read import check_video  # PyAV: only for video bundles

    m = _manifest(bz)
    check = check_video(bz, m, video, limits)
    n_detections = len(check.detections) if check.detections is not None else 0
    return BundleCheck(m.camera_id, m.vehicle_id, m.captured_at, check.header.n_frames,
                       n_detections, ())


def check_bundle(zip_path: Path, limits: BundleLimits = BundleLimits(), *,
                 decode_images: bool = True) -> BundleCheck:
    """Validate the bundle at ``zip_path`` without writing anything or building tracks. Every
    frame's header and end are checked; ``decode_images`` also decodes each frame in full (off in
    the API, where it cost seconds of CPU per large frame: decoding is left to the job)."""
    with open_bundle(Path(zip_path), limits) as bz:
        video = video_entry(bz)
        if video is not None:
            return _check_video(bz, video, limits)
        valid = _validate(bz, limits, decode_images, frames_dir=None, tail=True)
    keep = _kept_mask(valid)
    n_detections = int(keep[valid.detections.frame].sum()) if valid.detections else 0
    m = valid.manifest
    return BundleCheck(m.camera_id, m.vehicle_id, m.captured_at, int(keep.sum()), n_detections,
                       tuple(valid.gps.warnings))


def read_bundle(zip_path: Path, extract_dir: Path, *, limits: BundleLimits = BundleLimits(),
                decode_images: bool = True,
                progress: Callable[[float], None] | None = None) -> Journey:
    """Validate the bundle at ``zip_path``, extract its frames under ``extract_dir/frames/`` (a
    video's: decode it and keep the frames the pipeline needs, ``progress`` of the decoding)."""
    with open_bundle(Path(zip_path), limits) as bz:
        video = video_entry(bz)
        if video is not None:
            from app.pipeline.bundle.video.read import read_video

            journey = read_video(bz, _manifest(bz), video, Path(extract_dir), limits, progress)
            for warning in journey.warnings:
                log.warning("%s: %s", Path(zip_path).name, warning)
            return journey
        valid = _validate(bz, limits, decode_images, frames_dir=Path(extract_dir) / "frames")
    gps = valid.gps
    kept_ids, kept_paths = valid.frame_ids[gps.kept], valid.paths[gps.kept]
    for path in set(valid.paths) - set(kept_paths):
        path.unlink()  # so the extracted frames/ holds exactly the journey's frames
    for warning in gps.warnings:
        log.warning("%s: %s", Path(zip_path).name, warning)
    detections = []
    if valid.detections is not None:
        detections = valid.detections.to_detections(valid.frame_ids, _kept_mask(valid))
        detections = sort_detections(assign_tracks(detections, kept_ids), kept_ids)
    frames = [Frame(fid, path, float(t))
              for fid, path, t in zip(kept_ids, kept_paths, gps.timestamp_s)]
    m, width, height = valid.manifest, valid.width, valid.height
    prior = m.camera_prior.camera(width, height) if m.camera_prior else None
    return Journey(camera_id=m.camera_id, frames=frames, lat_deg=gps.lat_deg,
                   lon_deg=gps.lon_deg, alt_m=gps.alt_m, detections=detections,
                   image_width=width, image_height=height, vehicle_id=m.vehicle_id,
                   captured_at=m.captured_at, camera_prior=prior, warnings=list(gps.warnings),
                   gps_noise_m=gps.noise_m, gps_accuracy_m=gps.accuracy_m,
                   gps_fixes=None if gps.fixes is None else GpsTrack(
                       gps.fixes.timestamp_s, gps.fixes.lat_deg, gps.fixes.lon_deg,
                       gps.fixes.alt_m),
                   gps_antenna_offset=m.gps_antenna_offset_m.offset()
                   if m.gps_antenna_offset_m else None)
