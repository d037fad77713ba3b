"""GPS from the EXIF tags of JPEG frames, used when a bundle has neither gps.csv nor gps.gpx.

Every frame must then be a JPEG carrying GPSLatitude/Ref and GPSLongitude/Ref (GPSAltitude/Ref
optional) and a time. One clock is used for the whole journey, the first that every frame has:
GPSDateStamp + GPSTimeStamp (UTC), else DateTimeOriginal (+ SubSecTimeOriginal, + OffsetTimeOriginal;
without an offset taken as UTC), else GPSTimeStamp alone (seconds of the day; a journey crossing
midnight UTC then fails the order check). Timestamps are seconds since the first frame. Cameras often
stamp whole seconds only, so frames may share a timestamp (but not go back in time); each frame's
position is its own fix, nothing is interpolated.
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
                                     check_frame_times, check_plausible_motion, check_position)
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
    text = exif_ifd.get(ExifTags.Base.DateTimeOriginal)
    if not text:
        return None
    try:
        value = datetime.strptime(str(text).strip("\x00 "), "%Y:%m:%d %H:%M:%S")
    except ValueError:
        return None
    subsec = str(exif_ifd.get(ExifTags.Base.SubsecTimeOriginal, "")).strip("\x00 ")
    if subsec.isdigit():
        value = value.replace(microsecond=int(float("0." + subsec) * 1e6))
    offset = str(exif_ifd.get(ExifTags.Base.OffsetTimeOriginal, "")).strip("\x00 ")
    try:
        tz = datetime.strptime(offset, "%z").tzinfo if offset else timezone.utc
    except ValueError:
        tz = timezone.utc
    return value.replace(tzinfo=tz)


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
    return ExifFix(lat, lon, alt if math.isfinite(alt) else math.nan, gps_utc,
                   _original_time(exif_ifd), time_of_day)


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
