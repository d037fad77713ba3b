"""Rendered synthetic journeys for the tests, made once per session (or cached on disk).

Under pytest-xdist (``scripts/test.sh`` runs the suite in one worker per core) the workers share
one cache, the parent of their own temporary directories, and a file lock makes one of them render
a journey while the others wait for it instead of rendering it again."""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path


def synthetic_journey(tmp_path_factory, name: str, **config) -> tuple[Path, dict]:
    """Render a synthetic journey once per session (or reuse SIGNMAP_TEST_SYNTH_CACHE/<hash>)."""
    import hashlib

    from app.synth.journey import GENERATOR_VERSION, SynthConfig, write_bundle

    cfg = SynthConfig(**config)
    cache = os.environ.get("SIGNMAP_TEST_SYNTH_CACHE")
    base = tmp_path_factory.getbasetemp()
    root = Path(cache) if cache else (base.parent if os.environ.get("PYTEST_XDIST_WORKER")
                                      else base) / "synth"
    digest = hashlib.sha256(repr((GENERATOR_VERSION, cfg)).encode()).hexdigest()[:12]
    out = root / f"{name}-{digest}"
    root.mkdir(parents=True, exist_ok=True)
    with open(root / f"{name}-{digest}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (out / "truth.json").exists():
            write_bundle(cfg, out)
    return out / "bundle.zip", json.loads((out / "truth.json").read_text())


def video_journey(tmp_path_factory, frames_bundle: Path, name: str, **options) -> Path:
    """``frames_bundle`` as a dash cam's video bundle (``app.synth.video.bundle.video_bundle``
    with ``options``), made once per session (the frames bundle's cache directory holds it)."""
    import hashlib

    from app.synth.video.bundle import video_bundle

    digest = hashlib.sha256(repr(sorted(options.items())).encode()).hexdigest()[:12]
    out = frames_bundle.parent / f"{name}-{digest}.zip"
    with open(frames_bundle.parent / f"{name}-{digest}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not out.exists():
            video_bundle(frames_bundle, out.with_suffix(".part"), **options).replace(out)
    return out


def first_frames(bundle: Path, n_frames: int, out: Path) -> Path:
    """``bundle`` (a rendered journey) cut to its first ``n_frames`` frames: their images, GPS
    rows and detections, and the frame-less fix rows up to the first one after the last frame
    (so that interpolation still covers it); the manifest as it was. Written to ``out``."""
    import csv
    import io
    import zipfile

    from tests.utils.bundle_factory import zip_bytes

    with zipfile.ZipFile(bundle) as src:
        files = {name: src.read(name) for name in src.namelist()}
    frames = sorted(n for n in files if n.startswith("frames/"))
    kept = {Path(n).stem for n in frames[:n_frames]}
    files = {n: data for n, data in files.items()
             if not n.startswith("frames/") or Path(n).stem in kept}

    def rows(name: str, keep) -> None:
        table = list(csv.reader(io.StringIO(files[name].decode())))
        out_rows = [table[0]] + [r for r in table[1:] if keep(dict(zip(table[0], r)))]
        text = io.StringIO()
        csv.writer(text, lineterminator="\n").writerows(out_rows)
        files[name] = text.getvalue().encode()

    if "gps.csv" in files:
        table = list(csv.DictReader(io.StringIO(files["gps.csv"].decode())))
        t_end = max(float(r["timestamp_s"]) for r in table if r["frame"] in kept)
        t_fix = min((float(r["timestamp_s"]) for r in table
                     if not r["frame"] and float(r["timestamp_s"]) >= t_end), default=t_end)
        rows("gps.csv", lambda r: r["frame"] in kept if r["frame"]
             else float(r["timestamp_s"]) <= t_fix)
    if "detections.csv" in files:
        rows("detections.csv", lambda r: r["frame"] in kept)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(zip_bytes(files, zipfile.ZIP_STORED))
    return out


def sliding_frames(directory: Path, n: int, shift_px: int = 40) -> list[str]:
    """``n`` 640x480 PNG views sliding ``shift_px`` left per frame across one textured scene (SIFT
    finds and matches it); their names."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(5)
    scene = cv2.GaussianBlur(rng.integers(0, 255, (480, 1400), dtype=np.uint8), (0, 0), 2.0)
    names = []
    for k in range(n):
        names.append(f"{k:06d}.png")
        cv2.imwrite(str(directory / names[-1]), scene[:, shift_px * k:shift_px * k + 640])
    return names
