"""``signmap bench video``: what a video journey's intake costs the worker, per minute of video.

A moving texture (a camera panning across a blurred noise texture) is encoded as H.264 at 1080p or
4K and 30 or 60 fps; then, each in a fresh process so that peak memory
is its own:

* baseline: PyAV decodes every frame and converts none (the floor any intake pays);
* intake: ``bundle.video.frames.decode_frames`` at 10 Hz with the image-motion signal fed, as
  the worker runs it (JPEG writes included).

The table gives seconds per minute of video, their ratio (the machine's speed cancels) and each
process's peak resident memory.
"""

from __future__ import annotations

import multiprocessing as mp
import tempfile
import time
from pathlib import Path

import numpy as np

SIZES = {"1080p": (1920, 1080), "4k": (3840, 2160)}


def _frames(n: int, width: int, height: int):
    rng = np.random.default_rng(0)
    import cv2

    texture = cv2.GaussianBlur(rng.integers(0, 255, (height, width * 3, 3), np.uint8), (0, 0), 3)
    for i in range(n):
        x = int(i * 6) % (width * 2)
        yield np.ascontiguousarray(texture[:, x:x + width])


def _peak_mb() -> float:
    # VmHWM, not ru_maxrss: the latter survives exec, so a spawned child would report its parent's.
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _baseline(video: str, queue) -> None:
    import av

    t0 = time.perf_counter()
    with av.open(video) as c:
        stream = c.streams.video[0]
        stream.thread_type = "AUTO"
        n = sum(1 for _ in c.decode(stream))
    queue.put((time.perf_counter() - t0, n, _peak_mb()))


def _intake(video: str, out_dir: str, queue) -> None:
    import cv2

    from app.pipeline.bundle.video.frames import FrameChoice, decode_frames
    from app.pipeline.bundle.video.motion import ImageMotion

    motion = ImageMotion()
    t0 = time.perf_counter()
    decoded = decode_frames(Path(video), "video.mp4", FrameChoice(10.0), Path(out_dir),
                            on_kept=lambda t, bgr: motion.add(t, cv2.cvtColor(bgr,
                                                                              cv2.COLOR_BGR2GRAY)))
    motion.signal()
    queue.put((time.perf_counter() - t0, len(decoded.index),
               _peak_mb()))


def _run(target, *args):
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=target, args=(*args, queue))
    proc.start()
    result = queue.get()
    proc.join()
    return result


def run_video_bench(seconds: float, out_dir: Path, size: str = "1080p", fps: int = 30) -> Path:
    from app.synth.video.encode import write_video

    width, height = SIZES[size]
    n = int(seconds * fps)
    with tempfile.TemporaryDirectory(prefix="signmap-video-bench-") as tmp:
        video = write_video(_frames(n, width, height), np.arange(n) / fps, Path(tmp) / "v.mp4",
                            creation_utc=None, fps=fps, crf=15)
        size_mb = video.stat().st_size / 2**20
        base_s, n_base, base_mb = _run(_baseline, str(video))
        intake_s, n_kept, intake_mb = _run(_intake, str(video), str(Path(tmp) / "frames"))
        scratch_mb = sum(p.stat().st_size for p in (Path(tmp) / "frames").iterdir()) / 2**20
    per_min = 60.0 / seconds
    rows = [("decode only (baseline)", base_s * per_min, 1.0, base_mb, n_base, "-"),
            ("intake: decode, keep 10 Hz, JPEG, image motion", intake_s * per_min,
             intake_s / base_s, intake_mb, n_kept, f"{scratch_mb * per_min:.0f} MB")]
    md = [f"# Video intake, {width}x{height} {fps} fps H.264 ({seconds:.0f} s, {size_mb:.0f} MB)",
          "", "| step | s per minute of video | ratio to decode only | peak memory (MB) | "
          "frames | scratch per minute |", "| --- | --- | --- | --- | --- | --- |"]
    md += [f"| {r[0]} | {r[1]:.1f} | {r[2]:.2f} | {r[3]:.0f} | {r[4]} | {r[5]} |" for r in rows]
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"video-intake-{size}{fps}.md"
    path.write_text("\n".join(md) + "\n")
    return path
