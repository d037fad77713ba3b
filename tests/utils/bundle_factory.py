"""Tiny journey bundles for tests, built in memory: valid by default, with knobs to break each rule.

    files = valid_files()                   # {entry name: bytes}: a valid 5-frame 64x48 bundle
    files["manifest.json"] = b"{oops"        # break one rule
    data = zip_bytes(files)                 # the .zip as bytes: write it, or POST it

``broken_bundle(case)`` gives, for each name in ``BROKEN_CASES``, a bundle violating one rule of the
contract and a fragment the BundleError message (the HTTP ``detail``) must contain.

The valid bundle's GPS (``gps="csv"``, ``fix_rows=True``): frame i has only a timestamp,
``frame_times_s()`` = 0.05 + 0.1 i; frame-less fix rows every 0.2 s carry the positions
(``fix_table()``: lat = LAT0 + 1e-5 k^2, so interpolation is not the identity). In the other GPS modes
every frame carries its own position ``frame_positions()``.
"""

from __future__ import annotations

import io
import json
import math
import struct
import zipfile
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from PIL import ExifTags, Image

WIDTH, HEIGHT = 64, 48
LAT0, LON0, ALT0 = 49.0110, 8.4180, 112.0
FRAME_T0_S, FRAME_DT_S, FIX_DT_S = 0.05, 0.1, 0.2
CAPTURED_AT = datetime(2024, 5, 1, 12, 30, 0, tzinfo=timezone.utc)
GPS_HEADER = ("frame", "timestamp_s", "lat", "lon", "alt_m")
DETECTIONS_HEADER = ("frame", "track_id", "class", "x1", "y1", "x2", "y2", "score")


def frame_ids(n_frames: int = 5) -> list[str]:
    return [f"{i:06d}" for i in range(n_frames)]


def frame_times_s(n_frames: int = 5) -> np.ndarray:
    return FRAME_T0_S + FRAME_DT_S * np.arange(n_frames)


def fix_table(n_frames: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(timestamp_s, lat_deg, lon_deg, alt_m) of the frame-less fixes, covering every frame."""
    k = np.arange(int(frame_times_s(n_frames)[-1] // FIX_DT_S) + 2)
    return FIX_DT_S * k, LAT0 + 1e-5 * k**2, LON0 + 2e-5 * k, ALT0 + 0.5 * k


def frame_positions(n_frames: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lat_deg, lon_deg, alt_m) per frame in the modes where frames carry their own fix."""
    i = np.arange(n_frames)
    return LAT0 + 1e-5 * i, LON0 + 1.5e-5 * i, ALT0 + 0.1 * i


def image_bytes(fmt: str = "png", width: int = WIDTH, height: int = HEIGHT, seed: int = 0,
                exif: Image.Exif | None = None) -> bytes:
    """A noise image encoded as "png" or "jpg" (optionally with EXIF)."""
    pixels = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    out = io.BytesIO()
    kwargs = {"exif": exif} if exif is not None else {}
    Image.fromarray(pixels).save(out, "PNG" if fmt == "png" else "JPEG", **kwargs)
    return out.getvalue()


def _dms(value_deg: float) -> tuple[float, float, float]:
    value_deg = abs(value_deg)
    deg = math.floor(value_deg)
    minutes = math.floor((value_deg - deg) * 60)
    return float(deg), float(minutes), (value_deg - deg - minutes / 60) * 3600


def exif_gps(lat_deg: float, lon_deg: float, alt_m: float | None, when: datetime) -> Image.Exif:
    """EXIF with GPS position, GPSDateStamp/GPSTimeStamp (UTC) and DateTimeOriginal."""
    exif = Image.Exif()
    gps = exif.get_ifd(ExifTags.IFD.GPSInfo)
    gps[ExifTags.GPS.GPSLatitudeRef] = "N" if lat_deg >= 0 else "S"
    gps[ExifTags.GPS.GPSLatitude] = _dms(lat_deg)
    gps[ExifTags.GPS.GPSLongitudeRef] = "E" if lon_deg >= 0 else "W"
    gps[ExifTags.GPS.GPSLongitude] = _dms(lon_deg)
    if alt_m is not None:
        gps[ExifTags.GPS.GPSAltitudeRef] = 0 if alt_m >= 0 else 1
        gps[ExifTags.GPS.GPSAltitude] = abs(alt_m)
    utc = when.astimezone(timezone.utc)
    gps[ExifTags.GPS.GPSDateStamp] = utc.strftime("%Y:%m:%d")
    gps[ExifTags.GPS.GPSTimeStamp] = (float(utc.hour), float(utc.minute),
                                      utc.second + utc.microsecond / 1e6)
    exif.get_ifd(ExifTags.IFD.Exif)[ExifTags.Base.DateTimeOriginal] = \
        when.strftime("%Y:%m:%d %H:%M:%S")
    return exif


def csv_bytes(header: Sequence[str], rows: Sequence[Sequence]) -> bytes:
    lines = [",".join(header)] + [",".join("" if v is None else str(v) for v in r) for r in rows]
    return ("\n".join(lines) + "\n").encode()


def gps_rows(n_frames: int = 5, fix_rows: bool = True) -> list[tuple]:
    """Rows of the valid gps.csv (see the module docstring), in time order."""
    ids, t_frame = frame_ids(n_frames), frame_times_s(n_frames)
    if not fix_rows:
        lat, lon, alt = frame_positions(n_frames)
        return [(f, f"{t:.3f}", f"{a:.7f}", f"{o:.7f}", f"{h:.2f}")
                for f, t, a, o, h in zip(ids, t_frame, lat, lon, alt)]
    rows = [(t, (f, f"{t:.3f}", "", "", "")) for f, t in zip(ids, t_frame)]
    rows += [(t, ("", f"{t:.3f}", f"{a:.7f}", f"{o:.7f}", f"{h:.2f}"))
             for t, a, o, h in zip(*fix_table(n_frames))]
    return [r for _, r in sorted(rows, key=lambda tr: tr[0])]


def gpx_bytes(points: Sequence[tuple[float, float, float | None, datetime | None]]) -> bytes:
    """A GPX 1.1 track from (lat, lon, ele or None, time or None) points."""
    pts = []
    for lat, lon, ele, when in points:
        inner = (f"<ele>{ele:.2f}</ele>" if ele is not None else "") + \
            (f"<time>{when.isoformat().replace('+00:00', 'Z')}</time>" if when else "")
        pts.append(f'<trkpt lat="{lat:.7f}" lon="{lon:.7f}">{inner}</trkpt>')
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<gpx version="1.1" creator="test" '
            'xmlns="http://www.topografix.com/GPX/1/1"><trk><trkseg>'
            + "".join(pts) + "</trkseg></trk></gpx>\n").encode()


def detection_rows(n_frames: int = 5, blank_track_ids: bool = False) -> list[tuple]:
    """Sign "0" (stop) in every frame, sign "1" (yield) in frames 1..n-2, moving boxes."""
    rows = []
    for i, f in enumerate(frame_ids(n_frames)):
        rows.append((f, "0", "stop", 10 + 3 * i, 10, 18 + 3 * i, 18, 0.9))
        if 1 <= i <= n_frames - 2:
            rows.append((f, "1", "yield", 50 - 2 * i, 30, 58 - 2 * i, 38, ""))
    if blank_track_ids:
        rows = [(r[0], "", *r[2:]) for r in rows]
    return rows


def manifest_bytes(**overrides) -> bytes:
    manifest = {"format": "signmap-journey/1", "camera_id": "test-cam", "vehicle_id": "car-7",
                "captured_at": CAPTURED_AT.isoformat(), "camera_prior": None}
    manifest.update(overrides)
    return json.dumps(manifest).encode()


def valid_files(n_frames: int = 5, *, image_format: str = "png", gps: str = "csv",
                fix_rows: bool = True, detections: bool = True, blank_track_ids: bool = False,
                width: int = WIDTH, height: int = HEIGHT) -> dict[str, bytes]:
    """A valid bundle as {entry name: bytes}. gps: "csv" | "gpx" | "exif" | "none" (no GPS at all;
    with "exif" the frames are JPEGs carrying their fix)."""
    ids, t_frame = frame_ids(n_frames), frame_times_s(n_frames)
    lat, lon, alt = frame_positions(n_frames)
    when = [CAPTURED_AT + timedelta(seconds=float(t)) for t in t_frame]
    files = {"manifest.json": manifest_bytes()}
    ext = "png" if image_format == "png" else image_format
    for i, f in enumerate(ids):
        exif = exif_gps(lat[i], lon[i], alt[i], when[i]) if gps == "exif" else None
        files[f"frames/{f}.{ext}"] = image_bytes("png" if ext == "png" else "jpg", width, height,
                                                 seed=i, exif=exif)
    if gps == "csv":
        files["gps.csv"] = csv_bytes(GPS_HEADER, gps_rows(n_frames, fix_rows))
    elif gps == "gpx":
        files["gps.gpx"] = gpx_bytes(list(zip(lat, lon, alt, when)))
    if detections:
        files["detections.csv"] = csv_bytes(DETECTIONS_HEADER,
                                            detection_rows(n_frames, blank_track_ids))
    return files


def zip_bytes(files: Mapping[str, bytes], compression: int = zipfile.ZIP_DEFLATED) -> bytes:
    """The entries, in order, as a zip (names are stored verbatim, even hostile ones)."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression) as zf:
        for name, data in files.items():
            zf.writestr(zipfile.ZipInfo(name, (2024, 5, 1, 12, 30, 0)), data,
                        compress_type=compression)
    return out.getvalue()


def write_zip(path: Path, files: Mapping[str, bytes]) -> Path:
    path.write_bytes(zip_bytes(files))
    return path


def zip_bomb_files(uncompressed_bytes: int) -> dict[str, bytes]:
    """A valid bundle plus an ignored extra file of zeros that compresses ~1000:1."""
    return {**valid_files(), "padding.bin": bytes(uncompressed_bytes)}


def with_declared_size(data: bytes, name: str, declared_bytes: int) -> bytes:
    """Rewrite the uncompressed size the zip declares for entry ``name`` (a lying header)."""
    buf = bytearray(data)
    info = zipfile.ZipFile(io.BytesIO(data)).getinfo(name)
    struct.pack_into("<I", buf, info.header_offset + 22, declared_bytes)
    encoded = name.encode()
    pos = buf.find(b"PK\x01\x02")
    while pos >= 0:
        name_len = struct.unpack_from("<H", buf, pos + 28)[0]
        if bytes(buf[pos + 46:pos + 46 + name_len]) == encoded:
            struct.pack_into("<I", buf, pos + 24, declared_bytes)
            return bytes(buf)
        pos = buf.find(b"PK\x01\x02", pos + 4)
    raise KeyError(name)


def _edit(changes: Mapping[str, bytes | None], **valid_kwargs) -> dict[str, bytes]:
    """valid_files(**valid_kwargs) with entries replaced, added, or (value None) removed."""
    files = valid_files(**valid_kwargs)
    for name, data in changes.items():
        if data is None:
            files.pop(name, None)
        else:
            files[name] = data
    return files


def _gps(rows: list[tuple]) -> dict[str, bytes]:
    return {"gps.csv": csv_bytes(GPS_HEADER, rows)}


def _detection(row: tuple) -> dict[str, bytes]:
    return {"detections.csv": csv_bytes(DETECTIONS_HEADER, [*detection_rows(), row])}


def _gps_edit(row_index: int, **columns: str) -> dict[str, bytes]:
    rows = [list(r) for r in gps_rows()]
    for column, value in columns.items():
        rows[row_index][GPS_HEADER.index(column)] = value
    return _gps([tuple(r) for r in rows])


_PNG = image_bytes()
# Row layout of the default gps.csv (time order): fix 0.0, frame 0.05, frame 0.15, fix 0.2,
# frame 0.25, frame 0.35, fix 0.4, frame 0.45, fix 0.6 (file rows 2..10).
_CASES = {
    "not_a_zip": (lambda: b"PK\x03\x04 this is not really a zip", "not a zip file"),
    "empty_upload": (lambda: b"", "not a zip file"),
    "no_manifest": (lambda: _edit({"manifest.json": None}), "no manifest.json"),
    "manifest_bad_json": (lambda: _edit({"manifest.json": b'{"format": '}), "not valid JSON"),
    "manifest_not_object": (lambda: _edit({"manifest.json": b"[1, 2]"}), "JSON object"),
    "manifest_wrong_format": (lambda: _edit({"manifest.json": manifest_bytes(
        format="signmap-journey/2")}), 'format is "signmap-journey/2", expected "signmap-journey/1"'),
    "manifest_no_camera_id": (lambda: _edit({"manifest.json": manifest_bytes(camera_id="")}),
                              "camera_id"),
    "manifest_bad_captured_at": (lambda: _edit({"manifest.json": manifest_bytes(
        captured_at="yesterday")}), "captured_at"),
    "manifest_bad_prior": (lambda: _edit({"manifest.json": manifest_bytes(
        camera_prior={"fx": "800", "fy": 800, "cx": 32, "cy": 24})}), "camera_prior.fx"),
    "no_frames": (lambda: {k: v for k, v in valid_files().items() if not k.startswith("frames/")},
                  "no frames under frames/"),
    "uppercase_extension": (lambda: {("frames/" + k[7:13] + ".PNG" if k.startswith("frames/")
                                      else k): v for k, v in valid_files().items()},
                            "case-sensitive"),
    "duplicate_stem": (lambda: _edit({"frames/000001.jpg": image_bytes("jpg")}), "same stem"),
    "unreadable_image": (lambda: _edit({"frames/000002.png": b"not an image"}),
                         "frame 000002.png is not a readable image"),
    "truncated_image": (lambda: _edit({"frames/000002.png": _PNG[:len(_PNG) // 2]}),
                        "frame 000002.png is not a readable image"),
    "image_size_mismatch": (lambda: _edit({"frames/000003.png": image_bytes("png", 32, 24)}),
                            "frame 000003.png is 32x24, expected 64x48"),
    "no_gps": (lambda: _edit({"gps.csv": None}), "bundle has no GPS"),
    "gps_no_header": (lambda: _edit({"gps.csv": csv_bytes(gps_rows()[0], gps_rows()[1:])}),
                      "no header row"),
    "gps_not_increasing": (lambda: _edit(_gps_edit(6, timestamp_s="0.1")),
                           "GPS timestamps are not increasing at row 8 (0.1 after 0.2)"),
    "gps_missing_frame": (lambda: _edit(_gps([r for r in gps_rows() if r[0] != "000003"])),
                          "no GPS timestamp for frame 000003"),
    "gps_bad_lat": (lambda: _edit(_gps_edit(3, lat="91.5")), "gps.csv row 5: lat 91.5"),
    "gps_not_a_number": (lambda: _edit(_gps_edit(3, lon="8.41E")),
                         "gps.csv row 5: lon is '8.41E', expected a number"),
    "gps_jump": (lambda: _edit(_gps_edit(6, lat=f"{LAT0 + 0.01:.7f}")), "GPS jumps"),
    # Frame 4 at 5 s is 4.4 s after the last fix: dropped, and 4 frames are too few to keep.
    "gps_frame_outside_span": (lambda: _edit(_gps_edit(7, timestamp_s="5.0")),
                               "GPS covers only 4 of 5 frames (80 %)"),
    "gpx_point_without_time": (lambda: _edit({"gps.gpx": gpx_bytes([(LAT0, LON0, None, None)])},
                                             gps="gpx"), "no <time>"),
    "exif_missing_on_a_frame": (lambda: _edit({"frames/000002.jpg": image_bytes("jpg", seed=2)},
                                              gps="exif", image_format="jpg"),
                                "bundle has no GPS"),
    "detection_outside_image": (lambda: _edit(_detection(("000001", "7", "stop", 60, 10, 80, 20,
                                                          ""))),
                                "box (60,10)-(80,20) lies outside the 64x48 image"),
    "detection_unknown_frame": (lambda: _edit(_detection(("000999", "7", "stop", 1, 1, 5, 5, ""))),
                                "names frame 000999 which is not in frames/"),
    "detection_inverted_box": (lambda: _edit(_detection(("000001", "7", "stop", 9, 9, 5, 12, ""))),
                               "x1 < x2"),
    "detection_empty_class": (lambda: _edit(_detection(("000001", "7", "", 1, 1, 5, 5, ""))),
                              "empty class"),
    # Passed the upload and then failed the job on PostgreSQL (class is a VARCHAR(200) there).
    "detection_class_too_long": (lambda: _edit(_detection(("000001", "7", "x" * 201, 1, 1, 5, 5,
                                                           ""))),
                                 "class is 201 characters long, more than the limit of 200"),
    "path_traversal": (lambda: _edit({"../evil.png": _PNG}), "unsafe path in bundle: '../evil.png'"),
    "absolute_path": (lambda: _edit({"/abs.png": _PNG}), "unsafe path in bundle: '/abs.png'"),
    "backslash_path": (lambda: _edit({"frames\\000009.png": _PNG}), "unsafe path in bundle"),
    "drive_letter_path": (lambda: _edit({"C:/evil.png": _PNG}), "unsafe path in bundle"),
}
BROKEN_CASES: tuple[str, ...] = tuple(_CASES)


def broken_bundle(case: str) -> tuple[bytes, str]:
    """(zip bytes, fragment of the expected BundleError message) for one name of BROKEN_CASES."""
    build, fragment = _CASES[case]
    made = build()
    return (made if isinstance(made, bytes) else zip_bytes(made)), fragment
