"""Decode a video as a stream and keep the frames the pipeline needs.

Every frame is decoded (H.264/H.265 frames depend on each other) but only the kept ones are
converted and written, as JPEG, one in memory at a time: memory is a few frames at any length,
scratch disk is the kept frames. Kept: about ``rate_hz`` frames a second (the pipeline's ego-motion
and calibration were tuned on 10 Hz journeys: KITTI's rate), plus every frame that holds a
detection (a sign is triangulated from the frames that see it).

A stream that breaks part way (a dash cam losing power leaves a truncated file) ends the decoding
there with a warning; the frames before it are the journey. No decodable frame is a BundleError.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Callable, Collection

import av
import cv2
import numpy as np

from app.pipeline.types import BundleError

JPEG_QUALITY = 95
# Progress is reported at most this often (frames), so a 36,000-frame video is not 36,000 calls.
PROGRESS_EVERY = 250

KeptFn = Callable[[float, np.ndarray], None]
"""Called with each kept frame's video time (s) and its BGR pixels (H, W, 3) uint8."""


@dataclass(frozen=True)
class FrameChoice:
    """Which frames to keep: ``rate_hz`` a second, and ``must_keep`` (frame indices) always."""

    rate_hz: float = 10.0
    must_keep: Collection[int] = frozenset()


@dataclass(frozen=True)
class DecodedFrames:
    """The kept frames, in presentation order. ``index`` (K,) their 0-based presentation indices;
    ``t_video_s`` (K,) seconds since the first frame; ``paths`` the JPEG files; ``by_detection``
    (K,) bool, kept for a detection only (off the rate's grid)."""

    index: np.ndarray
    t_video_s: np.ndarray
    paths: list[Path]
    by_detection: np.ndarray
    n_decoded: int
    warning: str | None = None  # the stream broke part way

    def summary(self) -> str:
        n_rate = int((~self.by_detection).sum())
        return (f"{len(self.index)} of {self.n_decoded} decoded frames kept: {n_rate} at the "
                f"frame rate chosen, {int(self.by_detection.sum())} more because they hold "
                "detections")


def decode_frames(source: Path | BinaryIO, name: str, choice: FrameChoice, out_dir: Path, *,
                  on_kept: KeptFn | None = None,
                  progress: Callable[[int], None] | None = None) -> DecodedFrames:
    """Decode ``source`` (the bundle's video ``name``), write the kept frames to
    ``out_dir/<index:06d>.jpg``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    index, times, paths, by_det = [], [], [], []
    warning, n_decoded, t_first = None, 0, None
    period_s = 1.0 / choice.rate_hz
    next_t = 0.0
    try:
        container = av.open(str(source) if isinstance(source, Path) else source, "r")
    except (av.FFmpegError, ValueError, OSError):
        raise BundleError(f"{name} is not a video this service can read (or a corrupt one)") from None
    with container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"  # frame threads: the decoder is most of the cost
        fps = float(stream.average_rate or stream.guessed_rate or 30)
        half_frame_s = 0.5 / fps  # so that 30 fps at 10 Hz keeps exactly every third frame
        try:
            for frame in container.decode(stream):
                i = n_decoded
                n_decoded += 1
                t = frame.time if frame.time is not None else i / fps
                t_first = t if t_first is None else t_first
                t -= t_first
                on_grid = t >= next_t - half_frame_s
                if on_grid:
                    next_t = max(next_t + period_s, t + period_s - half_frame_s)
                if on_grid or i in choice.must_keep:
                    bgr = frame.to_ndarray(format="bgr24")
                    path = out_dir / f"{i:06d}.jpg"
                    if not cv2.imwrite(str(path), bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]):
                        raise OSError(f"could not write {path}")
                    index.append(i), times.append(t), paths.append(path)
                    by_det.append(not on_grid)
                    if on_kept is not None:
                        on_kept(t, bgr)
                if progress is not None and n_decoded % PROGRESS_EVERY == 0:
                    progress(n_decoded)
        except (av.FFmpegError, ValueError) as exc:
            warning = (f"{name}: decoding stopped after frame {n_decoded - 1:06d} ({exc}); the "
                       f"rest of the video is corrupt and was left out")
    if not index:
        raise BundleError(f"{name}: no frame of the video decodes; the video is corrupt")
    return DecodedFrames(np.array(index), np.array(times, float), paths, np.array(by_det, bool),
                         n_decoded, warning)


def read_frame(source: Path, index: int) -> np.ndarray | None:
    """Frame ``index`` (presentation order) as BGR pixels, None past the end: seeks to the key
    frame before its nominal time (index / rate) and decodes forward. Exact for constant-rate
    video (what dash cams record); for variable rate it may land a frame or two off, which is what
    a picture of the frame (the dashboard's crops) can afford and a measurement could not."""
    try:
        with av.open(str(source), "r") as container:
            stream = container.streams.video[0]
            fps = float(stream.average_rate or stream.guessed_rate or 30)
            start = stream.start_time or 0
            target = start + int(index / fps / stream.time_base)
            container.seek(target, stream=stream, backward=True, any_frame=False)
            for frame in container.decode(stream):
                at = round(float((frame.pts - start) * stream.time_base) * fps)
                if at >= index:
                    return frame.to_ndarray(format="bgr24")
    except (av.FFmpegError, ValueError, OSError):
        return None
    return None
