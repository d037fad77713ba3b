"""Two hosts, simulated (issue 15): the API and two real ``signmap worker`` processes each have a
data directory of their own and share only PostgreSQL, Redis and the object store (moto's S3
server, a real HTTP endpoint). Two fleets upload the same rendered journey (two journeys, one
stored object); the worker running the first is SIGKILLed mid-job and the other worker finishes
both journeys, each exactly once.

The camera's calibration is seeded as an earlier journey would leave it, so that the straight
journey skips self-calibration (about 30 s a run instead of 90 on 2 cores), and the journey is the
straight one's first 60 frames: what is tested is where each host's runs go, not the mapping."""

from __future__ import annotations

import hashlib
import secrets
import signal
import time
from pathlib import Path

import pytest
from sqlalchemy import func, select

from app.pipeline.types import CameraModel
from app.service.db.session import session_scope
from app.service.db.models import JourneySignRow
from tests.e2e.test_fusion_rendered import seed_calibration
from tests.utils.backends import SESSION_TAG, s3_objects
from tests.utils.journeys import first_frames
from tests.utils.stack import CeleryWorker, Stack, auth, make_settings, upload

pytestmark = [pytest.mark.postgres, pytest.mark.slow]
TIMEOUT_S = 240


def _files(data_dir: Path) -> list[str]:
    return sorted(str(p.relative_to(data_dir)) for p in data_dir.rglob("*") if p.is_file())


def _poll(client, headers: dict, ids: list[str], until, what: str,
          workers: list[CeleryWorker]) -> list[dict]:
    deadline = time.monotonic() + TIMEOUT_S
    while True:
        bodies = [client.get(f"/api/v1/journeys/{i}", headers=headers).json() for i in ids]
        if until(bodies):
            return bodies
        for worker in workers:
            if worker.proc.poll() is not None:
                pytest.fail(f"a worker exited ({worker.proc.returncode}): "
                            f"{worker.log_path.read_text()[-3000:]}")
        if time.monotonic() > deadline:
            pytest.fail(f"not {what} after {TIMEOUT_S} s: "
                        f"{[(b['status'], b['stage']) for b in bodies]}")
        time.sleep(0.5)


def test_a_killed_hosts_job_is_finished_by_the_other_host(own_pg_url, redis_url, s3_storage_url,
                                                          straight_journey_bundle, tmp_path):
    bundle, truth = straight_journey_bundle
    data = first_frames(bundle, 60, tmp_path / "first-60.zip").read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    shared = dict(database_url=own_pg_url, broker_url=redis_url, storage_url=s3_storage_url,
                  celery_queue=f"signmap_test_{SESSION_TAG}_{secrets.token_hex(3)}",
                  heartbeat_s=1.0, stale_after_s=10.0)  # a dead worker's job is found in seconds
    api = Stack("postgres", make_settings(tmp_path / "api", **shared))
    worker_dirs = [tmp_path / "worker-1", tmp_path / "worker-2"]
    seed_calibration(own_pg_url, truth["camera_id"], CameraModel(**truth["camera"]))
    workers = [CeleryWorker(make_settings(d, **shared), tmp_path / f"{d.name}.log")
               for d in worker_dirs]
    fleets = [api.key("fleet"), api.key("fleet")]
    admin = auth(api.key("admin"))
    try:
        with api.client() as client:
            ids = [upload(client, fleet, data) for fleet in fleets]
            # The first journey seen running past its extract: the bundle is in that host's scratch.
            bodies = _poll(client, admin, ids, what="running past extract", workers=workers,
                           until=lambda bs: any(b["status"] == "running" and b["stage"] not in (
                               None, "start", "extract") for b in bs))
            victim_id = next(b["id"] for b in bodies if b["status"] == "running"
                             and b["stage"] not in (None, "start", "extract"))
            fetched = [d for d in worker_dirs if (d / "work" / f"{victim_id}-1" / f"{sha}.zip")
                       .is_file()]
            assert len(fetched) == 1, [_files(d) for d in worker_dirs]
            k = worker_dirs.index(fetched[0])
            victim, survivor = workers[k], workers[1 - k]
            assert victim.kill(signal.SIGKILL) == -signal.SIGKILL

            bodies = _poll(client, admin, ids, what="finished", workers=[survivor],
                           until=lambda bs: all(b["status"] in ("done", "failed") for b in bs))
    finally:
        for worker in workers:
            worker.stop()

    by_id = {b["id"]: b for b in bodies}
    assert [b["status"] for b in bodies] == ["done", "done"], [b["error"] for b in bodies]
    assert {i: by_id[i]["attempts"] for i in ids} == {i: 2 if i == victim_id else 1 for i in ids}
    assert {b["calibration_source"] for b in bodies} == {"supplied"}
    assert "its worker stopped beating; sent again" in survivor.log_path.read_text()
    with session_scope(api.url) as session:
        for journey_id in ids:
            rows = session.scalars(select(JourneySignRow.id)
                                   .where(JourneySignRow.journey_id == journey_id)).all()
            assert len(rows) == len(set(rows)) == by_id[journey_id]["n_signs"] >= 1
        assert session.scalar(select(func.count()).select_from(JourneySignRow)) == \
            sum(b["n_signs"] for b in bodies)  # stored once each: no duplicate of the rerun

    # What each host keeps: the store has the one bundle; the API host nothing; the surviving
    # worker nothing (its runs' scratch is gone); the killed one only its interrupted run's scratch.
    assert s3_objects(s3_storage_url) == {f"bundles/{sha}.zip": data}
    assert _files(tmp_path / "api") == []
    assert _files(worker_dirs[1 - k]) == []
    left = _files(worker_dirs[k])
    assert f"work/{victim_id}-1/{sha}.zip" in left
    assert all(f.startswith(f"work/{victim_id}-1/") for f in left), left
