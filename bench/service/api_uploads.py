"""The upload-throughput part of ``signmap bench api`` (issue 15): N distinct journey bundles of
about M MB each, built in memory, sent by the bench's concurrent clients while the worker(s) run
the jobs they queue; reported: uploads accepted per second, MB/s, latency per upload, errors, and
that each accepted upload ended ``done``, ``failed`` or waiting for its camera exactly once.

A bundle is a straight drive (no turn, a camera no journey calibrated) so its job parks it within
seconds, waiting for its camera: the bench measures the API taking uploads in, not the pipeline. Its frames
are 720p JPEGs of the size a real dash cam writes (~320 KB), so the API validates (decodes) about
as many pixels per MB as for a real upload; the bundles differ only in manifest.json's vehicle_id,
which is enough for the content-addressed store to keep each one.
"""

from __future__ import annotations

import io
import json
import math
import re
import tempfile
import zipfile
from pathlib import Path

import cv2
import numpy as np

from app.pipeline.bundle import check_bundle
from app.pipeline.geometry.geodesy import frame_at
from app.settings import Settings
from bench.paper.tables import md_table

MB = 2**20  # as SIGNMAP_MAX_UPLOAD_MB counts
KIND = "upload (big)"
CAMERA_ID = "bench-api-big"  # never calibrated in a bench run: its straight journeys cannot borrow
FRAME_W, FRAME_H = 1280, 720
JPEG_QUALITY = 90
FRAME_DT_S, SPEED_M_S = 0.1, 10.0
# Away from the seeded map's box and the rendered journeys' world; a fixed heading, so no turn.
ORIGIN_LAT, ORIGIN_LON, ALT_M = 48.2, 9.2, 300.0
HEADING_DEG = 40.0


def _frame(rng: np.random.Generator) -> bytes:
    # Coarse colour noise scaled up plus fine grain: incompressible for zip, and about as many
    # bytes per pixel as a real 720p dash-cam JPEG (pure noise would be 2.5x larger per pixel and
    # so understate the API's decoding work per MB).
    coarse = rng.integers(0, 256, (FRAME_H // 8, FRAME_W // 8, 3), dtype=np.uint8)
    image = cv2.resize(coarse, (FRAME_W, FRAME_H), interpolation=cv2.INTER_CUBIC).astype(np.int16)
    image += rng.normal(0, 4, image.shape).astype(np.int16)
    ok, data = cv2.imencode(".jpg", np.clip(image, 0, 255).astype(np.uint8),
                            [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    assert ok
    return data.tobytes()


def frames(total_bytes: int, seed: int = 0) -> list[bytes]:
    """Distinct JPEG frames until they hold ``total_bytes`` (at least 2: a track needs two)."""
    rng = np.random.default_rng(seed)
    out: list[bytes] = []
    while len(out) < 2 or sum(map(len, out)) < total_bytes:
        out.append(_frame(rng))
    return out


def gps_csv(n_frames: int) -> bytes:
    """One fix per frame on a straight line at a constant speed."""
    s_m = SPEED_M_S * FRAME_DT_S * np.arange(n_frames)
    xyz_enu = np.column_stack([s_m * math.sin(math.radians(HEADING_DEG)),
                               s_m * math.cos(math.radians(HEADING_DEG)), np.zeros(n_frames)])
    lat, lon, _ = frame_at(ORIGIN_LAT, ORIGIN_LON, ALT_M).to_geodetic(xyz_enu)
    rows = [f"{i:06d},{i * FRAME_DT_S:.3f},{lat[i]:.9f},{lon[i]:.9f},{ALT_M:.1f}"
            for i in range(n_frames)]
    return ("frame,timestamp_s,lat,lon,alt_m\n" + "\n".join(rows) + "\n").encode()


def detections_csv(n_frames: int) -> bytes:
    """One stop sign growing as it is approached over the first (up to) ten frames."""
    rows = [f"{i:06d},0,stop,{900 + 8 * i},{300 - 4 * i},{930 + 12 * i},{330 + 4 * i},0.9"
            for i in range(min(n_frames, 10))]
    return ("frame,track_id,class,x1,y1,x2,y2,score\n" + "\n".join(rows) + "\n").encode()


def manifest(vehicle_id: str) -> bytes:
    return json.dumps({"format": "signmap-journey/1", "camera_id": CAMERA_ID,
                       "vehicle_id": vehicle_id, "captured_at": "2026-11-25T08:00:00Z",
                       "camera_prior": None}).encode()


def _zip(jpegs: list[bytes], tables: dict[str, bytes], vehicle_id: str) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        z.writestr("manifest.json", manifest(vehicle_id), zipfile.ZIP_DEFLATED)
        for name, data in tables.items():
            z.writestr(name, data, zipfile.ZIP_DEFLATED)
        for i, data in enumerate(jpegs):  # stored: deflate cannot shrink a JPEG, only cost CPU
            z.writestr(f"frames/{i:06d}.jpg", data, zipfile.ZIP_STORED)
    return out.getvalue()


def big_bundles(n: int, mb: float, seed: int = 0) -> list[bytes]:
    """``n`` valid straight-journey bundles of about ``mb`` MB each, all different bytes."""
    jpegs = frames(int(mb * MB), seed)
    tables = {"gps.csv": gps_csv(len(jpegs)), "detections.csv": detections_csv(len(jpegs))}
    return [_zip(jpegs, tables, f"bench-big-{i}") for i in range(n)]


def n_frames(bundle: bytes) -> int:
    with zipfile.ZipFile(io.BytesIO(bundle)) as z:
        return sum(name.startswith("frames/") for name in z.namelist())


def check_limits(bundle: bytes, settings: Settings) -> None:
    """Raise unless ``bundle`` passes the API's own checks under ``settings``: ValueError over the
    upload size, BundleError over a bundle limit (frames, pixels, unpacked bytes, ...). So a bench
    whose bundles a limit rejects stops here with the reason, not as N upload errors."""
    if len(bundle) > settings.max_upload_mb * MB:
        raise ValueError(f"a big upload of {len(bundle) / MB:.1f} MB is over "
                         f"SIGNMAP_MAX_UPLOAD_MB={settings.max_upload_mb}")
    with tempfile.TemporaryDirectory(prefix="signmap-bench-big-") as tmp:
        path = Path(tmp) / "bundle.zip"
        path.write_bytes(bundle)
        check_bundle(path, settings.bundle)


_VALIDATED = re.compile(r"journey (\S+) queued: .* validated in ([0-9.]+) s")


def validation_s(log_text: str, ids: set[str]) -> list[float]:
    """The API's own validation time (check_bundle) of each of ``ids``, from its log."""
    return [float(s) for journey_id, s in _VALIDATED.findall(log_text) if journey_id in ids]


def summary(latencies_s: list[float], errors: int, accepted_bytes: int, accepted: int,
            seconds: float, validated_s: list[float]) -> dict:
    """The phase's figures: throughput over its wall time, latency per upload in ms."""
    ms = np.array(latencies_s) * 1000 if latencies_s else np.zeros(1)
    return {"n": len(latencies_s), "accepted": accepted, "errors": errors,
            "seconds": round(seconds, 2),
            "uploads_per_s": round(accepted / seconds, 2) if seconds else 0.0,
            "mb_per_s": round(accepted_bytes / MB / seconds, 1) if seconds else 0.0,
            "p50_ms": round(float(np.percentile(ms, 50)), 1),
            "p95_ms": round(float(np.percentile(ms, 95)), 1),
            "max_ms": round(float(ms.max()), 1),
            "validate_p50_s": round(float(np.median(validated_s)), 2) if validated_s else None}


def lost(jobs: dict) -> int:
    return len(jobs["missing"]) + len(jobs["unfinished"])


def markdown(runs: list[dict], names: dict[str, str], options: dict) -> str:
    """One row per backend, then what became of the uploads."""
    runs = [r for r in runs if r.get("uploads")]
    if not runs:
        return ""
    rows, notes = [], []
    for run in runs:
        u, j = run["uploads"], run["uploads"]["jobs"]
        s = u["stats"]
        rows.append([names[run["backend"]], s["n"], s["accepted"], s["errors"], s["seconds"],
                     s["uploads_per_s"], s["mb_per_s"], s["p50_ms"], s["p95_ms"], s["max_ms"],
                     s["validate_p50_s"], j["done"], j["failed"], j.get("waiting", 0), lost(j)])
        notes.append(f"{names[run['backend']]}: every job had ended {u['drain_s']} s after the "
                     f"last answer (polled once a second: 0.0 = already at the first look); "
                     f"load average {u['loadavg'][0]} before, {u['loadavg'][1]} after; "
                     f"not ended exactly once in the job logs: {len(j['ended_not_once'])}; "
                     f"retried (attempts > 1): {len(j['attempts_not_1'])}; duplicate rows: "
                     f"{j['duplicate_rows']}. Failure reasons: "
                     + "; ".join(f"{n} x \"{r}\"" for r, n in j["failure_reasons"].items()))
    header = ["backend", "uploads", "accepted", "errors", "s", "uploads/s", "MB/s", "p50 ms",
              "p95 ms", "max ms", "validation p50 s", "done", "failed", "waiting", "lost"]
    mb = runs[0]["uploads"]["mb_each"]
    return "\n".join([
        f"## Upload throughput: {options['big_uploads']} uploads of {mb} MB, "
        f"{options['clients']} clients", "",
        f"Distinct straight journeys ({runs[0]['uploads']['frames_each']} frames of "
        f"{FRAME_W}x{FRAME_H} JPEG each) sent after the load above had drained, while the "
        f"worker(s) run the jobs they queue (each fails fast: no turn). uploads/s and MB/s: "
        f"accepted uploads over the wall time from the first request to the last answer; latency "
        f"per upload, whole request (sending {mb} MB, hashing, validation with every frame "
        f"decoded, storing); validation: the API's own check_bundle time, from its log.", "",
        md_table(header, rows), "", *[n + "\n" for n in notes]])
