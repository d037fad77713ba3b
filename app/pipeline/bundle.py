"""Reading and validating an uploaded journey bundle (wire contract, section 1) into a ``Journey``.

Every violation of the contract becomes a ``BundleError`` whose message tells the uploader what to
fix; the zip is treated as hostile (``app.pipeline.bundle_zip``). Checks run in the order a user
would fix them: zip, manifest, frames, images, GPS, detections.

Frames are ``frames/<stem>.jpg|.jpeg|.png`` (extensions are case-sensitive like every name in the
bundle; other files under ``frames/``, hidden ones such as macOS ``._000000.png`` and sub-folders are
ignored), ordered by stem, and are extracted to ``extract_dir/frames/``. Every frame's header must
be a JPEG or PNG of the first frame's size; with ``decode_images`` every frame is also fully
decoded (raw pixel orientation: the EXIF orientation tag is ignored, as detections refer to the
stored pixels). GPS comes from ``app.pipeline.gps`` / ``app.pipeline.gps_exif``; detections from
``app.pipeline.bundle_detections``, with empty track ids filled by ``app.pipeline.tracks``.

Frames lying too far outside the GPS fixes' time span are dropped from the journey's ends
(``app.pipeline.gps``): their files are removed again, their detections left out (a detection may
still name them: the bundle is valid), and ``Journey.warnings`` says so (also logged).
"""

from __future__ import annotations

import io
import logging
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from app.pipeline.bundle_detections import parse_detections
from app.pipeline.bundle_manifest import parse_manifest
from app.pipeline.bundle_zip import BundleLimits, BundleZip, open_bundle
from app.pipeline.csv_table import decode_text
from app.pipeline.gps import gps_from_csv, gps_from_gpx
from app.pipeline.gps_exif import gps_from_exif, read_exif_fix
from app.pipeline.tracks import assign_tracks, sort_detections
from app.pipeline.types import BundleError, Frame, Journey

__all__ = ["BundleLimits", "read_bundle"]

log = logging.getLogger(__name__)

FRAME_EXTENSIONS = ("jpg", "jpeg", "png")
MAX_MANIFEST_BYTES = 2**20
_DECODE_FLAGS = cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION


def _frame_entries(names: list[str]) -> list[tuple[str, str]]:
    """(stem, entry name) of the frames, sorted by stem."""
    by_stem: dict[str, str] = {}
    for name in names:
        folder, _, base = name.partition("/")
        stem, dot, ext = base.rpartition(".")
        if (folder != "frames" or "/" in base or not dot or not stem or stem.startswith(".")
                or ext not in FRAME_EXTENSIONS):
            continue
        if stem in by_stem:
            raise BundleError(f"frames {by_stem[stem].split('/')[1]} and {base} have the same "
                              "stem; keep one file per frame")
        by_stem[stem] = name
    return sorted(by_stem.items())


def _no_frames_error(names: list[str]) -> BundleError:
    hint = ""
    odd_case = [n for n in names if n.startswith("frames/") and n.count("/") == 1
                and n.rpartition(".")[2].lower() in FRAME_EXTENSIONS]
    if odd_case:
        hint = (f" (found {odd_case[0]}: names are case-sensitive, use lower-case "
                ".jpg, .jpeg or .png)")
    return BundleError(f"bundle has no frames under frames/{hint}")


def _image_size(data: bytes, base: str, limits: BundleLimits, decode: bool) -> tuple[int, int]:
    """(width, height) of a frame, checked to be a JPEG/PNG that decodes."""
    try:
        with Image.open(io.BytesIO(data)) as img:
            fmt, (width, height) = img.format, img.size
    except Exception:  # Pillow's parsers raise many types on hostile bytes; all mean "unreadable"
        raise BundleError(f"frame {base} is not a readable image") from None
    if fmt not in ("JPEG", "PNG"):
        raise BundleError(f"frame {base} is a {fmt} image; frames must be JPEG or PNG")
    if width * height > limits.max_frame_pixels:
        raise BundleError(f"frame {base} is {width}x{height}, more than the limit of "
                          f"{limits.max_frame_pixels} pixels")
    if decode:
        try:
            pixels = cv2.imdecode(np.frombuffer(data, np.uint8), _DECODE_FLAGS)
        except cv2.error:
            pixels = None
        if pixels is None:
            raise BundleError(f"frame {base} is not a readable image")
        height, width = pixels.shape[:2]
    return width, height


def _manifest_error(names: list[str]) -> BundleError:
    nested = next((n for n in names if n.endswith("/manifest.json")), None)
    hint = (f" (found {nested}: zip the bundle's contents, not the folder holding them)"
            if nested else "")
    return BundleError(f"bundle has no manifest.json at its top level{hint}")


def _read_frames(bz: BundleZip, entries: list[tuple[str, str]], frames_dir: Path,
                 limits: BundleLimits, decode_images: bool, want_exif: bool):
    frames_dir.mkdir(parents=True, exist_ok=True)
    size, paths, exif_fixes = None, [], []
    for _, name in entries:
        base = name.split("/", 1)[1]
        data = bz.read(name)
        width, height = _image_size(data, base, limits, decode_images)
        if size is None:
            size = (width, height)
        elif (width, height) != size:
            raise BundleError(f"frame {base} is {width}x{height}, expected {size[0]}x{size[1]} "
                              "like the first frame; all frames must have one size")
        if want_exif:
            exif_fixes.append(read_exif_fix(data))
        path = frames_dir / base
        path.write_bytes(data)
        paths.append(path)
    return size, paths, exif_fixes


def read_bundle(zip_path: Path, extract_dir: Path, *, limits: BundleLimits = BundleLimits(),
                decode_images: bool = True) -> Journey:
    """Validate the bundle at ``zip_path``, extract its frames under ``extract_dir/frames/``."""
    with open_bundle(Path(zip_path), limits) as bz:
        names = list(bz.files)
        if "manifest.json" not in bz.files:
            raise _manifest_error(names)
        manifest = parse_manifest(bz.read("manifest.json", MAX_MANIFEST_BYTES))
        entries = _frame_entries(names)
        if not entries:
            raise _no_frames_error(names)
        if len(entries) > limits.max_frames:
            raise BundleError(f"bundle has {len(entries)} frames, more than the limit of "
                              f"{limits.max_frames}")
        frame_ids = [stem for stem, _ in entries]
        want_exif = "gps.csv" not in bz.files and "gps.gpx" not in bz.files
        (width, height), paths, exif_fixes = _read_frames(
            bz, entries, Path(extract_dir) / "frames", limits, decode_images, want_exif)
        if "gps.csv" in bz.files:
            gps = gps_from_csv(decode_text(bz.read("gps.csv"), "gps.csv"), frame_ids)
        elif "gps.gpx" in bz.files:
            gps = gps_from_gpx(bz.read("gps.gpx"), frame_ids)
        else:
            gps = gps_from_exif(exif_fixes, frame_ids)
        kept_ids, kept_paths = frame_ids[gps.kept], paths[gps.kept]
        detections = []
        if "detections.csv" in bz.files:
            text = decode_text(bz.read("detections.csv"), "detections.csv")
            detections = parse_detections(text, frame_ids, width, height)
            kept = set(kept_ids)
            detections = [d for d in detections if d.frame_id in kept]
            detections = sort_detections(assign_tracks(detections, kept_ids), kept_ids)
    for path in set(paths) - set(kept_paths):
        path.unlink()  # so the extracted frames/ holds exactly the journey's frames
    for warning in gps.warnings:
        log.warning("%s: %s", Path(zip_path).name, warning)
    frames = [Frame(fid, path, float(t))
              for fid, path, t in zip(kept_ids, kept_paths, gps.timestamp_s)]
    prior = manifest.camera_prior.camera(width, height) if manifest.camera_prior else None
    return Journey(camera_id=manifest.camera_id, frames=frames, lat_deg=gps.lat_deg,
                   lon_deg=gps.lon_deg, alt_m=gps.alt_m, detections=detections,
                   image_width=width, image_height=height, vehicle_id=manifest.vehicle_id,
                   captured_at=manifest.captured_at, camera_prior=prior,
                   warnings=list(gps.warnings))
