"""GPS that a camera writes into its own video: GoPro GPMF (GPS5, or GPS9 on HERO11+) and Google's
Camera Motion Metadata (CAMM packet types 5 and 6).

PyAV demuxes the metadata track (the other tracks are discarded, so the MP4 demuxer seeks from one
metadata sample to the next instead of reading the video); the payloads are decoded here
(``docs/decisions/embedded-gps-parser.md`` says why no parser library).

Times: a sample's ``timestamp_s`` comes from the container's sample table, which shares the video's
clock, minus the first video frame's time. That is the point of embedded GPS: no clock offset to
estimate. A GPMF payload (about 1 s) holds several GPS samples; they are spread evenly over the
payload's duration, as GoPro's own parser does. UTC (``GpsLog.t0_utc``) comes from the payload's GPS
time when it has one (GPSU, GPS9's per-sample time, CAMM's ``time_gps_epoch``), the median over all
samples, else from the container's ``creation_time``; it never moves a sample on the video's clock.

Quality: samples without a fix (GPSF or GPS9 fix < 2, CAMM type 6 fix type 0) are skipped and
counted in ``notes``; GPSP / GPS9's DOP x ``UERE_M`` becomes ``accuracy_m``, CAMM gives its own
``horizontal_accuracy``. Altitude is passed on as the camera states it: above the WGS84 ellipsoid
for GPS5 (GoPro, gpmf-parser issue 4), above mean sea level when a GPSA says ``MSLV`` (MAX2), which
a note then says; CAMM does not say.
"""

from __future__ import annotations

import math
import re
import struct
from array import array
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import av
import numpy as np

from app.pipeline.bundle.gps import (MAX_ACCURACY_M, MAX_ALT_M, MIN_ALT_M, GpsFixes, GpsLog,
                                     NumberedLabels, check_position)
from app.pipeline.types import BundleError

SOURCE_GPMF, SOURCE_CAMM = "GoPro GPMF", "CAMM"
# 68 % horizontal radius per unit of DOP: a u-blox M8 (GoPro HERO5+) states 2.5 m CEP50 in open sky
# (DOP about 1); for a circular normal error the 68 % radius is 1.28 x CEP50.
UERE_M = 3.2
MIN_FIX = 2  # GPSF / GPS9 fix: 0 no lock, 2 2D, 3 3D
# CAMM's time_gps_epoch is GPS time (no leap seconds); GPS - UTC has been 18 s since 2017-01-01.
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)
GPS_MINUS_UTC_S = 18.0
GPS9_EPOCH = datetime(2000, 1, 1, tzinfo=timezone.utc)

# GPMF type characters -> numpy dtypes (big-endian); 'q'/'Q' are fixed point, scaled below.
_GPMF_DTYPES = {"b": ">i1", "B": ">u1", "c": "S1", "d": ">f8", "f": ">f4", "F": "S4", "G": "S16",
                "j": ">i8", "J": ">u8", "l": ">i4", "L": ">u4", "q": ">i4", "Q": ">i8",
                "s": ">i2", "S": ">u2", "U": "S16"}
_FIXED_POINT_DIVISOR = {"q": 65536.0, "Q": 4294967296.0}
_FOURCC = re.compile(rb"[A-Za-z0-9 ]{4}")

# CAMM packet type -> payload size (bytes, little-endian), from the CAMM spec.
_CAMM_SIZES = {0: 12, 1: 8, 2: 12, 3: 12, 4: 12, 5: 24, 6: 56, 7: 12}
_CAMM5 = struct.Struct("<3d")  # latitude, longitude, altitude
# time_gps_epoch, fix type, lat, lon, alt, h/v accuracy, velocity east/north/up, speed accuracy
_CAMM6 = struct.Struct("<di2d7f")


class _Corrupt(Exception):
    """A payload that does not decode; turned into a BundleError naming the track and payload."""


@dataclass(frozen=True)
class _Payload:
    """One metadata sample (GPMF payload, CAMM packet): its time span on the video clock (s) and
    the GPS samples it holds, arrays of shape (n,); ``utc_s`` is each sample's GPS time as seconds
    after ``GPS_EPOCH`` (NaN where the payload gives none), ``fix`` -1 where unknown."""

    t_in_s: float
    duration_s: float | None
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    accuracy_m: np.ndarray
    fix: np.ndarray
    utc_s: np.ndarray
    msl: bool = False


def read_embedded_gps(video_path: Path, *, max_points: int | None = None) -> GpsLog | None:
    """The GPS track inside a video (GoPro GPMF or CAMM), timestamps on the video's clock (seconds
    since its first frame); None when the video has none. A damaged track, a file that is not a
    video, or more than ``max_points`` fixes is a BundleError."""
    name = Path(video_path).name
    try:
        container = av.open(str(video_path), "r")
    except (av.FFmpegError, OSError, UnicodeDecodeError) as exc:
        raise BundleError(f"{name} is not a video file that can be read ({_reason(exc)}); "
                          "upload the camera's original MP4/MOV") from None
    with container:
        videos = [s for s in container.streams.video
                  if not s.disposition & av.stream.Disposition.attached_pic]
        if not videos:
            raise BundleError(f"{name} has no video stream; upload the camera's original MP4/MOV")
        video = videos[0]
        t_video0_s = _seconds(video.start_time or 0, video.time_base)
        data_streams = list(container.streams.data)
        if not data_streams:
            return None
        for stream in container.streams:
            if stream not in data_streams:
                # The MP4 demuxer then skips their samples on disk, not only in the output.
                stream.discard = av.stream.Discard.all
        payloads = _demux_gps(container, data_streams, t_video0_s, name, max_points)
        if payloads is None:
            return None
        source, stream_index, decoded = payloads
        creation_time = container.metadata.get("creation_time")
    return _to_log(decoded, source, stream_index, name, creation_time, max_points)


def _reason(exc: BaseException) -> str:
    return str(getattr(exc, "strerror", None) or exc)[:200]


def _seconds(ticks: int, time_base: Fraction | None) -> float:
    return float(ticks * (time_base or Fraction(1)))


def _demux_gps(container, data_streams, t_video0_s: float, name: str, max_points: int | None
               ) -> tuple[str, int, list[_Payload]] | None:
    """One pass over the metadata tracks: each is told GPMF, CAMM or neither by its handler name
    and first payload, then decoded as it streams past. The first track that holds GPS wins."""
    kinds: dict[int, str | None] = {}
    decoded: dict[int, list[_Payload]] = {}
    counts: dict[int, int] = {}
    payload_no: dict[int, int] = {}
    try:
        for packet in container.demux(*data_streams):
            stream = packet.stream
            if packet.size == 0 or (packet.pts is None and packet.dts is None):
                continue
            data = bytes(packet)
            idx = stream.index
            if idx not in kinds:
                kinds[idx] = _kind(stream, data)
            kind = kinds[idx]
            if kind is None:
                continue
            payload_no[idx] = payload_no.get(idx, 0) + 1
            t_in_s = _seconds(packet.pts if packet.pts is not None else packet.dts,
                              packet.time_base) - t_video0_s
            duration_s = _seconds(packet.duration, packet.time_base) if packet.duration else None
            try:
                payload = (_decode_gpmf if kind == SOURCE_GPMF else _decode_camm)(
                    data, t_in_s, duration_s)
            except (_Corrupt, ValueError, IndexError, struct.error) as exc:
                raise BundleError(
                    f"{name}: the {kind} GPS track (stream {idx}) is damaged: payload "
                    f"{payload_no[idx]} at {t_in_s:.3f} s: {exc}; upload the camera's original "
                    "file, or give the GPS as gps.csv / gps.gpx") from None
            if payload is None:
                continue
            decoded.setdefault(idx, []).append(payload)
            # Only fixes count: a camera waiting minutes for a lock is no longer journey.
            counts[idx] = counts.get(idx, 0) + int(np.sum(~((payload.fix >= 0)
                                                            & (payload.fix < MIN_FIX))))
            if max_points is not None and counts[idx] > max_points:
                raise _too_many(name, kind, max_points)
    except av.FFmpegError as exc:
        raise BundleError(f"{name}: reading its metadata tracks failed ({_reason(exc)}); the file "
                          "is damaged or truncated, upload the camera's original file") from None
    for idx, payloads in decoded.items():
        if payloads:
            return kinds[idx], idx, payloads
    return None


def _too_many(name: str, kind: str, max_points: int) -> BundleError:
    return BundleError(f"{name}: the {kind} GPS track has more than {max_points} fixes, the limit "
                       "per journey; split the journey into shorter ones")


def _kind(stream, first: bytes) -> str | None:
    handler = stream.metadata.get("handler_name", "").strip().lower()
    if first.startswith(b"DEVC") or "gopro met" in handler:
        return SOURCE_GPMF
    if "camm" in handler or "cameramotionmetadata" in handler or _looks_like_camm(first):
        return SOURCE_CAMM
    return None


def _looks_like_camm(data: bytes) -> bool:
    # A CAMM packet is one record (reserved 0, type, fixed-size payload); a timecode or vendor
    # track rarely has exactly that shape.
    if len(data) < 4 or data[:2] != b"\0\0":
        return False
    kind = int.from_bytes(data[2:4], "little")
    return kind in _CAMM_SIZES and len(data) % (4 + _CAMM_SIZES[kind]) == 0


# -- GPMF ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Klv:
    key: bytes
    type_char: str
    struct_size: int
    repeat: int
    data: bytes


def _klvs(buf: bytes) -> Iterator[_Klv]:
    pos = 0
    while pos + 8 <= len(buf):
        key = buf[pos:pos + 4]
        if key == b"\0\0\0\0":  # padding to the payload's end
            return
        if not _FOURCC.fullmatch(key):
            raise _Corrupt(f"bad GPMF key {key!r} at byte {pos}")
        type_byte, struct_size, repeat = buf[pos + 4], buf[pos + 5], int.from_bytes(
            buf[pos + 6:pos + 8], "big")
        size = struct_size * repeat
        end = pos + 8 + size
        if end > len(buf):
            raise _Corrupt(f"{key.decode()} claims {size} bytes, past the payload's end")
        yield _Klv(key, chr(type_byte) if type_byte else "\0", struct_size, repeat,
                   buf[pos + 8:end])
        pos += 8 + ((size + 3) & ~3)
    if any(buf[pos:]):
        raise _Corrupt(f"{len(buf) - pos} stray bytes at the payload's end")


def _values(klv: _Klv, type_chars: str | None = None) -> np.ndarray:
    """A KLV's samples as float64, shape (repeat, elements); ``type_chars`` for a '?' structure."""
    if klv.type_char == "?":
        if not type_chars:
            raise _Corrupt(f"{klv.key.decode()} is a structure without a TYPE")
        dtype = np.dtype([(f"f{i}", _dtype(c)) for i, c in enumerate(type_chars)])
        if dtype.itemsize != klv.struct_size:
            raise _Corrupt(f"{klv.key.decode()}: TYPE {type_chars!r} is {dtype.itemsize} bytes, "
                           f"the samples {klv.struct_size}")
        rows = np.frombuffer(klv.data, dtype)
        return np.stack([rows[f].astype(np.float64) / _FIXED_POINT_DIVISOR.get(c, 1.0)
                         for f, c in zip(dtype.names, type_chars)], axis=1)
    dtype = _dtype(klv.type_char)
    if klv.struct_size % dtype.itemsize:
        raise _Corrupt(f"{klv.key.decode()}: samples of {klv.struct_size} bytes are no whole "
                       f"number of {klv.type_char!r} values")
    flat = np.frombuffer(klv.data, dtype).astype(np.float64)
    flat /= _FIXED_POINT_DIVISOR.get(klv.type_char, 1.0)
    return flat.reshape(klv.repeat, klv.struct_size // dtype.itemsize)


def _dtype(type_char: str) -> np.dtype:
    if type_char not in _GPMF_DTYPES or type_char in "cFGU":
        raise _Corrupt(f"GPMF type {type_char!r} is not a number")
    return np.dtype(_GPMF_DTYPES[type_char])


def _text(klv: _Klv) -> str:
    return klv.data.split(b"\0", 1)[0].decode("latin-1").strip()


def _gpsu_s(klv: _Klv | None) -> float:
    """GPSU ``yymmddhhmmss.sss`` (UTC) -> seconds after GPS_EPOCH (UTC scale); NaN if unreadable."""
    if klv is None:
        return math.nan
    try:
        when = datetime.strptime(_text(klv), "%y%m%d%H%M%S.%f").replace(tzinfo=timezone.utc)
    except ValueError:
        return math.nan
    return (when - GPS_EPOCH).total_seconds()


def _decode_gpmf(payload: bytes, t_in_s: float, duration_s: float | None) -> _Payload | None:
    """A GPMF payload's GPS stream: GPS9 when the payload has one (per-sample time, DOP and fix),
    else GPS5 with the stream's GPSF / GPSP / GPSU."""
    streams: list[list[_Klv]] = []
    for devc in _klvs(payload):
        if devc.key == b"DEVC" and devc.type_char == "\0":
            for strm in _klvs(devc.data):
                if strm.key == b"STRM" and strm.type_char == "\0":
                    items = list(_klvs(strm.data))
                    if any(k.key in (b"GPS5", b"GPS9") for k in items):
                        streams.append(items)
    if not streams:
        return None
    gps9 = [s for s in streams if any(k.key == b"GPS9" for k in s)]
    items = gps9[0] if gps9 else streams[0]
    by_key = {k.key: k for k in items}
    data = by_key[b"GPS9" if gps9 else b"GPS5"]
    if b"SCAL" not in by_key:
        raise _Corrupt(f"{data.key.decode()} has no SCAL (its scale)")
    type_klv = by_key.get(b"TYPE")
    raw = _values(data, _text(type_klv) if type_klv else None)
    scale = _values(by_key[b"SCAL"]).ravel()
    if (raw.shape[1] < (9 if gps9 else 3) or scale.size not in (1, raw.shape[1])
            or np.any(scale == 0)):
        raise _Corrupt(f"{data.key.decode()} has {raw.shape[1]} values per sample and "
                       f"{scale.size} scales")
    values = raw / scale
    n = len(values)
    msl = b"GPSA" in by_key and _text(by_key[b"GPSA"]).upper().startswith("MSL")
    if gps9:
        dop = values[:, 7]
        fix = values[:, 8]
        utc_s = (GPS9_EPOCH - GPS_EPOCH).total_seconds() + values[:, 5] * 86400.0 + values[:, 6]
    else:
        dop = np.full(n, _values(by_key[b"GPSP"])[0, 0] / 100.0 if b"GPSP" in by_key else math.nan)
        fix = np.full(n, _values(by_key[b"GPSF"])[0, 0] if b"GPSF" in by_key else -1.0)
        # GPSU is the UTC of the payload's first sample; the others follow at the payload's pace.
        utc_s = np.full(n, _gpsu_s(by_key.get(b"GPSU")))
        if duration_s:
            utc_s += np.arange(n) * (duration_s / n)
    with np.errstate(invalid="ignore"):
        accuracy = np.where(dop > 0, dop * UERE_M, np.nan)
    return _Payload(t_in_s, duration_s, values[:, 0], values[:, 1], values[:, 2], accuracy, fix,
                    utc_s, msl)


# -- CAMM ------------------------------------------------------------------------------------------

def _decode_camm(packet: bytes, t_in_s: float, duration_s: float | None) -> _Payload | None:
    """A CAMM sample: one record (more are read too, spread over the sample's duration); only
    types 5 and 6 carry GPS."""
    lat, lon, alt, acc, fix, utc = (array("d") for _ in range(6))
    pos = 0
    while pos < len(packet):
        if pos + 4 > len(packet):
            raise _Corrupt(f"{len(packet) - pos} stray bytes after the last record")
        reserved, kind = struct.unpack_from("<HH", packet, pos)
        if reserved != 0 or kind not in _CAMM_SIZES:
            raise _Corrupt(f"unknown CAMM record (reserved {reserved}, type {kind}) at byte {pos}")
        body = pos + 4
        pos = body + _CAMM_SIZES[kind]
        if pos > len(packet):
            raise _Corrupt(f"CAMM type {kind} record cut short")
        if kind == 5:
            la, lo, al = _CAMM5.unpack_from(packet, body)
            lat.append(la), lon.append(lo), alt.append(al)
            acc.append(math.nan), fix.append(-1.0), utc.append(math.nan)
        elif kind == 6:
            t_gps, fix_type, la, lo, al, h_acc, *_ = _CAMM6.unpack_from(packet, body)
            lat.append(la), lon.append(lo), alt.append(al)
            acc.append(h_acc), fix.append(MIN_FIX if fix_type > 0 else 0)
            utc.append(t_gps - GPS_MINUS_UTC_S if t_gps > 0 else math.nan)
    if not lat:
        return None
    return _Payload(t_in_s, duration_s, *(np.frombuffer(a, np.float64)
                                          for a in (lat, lon, alt, acc, fix, utc)))


# -- to a GpsLog -----------------------------------------------------------------------------------

def _sample_times_s(payloads: list[_Payload]) -> np.ndarray:
    """Each sample's time on the video clock: spread evenly over its payload's duration (a payload
    without one lasts until the next payload starts, the last one as long as the one before)."""
    t_in = np.array([p.t_in_s for p in payloads])
    durations = np.array([p.duration_s or math.nan for p in payloads])
    gaps = np.append(np.diff(t_in), math.nan)
    durations = np.where(np.isfinite(durations), durations, gaps)
    if len(durations) > 1 and not np.isfinite(durations[-1]):
        durations[-1] = durations[-2]
    durations = np.where(np.isfinite(durations) & (durations > 0), durations, 0.0)
    return np.concatenate([t + np.arange(len(p.lat_deg)) * (d / len(p.lat_deg))
                           for p, t, d in zip(payloads, t_in, durations)])


def _to_log(payloads: list[_Payload], source: str, stream_index: int, name: str,
            creation_time: str | None, max_points: int | None) -> GpsLog:
    t_s = _sample_times_s(payloads)
    lat, lon, alt, acc, fix, utc = (np.concatenate([getattr(p, f) for p in payloads]) for f in
                                    ("lat_deg", "lon_deg", "alt_m", "accuracy_m", "fix", "utc_s"))
    numbers = np.arange(1, len(t_s) + 1)
    notes: list[str] = []
    track = f"{name} {source} track"
    no_fix = (fix >= 0) & (fix < MIN_FIX)
    if no_fix.all():
        raise BundleError(f"{track}: none of its {len(t_s)} GPS samples has a fix (the camera "
                          "never locked on to satellites); give the GPS as gps.csv or gps.gpx")
    if no_fix.any():
        notes.append(f"{track}: {int(no_fix.sum())} of {len(t_s)} GPS samples without a fix "
                     "skipped")
    keep = ~no_fix
    # Duplicate times (a payload repeating the last fix, a zero-length payload) are no new fix.
    kept_idx = np.flatnonzero(keep)
    running_max = np.maximum.accumulate(t_s[kept_idx])
    repeated = np.zeros(len(kept_idx), bool)
    repeated[1:] = t_s[kept_idx][1:] <= running_max[:-1]
    if repeated.any():
        notes.append(f"{track}: {int(repeated.sum())} GPS samples at a time already seen dropped")
        keep[kept_idx[repeated]] = False
    if max_points is not None and keep.sum() > max_points:
        raise _too_many(name, source, max_points)
    t_s, lat, lon, alt, acc, utc, numbers = (a[keep] for a in
                                             (t_s, lat, lon, alt, acc, utc, numbers))
    labels = NumberedLabels(f"{track} sample", numbers)
    for i in np.flatnonzero(~((np.abs(lat) <= 90.0) & (np.abs(lon) <= 180.0))):
        check_position(float(lat[i]), float(lon[i]), f"{labels[i]} at {t_s[i]:.3f} s")
    bad_alt = ~((alt >= MIN_ALT_M) & (alt <= MAX_ALT_M))
    if bad_alt.any():
        notes.append(f"{track}: altitude ignored on {int(bad_alt.sum())} fixes (outside "
                     f"[{MIN_ALT_M:g}, {MAX_ALT_M:g}] m)")
        alt = np.where(bad_alt, np.nan, alt)
    acc = np.where((acc > 0) & (acc < MAX_ACCURACY_M), acc, np.nan)
    if any(p.msl for p in payloads):
        notes.append(f"{track}: altitude is above mean sea level (GPSA MSLV), not the ellipsoid")
    t0_utc = _t0_utc(t_s, utc, creation_time, track, notes)
    return GpsLog(GpsFixes(t_s, lat, lon, alt, labels, acc if np.isfinite(acc).any() else None),
                  t0_utc, source, tuple(notes))


def _t0_utc(t_s: np.ndarray, utc_s: np.ndarray, creation_time: str | None, track: str,
            notes: list[str]) -> datetime:
    """UTC of the video's first frame: the median of (GPS time - video time) over the samples that
    have a GPS time (one late GPSU does not move it), else the container's creation_time."""
    has = np.isfinite(utc_s)
    if has.any():
        offset_s = float(np.median(utc_s[has] - t_s[has]))
        return GPS_EPOCH + timedelta(seconds=offset_s)
    if creation_time:
        try:
            when = datetime.fromisoformat(creation_time.replace("Z", "+00:00"))
        except ValueError:
            when = None
        if when is not None:
            notes.append(f"{track}: no GPS time in the track, UTC from the file's creation time")
            return when if when.tzinfo else when.replace(tzinfo=timezone.utc)
    raise BundleError(f"{track} gives no time of day (no GPS time, no creation_time); give the GPS "
                      "as gps.csv or gps.gpx")
