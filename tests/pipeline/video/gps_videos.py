"""Small real MP4s that carry GPS the way cameras write it: a GoPro GPMF track (GPS5 + GPSU / GPSF /
GPSP, one payload per second) or a CAMM track (one packet of type 5 or 6 per fix), beside a few tiny
H.264 frames; and a video without GPS.

PyAV muxes the metadata track (FFmpeg writes a ``bin_data`` stream as GoPro's ``gpmd`` track,
handler "GoPro MET"). FFmpeg cannot write CAMM, so the CAMM file is that same MP4 with the track's
handler type and sample entry renamed to ``camm`` in place (same sizes, no offsets move).
"""

from __future__ import annotations

import struct
from datetime import datetime, timedelta, timezone
from fractions import Fraction
from pathlib import Path
from typing import Sequence

import av
import numpy as np

DATA_TIME_BASE = Fraction(1, 1000)
CREATION_TIME = datetime(2024, 5, 1, 12, 0, 0, tzinfo=timezone.utc)
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)
GPS_MINUS_UTC_S = 18.0


def write_video(path: Path, duration_s: float = 2.0, *, fps: int = 5,
                data_packets: Sequence[tuple[float, float, bytes]] = (),
                creation_time: datetime | None = CREATION_TIME) -> Path:
    """An MP4 of ``duration_s`` at ``fps`` (16x16 px H.264) and, when ``data_packets`` are given
    as (t_s, duration_s, payload), a metadata track holding them at those times (ms clock)."""
    with av.open(str(path), "w", format="mp4") as out:
        if creation_time is not None:
            out.metadata["creation_time"] = creation_time.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        video = out.add_stream("libx264", rate=fps)
        video.width = video.height = 16
        video.pix_fmt = "yuv420p"
        data = out.add_data_stream("bin_data") if data_packets else None
        if data is not None:
            data.time_base = DATA_TIME_BASE
        frames = [(i / fps, "v", i) for i in range(max(1, round(duration_s * fps)))]
        meta = [(t, "d", k) for k, (t, _, _) in enumerate(data_packets)]
        for t, what, k in sorted(frames + meta):
            if what == "v":
                frame = av.VideoFrame.from_ndarray(np.full((16, 16, 3), 8 * k % 256, np.uint8),
                                                   format="rgb24")
                frame.pts = k
                out.mux(video.encode(frame))
            else:
                t_s, dur_s, payload = data_packets[k]
                packet = av.Packet(payload)
                packet.stream = data
                packet.time_base = DATA_TIME_BASE
                packet.pts = packet.dts = round(t_s * 1000)
                packet.duration = round(dur_s * 1000)
                out.mux(packet)
        out.mux(video.encode())
    return path


# -- GPMF --------------------------------------------------------------------------------------

def klv(key: bytes, type_char: str, struct_size: int, repeat: int, data: bytes) -> bytes:
    """One GPMF key-length-value, padded to 32 bits."""
    header = key + type_char.encode() + bytes([struct_size]) + repeat.to_bytes(2, "big")
    return header + data + b"\0" * (-len(data) % 4)


def nest(key: bytes, *children: bytes) -> bytes:
    body = b"".join(children)
    return klv(key, "\0", 4, len(body) // 4, body)


def gpmf_payload(lat: np.ndarray, lon: np.ndarray, alt: np.ndarray, *, fix: int = 3,
                 dop: float = 1.5, utc: datetime | None = None, extra: bytes = b"") -> bytes:
    """A one-payload GPMF sample: DEVC > STRM with GPSF, GPSU, GPSP, SCAL and GPS5 (5 x int32:
    lat, lon, alt, 2D and 3D speed, scaled 1e7, 1e7, 1e3, 1e3, 1e2). ``extra`` goes in the STRM
    before the GPS (e.g. a GPSA)."""
    n = len(lat)
    rows = np.stack([np.round(np.asarray(lat) * 1e7), np.round(np.asarray(lon) * 1e7),
                     np.round(np.asarray(alt) * 1e3), np.zeros(n), np.zeros(n)], axis=1)
    gps5 = rows.astype(">i4").tobytes()
    utc_text = (utc.strftime("%y%m%d%H%M%S.%f")[:16] if utc else "000000000000.000").encode()
    stream = nest(
        b"STRM",
        klv(b"STNM", "c", 1, 42, b"GPS (Lat., Long., Alt., 2D speed, 3D speed)"),
        klv(b"GPSF", "L", 4, 1, struct.pack(">I", fix)),
        klv(b"GPSU", "U", 16, 1, utc_text),
        klv(b"GPSP", "S", 2, 1, struct.pack(">H", round(dop * 100))),
        extra,
        klv(b"SCAL", "l", 4, 5, struct.pack(">5i", 10_000_000, 10_000_000, 1000, 1000, 100)),
        klv(b"GPS5", "l", 20, n, gps5),
    )
    accel = nest(b"STRM", klv(b"SCAL", "s", 2, 1, struct.pack(">h", 418)),
                 klv(b"ACCL", "s", 6, 2, struct.pack(">6h", 1, 2, 3, 4, 5, 6)))
    return nest(b"DEVC", klv(b"DVID", "L", 4, 1, struct.pack(">I", 1)),
                klv(b"DVNM", "c", 1, 6, b"Camera"), accel, stream)


def gps9_payload(lat: np.ndarray, lon: np.ndarray, alt: np.ndarray, utc: Sequence[datetime],
                 fix: Sequence[int], *, dop: float = 1.5) -> bytes:
    """A HERO11+ payload: GPS9 samples (TYPE ``lllllllSS``: lat, lon, alt, 2D and 3D speed, days
    since 2000, ms of the day, DOP x 100, fix), each with its own time, DOP and fix."""
    epoch = datetime(2000, 1, 1, tzinfo=timezone.utc)
    rows = b""
    for la, lo, al, when, fx in zip(lat, lon, alt, utc, fix):
        since = when - epoch
        rows += struct.pack(">7l2H", round(la * 1e7), round(lo * 1e7), round(al * 1e3), 0, 0,
                            since.days, round(since.seconds * 1e3 + since.microseconds / 1e3),
                            round(dop * 100), fx)
    stream = nest(
        b"STRM",
        klv(b"STNM", "c", 1, 8, b"GPS9 raw"),
        klv(b"SCAL", "l", 4, 9, struct.pack(">9i", 10_000_000, 10_000_000, 1000, 1000, 100, 1,
                                            1000, 100, 1)),
        klv(b"TYPE", "c", 1, 9, b"lllllllSS"),
        klv(b"GPS9", "?", 32, len(lat), rows),
    )
    return nest(b"DEVC", klv(b"DVNM", "c", 1, 6, b"Camera"), stream)


def write_gpmf_video(path: Path, lat: np.ndarray, lon: np.ndarray, alt: np.ndarray, *,
                     rate_hz: int = 18, fix: Sequence[int] | None = None, dop: float = 1.5,
                     t0_utc: datetime | None = CREATION_TIME, extra: bytes = b"",
                     gps9: bool = False) -> Path:
    """A GoPro-style MP4: fix k at video time k / rate_hz, one GPMF payload per second
    (``rate_hz`` fixes each); ``fix`` gives each payload's GPSF (3 by default); GPSU is
    ``t0_utc`` + the payload's start (none when ``t0_utc`` is None). ``gps9``: GPS9 samples
    instead (HERO11+), each stamped ``t0_utc`` + its video time."""
    n_payloads = -(-len(lat) // rate_hz)
    packets = []
    for i in range(n_payloads):
        part = slice(i * rate_hz, (i + 1) * rate_hz)
        payload_fix = 3 if fix is None else fix[i]
        if gps9:
            n = len(lat[part])
            utc = [t0_utc + timedelta(seconds=i + k / rate_hz) for k in range(n)]
            payload = gps9_payload(lat[part], lon[part], alt[part], utc, [payload_fix] * n,
                                   dop=dop)
        else:
            utc = t0_utc + timedelta(seconds=i) if t0_utc else None
            payload = gpmf_payload(lat[part], lon[part], alt[part], fix=payload_fix, dop=dop,
                                   utc=utc, extra=extra)
        packets.append((float(i), 1.0, payload))
    return write_video(path, n_payloads, data_packets=packets)


# -- CAMM --------------------------------------------------------------------------------------

def camm_type5(lat: float, lon: float, alt: float) -> bytes:
    return struct.pack("<HH3d", 0, 5, lat, lon, alt)


def camm_type6(utc: datetime, fix_type: int, lat: float, lon: float, alt: float,
               horizontal_accuracy_m: float = 4.0) -> bytes:
    t_gps_s = (utc - GPS_EPOCH).total_seconds() + GPS_MINUS_UTC_S
    return struct.pack("<HHdi2d7f", 0, 6, t_gps_s, fix_type, lat, lon, alt,
                       horizontal_accuracy_m, 6.0, 0.0, 0.0, 0.0, 0.5)


def write_camm_video(path: Path, t_s: np.ndarray, lat: np.ndarray, lon: np.ndarray,
                     alt: np.ndarray, *, packet_type: int = 6,
                     fix_type: Sequence[int] | None = None, t0_utc: datetime = CREATION_TIME,
                     accuracy_m: float = 4.0,
                     creation_time: datetime | None = CREATION_TIME) -> Path:
    """A CAMM MP4: one packet per fix at video time ``t_s`` (ms clock): type 6 (GPS time
    ``t0_utc`` + t, ``fix_type`` per fix, 3 by default) or type 5 (position only)."""
    packets = []
    for k, t in enumerate(t_s):
        if packet_type == 5:
            payload = camm_type5(lat[k], lon[k], alt[k])
        else:
            payload = camm_type6(t0_utc + timedelta(seconds=float(t)),
                                 3 if fix_type is None else fix_type[k],
                                 lat[k], lon[k], alt[k], accuracy_m)
        dur = float(t_s[k + 1] - t) if k + 1 < len(t_s) else float(t_s[1] - t_s[0])
        packets.append((float(t), dur, payload))
    write_video(path, float(t_s[-1]) + 0.5, data_packets=packets, creation_time=creation_time)
    return rename_metadata_track(path, b"camm", b"CAMM")


_CONTAINER_BOXES = {b"moov", b"trak", b"mdia", b"minf", b"stbl"}


def _boxes(buf: bytearray, start: int, end: int):
    i = start
    while i + 8 <= end:
        size, kind = struct.unpack_from(">I4s", buf, i)
        header = 8
        if size == 1:
            size, header = struct.unpack_from(">Q", buf, i + 8)[0], 16
        elif size == 0:
            size = end - i
        yield kind, i + header, i + size
        if kind in _CONTAINER_BOXES:
            yield from _boxes(buf, i + header, i + size)
        i += size


def rename_metadata_track(path: Path, fourcc: bytes, handler_name: bytes) -> Path:
    """Rename the GoPro ``meta``/``gpmd`` track in place: handler type and sample entry become
    ``fourcc``, the handler name ``handler_name`` (null-padded to the old name's length)."""
    buf = bytearray(path.read_bytes())
    for kind, body, end in _boxes(buf, 0, len(buf)):
        if kind == b"hdlr" and buf[body + 8:body + 12] == b"meta":
            buf[body + 8:body + 12] = fourcc
            old = end - (body + 24)
            buf[body + 24:end] = handler_name[:old - 1].ljust(old, b"\0")
        if kind == b"stsd" and buf[body + 12:body + 16] == b"gpmd":
            buf[body + 12:body + 16] = fourcc
    path.write_bytes(bytes(buf))
    return path
