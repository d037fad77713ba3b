"""Load benchmark of the admin dashboard: a SQLite database with 1,000 journeys and 100,000 signs,
then each page timed through the real app (TestClient, signed in).

    python -m bench.service.admin_load [--journeys 1000] [--signs 100000] [--repeat 5] [--out DIR]

Prints the median and worst time per page. The map is timed through the dashboard's pass-through to
the public GET /api/v1/signs, for a street-sized viewport and a city-sized one.
"""

from __future__ import annotations

import argparse
import secrets
import statistics
import tempfile
import time
import uuid
from datetime import timedelta
from pathlib import Path

import numpy as np
from sqlalchemy import insert

from app.service.db.session import session_scope, upgrade
from app.service.db.models import (STATUSES, CalibrationRow, JourneyRow, JourneySignRow, MapSignRow,
                                MapSignMemberRow, utc_now)
from app.settings import Settings

LAT0, LON0 = 49.0, 8.4
CITY_DEG = 0.1  # signs spread over ~11 x 7 km


def _status(i: int) -> str:
    # One of each at the newest end, then 90 % done and 10 % failed.
    return STATUSES[i % 4] if i < 4 else ("failed" if i % 10 == 9 else "done")


def fill(url: str, n_journeys: int, n_signs: int, seed: int = 0) -> list[str]:
    """Journeys of 20 cameras in every status; ``n_signs`` signs shared among the done ones, which
    also carry a calibration. Returns the ids, oldest first."""
    rng = np.random.default_rng(seed)
    n_done = sum(_status(i) == "done" for i in range(n_journeys))
    per_done = -(-n_signs // max(1, n_done))
    now = utc_now()
    journeys, signs, calibrations, ids = [], [], [], []
    for i in range(n_journeys):
        journey_id = str(uuid.uuid4())
        ids.append(journey_id)
        status = _status(n_journeys - 1 - i)
        camera = f"cam-{i % 20:02d}"
        created = now - timedelta(minutes=n_journeys - i)
        done = status == "done"
        signs_per_journey = min(per_done, n_signs - len(signs)) if done else 0
        journeys.append(dict(
            id=journey_id, camera_id=camera, bundle_sha256=secrets.token_hex(32),
            bundle_bytes=50_000_000, status=status, stage="done" if done else "calibrate",
            progress=1.0 if done else 0.3, n_frames=600, n_signs=signs_per_journey if done else None,
            error="no turn found" if status == "failed" else None, attempts=1,
            created_at=created, started_at=created, finished_at=created + timedelta(seconds=300),
            timings_s={"total_s": 300.0} if done else None))
        if not done:
            continue
        calibrations.append(dict(
            camera_id=camera, journey_id=journey_id, width=1280, height=720,
            fx=float(900 + rng.normal(0, 5)), fy=float(900 + rng.normal(0, 5)), cx=640.0, cy=360.0,
            k1=-0.1, k2=0.01, n_images=40, n_registered=40, reprojection_error_px=0.5,
            rotation_deg=90.0, created_at=created))
        lat = LAT0 + rng.uniform(0, CITY_DEG * 0.66, signs_per_journey)
        lon = LON0 + rng.uniform(0, CITY_DEG, signs_per_journey)
        for k in range(signs_per_journey):
            signs.append(dict(
                id=f"{journey_id}:{k}", journey_id=journey_id, track_id=str(k),
                cls=("stop", "yield", "speed_50", "no_entry")[k % 4], lat_deg=float(lat[k]),
                lon_deg=float(lon[k]), alt_m=110.0, x_enu_m=0.0, y_enu_m=0.0, z_enu_m=0.0,
                std_m=0.3, reprojection_rms_px=0.8,
                observations=[{"frame": f"{f:06d}", "x": 1.0, "y": -0.5, "z": 12.0,
                               "box": [600, 300, 630, 330]} for f in range(k, k + 3)]))
    # The fused map, at its largest: one map sign per journey sign.
    map_signs = [dict(id=f"ms-{n:012d}", cls=s["cls"], lat_deg=s["lat_deg"], lon_deg=s["lon_deg"],
                      alt_m=s["alt_m"], cov_enu=[[0.09, 0, 0], [0, 0.09, 0], [0, 0, 0.09]],
                      std_m=0.3, n_journeys=1, n_observations=3, first_seen_at=now,
                      last_seen_at=now, state=("new", "confirmed", "possibly_removed")[n % 3],
                      evidence={"weights": {s["id"]: 1.0}, "outliers": []}, created_at=now,
                      updated_at=now) for n, s in enumerate(signs)]
    members = [dict(map_sign_id=m["id"], journey_sign_id=s["id"], weight=1.0)
               for m, s in zip(map_signs, signs)]
    with session_scope(url) as session:
        session.execute(insert(JourneyRow), journeys)
        session.execute(insert(CalibrationRow), calibrations)
        for table, rows in ((JourneySignRow, signs), (MapSignRow, map_signs), (MapSignMemberRow, members)):
            for start in range(0, len(rows), 10_000):
                session.execute(insert(table), rows[start:start + 10_000])
    return ids


def timed(client, path: str, repeat: int, headers: dict | None = None
          ) -> tuple[float, float, int]:
    """Median and worst seconds, and the answer's size in bytes."""
    times, size = [], 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        answer = client.get(path, headers=headers)
        times.append(time.perf_counter() - t0)
        assert answer.status_code == 200, (path, answer.status_code, answer.text[:200])
        size = len(answer.content)
    return statistics.median(times), max(times), size


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--journeys", type=int, default=1000)
    parser.add_argument("--signs", type=int, default=100_000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--out", default=None, help="data dir to keep (default: a temp dir)")
    args = parser.parse_args(argv)
    from fastapi.testclient import TestClient

    from app.commands.service import create_service_app

    data_dir = Path(args.out or tempfile.mkdtemp(prefix="signmap-admin-load-"))
    admin_key = secrets.token_urlsafe(16)
    settings = Settings(data_dir=data_dir, admin_key=admin_key, embedded_worker=False)
    upgrade(settings.effective_database_url)
    t0 = time.perf_counter()
    ids = fill(settings.effective_database_url, args.journeys, args.signs)
    print(f"filled {len(ids)} journeys and {args.signs} signs in {time.perf_counter() - t0:.1f} s "
          f"({data_dir})")
    done_id = ids[-5]  # the newest done one
    street = f"{LON0 + 0.05:.4f},{LAT0 + 0.03:.4f},{LON0 + 0.053:.4f},{LAT0 + 0.032:.4f}"
    city = f"{LON0:.4f},{LAT0:.4f},{LON0 + CITY_DEG:.4f},{LAT0 + CITY_DEG:.4f}"
    pages = {
        "journeys, page 1": "/admin/journeys",
        "journeys, page 20": "/admin/journeys?page=20",
        "journeys, failed of cam-09": "/admin/journeys?status=failed&camera=cam-09",
        "progress.json (50 ids)": "/admin/journeys/progress.json?ids=" + ",".join(ids[-50:]),
        "journey page (a done journey)": f"/admin/journeys/{done_id}",
        "cameras": "/admin/cameras",
        "map page": "/admin/map",
        "map query, street viewport": f"/admin/api/signs?bbox={street}&limit=2000",
        "map query, city viewport": f"/admin/api/signs?bbox={city}&limit=2000",
    }
    with TestClient(create_service_app(settings)) as client:
        client.post("/admin/login", data={"key": admin_key})
        print(f"{'page':32s} {'median ms':>10s} {'max ms':>8s} {'kB':>7s}")
        for name, path in pages.items():
            median_s, worst_s, size = timed(client, path, args.repeat)
            print(f"{name:32s} {median_s * 1e3:10.1f} {worst_s * 1e3:8.1f} {size / 1e3:7.1f}")
        # The same city query straight to the public API: what the pass-through adds.
        median_s, worst_s, size = timed(client, f"/api/v1/signs?bbox={city}&limit=2000",
                                        args.repeat, {"Authorization": f"Bearer {admin_key}"})
        print(f"{'  (direct GET /api/v1/signs)':32s} {median_s * 1e3:10.1f} {worst_s * 1e3:8.1f} "
              f"{size / 1e3:7.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
