"""The container header of a video journey, read without decoding the video (the upload request's
check): codec, size, frame rate, duration, frame count, the camera's ``creation_time``, and whether
the first frame decodes, all bounded by ``BundleLimits`` before the worker spends anything on it.

Frame indices are presentation order from 0, the contract's frame ids as six digits.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import BinaryIO

import av

from app.pipeline.config import BundleLimits
from app.pipeline.types import BundleError

VIDEO_NAMES = ("video.mp4", "video.mov", "video.mkv")
# Packets read to find the first decodable frame: a stream whose first second or two of packets
# yield no picture is broken, and reading further would let the upload decode the whole video.
MAX_PROBE_PACKETS = 120

logging.getLogger("libav").setLevel(logging.ERROR)  # PyAV forwards FFmpeg's warnings to logging


@dataclass(frozen=True)
class VideoHeader:
    """What the container says of its video stream. ``n_frames``: declared by the container or
    estimated from duration x rate (MKV declares none); ``creation_utc``: the camera's clock at the
    first frame, None when the container has no ``creation_time``."""

    name: str
    codec: str
    width: int
    height: int
    fps: float
    duration_s: float
    n_frames: int
    creation_utc: datetime | None
    data_handlers: tuple[str, ...] = ()  # handler names of data streams, lower case ("gopro met")

    def frame_id(self, index: int) -> str:
        return f"{index:06d}"


def _creation_time(container) -> datetime | None:
    stamps = [container.metadata.get("creation_time")]
    stamps += [s.metadata.get("creation_time") for s in container.streams]
    for text in filter(None, stamps):
        try:
            value = datetime.fromisoformat(text.replace("Z", "+00:00"))
        except ValueError:
            continue
        # MP4 stores UTC seconds since 1904; a zero field reads as 1904 or 1970: no clock set.
        if value.year >= 2000:
            return value if value.tzinfo else value.replace(tzinfo=timezone.utc)
    return None


def _first_frame_decodes(container, stream) -> bool:
    try:
        for n, packet in enumerate(container.demux(stream)):
            if n >= MAX_PROBE_PACKETS:
                return False
            for _ in packet.decode():
                return True
        # Flush: a stream of few packets holds its frames in the decoder until the end.
        for _ in stream.codec_context.decode(None):
            return True
    except (av.FFmpegError, ValueError):
        return False
    return False


def probe_video(source: Path | BinaryIO, name: str, limits: BundleLimits, *,
                decode_first: bool = True) -> VideoHeader:
    """Read the header of the video ``source`` (a path or a seekable stream) named ``name`` in the
    bundle; BundleError unless it is a video within ``limits`` (and, with ``decode_first``, its
    first frame decodes)."""
    not_video = BundleError(f"{name} is not a video this service can read (or a corrupt one); "
                            "upload the camera's MP4, MOV or MKV file as recorded")
    try:
        container = av.open(source if isinstance(source, str) else
                            str(source) if isinstance(source, Path) else source, "r")
    except (av.FFmpegError, ValueError, OSError):
        raise not_video from None
    with container:
        if not container.streams.video:
            raise BundleError(f"{name} has no video stream")
        stream = container.streams.video[0]
        ctx = stream.codec_context
        width, height = int(ctx.width or 0), int(ctx.height or 0)
        if width <= 0 or height <= 0:
            raise not_video
        if width * height > limits.max_frame_pixels:
            raise BundleError(f"{name} is {width}x{height}, more than the limit of "
                              f"{limits.max_frame_pixels} pixels ({limits.max_frame_pixels / 1e6:.1f} "
                              "megapixels) per frame")
        rate = stream.average_rate or stream.guessed_rate or stream.base_rate
        fps = float(rate) if rate else 0.0
        if stream.duration is not None and stream.time_base is not None:
            duration_s = float(stream.duration * stream.time_base)
        else:
            duration_s = (container.duration or 0) / av.time_base
        if not (fps > 0 and math.isfinite(fps)) or not (duration_s > 0):
            raise BundleError(f"{name} declares no frame rate or duration; the container is "
                              "incomplete (was the recording cut off?)")
        n_frames = int(stream.frames) or math.ceil(duration_s * fps)
        if duration_s > limits.max_video_s:
            raise BundleError(f"{name} lasts {duration_s:.0f} s, more than the limit of "
                              f"{limits.max_video_s:.0f} s; split the journey into shorter ones")
        if n_frames > limits.max_video_frames:
            raise BundleError(f"{name} has {n_frames} frames, more than the limit of "
                              f"{limits.max_video_frames}")
        handlers = tuple(str(s.metadata.get("handler_name", "")).strip().lower()
                         for s in container.streams if s.type == "data")
        header = VideoHeader(name, ctx.name, width, height, fps, duration_s, n_frames,
                             _creation_time(container), handlers)
        if decode_first and not _first_frame_decodes(container, stream):
            raise BundleError(f"{name}: no frame of its {ctx.name} stream decodes; the video is "
                              "corrupt")
    return header
