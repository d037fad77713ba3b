"""Small video bundles, valid and broken, for the upload checks (here and in the service's
bad-input corpus). The video is a few seconds of noise at 10 fps: enough for a container, a
decoder and a GPS log to be checked, not for the pipeline."""

from __future__ import annotations

import io
import json
import tempfile
import zipfile
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from app.synth.video.encode import write_video
from app.synth.video.gps_logs import nmea_log

START_UTC = datetime(2024, 5, 1, 12, 0, 0, tzinfo=timezone.utc)
MANIFEST = {"format": "signmap-journey/1", "camera_id": "dashcam-test"}
N_FRAMES, FPS = 40, 10.0
SIZE = (320, 240)


def tiny_video(n_frames: int = N_FRAMES, size: tuple[int, int] = SIZE,
               creation_utc: datetime | None = START_UTC) -> bytes:
    rng = np.random.default_rng(0)
    frames = (rng.integers(0, 255, (size[1], size[0], 3), np.uint8) for _ in range(n_frames))
    with tempfile.TemporaryDirectory() as tmp:
        path = write_video(frames, np.arange(n_frames) / FPS, Path(tmp) / "v.mp4",
                           creation_utc=creation_utc, fps=FPS)
        return path.read_bytes()


def nmea(start_utc: datetime = START_UTC - timedelta(seconds=2), seconds: int = 10) -> str:
    """1 Hz fixes of a car driving north at 10 m/s from ``start_utc``."""
    t = np.arange(seconds + 1, dtype=float)
    lat = 48.0 + t * 10.0 / 111_200.0
    return nmea_log(start_utc, t, lat, np.full_like(t, 11.0), np.full_like(t, 500.0))


def bundle(members: dict[str, bytes | str], manifest: dict | None = None,
           compress_type: int = zipfile.ZIP_STORED) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        z.writestr("manifest.json", json.dumps(manifest or MANIFEST))
        for name, data in members.items():
            z.writestr(name, data, compress_type=compress_type)
    return out.getvalue()


def valid() -> bytes:
    return bundle({"video.mp4": tiny_video(), "gps.nmea": nmea()})


def deflated() -> bytes:
    return bundle({"video.mp4": tiny_video(), "gps.nmea": nmea()}, compress_type=zipfile.ZIP_DEFLATED)


def not_a_video() -> bytes:
    return bundle({"video.mp4": b"\x00\x00\x00\x18ftypisom" + b"garbage" * 1000,
                   "gps.nmea": nmea()})


def truncated_container() -> bytes:
    return bundle({"video.mp4": tiny_video()[:2000], "gps.nmea": nmea()})


def no_decodable_frame() -> bytes:
    """A well-formed container whose H.264 payload is zeros."""
    data = bytearray(tiny_video())
    start = data.find(b"mdat") + 4
    size = int.from_bytes(data[start - 8:start - 4], "big") - 8
    data[start:start + size] = bytes(size)
    return bundle({"video.mp4": bytes(data), "gps.nmea": nmea()})


def two_videos() -> bytes:
    video = tiny_video()
    return bundle({"video.mp4": video, "video.mov": video, "gps.nmea": nmea()})


def video_and_frames() -> bytes:
    return bundle({"video.mp4": tiny_video(), "frames/000000.png": b"", "gps.nmea": nmea()})


def gps_a_day_later() -> bytes:
    return bundle({"video.mp4": tiny_video(), "gps.nmea": nmea(START_UTC + timedelta(days=1))})


def garbage_nmea() -> bytes:
    lines = "".join(f"$GPRMC,garbage,{i}*00\r\n" for i in range(50))
    return bundle({"video.mp4": tiny_video(), "gps.nmea": lines})


def no_gps() -> bytes:
    return bundle({"video.mp4": tiny_video()})
