"""GPS from the EXIF tags of JPEG frames, used when a bundle has neither gps.csv nor gps.gpx.

Every frame must then be a JPEG carrying GPSLatitude/Ref and GPSLongitude/Ref (GPSAltitude/Ref
optional) and a time. One clock is used for the whole journey, the first that every frame has:
GPSDateStamp + GPSTimeStamp (UTC), else DateTimeOriginal (+ SubSecTimeOriginal, + OffsetTimeOriginal;
without an offset taken as UTC), else GPSTimeStamp alone (seconds of the day; a journey crossing
midnight UTC then fails the order check). Timestamps are seconds since the first frame. Cameras often
stamp whole seconds only, so frames may share a timestamp (but not go back in time); each frame's
position is its own fix, nothing is interpolated.

Frame times for a GPS track that is not one fix per frame (``frame_times_utc_s``, for ``gps.gpx``):
each frame's UTC time, by precedence from the manifest's ``captured_at`` + i / ``frame_rate_hz``
(both needed), else every frame's DateTimeOriginal (+ SubSecTimeOriginal): with
OffsetTimeOriginal an absolute time; without, the camera's local time, whose spacing only is used,
anchored at ``captured_at`` (a time zone cannot be guessed: without ``captured_at`` the bundle is
refused). ``captured_at`` without an offset is UTC. The manifest's ``gps_time_offset_s`` (camera
time to GPS time) is added to all of them.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Sequence

import numpy as np
from PIL import ExifTags, Image

from app.pipeline.bundle.gps import (MAX_TIMESTAMP_S, FrameGps, check_altitude,
                                     check_frame_times, check_plausible_motion, check_position,
                                     parse_iso_time)
from app.pipeline.types import BundleError

NO_GPS_MESSAGE = "bundle has no GPS: add gps.csv, gps.gpx, or EXIF GPS tags to every JPEG frame"


@dataclass(frozen=True)
class ExifFix:
    """What one JPEG's EXIF says about where and when it was taken."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    gps_utc: datetime | None
    original_time: datetime | None
    gps_time_of_day_s: float | None


def _dms_to_deg(dms, ref) -> float:
    deg, minutes, seconds = (float(v) for v in dms)
    sign = -1.0 if str(ref).strip().upper() in ("S", "W") else 1.0
    return sign * (deg + minutes / 60.0 + seconds / 3600.0)


def _seconds_of_day(hms) -> float:
    h, m, s = (float(v) for v in hms)
    return 3600.0 * h + 60.0 * m + s


def _original_time(exif_ifd: dict) -> datetime | None:
    """DateTimeOriginal (+ sub-seconds): aware when OffsetTimeOriginal says the zone, else naive
    (the camera's local time)."""
    text = exif_ifd.get(ExifTags.Base.DateTimeOriginal)
    if not text:
        return None
    try:
        value = datetime.strptime(str(text).strip("\x00 "), "%Y:%m:%d %H:%M:%S")
    except ValueError:
        return None
    subsec = str(exif_ifd.get(ExifTags.Base.SubsecTimeOriginal, "")).strip("\x00 ")
    if subsec.isascii() and subsec.isdigit():  # "²" is a digit to isdigit, not to float
        value = value.replace(microsecond=int(float("0." + subsec) * 1e6))
    offset = str(exif_ifd.get(ExifTags.Base.OffsetTimeOriginal, "")).strip("\x00 ")
    try:
        tz = datetime.strptime(offset, "%z").tzinfo if offset else None
    except ValueError:
        tz = None
    return value.replace(tzinfo=tz)


def _exif_ifd(image_bytes: bytes) -> dict | None:
    with Image.open(io.BytesIO(image_bytes)) as img:
        if img.format != "JPEG":
            return None
        return dict(img.getexif().get_ifd(ExifTags.IFD.Exif))


def read_exif_time(image_bytes: bytes) -> datetime | None:
    """A JPEG's DateTimeOriginal (aware with OffsetTimeOriginal, naive without), None when it is
    not a JPEG or has none."""
    try:
        exif_ifd = _exif_ifd(image_bytes)
    except Exception:  # whatever Pillow raises on a mangled file: no time to read
        return None
    return None if exif_ifd is None else _original_time(exif_ifd)


def read_exif_fix(image_bytes: bytes) -> ExifFix | None:
    """The EXIF GPS fix of a JPEG, or None when it is not a JPEG or lacks a position."""
    try:
        with Image.open(io.BytesIO(image_bytes)) as img:
            if img.format != "JPEG":
                return None
            exif = img.getexif()
            gps = dict(exif.get_ifd(ExifTags.IFD.GPSInfo))
            exif_ifd = dict(exif.get_ifd(ExifTags.IFD.Exif))
        lat = _dms_to_deg(gps[ExifTags.GPS.GPSLatitude], gps.get(ExifTags.GPS.GPSLatitudeRef, "N"))
        lon = _dms_to_deg(gps[ExifTags.GPS.GPSLongitude],
                          gps.get(ExifTags.GPS.GPSLongitudeRef, "E"))
    except Exception:  # absent tags (KeyError) or whatever Pillow raises on a mangled EXIF block
        return None
    alt = math.nan
    try:
        if ExifTags.GPS.GPSAltitude in gps:
            alt = float(gps[ExifTags.GPS.GPSAltitude])
            ref = gps.get(ExifTags.GPS.GPSAltitudeRef, 0)
            if ref in (1, b"\x01"):
                alt = -alt
        time_of_day = (_seconds_of_day(gps[ExifTags.GPS.GPSTimeStamp])
                       if ExifTags.GPS.GPSTimeStamp in gps else None)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    if time_of_day is not None and not math.isfinite(time_of_day):
        time_of_day = None
    gps_utc = None
    date = str(gps.get(ExifTags.GPS.GPSDateStamp, "")).strip("\x00 ")
    if date and time_of_day is not None:
        try:
            day = datetime.strptime(date, "%Y:%m:%d").replace(tzinfo=timezone.utc)
            gps_utc = datetime.fromtimestamp(day.timestamp() + time_of_day, timezone.utc)
        except (ValueError, OverflowError, OSError):  # a time of day far past the calendar
            gps_utc = None
    if not (math.isfinite(lat) and math.isfinite(lon)):
        return None
    original = _original_time(exif_ifd)
    if original is not None and original.tzinfo is None:
        original = original.replace(tzinfo=timezone.utc)  # one clock: only differences count
    return ExifFix(lat, lon, alt if math.isfinite(alt) else math.nan, gps_utc, original,
                   time_of_day)


def gps_from_exif(fixes: Sequence[ExifFix | None], frame_ids: Sequence[str]) -> FrameGps:
    """Per-frame EXIF fixes (None: the frame has none) -> per-frame GPS."""
    for frame, fix in zip(frame_ids, fixes):
        if fix is None:
            raise BundleError(f"{NO_GPS_MESSAGE} (frame {frame} has no EXIF GPS position)")
        check_position(fix.lat_deg, fix.lon_deg, f"frame {frame} EXIF GPS")
        if math.isfinite(fix.alt_m):
            check_altitude(fix.alt_m, f"frame {frame} EXIF GPS")
    fixes = [f for f in fixes if f is not None]
    if all(f.gps_utc for f in fixes):
        t_s = [(f.gps_utc - fixes[0].gps_utc).total_seconds() for f in fixes]
    elif all(f.original_time for f in fixes):
        t_s = [(f.original_time - fixes[0].original_time).total_seconds() for f in fixes]
    elif all(f.gps_time_of_day_s is not None for f in fixes):
        t_s = [f.gps_time_of_day_s - fixes[0].gps_time_of_day_s for f in fixes]
    else:
        timeless = [fid for fid, f in zip(frame_ids, fixes)
                    if not (f.gps_utc or f.original_time or f.gps_time_of_day_s is not None)]
        if timeless:
            raise BundleError(f"frame {timeless[0]} has EXIF GPS but no time (GPSTimeStamp or "
                              "DateTimeOriginal); every frame needs one")
        raise BundleError("frames carry different kinds of EXIF time; every frame needs the same "
                          "one (GPSDateStamp+GPSTimeStamp, DateTimeOriginal or GPSTimeStamp)")
    timestamp_s = np.array(t_s, dtype=float)
    if np.any(np.abs(timestamp_s) > MAX_TIMESTAMP_S):
        i = int(np.argmax(np.abs(timestamp_s) > MAX_TIMESTAMP_S))
        raise BundleError(f"frame {frame_ids[i]} EXIF time is {timestamp_s[i]:g} s from the first "
                          f"frame's, more than {MAX_TIMESTAMP_S:g} s")
    check_frame_times(timestamp_s, frame_ids, strict=False)
    gps = FrameGps(timestamp_s, np.array([f.lat_deg for f in fixes]),
                   np.array([f.lon_deg for f in fixes]), np.array([f.alt_m for f in fixes]))
    check_plausible_motion(gps.timestamp_s, gps.lat_deg, gps.lon_deg,
                           [f"frame {f}" for f in frame_ids])
    return gps


def frame_times_utc_s(frame_ids: Sequence[str], *, captured_at: str | None,
                      frame_rate_hz: float | None, exif_times: Sequence[datetime | None] | None,
                      gps_time_offset_s: float | None = None) -> np.ndarray:
    """Each frame's time on the GPS clock (N,), UTC POSIX seconds (module docstring for the
    rules). ``exif_times``: each frame's ``read_exif_time``, None when the frames are no JPEGs."""
    start = parse_iso_time(captured_at, "manifest.json captured_at") if captured_at else None
    if frame_rate_hz is not None:
        if start is None:
            raise BundleError("manifest.json gives frame_rate_hz but no captured_at: frame i is "
                              "taken at captured_at + i / frame_rate_hz, so both are needed")
        utc_s = start.timestamp() + np.arange(len(frame_ids)) / frame_rate_hz
    else:
        utc_s = _exif_utc_s(frame_ids, start, exif_times)
    return utc_s + (gps_time_offset_s or 0.0)


def _exif_utc_s(frame_ids: Sequence[str], start: datetime | None,
                exif_times: Sequence[datetime | None] | None) -> np.ndarray:
    missing = None if exif_times is None else next(
        (i for i, t in enumerate(exif_times) if t is None), None)
    if exif_times is None or missing is not None:
        which = ("these frames are not all JPEGs" if exif_times is None
                 else f"frame {frame_ids[missing]} has none")
        raise BundleError(
            "the frames have no times: give captured_at and frame_rate_hz in manifest.json "
            "(frame i taken at captured_at + i / frame_rate_hz), or JPEG frames with EXIF "
            f"DateTimeOriginal ({which})")
    zoned = [t.tzinfo is not None for t in exif_times]
    if all(zoned):
        utc_s = np.array([t.timestamp() for t in exif_times])
    elif any(zoned):
        i = zoned.index(not zoned[0])
        raise BundleError(f"frame {frame_ids[0]}'s EXIF time {'has' if zoned[0] else 'lacks'} "
                          f"a time zone (OffsetTimeOriginal) and frame {frame_ids[i]}'s "
                          f"{'lacks' if zoned[0] else 'has'} one; every frame needs the same kind")
    elif start is None:
        raise BundleError(
            "the frames' EXIF DateTimeOriginal has no time zone (OffsetTimeOriginal), so it is "
            "the camera's local time: give captured_at in manifest.json (the first frame's time, "
            "UTC unless it gives an offset) to anchor it, or frame_rate_hz with captured_at")
    else:
        # Local time: its spacing is right, its zone unknown; captured_at fixes the first frame.
        utc_s = start.timestamp() + np.array(
            [(t - exif_times[0]).total_seconds() for t in exif_times])
    same = np.flatnonzero(np.diff(utc_s) <= 0)
    if same.size:
        i = int(same[0])
        raise BundleError(
            f"frames {frame_ids[i]} and {frame_ids[i + 1]} have EXIF times "
            f"{exif_times[i].isoformat()} and {exif_times[i + 1].isoformat()}: frame times must "
            "increase (whole seconds need SubSecTimeOriginal); give captured_at and frame_rate_hz "
            "in manifest.json instead")
    return utc_s
