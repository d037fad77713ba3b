"""Encode frames as an MP4 the way a dash cam records one: H.264, yuv420p (4:4:4 for odd sizes),
a ``creation_time``."""

from __future__ import annotations

from datetime import datetime
from fractions import Fraction
from pathlib import Path
from typing import Iterable

import av
import numpy as np

TIME_BASE = Fraction(1, 1000)  # ms presentation timestamps: frame times as the journey has them


def write_video(frames_bgr: Iterable[np.ndarray], timestamps_s: np.ndarray, path: Path, *,
                creation_utc: datetime | None, codec: str = "libx264", crf: int = 18,
                fps: float | None = None) -> Path:
    """Write frames (H, W, 3) BGR uint8 at ``timestamps_s`` (increasing, seconds from the first
    frame) to ``path``; ``creation_utc`` becomes the container's ``creation_time``."""
    t = np.asarray(timestamps_s, float) - float(timestamps_s[0])
    rate = fps or (len(t) - 1) / max(t[-1], 1e-9)
    with av.open(str(path), "w") as container:
        if creation_utc is not None:
            container.metadata["creation_time"] = creation_utc.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        stream = None
        for i, bgr in enumerate(frames_bgr):
            if stream is None:
                stream = container.add_stream(codec, rate=Fraction(rate).limit_denominator(1001))
                stream.height, stream.width = bgr.shape[:2]
                # 4:2:0 (what dash cams record) needs even sizes; KITTI's 1242x375 is not.
                even = bgr.shape[0] % 2 == 0 and bgr.shape[1] % 2 == 0
                stream.pix_fmt = "yuv420p" if even else "yuv444p"
                stream.time_base = TIME_BASE
                stream.codec_context.time_base = TIME_BASE
                # x264's output depends on its thread count, which defaults to the machine's
                # cores: pinned, a bundle is the same bytes on every machine (CI's 3 threads once
                # moved a real clip's clock offset past a test's bound where 2 did not).
                stream.options = {"crf": str(crf), "threads": "2"} \
                    if codec.startswith("libx26") else {}
            frame = av.VideoFrame.from_ndarray(bgr, format="bgr24")
            frame.pts = int(round(t[i] / TIME_BASE))
            frame.time_base = TIME_BASE
            container.mux(stream.encode(frame))
        if stream is not None:
            container.mux(stream.encode(None))
    return path
