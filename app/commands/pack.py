"""``signmap pack VIDEO --gps LOG``: a dash cam's recording made into the upload bundle of the wire
contract (section 1a), so that a fleet need not write its own converter. ``signmap process``
packs a video the same way before it runs the pipeline.

The bundle is checked as the service checks it before it is written: a bundle ``pack`` makes is
one the service accepts."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv")
# The GPS file's name in the bundle, by the suffix it has on disk (anything else: an NMEA log,
# which loggers name .nmea, .nma, .log or .txt).
GPS_NAMES = {".gpx": "gps.gpx", ".csv": "gps.csv"}
DEFAULT_CAMERA_ID = "dashcam"


class PackError(Exception):
    """The files given cannot make a bundle; the message says why."""


def is_video(path: Path) -> bool:
    return path.suffix.lower() in VIDEO_SUFFIXES


def pack_video(video: Path, out: Path, *, gps: Path | None = None, detections: Path | None = None,
               camera_id: str = DEFAULT_CAMERA_ID, vehicle_id: str | None = None,
               gps_time_offset_s: float | None = None) -> Path:
    """Write ``out`` (a zip): ``video`` as video.<ext>, ``gps`` as gps.nmea|gpx|csv, detections,
    and the manifest. The video is stored, not deflated (it is compressed already, and a stored
    entry lets the service read its header without decompressing the rest)."""
    if not is_video(video):
        raise PackError(f"{video} is not an MP4, MOV or MKV file (by its name)")
    manifest = {"format": "signmap-journey/1", "camera_id": camera_id}
    if vehicle_id is not None:
        manifest["vehicle_id"] = vehicle_id
    if gps_time_offset_s is not None:
        manifest["gps_time_offset_s"] = gps_time_offset_s
    out.parent.mkdir(parents=True, exist_ok=True)
    part = out.with_name(out.name + ".part")
    try:
        with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED, allowZip64=True) as z:
            z.writestr("manifest.json", json.dumps(manifest, indent=2))
            z.write(video, "video" + video.suffix.lower(), compress_type=zipfile.ZIP_STORED)
            if gps is not None:
                z.write(gps, GPS_NAMES.get(gps.suffix.lower(), "gps.nmea"))
            if detections is not None:
                z.write(detections, "detections.csv")
        part.replace(out)
    finally:
        part.unlink(missing_ok=True)
    return out
