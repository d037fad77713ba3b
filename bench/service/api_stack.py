"""The service under ``signmap bench api``: a real ``signmap serve`` process on a free port of
127.0.0.1 (SQLite with the embedded worker, or PostgreSQL + Redis with a real ``signmap worker``
process), a seeded map, keys, the bundles it is sent, and the database's account of the uploads."""

from __future__ import annotations

import io
import json
import re
import secrets
import zipfile
from collections import Counter
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import Iterator

import numpy as np
from sqlalchemy import func, insert, select

from app.pipeline.types import CameraModel
from app.service.auth import create_key
from app.service.db.session import session_scope, temporary_database, upgrade
from app.service.db.models import (WAITING_FOR_CAMERA, JourneyRow, JourneySignRow, MapSignRow,
                                   utc_now)
from app.settings import Settings
from app.synth.journey import SynthConfig
from bench.service.serve import child_env, serve, signmap_child
from bench.paper.suite import JourneySpec, ensure_journey, quick_suite

# The seeded map: signs spread over a city-sized box, away from the rendered journeys' world.
CITY = (9.0, 48.0, 9.1, 48.07)  # minlon, minlat, maxlon, maxlat
STREET = (9.0, 48.0, 9.004, 48.003)
# A straight road of a small camera: accepted at upload, then parked within seconds by the job
# ("the journey has no turn"), so many uploads can run through a 2-core machine.
STRAIGHT = JourneySpec("api-straight-30", SynthConfig(
    n_frames=30, turns=0, world_seed=5, seed=5, camera_id="bench-api-straight",
    camera=CameraModel(310, 94, 239.8, 238.2, 173.6, 60.4, -0.369, 0.158)),
    ("ours",), "30 small frames, no turn: fails fast")


@dataclass
class Service:
    backend: str
    base_url: str
    settings: Settings
    fleet_key: str
    reader_key: str
    logs: list[Path]


@contextmanager
def _redis_queue(redis_url: str, queue: str) -> Iterator[None]:
    import redis

    client = redis.Redis.from_url(redis_url)
    client.ping()
    try:
        yield
    finally:
        for key in client.scan_iter(f"*{queue}*"):
            client.delete(key)
        client.close()


@contextmanager
def running_service(backend: str, run_dir: Path, postgres_url: str, redis_url: str,
                    n_map_signs: int) -> Iterator[Service]:
    """The API (and for ``postgres`` a Celery worker) as real processes on a fresh database."""
    tag = secrets.token_hex(4)
    (run_dir / "data").mkdir(parents=True, exist_ok=True)
    with ExitStack() as stack:
        # The load comes from one fleet key on purpose: its per-key upload limits are off.
        values = dict(data_dir=run_dir / "data", admin_key=secrets.token_urlsafe(24),
                      log_level="INFO", upload_limit_count_per_min=0, upload_limit_bytes_per_min=0)
        if backend == "postgres":
            values.update(database_url=stack.enter_context(
                temporary_database(postgres_url, f"signmap_bench_api_{tag}")),
                broker_url=redis_url, celery_queue=f"signmap_bench_api_{tag}")
            stack.enter_context(_redis_queue(redis_url, values["celery_queue"]))
        settings = Settings(**values)
        upgrade(settings.effective_database_url)
        seed_map(settings.effective_database_url, n_map_signs)
        with session_scope(settings.effective_database_url) as session:
            fleet, reader = create_key(session, "fleet", "bench"), create_key(session, "reader")
        logs = [run_dir / f"{backend}-api.log"]
        base_url = stack.enter_context(serve(child_env(settings), logs[0]))
        if backend == "postgres":
            logs.append(run_dir / f"{backend}-worker.log")
            stack.enter_context(signmap_child(["worker", "--hostname", f"bench-{tag}@%h"],
                                                child_env(settings), logs[1]))
        yield Service(backend, base_url, settings, fleet, reader, logs)


def seed_map(url: str, n: int, seed: int = 0) -> None:
    """``n`` fused signs over the city box (what a map reader reads while uploads come in)."""
    rng = np.random.default_rng(seed)
    now = utc_now()
    lon = rng.uniform(CITY[0], CITY[2], n)
    lat = rng.uniform(CITY[1], CITY[3], n)
    rows = [dict(id=f"ms-bench-{i:08d}", cls=("stop", "yield", "speed_50")[i % 3],
                 lat_deg=float(lat[i]), lon_deg=float(lon[i]), alt_m=110.0,
                 cov_enu=[[0.09, 0, 0], [0, 0.09, 0], [0, 0, 0.09]], std_m=0.3, n_journeys=1,
                 n_observations=3, first_seen_at=now - timedelta(days=1), last_seen_at=now,
                 state="confirmed", evidence={}, created_at=now, updated_at=now)
            for i in range(n)]
    with session_scope(url) as session:
        for start in range(0, len(rows), 5000):
            session.execute(insert(MapSignRow), rows[start:start + 5000])


def bundles(cache_dir: Path, with_turn: bool = True) -> tuple[bytes, bytes]:
    """(a rendered journey with a turn that really gets processed, or b"" without ``with_turn``;
    the fail-fast straight one), rendered once into ``cache_dir`` (the turn journey is the quick
    bench suite's)."""
    turn = ensure_journey(quick_suite()[0], cache_dir)[0].read_bytes() if with_turn else b""
    return turn, ensure_journey(STRAIGHT, cache_dir)[0].read_bytes()


def variant(bundle: bytes, vehicle_id: str) -> bytes:
    """``bundle`` with another vehicle_id in its manifest: other bytes, so a new upload."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(bundle)) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "manifest.json":
                data = json.dumps({**json.loads(data), "vehicle_id": vehicle_id}).encode()
            dst.writestr(info, data)
    return out.getvalue()


def journey_states(url: str, ids: set[str]) -> dict[str, str]:
    """Journey id -> status, ``waiting`` for a journey parked until its camera is calibrated."""
    with session_scope(url) as session:
        rows = session.execute(select(JourneyRow.id, JourneyRow.status, JourneyRow.stage)
                               .where(JourneyRow.id.in_(ids))).all()
    return {i: _state(status, stage) for i, status, stage in rows}


def _state(status: str, stage: str | None) -> str:
    return "waiting" if status == "queued" and stage == WAITING_FOR_CAMERA else status


def account(service: Service, accepted: Counter, repeats: dict[str, set[str]]) -> dict:
    """What the database and the logs say became of the accepted uploads (journey id -> 202
    answers: a re-upload of a failed journey queues it again): each must exist once, end done,
    failed or waiting for its camera (the straight ones: no turn, a camera nobody calibrated), have
    ended once per 202 in the job logs (and its last run be its first attempt), a
    done one with as many sign rows as it says; re-uploads of the same bytes must name one
    journey."""
    url = service.settings.effective_database_url
    ids = set(accepted)
    with session_scope(url) as session:
        rows = {r.id: r for r in session.scalars(select(JourneyRow).where(JourneyRow.id.in_(ids)))}
        sign_rows = dict(session.execute(
            select(JourneySignRow.journey_id, func.count()).where(JourneySignRow.journey_id.in_(ids))
            .group_by(JourneySignRow.journey_id)).all())
        twins = session.execute(select(JourneyRow.bundle_sha256).group_by(
            JourneyRow.owner_key_id, JourneyRow.bundle_sha256).having(func.count() > 1)).all()
    log_text = "\n".join(p.read_text(errors="replace") for p in service.logs if p.exists())
    endings = Counter()
    for line in log_text.splitlines():
        for journey_id in _ended_id(line):
            endings[journey_id] += 1
    statuses = Counter(_state(r.status, r.stage) for r in rows.values())
    ended = ("done", "failed", "waiting")
    return {
        "accepted": len(ids), "requeued_by_reupload": sum(n - 1 for n in accepted.values()),
        "done": statuses["done"], "failed": statuses["failed"], "waiting": statuses["waiting"],
        "missing": sorted(ids - set(rows)),
        "unfinished": sorted(i for i, r in rows.items() if _state(r.status, r.stage) not in ended),
        "attempts_not_1": sorted(i for i, r in rows.items() if r.attempts != 1),
        "ended_not_once": sorted(i for i in ids if endings[i] != accepted[i]),
        "sign_rows_mismatch": sorted(i for i, r in rows.items() if r.status == "done"
                                     and sign_rows.get(i, 0) != (r.n_signs or 0)),
        "duplicate_rows": len(twins),
        "repeats_split": sorted(sha for sha, ids in repeats.items() if len(ids) != 1),
        # The reasons' first clause: the rest is advice, the same for every journey.
        "failure_reasons": dict(Counter((r.error or "").split(";")[0][:160]
                                        for r in rows.values() if r.status == "failed")),
        "n_signs_done": sum(r.n_signs or 0 for r in rows.values() if r.status == "done"),
    }


_ENDED = re.compile(r"journey (\S+): (?:done in |failed at |internal error during "
                    r"|no turn and no calibration of camera )")


def _ended_id(line: str) -> list[str]:
    """The journey id of a job's last log line (app.service.jobs.run: done, failed or crashed)."""
    return _ENDED.findall(line)

