"""Things the journey page reads out of a stored bundle: the GPS track and sign crops. Both are
cached under ``data_dir/cache/admin/`` (bundles are immutable, content-addressed files); a bundle
in an object store is fetched into ``cache/admin/bundles/`` once for all the crops of its page, and
only the few most recently used are kept there."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from app.pipeline.bundle import FRAME_EXTENSIONS, read_bundle
from app.pipeline.bundle.read import video_entry
from app.pipeline.bundle.video.frames import read_frame
from app.pipeline.bundle.video.read import read_gps_log
from app.pipeline.bundle.zip import BundleLimits, open_bundle
from app.pipeline.geometry.geodesy import frame_at
from app.service.storage import BundleStore

CROP_MARGIN = 1.0  # context around the box, as a fraction of its size on each side
CROP_MIN_PX = 96
BOX_BGR = (0, 0, 255)
KEEP_FETCHED = 4  # bundles fetched from an object store kept on this host for their crops


def cache_dir(data_dir: Path) -> Path:
    return data_dir / "cache" / "admin"


def _bundle(data_dir: Path, store: BundleStore, sha256: str) -> Path:
    fetched = cache_dir(data_dir) / "bundles"
    path = store.fetch(sha256, fetched)
    if fetched.is_dir():
        by_use = sorted(fetched.glob("*.zip"), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in by_use[KEEP_FETCHED:]:
            old.unlink(missing_ok=True)
    return path


def _write_atomic(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def gps_track(data_dir: Path, store: BundleStore, sha256: str) -> list[list[float]]:
    """[[lat, lon], ...] per frame, as the pipeline reads it (csv, gpx or EXIF); a video
    journey's GPS fixes."""
    cached = cache_dir(data_dir) / f"{sha256}.gps.json"
    if cached.exists():
        return json.loads(cached.read_text())
    scratch = Path(tempfile.mkdtemp(dir=data_dir))
    try:
        bundle = _bundle(data_dir, store, sha256)
        with open_bundle(bundle, BundleLimits()) as bz:
            video = video_entry(bz)
            if video is not None:  # its fixes: decoding the video is the worker's job
                fixes = read_gps_log(bz, video, scratch, BundleLimits()).fixes
                lat, lon = fixes.lat_deg, fixes.lon_deg
        if video is None:
            journey = read_bundle(bundle, scratch, decode_images=False)
            lat, lon = journey.lat_deg, journey.lon_deg
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    track = [[float(a), float(o)] for a, o in zip(lat, lon)]
    _write_atomic(cached, json.dumps(track).encode())
    return track


def estimated_track(poses: list[list[float]], origin_lat_deg: float, origin_lon_deg: float,
                    origin_alt_m: float) -> list[list[float]]:
    """[[lat, lon], ...] of the camera centres of aligned poses (rows of T_world_cam[:3, :4], local
    ENU metres at the origin), as the journey coverage stores them."""
    T_world_cam = np.asarray(poses, dtype=float).reshape(-1, 3, 4)
    if not len(T_world_cam):
        return []
    lat, lon, _ = frame_at(origin_lat_deg, origin_lon_deg, origin_alt_m).to_geodetic(
        T_world_cam[:, :, 3])
    return [[float(a), float(o)] for a, o in zip(lat, lon)]


def crop_box(image_bgr: np.ndarray, box: list[float] | None) -> np.ndarray:
    """The region around ``box`` ([x1, y1, x2, y2], OpenCV pixels) with the box drawn; the whole
    frame when there is no box."""
    out = image_bgr.copy()
    if box is None:
        return out
    x1, y1, x2, y2 = box
    cv2.rectangle(out, (round(x1), round(y1)), (round(x2), round(y2)), BOX_BGR, 1)
    h, w = out.shape[:2]
    half_w = max((x2 - x1) * (0.5 + CROP_MARGIN), CROP_MIN_PX / 2)
    half_h = max((y2 - y1) * (0.5 + CROP_MARGIN), CROP_MIN_PX / 2)
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
    left, right = max(0, int(cx - half_w)), min(w, int(np.ceil(cx + half_w)) + 1)
    top, bottom = max(0, int(cy - half_h)), min(h, int(np.ceil(cy + half_h)) + 1)
    return out[top:bottom, left:right]


def _video_frame(data_dir: Path, bz, video: str, sha256: str, frame_id: str):
    """Frame ``frame_id`` (six digits: its presentation index) of a video bundle, None when there
    is none; the video is extracted once into the cache (like the fetched bundles, only the few
    most recently used are kept)."""
    if not (frame_id.isascii() and frame_id.isdigit()):
        return None
    videos = cache_dir(data_dir) / "videos"
    path = videos / f"{sha256}{Path(video).suffix.lower()}"
    if not path.exists():
        bz.extract(video, path)
        by_use = sorted(videos.iterdir(), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in by_use[KEEP_FETCHED:]:
            old.unlink(missing_ok=True)
    return read_frame(path, int(frame_id))


def crop_png(data_dir: Path, store: BundleStore, sha256: str, frame_id: str,
             box: list[float] | None) -> bytes | None:
    """PNG of ``frame_id``'s crop around ``box``; None when the bundle has no such frame."""
    tag = "full" if box is None else "_".join(f"{v:g}" for v in box)
    cached = cache_dir(data_dir) / sha256 / f"{frame_id}_{tag}.png"
    if cached.exists():
        return cached.read_bytes()
    with open_bundle(_bundle(data_dir, store, sha256), BundleLimits()) as bz:
        video = video_entry(bz)
        if video is not None:
            image = _video_frame(data_dir, bz, video, sha256, frame_id)
        else:
            names = [f"frames/{frame_id}.{ext}" for ext in FRAME_EXTENSIONS]
            name = next((n for n in names if n in bz.files), None)
            if name is None:
                return None
            image = cv2.imdecode(np.frombuffer(bz.read(name), np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        return None
    ok, png = cv2.imencode(".png", crop_box(image, box))
    if not ok:
        return None
    _write_atomic(cached, png.tobytes())
    return png.tobytes()
