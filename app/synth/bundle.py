"""Files of a synthetic journey: the contract's bundle (manifest, frames, GPS as CSV, GPX or EXIF,
detections) and the ground truth (``truth.json``)."""

from __future__ import annotations

import csv
import io
import json
import os
import zipfile
from dataclasses import asdict
from datetime import datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING
from xml.etree import ElementTree as ET

import cv2
import numpy as np
import piexif

from app.pipeline.geometry.facing import bearing_deg
from app.pipeline.types import Detection

if TYPE_CHECKING:
    from app.synth.journey import SynthJourney  # type only: journey imports this module

GPX_NS = "http://www.topografix.com/GPX/1/1"
# Bumped whenever the same SynthConfig renders different files: caches of bundles key on it.
GENERATOR_VERSION = "2"  # 2: mip levels sampled where cv2.pyrDown puts them


def gps_csv(frame_ids, timestamps_s, lat_deg, lon_deg, alt_m) -> str:
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["frame", "timestamp_s", "lat", "lon", "alt_m"])
    for row in zip(frame_ids, timestamps_s, lat_deg, lon_deg, alt_m):
        w.writerow([row[0], f"{row[1]:.3f}", f"{row[2]:.9f}", f"{row[3]:.9f}", f"{row[4]:.3f}"])
    return out.getvalue()


def gps_csv_async(frame_ids, frame_timestamps_s, fix_timestamps_s, lat_deg, lon_deg,
                  alt_m) -> str:
    """The contract's asynchronous form: a timestamp-only row per frame, a frame-less row per fix,
    in time order (a frame before a fix at the same time)."""
    rows = [(t, 0, [fid, f"{t:.3f}", "", "", ""]) for fid, t in zip(frame_ids, frame_timestamps_s)]
    rows += [(t, 1, ["", f"{t:.3f}", f"{la:.9f}", f"{lo:.9f}", f"{al:.3f}"])
             for t, la, lo, al in zip(fix_timestamps_s, lat_deg, lon_deg, alt_m)]
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["frame", "timestamp_s", "lat", "lon", "alt_m"])
    for _, _, row in sorted(rows, key=lambda r: (r[0], r[1])):
        w.writerow(row)
    return out.getvalue()


def gps_gpx(start: datetime, timestamps_s, lat_deg, lon_deg, alt_m) -> str:
    """One track point per frame, timed ``start + timestamp_s``."""
    ET.register_namespace("", GPX_NS)
    gpx = ET.Element(f"{{{GPX_NS}}}gpx", version="1.1", creator="signmap-synth")
    seg = ET.SubElement(ET.SubElement(gpx, f"{{{GPX_NS}}}trk"), f"{{{GPX_NS}}}trkseg")
    for t, lat, lon, alt in zip(timestamps_s, lat_deg, lon_deg, alt_m):
        pt = ET.SubElement(seg, f"{{{GPX_NS}}}trkpt", lat=f"{lat:.9f}", lon=f"{lon:.9f}")
        ET.SubElement(pt, f"{{{GPX_NS}}}ele").text = f"{alt:.3f}"
        ET.SubElement(pt, f"{{{GPX_NS}}}time").text = _iso(start + timedelta(seconds=float(t)))
    return ET.tostring(gpx, encoding="unicode", xml_declaration=True)


def detections_csv(dets: list[Detection]) -> str:
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["frame", "track_id", "class", "x1", "y1", "x2", "y2", "score"])
    for d in dets:
        w.writerow([d.frame_id, d.track_id, d.cls, f"{d.x1:.2f}", f"{d.y1:.2f}", f"{d.x2:.2f}",
                    f"{d.y2:.2f}", "" if d.score is None else f"{d.score:.3f}"])
    return out.getvalue()


def _rational_dms(deg: float) -> tuple[tuple[int, int], ...]:
    deg = abs(deg)
    d = int(deg)
    m = int((deg - d) * 60)
    s = (deg - d - m / 60.0) * 3600.0
    return ((d, 1), (m, 1), (int(round(s * 1_000_000)), 1_000_000))


def exif_gps(when: datetime, lat_deg: float, lon_deg: float, alt_m: float) -> bytes:
    """EXIF with the GPS position and the capture time (to the millisecond)."""
    gps = {
        piexif.GPSIFD.GPSVersionID: (2, 3, 0, 0),
        piexif.GPSIFD.GPSLatitudeRef: b"N" if lat_deg >= 0 else b"S",
        piexif.GPSIFD.GPSLatitude: _rational_dms(lat_deg),
        piexif.GPSIFD.GPSLongitudeRef: b"E" if lon_deg >= 0 else b"W",
        piexif.GPSIFD.GPSLongitude: _rational_dms(lon_deg),
        piexif.GPSIFD.GPSAltitudeRef: 0 if alt_m >= 0 else 1,
        piexif.GPSIFD.GPSAltitude: (int(round(abs(alt_m) * 1000)), 1000),
        piexif.GPSIFD.GPSTimeStamp: ((when.hour, 1), (when.minute, 1),
                                     (when.second * 1000 + when.microsecond // 1000, 1000)),
        piexif.GPSIFD.GPSDateStamp: when.strftime("%Y:%m:%d").encode(),
    }
    exif = {
        piexif.ExifIFD.DateTimeOriginal: when.strftime("%Y:%m:%d %H:%M:%S").encode(),
        piexif.ExifIFD.SubSecTimeOriginal: f"{when.microsecond // 1000:03d}".encode(),
    }
    return piexif.dump({"0th": {}, "Exif": exif, "GPS": gps, "1st": {}, "thumbnail": None})


def _iso(t: datetime) -> str:
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def _start_time(captured_at: str) -> datetime:
    t = datetime.fromisoformat(captured_at)
    return t.replace(tzinfo=None) - (t.utcoffset() or timedelta(0))


def manifest(j: "SynthJourney") -> dict:
    cfg = j.config
    m = {"format": "signmap-journey/1", "camera_id": cfg.effective_camera_id(),
         "vehicle_id": cfg.vehicle_id, "captured_at": cfg.captured_at,
         "camera_prior": None if cfg.camera_prior is None else cfg.camera_prior.params()}
    if cfg.gps_antenna_offset_declared and any(v != 0.0 for v in cfg.gps_antenna_offset_m):
        m["gps_antenna_offset_m"] = dict(zip(("forward", "left", "up"),
                                             map(float, cfg.gps_antenna_offset_m)))
    return {k: v for k, v in m.items() if v is not None or k == "camera_prior"}


def truth(j: "SynthJourney") -> dict:
    """Ground truth: the camera, the true poses, the signs with their true positions and their
    camera-frame positions in the frames that detected them."""
    cfg = j.config
    lat, lon, alt = j.origin.to_geodetic(np.array([s.centre_enu for s in j.signs]).reshape(-1, 3))
    observations: dict[int, list] = {k: [] for k in range(len(j.signs))}
    for det, view in zip(j.detections, j.views):
        observations[view.sign_index].append(
            {"frame": det.frame_id, "x": float(view.p_cam[0]), "y": float(view.p_cam[1]),
             "z": float(view.p_cam[2]), "box_true": [round(float(b), 3) for b in view.box_px]})
    config = asdict(cfg)
    config["camera"] = {"width": cfg.camera.width, "height": cfg.camera.height,
                        **cfg.camera.params()}
    config["camera_prior"] = None if cfg.camera_prior is None else cfg.camera_prior.params()
    return {
        "format": "signmap-synth-truth/1",
        "generator_version": GENERATOR_VERSION,
        "origin": {"lat": j.origin.lat0_deg, "lon": j.origin.lon0_deg, "alt_m": j.origin.alt0_m},
        "camera": config["camera"],
        "camera_id": cfg.effective_camera_id(),
        "world": asdict(j.world.spec),
        "config": config,
        "frames": [{"frame": fid, "timestamp_s": float(t), "s_m": float(s),
                    "T_world_cam": np.round(T, 9).tolist()}
                   for fid, t, s, T in zip(j.frame_ids, j.timestamps_s, j.s_m, j.T_world_cam)],
        "signs": [{"id": s.sign_id, "track_id": tid, "class": s.cls, "shape": s.shape,
                   "size_m": s.size_m, "xyz_enu": [float(x) for x in s.centre_enu],
                   "facing_deg": bearing_deg(s.normal_enu),
                   "lat": float(la), "lon": float(lo), "alt_m": float(al),
                   "observations": observations[k]}
                  for k, (s, tid, la, lo, al)
                  in enumerate(zip(j.signs, j.track_ids, lat, lon, alt))],
        "removed_signs": list(cfg.removed_signs),
        # Detections in detections.csv that are not of any sign, and true ones the detector missed.
        "false_detections": [_det_truth(d) for d in j.false_detections],
        "missed_detections": [_det_truth(d) for d in j.missed_detections],
        **({} if j.gps_timestamps_s is None else {"gps_fixes": [
            {"timestamp_s": float(t), "true_enu": [round(float(x), 6) for x in true],
             "enu": [round(float(x), 6) for x in noisy]}
            for t, true, noisy in zip(j.gps_timestamps_s, j.gps_true_enu, j.gps_enu)]}),
    }


def _det_truth(d: Detection) -> dict:
    return {"frame": d.frame_id, "track_id": d.track_id, "class": d.cls,
            "box": [round(v, 3) for v in (d.x1, d.y1, d.x2, d.y2)]}


def _encode(j: "SynthJourney", i: int, image: np.ndarray, start: datetime) -> bytes:
    cfg = j.config
    if cfg.frame_format() == "png":
        ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        return buf.tobytes()
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, cfg.jpeg_quality])
    if cfg.gps_format != "exif":
        return buf.tobytes()
    when = start + timedelta(seconds=float(j.timestamps_s[i]))
    out = io.BytesIO()
    piexif.insert(exif_gps(when, float(j.lat_deg[i]), float(j.lon_deg[i]), float(j.alt_m[i])),
                  buf.tobytes(), out)
    return out.getvalue()


def _all_detections(j: "SynthJourney") -> list[Detection]:
    if not j.false_detections:
        return j.detections
    order = {fid: i for i, fid in enumerate(j.frame_ids)}
    return sorted(j.detections + j.false_detections, key=lambda d: order[d.frame_id])


def write_journey(j: "SynthJourney", out_dir: Path) -> Path:
    """Render every frame into ``out_dir/bundle.zip``; write ``out_dir/truth.json``."""
    cfg = j.config
    out_dir.mkdir(parents=True, exist_ok=True)
    bundle = out_dir / "bundle.zip"
    tmp = out_dir / "bundle.zip.part"
    start = _start_time(cfg.captured_at)
    ext = cfg.frame_format()
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("manifest.json", json.dumps(manifest(j), indent=2))
        for i, image in enumerate(j.frames()):
            # Compressed images gain nothing from deflate.
            z.writestr(f"frames/{j.frame_ids[i]}.{ext}", _encode(j, i, image, start),
                       compress_type=zipfile.ZIP_STORED)
        if cfg.gps_format == "csv" and j.gps_timestamps_s is not None:
            z.writestr("gps.csv", gps_csv_async(j.frame_ids, j.timestamps_s, j.gps_timestamps_s,
                                                j.lat_deg, j.lon_deg, j.alt_m))
        elif cfg.gps_format == "csv":
            z.writestr("gps.csv", gps_csv(j.frame_ids, j.timestamps_s, j.lat_deg, j.lon_deg,
                                          j.alt_m))
        elif cfg.gps_format == "gpx":
            z.writestr("gps.gpx", gps_gpx(start, j.timestamps_s, j.lat_deg, j.lon_deg, j.alt_m))
        if cfg.with_detections:
            z.writestr("detections.csv", detections_csv(_all_detections(j)))
    os.replace(tmp, bundle)
    (out_dir / "truth.json").write_text(json.dumps(truth(j), indent=1))
    return bundle
