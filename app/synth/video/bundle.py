"""A frames bundle (rendered, or a real drive's) turned into the video bundle a dash cam fleet
uploads: ``video.mp4`` + ``gps.nmea`` | ``gps.gpx`` | ``gps.csv``, detections by frame index.

Clocks: the frames bundle's first frame is at ``start_utc`` on the GPS's clock (UTC). The camera's
clock runs ``clock_error_s`` ahead, so the video's ``creation_time`` is ``start_utc +
clock_error_s`` and the offset the service must find (seconds to add to video time to get GPS
time) is ``-clock_error_s`` relative to what ``creation_time`` claims. An MP4 stores
``creation_time`` in whole seconds: give ``start_utc + clock_error_s`` on a whole second, or the
claim is the truncated one.
"""

from __future__ import annotations

import csv
import io
import json
import tempfile
import zipfile
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path

import cv2
import numpy as np

from app.synth.video.encode import write_video
from app.synth.video.gps_logs import gpx_track, nmea_log

DEFAULT_START_UTC = datetime(2024, 5, 1, 12, 0, 0, tzinfo=timezone.utc)


@dataclass(frozen=True)
class FramesJourney:
    """What a frames bundle holds, in its own clock: ``frame_t_s`` (N,) per frame; fixes
    ``fix_t_s`` (M,), ``lat_deg``, ``lon_deg``, ``alt_m`` (M,); entry names of the frames."""

    manifest: dict
    frame_names: list[str]
    frame_t_s: np.ndarray
    fix_t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    detections_csv: str | None


def read_frames_journey(z: zipfile.ZipFile) -> FramesJourney:
    """A frames bundle whose ``gps.csv`` times every frame (the synthetic ones, KITTI's)."""
    frames = sorted(n for n in z.namelist() if n.startswith("frames/") and n.count("/") == 1
                    and n.rsplit(".", 1)[-1] in ("png", "jpg", "jpeg"))
    frame_t: dict[str, float] = {}
    fixes = []
    for row in csv.DictReader(io.StringIO(z.read("gps.csv").decode())):
        t = float(row["timestamp_s"])
        if row.get("frame"):
            frame_t[row["frame"]] = t
        if row.get("lat"):
            alt = row.get("alt_m") or "nan"
            fixes.append((t, float(row["lat"]), float(row["lon"]), float(alt)))
    stems = [n.split("/")[1].rsplit(".", 1)[0] for n in frames]
    fix = np.array(sorted(fixes))
    dets = z.read("detections.csv").decode() if "detections.csv" in z.namelist() else None
    return FramesJourney(json.loads(z.read("manifest.json")), frames,
                         np.array([frame_t[s] for s in stems]), fix[:, 0], fix[:, 1], fix[:, 2],
                         fix[:, 3], dets)


def _resample(j: FramesJourney, rate_hz: float | None, t0_s: float):
    """Fixes at ``rate_hz`` on whole seconds of the GPS clock (a receiver's epochs), or as given."""
    if rate_hz is None:
        return j.fix_t_s, j.lat_deg, j.lon_deg, j.alt_m
    step = 1.0 / rate_hz
    first = np.ceil((j.fix_t_s[0] - t0_s) / step) * step + t0_s
    t = np.arange(first, j.fix_t_s[-1] + 1e-9, step)
    return t, *(np.interp(t, j.fix_t_s, v) for v in (j.lat_deg, j.lon_deg, j.alt_m))


def _renumbered_detections(text: str, stems: list[str]) -> str:
    """``frame`` = the stem's position in the frames (the video's presentation index)."""
    index = {s: f"{i:06d}" for i, s in enumerate(stems)}
    rows = list(csv.reader(io.StringIO(text)))
    col = rows[0].index("frame")
    for row in rows[1:]:
        row[col] = index[row[col]]
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue()


def video_bundle(frames_zip: Path, out_zip: Path, *, gps_format: str = "nmea",
                 gps_rate_hz: float | None = 1.0, clock_error_s: float = 0.0,
                 declare_offset: bool = False, start_utc: datetime = DEFAULT_START_UTC,
                 with_detections: bool = True) -> Path:
    """Write ``out_zip``: the frames of ``frames_zip`` as ``video.mp4`` and its GPS as
    ``gps_format`` ("nmea", "gpx", "csv" or "none") at ``gps_rate_hz`` (None: the fixes as
    given). ``declare_offset``: the manifest states the true offset."""
    with zipfile.ZipFile(frames_zip) as z, tempfile.TemporaryDirectory() as tmp:
        j = read_frames_journey(z)
        t0 = float(j.frame_t_s[0])

        def frames():
            for name in j.frame_names:
                yield cv2.imdecode(np.frombuffer(z.read(name), np.uint8), cv2.IMREAD_COLOR)

        video = write_video(frames(), j.frame_t_s, Path(tmp) / "video.mp4",
                            creation_utc=start_utc + timedelta(seconds=clock_error_s))
        manifest = {k: v for k, v in j.manifest.items() if k != "captured_at"}
        if declare_offset:
            manifest["gps_time_offset_s"] = -clock_error_s
        t, lat, lon, alt = _resample(j, gps_rate_hz, t0)
        out_zip.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(out_zip, "w", zipfile.ZIP_DEFLATED) as out:
            out.writestr("manifest.json", json.dumps(manifest, indent=2))
            out.write(video, "video.mp4", compress_type=zipfile.ZIP_STORED)
            gps_start = start_utc + timedelta(seconds=float(t[0]) - t0)
            if gps_format == "nmea":
                out.writestr("gps.nmea", nmea_log(gps_start, t - t[0], lat, lon, alt))
            elif gps_format == "gpx":
                out.writestr("gps.gpx", gpx_track(gps_start, t - t[0], lat, lon, alt))
            elif gps_format == "csv":
                rows = "".join(f",{ti - t0:.3f},{la:.9f},{lo:.9f},{al:.3f}\n"
                               for ti, la, lo, al in zip(t, lat, lon, alt))
                out.writestr("gps.csv", "frame,timestamp_s,lat,lon,alt_m\n" + rows)
            if with_detections and j.detections_csv:
                stems = [n.split("/")[1].rsplit(".", 1)[0] for n in j.frame_names]
                out.writestr("detections.csv", _renumbered_detections(j.detections_csv, stems))
    return out_zip
