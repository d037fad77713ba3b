"""GPS of a journey: parse ``gps.csv`` or ``gps.gpx`` and give every frame a time and a position.

Sources, by precedence: ``gps.csv``, else ``gps.gpx``, else EXIF tags of JPEG frames
(``app.pipeline.bundle.gps_exif``).

``gps.csv`` (columns ``frame,timestamp_s,lat,lon[,alt_m]``; row numbers as in ``csv_table``):

* a row with a frame and a position is both that frame's timestamp and a fix;
* a row with an empty frame is a fix only; a row with a frame and empty lat/lon is a timestamp only;
* fixes must come in strictly increasing time; every frame needs a timestamp, and frame timestamps
  must increase in frame order; a row naming a frame that is not in ``frames/`` is used as a fix only;
* lat/lon/alt are interpolated linearly in time to each frame; a gap between fixes (a dropout) is
  simply interpolated across;
* frames outside the fixes' time span: a 1 Hz receiver's first fix often comes up to a second after
  the first frame, and its last one before the last frame. A frame at most ``extrapolation_bound_s``
  = max(1.5 s, 1.5 median fix intervals), capped at 3 s, outside the span is extrapolated with the
  velocity of the two end fixes (held at the end fix when they are less than
  ``MIN_VELOCITY_BASELINE_S`` apart: their difference is then noise, not motion). The bound covers
  one missed fix plus latency; beyond ~3 s a linear guess of a turning car drifts by metres
  (0.5 a t^2 = 9 m at 2 m/s^2 lateral acceleration), more than GPS noise, which would skew the
  alignment. Frames further outside are dropped from the journey's ends (frames, their GPS and
  detections) with a warning in ``FrameGps.warnings``; the journey is refused when that would leave
  fewer than ``MIN_COVERED_FRACTION`` of its frames or fewer than ``MIN_COVERED_FRAMES`` (a short
  journey that the GPS covers entirely is fine);
* ``accuracy_m`` (this project's extension; the contract ignores extra columns) may give a fix's
  horizontal accuracy as receivers state it: the radius of 68 % confidence, metres (Android's
  ``Location.getAccuracy``, iOS's ``horizontalAccuracy``). A receiver smooths its fixes, so the
  error common to a whole stretch (metres for a standalone receiver) does not show in their
  scatter; the stated accuracy is the only evidence of it (``FrameGps.accuracy_m``);
* ``alt_m`` may be absent or empty: altitude is interpolated over the fixes that have one, held at
  the end value within the same bound outside their span (GPS altitude is too noisy to extrapolate a
  slope from), and NaN beyond.

``gps.gpx`` (every ``<trkpt lat lon>`` with a ``<time>``, optional ``<ele>``, in document order;
a time without an offset is taken as UTC): when there are exactly as many track points as frames,
point i is frame i (a pairing: the frames' own times are not needed). Otherwise frames are placed
on the track by time, never spread over it: each frame's UTC time (``frame_utc_s``, worked out by
``gps_exif.frame_times_utc_s`` from the manifest's ``captured_at`` + i / ``frame_rate_hz``, or the
frames' EXIF DateTimeOriginal; ``gps_time_offset_s`` added) is interpolated on the track like a
``gps.csv`` frame on its fixes (same extrapolation bound, ends dropped the same way). A bundle
whose frames have no time is refused. Timestamps are seconds since the first track point.

Plausibility: positions may not move more than ``MAX_JUMP_M`` faster than ``MAX_SPEED_MPS`` between
consecutive fixes or consecutive frames (a car cannot; GPS noise does not jump that far).
"""

from __future__ import annotations

import io
import math
import xml.etree.ElementTree as ET
from array import array
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta, timezone
from typing import BinaryIO, Sequence

import numpy as np
from pyproj import Geod

from app.pipeline.bundle.csv_table import check_text, iter_table, parse_float
from app.pipeline.geometry.gps_noise import white_noise_m
from app.pipeline.types import BundleError

EXTRAPOLATION_MIN_S = 1.5  # extrapolation bound: max(MIN, FIX_INTERVALS x median interval), <= MAX
EXTRAPOLATION_FIX_INTERVALS = 1.5
EXTRAPOLATION_MAX_S = 3.0
MIN_VELOCITY_BASELINE_S = 0.05  # fixes closer than a 20 Hz receiver's are a duplicate, not motion
MIN_COVERED_FRACTION = 0.5
MIN_COVERED_FRAMES = 10
MAX_JUMP_M = 100.0
MAX_SPEED_MPS = 100.0
MAX_ACCURACY_M = 1000.0  # a stated accuracy beyond this is no fix worth the name
# Altitudes a vehicle's receiver can report (the Dead Sea shore is at -430 m, ellipsoidal heights
# differ from sea level by at most ~110 m; aircraft stay below 20 km). Beyond them a value is no
# altitude, and one such as 1e308 turned the job's fits into NaN.
MIN_ALT_M, MAX_ALT_M = -1000.0, 20000.0
# Timestamps are seconds from any origin, Unix time included (1.7e9 today), before it too (the
# contract sets no sign); larger is no clock it means (milliseconds, or an overflow that breaks the
# interpolation).
MAX_TIMESTAMP_S = 1e10


@dataclass(frozen=True)
class GpsFixes:
    """Position fixes in time order; arrays of shape (M,), ``alt_m`` NaN where unknown.
    ``labels`` name each fix's origin for messages ("row 7", "track point 3")."""

    timestamp_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    labels: Sequence[str]
    accuracy_m: np.ndarray | None = None  # (M,) stated 68 % horizontal radius, NaN where none


@dataclass(frozen=True)
class GpsLog:
    """A GPS log with absolute times (NMEA, GPX, a video's own track), before it meets frames.

    ``fixes.timestamp_s`` counts from ``t0_utc`` (aware, UTC). ``notes`` are report lines on what
    was read and skipped ("3 lines with a bad checksum skipped")."""

    fixes: GpsFixes
    t0_utc: datetime
    source: str  # the file or track it came from, for messages ("gps.nmea", "GoPro GPMF")
    notes: tuple[str, ...] = ()


class NumberedLabels(Sequence[str]):
    """``prefix`` + number, made when a message needs one (not a string kept per fix)."""

    def __init__(self, prefix: str, numbers: np.ndarray):
        self._prefix, self._numbers = prefix, numbers

    def __len__(self) -> int:
        return len(self._numbers)

    def __getitem__(self, i):
        return f"{self._prefix} {self._numbers[i]}"


@dataclass(frozen=True)
class FrameGps:
    """Per-frame time (s) and WGS84 position, arrays aligned with ``frame_ids[kept]`` (all frames
    unless some lay too far outside the GPS fixes); ``warnings`` say which were dropped."""

    timestamp_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    kept: slice = field(default_factory=lambda: slice(None))
    warnings: tuple[str, ...] = ()
    fixes: GpsFixes | None = None  # the fixes they came from (None: EXIF, one per frame)

    @property
    def noise_m(self) -> float | None:
        """White-noise sigma of the fixes (geometry.gps_noise); computed on demand, so the
        API's upload validation, which never asks, does not pay for it."""
        if self.fixes is None:
            return None
        return white_noise_m(self.fixes.timestamp_s, self.fixes.lat_deg, self.fixes.lon_deg)

    @property
    def accuracy_m(self) -> float | None:
        """The median horizontal accuracy (68 % radius, m) the fixes state, None when none does."""
        stated = None if self.fixes is None else self.fixes.accuracy_m
        if stated is None or not np.isfinite(stated).any():
            return None
        return float(np.median(stated[np.isfinite(stated)]))


def check_altitude(alt_m: float, where: str) -> None:
    if not MIN_ALT_M <= alt_m <= MAX_ALT_M:
        raise BundleError(f"{where}: altitude {alt_m:g} m is outside [{MIN_ALT_M:g}, "
                          f"{MAX_ALT_M:g}] m")


def check_position(lat_deg: float, lon_deg: float, where: str) -> None:
    if not -90.0 <= lat_deg <= 90.0:
        raise BundleError(f"{where}: lat {lat_deg} is outside [-90, 90] degrees")
    if not -180.0 <= lon_deg <= 180.0:
        raise BundleError(f"{where}: lon {lon_deg} is outside [-180, 180] degrees")


def check_frame_times(timestamp_s: np.ndarray, frame_ids: Sequence[str], *, strict: bool) -> None:
    """Frames are ordered by file name; their clock must agree with that order."""
    step = np.diff(timestamp_s)
    bad = np.flatnonzero(step <= 0 if strict else step < 0)
    if bad.size:
        i = int(bad[0])
        raise BundleError(
            f"frame timestamps are not increasing: frame {frame_ids[i + 1]} at "
            f"{timestamp_s[i + 1]:.3f} s comes after frame {frame_ids[i]} at {timestamp_s[i]:.3f} s "
            "(frames are ordered by file name)")


def check_plausible_motion(timestamp_s: np.ndarray, lat_deg: np.ndarray, lon_deg: np.ndarray,
                           labels: Sequence[str]) -> None:
    """Reject the first step that moves > MAX_JUMP_M at > MAX_SPEED_MPS; ``labels`` name points."""
    if len(timestamp_s) < 2:
        return
    _, _, dist_m = Geod(ellps="WGS84").inv(lon_deg[:-1], lat_deg[:-1], lon_deg[1:], lat_deg[1:])
    dist_m = np.asarray(dist_m)
    dt_s = np.diff(timestamp_s)
    jump = (dist_m > MAX_JUMP_M) & (dist_m > MAX_SPEED_MPS * dt_s)
    if np.any(jump):
        i = int(np.flatnonzero(jump)[0])
        raise BundleError(
            f"GPS jumps {dist_m[i]:.0f} m in {dt_s[i]:.2f} s between {labels[i]} and "
            f"{labels[i + 1]}; remove the outlier fix (more than {MAX_JUMP_M:.0f} m at over "
            f"{MAX_SPEED_MPS:.0f} m/s is not a car)")


def extrapolation_bound_s(t_fix_s: np.ndarray) -> float:
    """How far (s) outside the fixes' span a frame may still be placed (module docstring)."""
    median_interval_s = float(np.median(np.diff(t_fix_s))) if len(t_fix_s) > 1 else 0.0
    return min(EXTRAPOLATION_MAX_S,
               max(EXTRAPOLATION_MIN_S, EXTRAPOLATION_FIX_INTERVALS * median_interval_s))


def _interp_extrap(t_query_s: np.ndarray, t_fix_s: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Linear in time inside the fixes; outside, the end pair's velocity continued (np.interp holds
    the end value, which is kept when the pair is too close in time to give a velocity)."""
    out = np.interp(t_query_s, t_fix_s, value)
    if len(t_fix_s) < 2:
        return out
    for end, other, side in ((0, 1, t_query_s < t_fix_s[0]), (-1, -2, t_query_s > t_fix_s[-1])):
        dt_s = t_fix_s[end] - t_fix_s[other]
        if abs(dt_s) >= MIN_VELOCITY_BASELINE_S:
            rate = (value[end] - value[other]) / dt_s
            out[side] = value[end] + rate * (t_query_s[side] - t_fix_s[end])
    return out


def _interp_lon(t_query: np.ndarray, t_fix: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    # Unwrap so a track crossing the antimeridian does not interpolate through lon 0.
    lon_unwrapped = np.unwrap(lon_deg, period=360.0)
    lon = _interp_extrap(t_query, t_fix, lon_unwrapped)
    return (lon + 180.0) % 360.0 - 180.0 if np.any(np.abs(lon) > 180.0) else lon


def _dropped_warning(ids: Sequence[str], gap_s: float, where: str, bound_s: float) -> str:
    span = ids[0] if len(ids) == 1 else f"{ids[0]}-{ids[-1]}"
    return (f"dropped {len(ids)} frame{'s' if len(ids) > 1 else ''} {span} (up to {gap_s:.1f} s "
            f"{where}; frames more than {bound_s:.1f} s outside the GPS fixes cannot be placed)")


def interpolate_to_frames(fixes: GpsFixes, frame_timestamp_s: np.ndarray,
                          frame_ids: Sequence[str]) -> FrameGps:
    """Fixes (time-ordered) -> the frames (increasing times) they cover: interpolated inside the
    fixes' span, extrapolated just outside, frames further out dropped from both ends."""
    t_fix, t_frame = fixes.timestamp_s, np.asarray(frame_timestamp_s, float)
    bound_s = extrapolation_bound_s(t_fix)
    first = int(np.searchsorted(t_frame, t_fix[0] - bound_s, side="left"))
    stop = int(np.searchsorted(t_frame, t_fix[-1] + bound_s, side="right"))
    n_frames, n_kept = len(t_frame), max(0, stop - first)
    if n_kept < n_frames and (n_kept < MIN_COVERED_FRAMES
                              or n_kept < MIN_COVERED_FRACTION * n_frames):
        raise BundleError(
            f"GPS covers only {n_kept} of {n_frames} frames ({100 * n_kept / n_frames:.0f} %): "
            f"the fixes span {t_fix[0]:.3f} .. {t_fix[-1]:.3f} s, the frames {t_frame[0]:.3f} .. "
            f"{t_frame[-1]:.3f} s, and a frame may lie at most {bound_s:.1f} s outside the fixes; "
            f"at least {MIN_COVERED_FRACTION:.0%} of the frames and {MIN_COVERED_FRAMES} frames "
            "must be covered")
    warnings = []
    if first > 0:
        warnings.append(_dropped_warning(frame_ids[:first], t_fix[0] - t_frame[0],
                                         f"before the first GPS fix at {t_fix[0]:.3f} s", bound_s))
    if stop < n_frames:
        warnings.append(_dropped_warning(frame_ids[stop:], t_frame[-1] - t_fix[-1],
                                         f"after the last GPS fix at {t_fix[-1]:.3f} s", bound_s))
    t_kept = t_frame[first:stop]
    lat = _interp_extrap(t_kept, t_fix, fixes.lat_deg)
    lon = _interp_lon(t_kept, t_fix, fixes.lon_deg)
    alt = np.full(len(t_kept), np.nan)
    has_alt = np.isfinite(fixes.alt_m)
    if np.any(has_alt):
        t_alt = t_fix[has_alt]
        inside = (t_kept >= t_alt[0] - bound_s) & (t_kept <= t_alt[-1] + bound_s)
        alt[inside] = np.interp(t_kept[inside], t_alt, fixes.alt_m[has_alt])
    return FrameGps(t_kept, lat, lon, alt, slice(first, stop), tuple(warnings))


def _fixes_to_frames(fixes: GpsFixes, frame_timestamp_s: np.ndarray,
                     frame_ids: Sequence[str]) -> FrameGps:
    bad = np.flatnonzero(np.diff(fixes.timestamp_s) <= 0)
    if bad.size:
        i = int(bad[0])
        raise BundleError(
            f"GPS timestamps are not increasing at {fixes.labels[i + 1]} "
            f"({fixes.timestamp_s[i + 1]:g} after {fixes.timestamp_s[i]:g})")
    check_plausible_motion(fixes.timestamp_s, fixes.lat_deg, fixes.lon_deg, fixes.labels)
    check_frame_times(frame_timestamp_s, frame_ids, strict=True)
    frame_gps = interpolate_to_frames(fixes, frame_timestamp_s, frame_ids)
    check_plausible_motion(frame_gps.timestamp_s, frame_gps.lat_deg, frame_gps.lon_deg,
                           [f"frame {f}" for f in frame_ids[frame_gps.kept]])
    return replace(frame_gps, fixes=fixes)


def gps_from_csv(source: str | BinaryIO, frame_ids: Sequence[str], *,
                 max_rows: int | None = None) -> FrameGps:
    """``gps.csv`` (text, or a binary stream read as it goes) -> per-frame GPS (see the module
    docstring for the rules); more than ``max_rows`` rows is a BundleError."""
    rows = iter_table(source, "gps.csv", ("frame", "timestamp_s", "lat", "lon"),
                      ("alt_m", "accuracy_m"), max_rows=max_rows)
    frame_t: dict[str, tuple[float, int]] = {}
    known = set(frame_ids)
    # Compact columns: a long table costs 40 bytes per fix, not a Python object per value.
    t_fix, lat_fix, lon_fix, alt_fix, acc_fix, rows_fix = (
        array("d"), array("d"), array("d"), array("d"), array("d"), array("q"))
    bad_accuracy: list[int] = []
    for row, (frame, t_text, lat_text, lon_text, alt_text, acc_text) in rows:
        where = f"gps.csv row {row}"
        t = parse_float(t_text, f"{where}: timestamp_s", -MAX_TIMESTAMP_S, MAX_TIMESTAMP_S, " s")
        if frame:
            if frame not in known and frame not in frame_t:
                check_text(frame, f"{where}: frame")
            if frame in frame_t and frame_t[frame][0] != t:
                raise BundleError(f"{where} gives frame {frame} timestamp {t:g}, but row "
                                  f"{frame_t[frame][1]} gave it {frame_t[frame][0]:g}")
            frame_t[frame] = (t, row)
        if not lat_text and not lon_text:
            if not frame:
                raise BundleError(f"{where} has neither a frame nor a position (lat, lon)")
            continue
        lat = parse_float(lat_text, f"{where}: lat")
        lon = parse_float(lon_text, f"{where}: lon")
        check_position(lat, lon, where)
        alt = (parse_float(alt_text, f"{where}: alt_m", MIN_ALT_M, MAX_ALT_M, " m")
               if alt_text else math.nan)
        accuracy = _stated_accuracy_m(acc_text)
        if acc_text and math.isnan(accuracy):
            bad_accuracy.append(row)
        t_fix.append(t), lat_fix.append(lat), lon_fix.append(lon), alt_fix.append(alt)
        acc_fix.append(accuracy), rows_fix.append(row)
    if not t_fix:
        raise BundleError("gps.csv has no GPS fixes (rows with lat and lon)")
    for frame in frame_ids:
        if frame not in frame_t:
            raise BundleError(f"no GPS timestamp for frame {frame}: gps.csv needs a row with "
                              f"frame={frame} and its timestamp_s")
    fixes = GpsFixes(*(np.frombuffer(a, np.float64) for a in (t_fix, lat_fix, lon_fix, alt_fix)),
                     NumberedLabels("row", np.frombuffer(rows_fix, np.int64)),
                     np.frombuffer(acc_fix, np.float64))
    frame_timestamp_s = np.array([frame_t[f][0] for f in frame_ids])
    frame_gps = _fixes_to_frames(fixes, frame_timestamp_s, frame_ids)
    if bad_accuracy:
        # The contract ignores extra columns: a column of that name meaning something else must
        # not refuse a valid bundle, so values that are no accuracy are left out, with a warning.
        frame_gps = replace(frame_gps, warnings=(
            *frame_gps.warnings, f"gps.csv accuracy_m ignored on {len(bad_accuracy)} row(s) "
            f"(first: row {bad_accuracy[0]}): not a horizontal accuracy in metres "
            f"(0 < accuracy_m < {MAX_ACCURACY_M:g})"))
    return frame_gps


def _stated_accuracy_m(text: str) -> float:
    """A stated horizontal accuracy (m), NaN when absent or no plausible accuracy."""
    try:
        value = float(text) if text else math.nan
    except ValueError:
        return math.nan
    return value if 0.0 < value < MAX_ACCURACY_M else math.nan


def parse_iso_time(text: str, where: str) -> datetime:
    """ISO-8601 -> aware datetime; a time without an offset is taken as UTC."""
    try:
        value = datetime.fromisoformat(text.strip())
    except ValueError:
        raise BundleError(f"{where} is {text[:60]!r}, expected an ISO-8601 time such as "
                          "2024-05-01T12:30:00Z") from None
    return value if value.tzinfo else value.replace(tzinfo=timezone.utc)


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def read_gpx(source: bytes | BinaryIO, *, max_points: int | None = None) -> GpsLog:
    """Track points of a GPX 1.0/1.1 document (bytes, or a binary stream parsed as it is read),
    timed from the first point (``t0_utc``). Each point is dropped from the tree once read, so
    memory holds the point's numbers only; more than ``max_points`` is a BundleError."""
    t_s, lats, lons, alts = array("d"), array("d"), array("d"), array("d")
    t0, open_elements = None, []
    try:
        events = ET.iterparse(io.BytesIO(source) if isinstance(source, bytes) else source,
                              events=("start", "end"))
        for event, elem in events:
            if event == "start":
                open_elements.append(elem)
                continue
            open_elements.pop()
            if _local(elem.tag) != "trkpt":
                continue
            n = len(t_s) + 1
            if max_points is not None and n > max_points:
                raise BundleError(f"gps.gpx has more than {max_points} track points, the limit "
                                  "per journey; split the journey into shorter ones")
            where = f"gps.gpx track point {n}"
            lat = parse_float(elem.get("lat", ""), f"{where}: lat")
            lon = parse_float(elem.get("lon", ""), f"{where}: lon")
            check_position(lat, lon, where)
            children = {_local(c.tag): (c.text or "").strip() for c in elem}
            if not children.get("time"):
                raise BundleError(f"{where} has no <time>; every track point needs one")
            when = parse_iso_time(children["time"], f"{where}: time")
            t0 = t0 or when
            t_s.append((when - t0).total_seconds())
            if abs(t_s[-1]) > MAX_TIMESTAMP_S:
                raise BundleError(f"{where}: time {children['time'][:40]!r} is {t_s[-1]:g} s from "
                                  f"the first track point, more than {MAX_TIMESTAMP_S:g} s")
            alts.append(parse_float(children["ele"], f"{where}: ele", MIN_ALT_M, MAX_ALT_M, " m")
                        if children.get("ele") else math.nan)
            lats.append(lat), lons.append(lon)
            elem.clear()
            if open_elements:
                # The parent's finished points (later ones stay referenced).
                del open_elements[-1][:]
    except ET.ParseError as exc:
        raise BundleError(f"gps.gpx is not valid XML: {exc}") from None
    if not t_s:
        raise BundleError("gps.gpx has no track points (<trkpt lat=.. lon=..><time>..</time>)")
    fixes = GpsFixes(*(np.frombuffer(a, np.float64) for a in (t_s, lats, lons, alts)),
                     NumberedLabels("track point", np.arange(1, len(t_s) + 1)))
    return GpsLog(fixes, t0.astimezone(timezone.utc), "gps.gpx")


def parse_gpx(source: bytes | BinaryIO, *, max_points: int | None = None) -> GpsFixes:
    """``read_gpx``'s fixes (``timestamp_s`` relative to the first point)."""
    return read_gpx(source, max_points=max_points).fixes


def gps_from_gpx(source: bytes | BinaryIO | GpsLog, frame_ids: Sequence[str], *,
                 frame_utc_s: np.ndarray | None = None,
                 max_points: int | None = None) -> FrameGps:
    """``gps.gpx`` (bytes, a binary stream, or its ``read_gpx`` log) -> per-frame GPS.

    One track point per frame pairs them; otherwise ``frame_utc_s`` (N,) gives each frame's time
    on the GPS clock, UTC POSIX seconds, and frames are placed on the track by it (module
    docstring). Without it the frames cannot be placed: a BundleError."""
    log = source if isinstance(source, GpsLog) else read_gpx(source, max_points=max_points)
    fixes = log.fixes
    if len(fixes.timestamp_s) == len(frame_ids):
        return _fixes_to_frames(fixes, fixes.timestamp_s.copy(), frame_ids)
    if frame_utc_s is None:
        raise BundleError(
            f"{log.source} has {len(fixes.timestamp_s)} track points for {len(frame_ids)} "
            "frames, so point i cannot be frame i, and the frames have no times to place them on "
            "the track by: give captured_at and frame_rate_hz in manifest.json, or JPEG frames with "
            "EXIF DateTimeOriginal")
    frame_timestamp_s = np.asarray(frame_utc_s, float) - log.t0_utc.timestamp()
    if not np.all(np.abs(frame_timestamp_s) <= MAX_TIMESTAMP_S):  # NaN fails too
        raise BundleError(f"frame times lie more than {MAX_TIMESTAMP_S:g} s from {log.source}'s "
                          "first track point; check captured_at and frame_rate_hz")
    check_frame_times(frame_timestamp_s, frame_ids, strict=True)
    _check_time_overlap(log, frame_timestamp_s)
    return _fixes_to_frames(fixes, frame_timestamp_s, frame_ids)


def _utc_text(log: GpsLog, t_s: float) -> str:
    return (log.t0_utc + timedelta(seconds=float(t_s))).isoformat(timespec="milliseconds")


def _check_time_overlap(log: GpsLog, frame_timestamp_s: np.ndarray) -> None:
    """Frames that miss the track altogether mostly mean a wrong clock: say so in UTC."""
    t_fix = log.fixes.timestamp_s
    bound_s = extrapolation_bound_s(t_fix)
    if frame_timestamp_s[-1] < t_fix[0] - bound_s or frame_timestamp_s[0] > t_fix[-1] + bound_s:
        raise BundleError(
            f"the frames do not lie on the GPS track in time: {log.source} runs from "
            f"{_utc_text(log, t_fix[0])} to {_utc_text(log, t_fix[-1])}, the frames from "
            f"{_utc_text(log, frame_timestamp_s[0])} to {_utc_text(log, frame_timestamp_s[-1])} "
            "(UTC); check captured_at (UTC unless it gives an offset), the frames' EXIF times "
            "and gps_time_offset_s")
